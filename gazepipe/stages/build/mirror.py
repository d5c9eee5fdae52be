"""Mirroring for data augmentation (SPEC §2 "Mirroring", §3.6; Klein 6.2 "the dataset is mirrored").

Mirroring reflects X of the character frame (+X left, +Y up, +Z forward): M = diag(−1, 1, 1). Positions and
direction vectors negate X, a rotation R becomes M·R·M, left/right pairs swap (eyes, ``…Left``/``…Right``
blendshapes, left/right markers and segments), yaw and roll angles negate and pitch stays.

Every function here except :func:`mirror_markers` only negates and permutes numbers, so mirroring twice gives
back the input bit for bit (NaN included). :func:`mirror_markers` reflects lab-frame positions about a plane of
arbitrary orientation, which rounds (a few 1e-13 mm); twice is the identity to that precision.
Pure, vectorised functions; no file I/O.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Iterable, Mapping
from dataclasses import replace

import numpy as np

from gazepipe.arkit import EYE_NAMES, HEAD_NAMES, mirror_face
from gazepipe.errors import StageError
from gazepipe.model import Markers, MarkerSet
from gazepipe.stages.frames.stage import Joints, character_frame
from gazepipe.stages.geometry import from_wxyz

__all__ = [
    "marker_pairs",
    "mirror_eyes",
    "mirror_face",
    "mirror_joints",
    "mirror_markers",
    "mirror_quat",
    "mirror_six",
    "mirror_vectors",
    "mirror_yaw_pitch",
    "mirror_yaw_pitch_roll",
]

Pairs = Mapping[str, str] | Iterable[tuple[str, str]]


def _negate(a: np.ndarray, cols: tuple[int, ...], width: int, what: str) -> np.ndarray:
    """Copy of ``a`` (..., width) with the given last-axis columns negated (a sign-bit flip: exact, NaN too)."""
    a = np.asarray(a)
    if a.ndim == 0 or a.shape[-1] != width:
        raise ValueError(f"{what} must have a last axis of {width}, got shape {a.shape}")
    out = a.copy()
    idx = list(cols)
    out[..., idx] = np.negative(out[..., idx])
    return out


def mirror_vectors(v: np.ndarray) -> np.ndarray:
    """Mirror positions or directions (..., 3) in the character frame: negate X (mm or unitless)."""
    return _negate(v, (0,), 3, "vectors")


def mirror_quat(q: np.ndarray) -> np.ndarray:
    """Mirror rotations given as quaternions (..., 4) ``w, x, y, z``: the quaternion of M·R·M.

    Proof: M·R·M = (−M)·R·(−M) and −M = diag(1, −1, −1) is the half turn about X, q_x = (0, 1, 0, 0), so the
    result is q_x·q·q_x⁻¹ = (w, x, −y, −z). ``w`` is untouched, so a canonical (w ≥ 0) input stays canonical.
    """
    return _negate(q, (2, 3), 4, "quaternions")


def mirror_six(s: np.ndarray) -> np.ndarray:
    """Mirror the 6-number form (..., 6) (forward R·ẑ, then up R·ŷ): negate the X of both vectors.

    M·R·M·ẑ = M·(R·ẑ) because M·ẑ = ẑ, and likewise for ŷ.
    """
    return _negate(s, (0, 3), 6, "6-number rotations")


def mirror_yaw_pitch(angles: np.ndarray) -> np.ndarray:
    """Mirror gaze angles (..., 2) ``yaw, pitch`` (SPEC §2 convention, Ry(yaw)·Rx(−pitch)): yaw negates."""
    return _negate(angles, (0,), 2, "yaw/pitch angles")


_ANGLE_LAYOUTS: dict[int, tuple[str, ...]] = {3: HEAD_NAMES, 6: EYE_NAMES, 9: HEAD_NAMES + EYE_NAMES}


def mirror_yaw_pitch_roll(angles: np.ndarray, names: Iterable[str] | None = None) -> np.ndarray:
    """Mirror Live Link Face head and eye angles: yaw and roll negate, pitch stays, the eye blocks swap.

    Parameters
    ----------
    angles : (..., D) radians. Without ``names`` the last axis is one of: 3 = one ``yaw, pitch, roll`` block
        (the head); 6 = the left eye's block then the right eye's (:data:`gazepipe.arkit.EYE_NAMES`);
        9 = head, left eye, right eye.
    names : optional channel names of the last axis (any spelling :func:`gazepipe.arkit.normalise_name`
        accepts), for other layouts; may include blendshapes.

    The work is done by :func:`gazepipe.arkit.mirror_face`, so angles and blendshapes follow one rule.
    Exact involution.
    """
    a = np.asarray(angles)
    if names is None:
        width = a.shape[-1] if a.ndim else 0
        if width not in _ANGLE_LAYOUTS:
            raise ValueError(f"angles must have a last axis of 3, 6 or 9 without names, got shape {a.shape}")
        names = _ANGLE_LAYOUTS[width]
    return mirror_face(a, tuple(names))


def mirror_eyes(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mirror per-eye directions (..., 3) in the character frame: ``(mirror(right), mirror(left))``.

    The mirrored subject's left eye is the reflection of the original right eye, and vice versa.
    """
    return mirror_vectors(right), mirror_vectors(left)


