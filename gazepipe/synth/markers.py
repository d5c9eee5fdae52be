"""From a take's motion to marker trajectories: forward kinematics, eye directions, noise and occlusions."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.synth.motion import EYE_LIMIT_DEG, FORWARD, HEAD, TakeMotion
from gazepipe.synth.skeleton import (
    CLAPPER_MARKERS,
    ELBOW_SHOULDER,
    HALF_IPD_MM,
    HEAD_CENTRE_MARKER,
    JOINTS_MM,
    ROOT_MARKER,
    SEGMENT_MARKERS,
    SEGMENTS,
    SHOULDER_JOINT_BELOW_MM,
    TARGET_MARKER,
    UNLISTED_MARKERS,
    Placement,
    head_centre_offset,
    subject_marker_layout,
)


@dataclass
class Kinematics:
    """Noise-free kinematics of a take.

    ``q_char0[k]``: segment k's rotation relative to the neutral pose in the initial character axes (T stack);
    the lab rotation is ``h_lab * q_char0[k]``. Eye directions are unit vectors in the initial character axes
    (``eye_in_head``: head axes). Positions are lab millimetres.
    """

    labels: list[str]
    markers_true: np.ndarray          # (T, M, 3)
    h_lab: Rotation
    q_char0: list[Rotation]
    joints_lab: np.ndarray            # (T, S, 3)
    eye_dir_char0: np.ndarray         # (T, 3) cyclopean gaze
    eye_in_head: np.ndarray           # (T, 3)
    eye_left_char0: np.ndarray        # (T, 3)
    eye_right_char0: np.ndarray       # (T, 3)


def clamp_cone(v: np.ndarray, limit_rad: float) -> np.ndarray:
    """Rotate each unit vector (T, 3) toward +Z so that it lies within ``limit_rad`` of +Z."""
    cr = np.cross(np.broadcast_to(FORWARD, v.shape), v)
    sn = np.linalg.norm(cr, axis=1)
    ang = np.arctan2(sn, v[:, 2])
    axis = np.where(sn[:, None] > 1e-12, cr / np.maximum(sn, 1e-12)[:, None], np.array([1.0, 0.0, 0.0]))
    clamped = Rotation.from_rotvec(axis * np.minimum(ang, limit_rad)[:, None]).apply(FORWARD)
    return np.where((ang > limit_rad)[:, None], clamped, v)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def build_kinematics(motion: TakeMotion, placement: Placement, segments: tuple[str, ...] = SEGMENTS) -> Kinematics:
    """Forward kinematics of the chain, the noise-free position of every marker on ``segments``, and the eyes."""
    h = placement.h_lab
    n = len(motion.time_s)
    q = []
    acc = Rotation.identity(n)
    for loc in motion.local:
        acc = acc * loc
        q.append(acc)
    joints = np.empty((n, len(SEGMENTS), 3))
    joints[:, 0] = motion.floor_lab + h.apply(JOINTS_MM[0])
    for k in range(1, len(SEGMENTS)):
        joints[:, k] = joints[:, k - 1] + (h * q[k - 1]).apply(JOINTS_MM[k] - JOINTS_MM[k - 1])

    labels, seg, off = subject_marker_layout(segments)
    cols = []
    for m in range(len(labels)):
        cols.append(joints[:, seg[m]] + (h * q[seg[m]]).apply(off[m]))
    if motion.target_lab is not None:
        labels.append(TARGET_MARKER)
        cols.append(motion.target_lab)
    if motion.clapper_lab is not None:
        labels.extend(CLAPPER_MARKERS)
        cols.extend([motion.clapper_lab[:, 0], motion.clapper_lab[:, 1]])
    markers = np.stack(cols, axis=1)

    head_lab = h * q[HEAD]
    hc = joints[:, HEAD] + head_lab.apply(head_centre_offset())
    limit = np.deg2rad(EYE_LIMIT_DEG)
    if motion.gaze_dir_char is not None:
        want = motion.gaze_dir_char
    else:
        want = _unit(h.inv().apply(motion.fixation_lab - hc))
    in_head = clamp_cone(q[HEAD].inv().apply(want), limit)
    eyes = []
    for side in (1.0, -1.0):     # +X of the head is the subject's left
        pos = hc + head_lab.apply([side * HALF_IPD_MM, 0.0, 0.0])
        d = _unit(h.inv().apply(motion.fixation_lab - pos))
        eyes.append(q[HEAD].apply(clamp_cone(q[HEAD].inv().apply(d), limit)))
    return Kinematics(labels=labels, markers_true=markers, h_lab=h, q_char0=q, joints_lab=joints,
                      eye_dir_char0=q[HEAD].apply(in_head), eye_in_head=in_head,
                      eye_left_char0=eyes[0], eye_right_char0=eyes[1])


#: the unlisted markers' own motion (:func:`with_unlisted_markers`): the shoulder blade's reach out, shrug up and
#: reach forward (mm, at most), the upper arm's swing forward and out (degrees, at most) and its usual angle out
SHOULDER_MOTION_MM = (6.0, 20.0, 15.0)
ARM_SWING_DEG = (20.0, 8.0)
ARM_OUT_DEG = 8.0
#: the own motion goes on as the body moves: waves over the body's path (its markers' mean path, mm), so it
#: stops when the subject rests (the rests stay the body's) and looks the same at any capture rate
OWN_WAVELENGTH_MM = (80.0, 400.0)
OWN_WAVES = 6


def _own_motion(rng: np.random.Generator, path_mm: np.ndarray, count: int) -> np.ndarray:
    """(T, count) smooth signals in (−1, 1) over the body's path ``path_mm`` (T,): sums of :data:`OWN_WAVES`
    waves of random wavelength, phase and weight, squashed."""
    lam = rng.uniform(*OWN_WAVELENGTH_MM, size=(OWN_WAVES, count))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(OWN_WAVES, count))
    weight = rng.uniform(0.5, 1.0, size=(OWN_WAVES, count))
    s = (weight[None] * np.sin(2.0 * np.pi * path_mm[:, None, None] / lam[None] + phase[None])).sum(axis=1)
    return np.tanh(s / np.sqrt(0.5 * (weight ** 2).sum(axis=0))[None])


def with_unlisted_markers(rng: np.random.Generator, kin: Kinematics, names: tuple[str, ...], scale: float = 1.0
                          ) -> Kinematics:
    """``kin`` with the markers ``names`` (of :data:`~gazepipe.synth.skeleton.UNLISTED_MARKERS`) added after the
    subject's listed markers (before the target and the clapper).

    A shoulder (``LSHO``, ``RSHO``) rides on the chest and moves against it with its shoulder blade by up to
    :data:`SHOULDER_MOTION_MM`; an elbow (``LELB``, ``RELB``) hangs from that shoulder's joint
    (:data:`~gazepipe.synth.skeleton.SHOULDER_JOINT_BELOW_MM` below the acromion) on an upper arm that swings
    forward and out (:data:`ARM_SWING_DEG`). Both go on only while the body moves (:data:`OWN_WAVELENGTH_MM`).
    ``scale`` multiplies the own motion (the shoulder blade's millimetres and the arm's degrees).
    The signals are drawn for both sides whichever markers are asked for, so a set's shoulders move the same
    with or without its elbows."""
    unknown = [n for n in names if n not in UNLISTED_MARKERS]
    if unknown:
        raise ValueError(f"unknown unlisted marker(s) {', '.join(unknown)} (known: {', '.join(UNLISTED_MARKERS)})")
    subject = [i for i, lab in enumerate(kin.labels) if lab != TARGET_MARKER and lab not in CLAPPER_MARKERS]
    x = kin.markers_true[:, subject]
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(x, axis=0), axis=2).mean(axis=1))])
    own = _own_motion(rng, path, 10).reshape(-1, 2, 5)            # per side (left, right): 3 blade, 2 arm
    chest = SEGMENTS.index("chest")
    to_lab = kin.h_lab * kin.q_char0[chest]
    blade: dict[str, np.ndarray] = {}
    for k, shoulder in enumerate(("LSHO", "RSHO")):
        side = np.sign(UNLISTED_MARKERS[shoulder][0])
        moves = scale * own[:, k, :3] * np.asarray(SHOULDER_MOTION_MM)[None] * np.array([side, 1.0, 1.0])[None]
        blade[shoulder] = np.asarray(UNLISTED_MARKERS[shoulder])[None] + moves
    cols = []
    for name in names:
        if name in blade:
            local = blade[name]
        else:
            shoulder = ELBOW_SHOULDER[name]
            k = ("LSHO", "RSHO").index(shoulder)
            side = np.sign(UNLISTED_MARKERS[name][0])
            joint = np.asarray(UNLISTED_MARKERS[shoulder]) + np.asarray(SHOULDER_JOINT_BELOW_MM)
            arm = Rotation.from_euler("ZX", np.column_stack([
                side * np.deg2rad(ARM_OUT_DEG + scale * ARM_SWING_DEG[1] * own[:, k, 4]),
                np.deg2rad(scale * ARM_SWING_DEG[0]) * own[:, k, 3]]))
            local = blade[shoulder] + np.asarray(SHOULDER_JOINT_BELOW_MM)[None] \
                + arm.apply(np.asarray(UNLISTED_MARKERS[name]) - joint)
        cols.append(kin.joints_lab[:, chest] + to_lab.apply(local))
    at = len(subject)
    markers = np.concatenate([kin.markers_true[:, :at], np.stack(cols, axis=1), kin.markers_true[:, at:]], axis=1)
    return replace(kin, labels=[*kin.labels[:at], *names, *kin.labels[at:]], markers_true=markers)


#: gap length classes in frames (inclusive bounds) and how many of each a long take gets
GAP_CLASSES: tuple[tuple[int, int, int], ...] = ((1, 5, 8), (6, 15, 6), (16, 30, 4), (31, 90, 3), (31, 120, 2))
ROOT_MARKERS = (ROOT_MARKER, *SEGMENT_MARKERS["pelvis"])
MAX_ROOT_GAP = 3


def make_gaps(rng: np.random.Generator, labels: list[str], n: int, kind: str,  # noqa: C901
              clapper_busy: np.ndarray | None) -> np.ndarray:
    """Occlusion mask (T, M) bool, True where a sample is missing.

    Gaps of every length class, sometimes on several markers of one segment at once, one at the very start
    and one at the very end (long takes). The root marker and the pelvis markers only get gaps of at most
    ``MAX_ROOT_GAP`` frames; the clapper never loses a sample while it is in use.
    """
    mask = np.zeros((n, len(labels)), dtype=bool)
    idx = {lab: i for i, lab in enumerate(labels)}
    free = [lab for lab in labels if lab not in ROOT_MARKERS]
    root = [lab for lab in labels if lab in ROOT_MARKERS]

    def place(cols: list[int], length: int, start: int | None = None) -> None:
        length = min(length, n - 1)
        for _ in range(100):
            s = int(rng.integers(0, n - length + 1)) if start is None else start
            if clapper_busy is not None and any(labels[c] in CLAPPER_MARKERS for c in cols) \
                    and clapper_busy[s:s + length].any():
                if start is not None:
                    return
                continue
            mask[s:s + length, cols] = True
            return

    if kind == "gaze_follow" or n > 600:
        scale = max(1.0, n / 1400.0)
        for lo, hi, count in GAP_CLASSES:
            for _ in range(int(round(count * scale))):
                place([idx[str(rng.choice(free))]], int(rng.integers(lo, hi + 1)))
        for _ in range(int(round(3 * scale))):
            place([idx[str(rng.choice(root))]], int(rng.integers(1, MAX_ROOT_GAP + 1)))
        for seg in ("head", "chest", "spine3"):
            names = [lab for lab in SEGMENT_MARKERS[seg] if lab in idx]
            if len(names) < 2:
                continue
            pick = rng.choice(len(names), size=2, replace=False)
            place([idx[names[i]] for i in sorted(pick)], int(rng.integers(6, 40)))
        for _ in range(int(round(2 * scale))):      # something passes in front: markers of several segments
            pick = rng.choice(len(free), size=4, replace=False)
            place([idx[free[i]] for i in sorted(pick)], int(rng.integers(5, 25)))
        place([idx[str(rng.choice(free))]], int(rng.integers(3, 20)), start=0)
        length = int(rng.integers(3, 20))
        place([idx[str(rng.choice(free))]], length, start=n - length)
    elif kind == "gaze_shift":
        place([idx[str(rng.choice(free))]], int(rng.integers(1, 6)))
        place([idx[str(rng.choice(free))]], int(rng.integers(6, 16)))
        if rng.random() < 0.5:
            place([idx[str(rng.choice(free))]], int(rng.integers(16, 31)))
        if rng.random() < 0.4:
            length = int(rng.integers(2, 10))
            start = 0 if rng.random() < 0.5 else n - length
            place([idx[str(rng.choice(free))]], length, start=start)
    else:
        for _ in range(2):
            place([idx[str(rng.choice(free))]], int(rng.integers(1, 6)))
    return mask


#: segments whose markers get the long occlusions of :func:`make_long_gaps` (the trunk and the neck)
LONG_GAP_SEGMENTS = ("spine1", "spine2", "spine3", "spine4", "chest", "neck1", "neck2", "neck3")
#: length of those occlusions, seconds
LONG_GAP_S = (1.0, 3.0)


def make_long_gaps(rng: np.random.Generator, labels: list[str], n: int, rate_hz: float, count: int,
                   per_marker_min: float, rests: np.ndarray, crop: tuple[int, int] | None) -> np.ndarray:
    """The occlusions of a crowded capture volume, as a (T, M) mask to add to :func:`make_gaps`'.

    ``count`` gaps of 1–3 s on trunk and neck markers: the first inside the first rest period (where the
    neutral pose is measured), the next two across the crop's start and end, the rest anywhere; and interior
    gaps of the usual lengths (1–120 frames) on any subject marker but the root's, about ``per_marker_min`` per
    marker per minute (Poisson).
    """
    mask = np.zeros((n, len(labels)), dtype=bool)
    trunk = [i for i, lab in enumerate(labels) if any(lab in SEGMENT_MARKERS[s] for s in LONG_GAP_SEGMENTS)]
    free = [i for i, lab in enumerate(labels)
            if lab not in ROOT_MARKERS and lab != TARGET_MARKER and lab not in CLAPPER_MARKERS]
    anchors: list[int] = []
    if len(rests):
        anchors.append(int(rng.integers(rests[0, 0], max(rests[0, 0] + 1, rests[0, 1]))))
    if crop is not None:
        anchors.extend(crop)
    for k in range(count):
        length = min(n - 1, int(rng.uniform(*LONG_GAP_S) * rate_hz))     # whole frames within 3 s
        if k < len(anchors):
            start = anchors[k] - int(rng.integers(0, length)) if k > 0 else anchors[k]  # straddle a crop edge
        else:
            start = int(rng.integers(0, n - length + 1))
        start = int(np.clip(start, 0, n - length))
        mask[start:start + length, int(rng.choice(trunk))] = True
    weights = np.array([c for _, _, c in GAP_CLASSES], dtype=float)
    for _ in range(int(rng.poisson(per_marker_min * len(free) * n / rate_hz / 60.0))):
        lo, hi, _ = GAP_CLASSES[int(rng.choice(len(GAP_CLASSES), p=weights / weights.sum()))]
        length = min(n - 1, int(rng.integers(lo, hi + 1)))
        start = int(rng.integers(1, max(2, n - length)))       # interior: not at the take's first frame
        mask[start:start + length, int(rng.choice(free))] = True
    return mask


def make_root_rest_gap(rng: np.random.Generator, labels: list[str], n: int, rate_hz: float,
                       rests: np.ndarray) -> np.ndarray:
    """One 0.5–1.5 s gap on a root-segment marker (not the root marker) inside one of the take's rests, as a
    (T, M) mask: the hazard that used to end a rest when rest speeds needed every root-segment marker."""
    mask = np.zeros((n, len(labels)), dtype=bool)
    cols = [i for i, lab in enumerate(labels) if lab in SEGMENT_MARKERS["pelvis"]]
    if not len(rests) or not cols:
        return mask
    a, b = (int(x) for x in rests[int(rng.integers(0, len(rests)))])
    length = min(b - a, int(rng.uniform(0.5, 1.5) * rate_hz))
    if length < 1:
        return mask
    start = int(rng.integers(a, b - length + 1))
    mask[start:start + length, cols[int(rng.integers(0, len(cols)))]] = True
    return mask


def make_root_final_rest_gap(rng: np.random.Generator, labels: list[str], n: int, rate_hz: float,
                             rests: np.ndarray, seconds: float) -> np.ndarray:
    """A gap of ``seconds`` on the root marker itself inside the take's last rest, as a (T, M) mask: starting
    0.5–0.8 s into the rest, so the marker is measured still on both sides when the rest is long enough (the
    caller lengthens it). The hazard of a still subject whose root marker a camera lost for longer than
    ``clean.max_gap_s``: unfilled, it leaves the rest without a character frame."""
    mask = np.zeros((n, len(labels)), dtype=bool)
    if not len(rests) or ROOT_MARKER not in labels:
        return mask
    a, b = (int(x) for x in rests[-1])
    start = a + int(rng.uniform(0.5, 0.8) * rate_hz)
    stop = min(b - 1, start + int(round(seconds * rate_hz)))
    if stop > start:
        mask[start:stop, labels.index(ROOT_MARKER)] = True
    return mask


#: ghost reflections: displacement (mm) and length (frames) of a spike
SPIKE_MM = (15.0, 50.0)
SPIKE_FRAMES = (1, 2)


def make_spikes(rng: np.random.Generator, labels: list[str], gap_mask: np.ndarray, rate_hz: float,
                per_marker_min: float, clapper_busy: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Ghost-reflection spikes: on random measured samples of any marker (the root segment's and the target's
    included; the clapper's only while it is not in use), a displacement of 15–50 mm in a random direction for
    one or two frames. About ``per_marker_min`` spikes per marker per minute (Poisson).

    Returns the (T, M, 3) offsets to add to the measured positions and the (T, M) bool mask of spiked samples.
    """
    n, m = gap_mask.shape
    offsets = np.zeros((n, m, 3))
    spiked = np.zeros((n, m), dtype=bool)
    count = int(rng.poisson(per_marker_min * m * n / rate_hz / 60.0))
    for _ in range(count):
        col = int(rng.integers(0, m))
        length = int(rng.integers(SPIKE_FRAMES[0], SPIKE_FRAMES[1] + 1))
        if n < length + 6:
            break
        start = int(rng.integers(3, n - length - 2))
        rows = slice(start - 2, start + length + 2)      # measured around it, so the spike is on the path
        if gap_mask[rows, col].any() or spiked[rows, col].any():
            continue
        if labels[col] in CLAPPER_MARKERS and clapper_busy is not None and clapper_busy[rows].any():
            continue
        direction = rng.normal(size=3)
        offsets[start:start + length, col] = rng.uniform(*SPIKE_MM) * direction / np.linalg.norm(direction)
        spiked[start:start + length, col] = True
    return offsets, spiked


