"""The 52 ARKit face blendshapes, the head and eye angle channels, and name normalisation.

Canonical names are ARKit's camelCase spelling (``eyeBlinkLeft``, ``jawOpen``), in the order of Apple's
``ARFaceAnchor.BlendShapeLocation`` documentation: left eye, right eye, mouth and jaw, eyebrows, cheeks, nose,
tongue. "Left" and "right" are the face's own left and right (ARKit: ``eyeBlinkRight`` is the face's right eye).

Files spell the same channels differently: Live Link Face writes PascalCase (``EyeBlinkLeft``), ARKit's own raw
keys use ``_L`` / ``_R`` suffixes (``eyeBlink_L``), Live Link Face swaps the order of ``JawLeft``/``JawRight`` and
``MouthLeft``/``MouthRight``. :func:`normalise_name` maps all of these to the canonical name; readers always return
channels in :data:`ARKIT_NAMES` order, never in file order.
"""

from __future__ import annotations

import re

import numpy as np

#: The 52 ARKit blendshapes, canonical spelling and order (values are coefficients in [0, 1]).
ARKIT_NAMES: tuple[str, ...] = (
    # left eye
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft",
    "eyeSquintLeft", "eyeWideLeft",
    # right eye
    "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight",
    # mouth and jaw
    "jawForward", "jawLeft", "jawRight", "jawOpen",
    "mouthClose", "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight",
    "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthUpperUpLeft", "mouthUpperUpRight",
    # eyebrows
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight",
    # cheeks
    "cheekPuff", "cheekSquintLeft", "cheekSquintRight",
    # nose
    "noseSneerLeft", "noseSneerRight",
    # tongue
    "tongueOut",
)

#: Head rotation channels (radians), as written by Live Link Face.
HEAD_NAMES: tuple[str, ...] = ("headYaw", "headPitch", "headRoll")

#: Eye rotation channels (radians): the face's left eye, then the right eye.
EYE_NAMES: tuple[str, ...] = (
    "leftEyeYaw", "leftEyePitch", "leftEyeRoll", "rightEyeYaw", "rightEyePitch", "rightEyeRoll",
)

#: Every channel this module knows, canonical spelling.
ALL_NAMES: tuple[str, ...] = ARKIT_NAMES + HEAD_NAMES + EYE_NAMES

# lower-case, separator-free spelling -> canonical name
_TABLE: dict[str, str] = {n.lower(): n for n in ALL_NAMES}
_SUFFIX = re.compile(r"_([lr])$", re.IGNORECASE)


def _key(name: str) -> str:
    s = name.strip()
    s = _SUFFIX.sub(lambda m: "left" if m.group(1).lower() == "l" else "right", s)
    return s.replace("_", "").replace(" ", "").replace("-", "").lower()


def normalise_name(name: str) -> str | None:
    """Canonical ARKit spelling of a channel name, or ``None`` when it is not an ARKit channel.

    Accepts camelCase, PascalCase, any case, ``_L``/``_R`` suffixes and ``_``/``-``/space separators.
    """
    return _TABLE.get(_key(name))


def _partner(name: str) -> str:
    """The mirror partner of a canonical name (itself for unpaired channels)."""
    for a, b in (("Left", "Right"), ("Right", "Left")):
        if name.endswith(a):
            return name[: -len(a)] + b
    for a, b in (("left", "right"), ("right", "left")):
        if name.startswith(a):
            return b + name[len(a):]
    return name


def mirror_permutation(names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Column permutation and sign flips that mirror a table of face channels (SPEC §2).

    Mirroring swaps every ``…Left``/``…Right`` blendshape and the left/right eye rotations, and negates yaw and
    roll (pitch stays). ``mirrored[:, j] = sign[j] * values[:, perm[j]]``; both arrays are involutions, so
    mirroring twice is the identity.

    Parameters
    ----------
    names : channel names (any spelling :func:`normalise_name` accepts).

    Returns
    -------
    perm : (D,) int64 source column of every output column.
    negate : (D,) bool, True where the output column is negated.
    """
    canon = []
    for n in names:
        c = normalise_name(n)
        if c is None:
            raise ValueError(f"not an ARKit face channel: {n!r}")
        canon.append(c)
    if len(set(canon)) != len(canon):
        raise ValueError("duplicate face channels")
    where = {c: i for i, c in enumerate(canon)}
    perm = np.empty(len(canon), dtype=np.int64)
    for j, c in enumerate(canon):
        p = _partner(c)
        if p not in where:
            raise ValueError(f"cannot mirror {c!r}: its partner {p!r} is absent")
        perm[j] = where[p]
    negate = np.array([c.endswith(("Yaw", "Roll")) for c in canon], dtype=bool)
    return perm, negate


def mirror_face(values: np.ndarray, names: list[str] | tuple[str, ...]) -> np.ndarray:
    """Mirror face channels (SPEC §2): swap ``…Left``/``…Right`` and left/right eyes, negate yaw and roll.

    Parameters
    ----------
    values : (..., D) array whose last axis follows ``names`` (blendshapes, head and eye angles, or their
        derivatives).
    names : the D channel names (any spelling :func:`normalise_name` accepts).

    Returns
    -------
    A new array of the same shape and dtype. Mirroring twice gives back ``values`` exactly.
    """
    values = np.asarray(values)
    if values.shape[-1] != len(names):
        raise ValueError(f"{len(names)} names for {values.shape[-1]} columns")
    perm, negate = mirror_permutation(names)
    out = values[..., perm]
    out[..., negate] = np.negative(out[..., negate])
    return out