# ------------------------------------------------------------------------------------------ left/right names

def _swap_words(s: str) -> str:
    table = {"Left": "Right", "Right": "Left", "LEFT": "RIGHT", "RIGHT": "LEFT", "left": "right", "right": "left"}
    return re.sub(r"Left|Right|LEFT|RIGHT|left|right", lambda m: table[m.group(0)], s)


def _swap_letter_tokens(s: str) -> str:
    table = {"L": "R", "R": "L", "l": "r", "r": "l"}
    return re.sub(r"(?<![A-Za-z0-9])[LRlr](?![A-Za-z0-9])", lambda m: table[m.group(0)], s)


def _swap_prefix(s: str) -> str:
    if len(s) >= 2 and (s[0] in "LR" or (s[0] in "lr" and (s[1].isupper() or s[1].isdigit()))):
        return {"L": "R", "R": "L", "l": "r", "r": "l"}[s[0]] + s[1:]
    return s


def _swap_suffix(s: str) -> str:
    if len(s) >= 2 and s[-1] in "LR":
        return s[:-1] + {"L": "R", "R": "L"}[s[-1]]
    return s


# in priority order; each is an involution on strings
_RULES = (_swap_words, _swap_letter_tokens, _swap_prefix, _swap_suffix)


def marker_pairs(labels: Iterable[str]) -> dict[str, str]:
    """Left/right pairs among ``labels`` by naming convention.

    Rules, in priority order (case-sensitive; a label pairs only with a label that is also present):

    1. the words ``Left``/``Right``, ``LEFT``/``RIGHT``, ``left``/``right`` anywhere (``LeftHand`` ↔
       ``RightHand``, ``LEFT_KNEE`` ↔ ``RIGHT_KNEE``);
    2. a single letter ``L``/``R`` or ``l``/``r`` standing alone between separators or the ends
       (``HF_L`` ↔ ``HF_R``, ``l_ankle`` ↔ ``r_ankle``);
    3. a leading ``L``/``R`` (``LASI`` ↔ ``RASI``), or a leading ``l``/``r`` before a capital or digit
       (``lKnee`` ↔ ``rKnee``);
    4. a trailing ``L``/``R`` (``HFL`` ↔ ``HFR``).

    Rules apply to the whole label set one after the other; a label paired by an earlier rule is not
    paired again. A label left unpaired although some rule names a present partner (that partner is taken,
    e.g. ``LHL``, ``RHL``, ``LHR``) is ambiguous: :class:`~gazepipe.errors.StageError`; pass explicit pairs.

    Returns
    -------
    dict mapping every paired label to its partner (both directions). Unpaired labels are absent.
    """
    labels = list(labels)
    present = set(labels)
    out: dict[str, str] = {}
    for rule in _RULES:
        for a in labels:
            if a in out:
                continue
            b = rule(a)
            if b != a and b in present and b not in out and rule(b) == a:
                out[a] = b
                out[b] = a
    for a in labels:
        if a in out:
            continue
        named = sorted({r(a) for r in _RULES} & present - {a})
        if named:
            raise StageError(None, f"ambiguous left/right marker name {a!r}: its partner by name "
                             f"({', '.join(map(repr, named))}) is already paired; give the pairs explicitly")
    return out