def gap_runs(mask: np.ndarray) -> np.ndarray:
    """Every run of True per column of a (T, M) mask as rows (marker, start, stop), stop exclusive, int64."""
    rows: list[tuple[int, np.integer, np.integer]] = []
    pad = np.zeros((1, mask.shape[1]), dtype=np.int8)
    d = np.diff(np.vstack([pad, mask.astype(np.int8), pad]), axis=0)
    for m in range(mask.shape[1]):
        starts = np.flatnonzero(d[:, m] == 1)
        stops = np.flatnonzero(d[:, m] == -1)
        rows.extend((m, a, b) for a, b in zip(starts, stops, strict=True))
    return np.array(rows, dtype=np.int64).reshape(-1, 3)


#: how long an auto-labeller keeps two markers' names exchanged, seconds
SWAP_S = (0.3, 3.0)


def swap_pairs(labels: list[str]) -> dict[str, list[tuple[int, int]]]:
    """The marker pairs an auto-labeller exchanges, by kind, as column pairs of ``labels``: ``cluster`` (two
    markers of one segment), ``neighbour`` (the root marker and the nearest pelvis marker, the head centre and
    the nearest head marker: close markers of neighbouring rigid bodies), ``left_right`` (the chest's, else the
    pelvis's, left and right markers, as when the arms cross before the body); with unlisted markers
    (:data:`~gazepipe.synth.skeleton.UNLISTED_MARKERS`), ``mirror`` (the left and right shoulders, the left and
    right elbows: mirror images across the body, in no segment) and ``unlisted`` (a shoulder and its elbow, a
    shoulder and the chest's marker on its side)."""
    idx = {lab: i for i, lab in enumerate(labels)}
    cluster = [(idx[a], idx[b]) for seg in SEGMENT_MARKERS.values() for a in seg for b in seg
               if a in idx and b in idx and idx[a] < idx[b]]
    neighbour = [(idx[a], idx[b]) for a, b in ((ROOT_MARKER, "PEL_B"), (HEAD_CENTRE_MARKER, "HFL"))
                 if a in idx and b in idx]
    left_right = [(idx[a], idx[b]) for a, b in (("CHA", "CHB"), ("PEL_L", "PEL_R")) if a in idx and b in idx][:1]
    mirror = [(idx[a], idx[b]) for a, b in (("LSHO", "RSHO"), ("LELB", "RELB")) if a in idx and b in idx]
    unlisted = [(idx[a], idx[b]) for a, b in (("LSHO", "LELB"), ("RSHO", "RELB"), ("CHA", "LSHO"), ("CHB", "RSHO"))
                if a in idx and b in idx]
    kinds = {"cluster": cluster, "neighbour": neighbour, "left_right": left_right, "mirror": mirror,
             "unlisted": unlisted}
    return {k: v for k, v in kinds.items() if v}


def make_label_swaps(rng: np.random.Generator, labels: list[str], gap_mask: np.ndarray, rate_hz: float,
                     count: int) -> list[tuple[int, int, int, int]]:
    """``count`` label swaps: a kind of :func:`swap_pairs` at random, then a pair of it, exchanged for 0.3–3 s.
    Half of them begin where one of the two markers comes back from a gap, or end where one goes into one
    (the labeller guesses again after an occlusion). Returns ``(first, second, start, stop)`` columns and
    half-open frames; no marker is in two swaps at once."""
    n = gap_mask.shape[0]
    kinds = swap_pairs(labels)
    out: list[tuple[int, int, int, int]] = []
    if not kinds or n < 4:
        return out
    names = sorted(kinds)
    for _ in range(count):
        pairs = kinds[names[int(rng.integers(0, len(names)))]]
        a, b = pairs[int(rng.integers(0, len(pairs)))]
        length = max(2, min(n - 2, int(rng.uniform(*SWAP_S) * rate_hz)))
        start = int(rng.integers(1, n - length))
        if rng.random() < 0.5:          # at a gap's edge
            col = (a, b)[int(rng.integers(0, 2))]
            edges = np.flatnonzero(np.diff(gap_mask[:, col].astype(np.int8)))   # last row before a change
            if edges.size:
                edge = int(edges[int(rng.integers(0, edges.size))]) + 1
                start = edge if gap_mask[edge, col] == 0 else edge - length   # after a gap, or into one
                start = int(np.clip(start, 1, n - length - 1))
        if any({a, b} & {p, q} and start < e and s < start + length for p, q, s, e in out):
            continue                    # one marker in two swaps at once: not what a labeller does
        out.append((a, b, start, start + length))
    return out