def _normalise_pairs(pairs: Pairs, labels: list[str], path: str | None) -> dict[str, str]:
    items = pairs.items() if isinstance(pairs, Mapping) else pairs
    out: dict[str, str] = {}
    for a, b in items:
        for x in (a, b):
            if x not in labels:
                raise StageError(path, f"mirror pair ({a!r}, {b!r}): {x!r} is not in the capture")
        if a == b or out.get(a, b) != b or out.get(b, a) != a:
            raise StageError(path, f"mirror pair ({a!r}, {b!r}) conflicts with another pair")
        out[a], out[b] = b, a
    return out


def _char_matrices(char_rot: np.ndarray, n: int) -> np.ndarray:
    """Lab-from-character matrices (n, 3, 3) from (n, 4) ``w, x, y, z`` or (n, 3, 3); NaN rows stay NaN."""
    r = np.asarray(char_rot, dtype=np.float64)
    if r.shape == (n, 3, 3):
        return r
    if r.shape != (n, 4):
        raise ValueError(f"char_rot must be ({n}, 4) quaternions or ({n}, 3, 3) matrices, got {r.shape}")
    out = np.full((n, 3, 3), np.nan)
    ok = np.isfinite(r).all(axis=1)
    if ok.any():
        out[ok] = from_wxyz(r[ok]).as_matrix()
    return out


def mirror_markers(markers: Markers, markerset: MarkerSet, char_origin: np.ndarray | None = None,
                   char_rot: np.ndarray | None = None, *, pairs: Pairs | None = None,
                   take: str | None = None) -> Markers:
    """Mirror lab-frame markers about the character's sagittal plane, frame by frame, swapping left/right.

    Each frame is reflected about the plane through the character frame's origin spanned by its up and forward
    axes: p' = p − 2·((p − o)·x̂)·x̂, x̂ = the frame's +X (left) axis in lab coordinates, which is M applied in
    character coordinates. Then the data of every left/right pair swap columns (labels keep their order), so
    the mirrored subject's left marker is again on its left.

    Parameters
    ----------
    markers : positions in mm, lab frame.
    markerset : the session's markerset (root marker and root segment).
    char_origin, char_rot : that take's character frame per frame, (T, 3) mm and (T, 4) ``w, x, y, z`` or
        (T, 3, 3) lab-from-character, as from :func:`gazepipe.stages.frames.stage.character_frame` or
        :class:`~gazepipe.stages.frames.stage.Joints`; computed from ``markers`` when omitted.
    pairs : explicit left/right pairs (a mapping or (a, b) tuples), replacing :func:`marker_pairs`.

    Frames without a character frame cannot be mirrored: every marker there becomes NaN and invalid.
    The character frame of the result equals the input's (its origin is the unpaired root marker, its heading
    the root segment's left − right pair, which the mirror maps onto itself).

    Raises
    ------
    StageError : the root segment's first two markers are not a pair (the mirrored heading would flip), the
        root marker is paired, or pairs are ambiguous or name absent markers.
    """
    labels = list(markers.labels)
    path = markerset.path
    rs = markerset.root_segment
    for m in (markerset.root, *rs.markers[:2]):
        if m not in labels:
            what = "root" if m == markerset.root else "root segment"
            raise StageError(path, f"mirroring: {what} marker {m!r} is not in the capture", take=take)
    try:
        partner = marker_pairs(labels) if pairs is None else _normalise_pairs(pairs, labels, path)
    except StageError as e:
        raise StageError(path, e.problem, take=take) from None
    m0, m1 = (rs.markers + ("", ""))[:2]
    if partner.get(m0) != m1:
        raise StageError(path, f"mirroring: the root segment {rs.name!r}'s first two markers ({m0!r}, {m1!r}) "
                         "must be a left/right pair, or the mirrored heading flips", take=take)
    if markerset.root in partner:
        raise StageError(path, f"mirroring: the root marker {markerset.root!r} must not be a left/right marker "
                         f"(paired with {partner[markerset.root]!r})", take=take)

    n = markers.n_frames
    if char_origin is None or char_rot is None:
        char_origin, cmat = character_frame(markers, markerset, path=path, take=take)
    else:
        cmat = _char_matrices(char_rot, n)
    origin = np.asarray(char_origin, dtype=np.float64)
    if origin.shape != (n, 3):
        raise ValueError(f"char_origin must be ({n}, 3), got {origin.shape}")
    ok = np.isfinite(origin).all(axis=1) & np.isfinite(cmat).all(axis=(1, 2))
    x_axis = cmat[:, :, 0]                                               # (T, 3) the character's left, lab
    d = markers.xyz - origin[:, None, :]
    refl = markers.xyz - 2.0 * np.einsum("tmi,ti->tm", d, x_axis)[..., None] * x_axis[:, None, :]

    perm = np.array([labels.index(partner.get(lab, lab)) for lab in labels], dtype=np.int64)
    xyz = np.where(ok[:, None, None], refl, np.nan)[:, perm]
    valid = (markers.valid & ok[:, None])[:, perm] & np.isfinite(xyz).all(axis=2)
    return replace(markers, labels=list(labels), xyz=xyz, valid=valid,
                   model_outputs=list(markers.model_outputs), warnings=list(markers.warnings))