def apply_label_swaps(xyz: np.ndarray, mask: np.ndarray, swaps: list[tuple[int, int, int, int]]) -> np.ndarray:
    """Exchange the names of each swap's two markers over its frames, in place: positions (T, M, 3) and the gap
    mask (T, M; an occluded marker stays occluded under either name). Returns the (T, M) bool mask of samples
    written under the wrong name (measured ones only)."""
    swapped = np.zeros(mask.shape, dtype=bool)
    for a, b, s, e in swaps:
        xyz[s:e, [a, b]] = xyz[s:e, [b, a]]
        mask[s:e, [a, b]] = mask[s:e, [b, a]]
        swapped[s:e, [a, b]] = True
    return swapped & ~mask


#: an occlusion burst: how long (s) and what share of the subject's markers it hides at once
BURST_S = (0.2, 1.5)
BURST_SHARE = (0.3, 0.8)


def make_occlusion_bursts(rng: np.random.Generator, labels: list[str], markers_true: np.ndarray, rate_hz: float,
                          count: int) -> np.ndarray:
    """``count`` occlusion bursts, as a (T, M) mask to add to the others: something passes in front of the
    cameras and 30–80 % of the subject's markers vanish at once for 0.2–1.5 s, those on one side of the body
    (farthest along a random horizontal direction from the subject's centroid when the burst starts; lab z up).
    The target and the clapper are not hidden; bursts start after the take's first frame."""
    n, m = markers_true.shape[:2]
    mask = np.zeros((n, m), dtype=bool)
    body = np.array([i for i, lab in enumerate(labels) if lab != TARGET_MARKER and lab not in CLAPPER_MARKERS])
    if n < 4 or body.size < 2:
        return mask
    for _ in range(count):
        length = min(n - 2, max(1, int(rng.uniform(*BURST_S) * rate_hz)))
        start = int(rng.integers(1, n - length))
        angle = rng.uniform(0.0, 2.0 * np.pi)
        side = np.array([np.cos(angle), np.sin(angle), 0.0])
        pos = markers_true[start, body]
        order = np.argsort(-(pos - pos.mean(axis=0)) @ side, kind="stable")
        hidden = body[order[:max(1, int(round(rng.uniform(*BURST_SHARE) * body.size)))]]
        mask[start:start + length, hidden] = True
    return mask