def mirror_joints(joints: Joints, segment_pairs: Pairs | None = None) -> Joints:
    """Mirror the frames stage's output (SPEC §2): an exact involution.

    ``quat`` and ``quat_local`` become M·R·M (:func:`mirror_quat`). For the local rotation this is again
    conjugation: (M·P·M)⁻¹·(M·G·M) = M·P⁻¹·G·M since M⁻¹ = M. ``six`` by :func:`mirror_six`;
    ``head_centre`` and ``target_dir`` negate X. ``char_origin``, ``char_rot`` and ``valid`` stay: the
    character frame is the mirror plane itself. Segments whose names form left/right pairs
    (:func:`marker_pairs` rules, or ``segment_pairs``) swap columns; central segments stay.

    Note: with ``eye_offset_mm`` (no head-centre marker) the mirror of the eyes' centre is the head centroid
    plus M·offset, which differs from re-running the frames stage on mirrored markers unless the offset's X
    is 0.
    """
    names = list(joints.segments)
    try:
        partner = marker_pairs(names) if segment_pairs is None else _normalise_pairs(segment_pairs, names, None)
    except StageError as e:
        raise StageError(None, f"segments: {e.problem}") from None
    perm = np.array([names.index(partner.get(s, s)) for s in names], dtype=np.int64)
    parents = np.asarray(joints.parents)
    mapped = np.where(parents >= 0, perm[np.maximum(parents, 0)], -1)
    if not np.array_equal(parents[perm], mapped):
        raise StageError(None, "segments: a left/right segment pair has parents that are not mirror images")
    return Joints(
        segments=names,
        parents=parents.copy(),
        quat=mirror_quat(joints.quat[:, perm]),
        quat_local=mirror_quat(joints.quat_local[:, perm]),
        six=mirror_six(joints.six[:, perm]),
        head_centre=mirror_vectors(joints.head_centre),
        target_dir=mirror_vectors(joints.target_dir),
        char_origin=np.array(joints.char_origin, copy=True),
        char_rot=np.array(joints.char_rot, copy=True),
        valid=np.array(joints.valid, copy=True),
        rot_filled=None if joints.rot_filled is None else np.array(joints.rot_filled)[:, perm],
        rot_measured=None if joints.rot_measured is None else np.array(joints.rot_measured)[:, perm],
        rate_hz=joints.rate_hz,
        first_frame=joints.first_frame,
        qc=copy.deepcopy(joints.qc),
    )
