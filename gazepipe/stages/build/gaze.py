"""Rows of the gaze datasets (SPEC §3.6): ``gaze_rnn`` / ``gaze_rnn_lod`` (Klein 6.1, 7) and ``gaze_map``
(Pejsa 5.1, 5.2.2.2). Pure functions on per-take arrays; :mod:`gazepipe.stages.build.stage` assembles the tables.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from gazepipe.errors import StageError
from gazepipe.stages.build.mirror import marker_pairs, mirror_quat, mirror_six, mirror_vectors
from gazepipe.stages.clean.filters import true_runs
from gazepipe.stages.geometry import from_wxyz, mean_wxyz, to_wxyz


@dataclass
class TakeRows:
    """Rows of one take before mirroring: identifiers and float32 feature arrays (N, D) or (N,)."""

    segment: np.ndarray
    frame: np.ndarray
    time_s: np.ndarray
    features: dict[str, np.ndarray]
    qc: dict = field(default_factory=dict)

    @property
    def n_rows(self) -> int:
        return int(self.frame.shape[0])


# ------------------------------------------------------------------------------------------------ gaze_rnn

def _xyz(prefix: str) -> list[str]:
    return [f"{prefix}.{a}" for a in "xyz"]


def rnn_feature_names(segments: list[str], with_eyes: bool) -> dict[str, list[str]]:
    """Names of the ``x`` and ``y`` elements: target direction, each segment's forward then up vector, then the
    eye direction (``x``: rotations and eyes of the previous frame; ``y``: of the current frame)."""
    rot = [n for s in segments for n in (*_xyz(f"{s}.fwd"), *_xyz(f"{s}.up"))]
    eyes = _xyz("eye_dir") if with_eyes else []
    return {"x": [*_xyz("target_dir"), *rot, *eyes], "y": [*rot, *eyes]}


def _unit(v: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def align_eyes(frames: np.ndarray, eye_frame: np.ndarray, eye_valid: np.ndarray,
               eye_dir: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eye validity (N,) and unit direction (N, 3) on the joints rows ``frames``, matched by frame number
    (a joints frame without an eyes row is invalid)."""
    order = np.argsort(eye_frame, kind="stable")
    ef = np.asarray(eye_frame)[order]
    pos = np.clip(np.searchsorted(ef, frames), 0, max(len(ef) - 1, 0))
    ok = np.zeros(len(frames), dtype=bool)
    d = np.full((len(frames), 3), np.nan)
    if len(ef):
        hit = ef[pos] == frames
        src = order[pos[hit]]
        ok[hit] = np.asarray(eye_valid, dtype=bool)[src]
        d[hit] = _unit(np.asarray(eye_dir, dtype=np.float64)[src])
    ok &= np.isfinite(d).all(axis=1)
    return ok, d


def rnn_rows(joints: dict, seg_idx: list[int], eyes: tuple[np.ndarray, np.ndarray] | None) -> TakeRows:
    """``gaze_rnn`` rows of one gaze_follow take (Klein 6.1).

    A frame is usable when it has a character frame, the kept segments' rotations are finite (other segments
    may be missing), the target direction is defined and (with ``eyes``) the eyes are valid. Consecutive usable
    frames (consecutive frame numbers) form a segment; an unusable frame, an invalid-eyes frame included, ends
    it. QC ``dropped`` counts the frames that give no row by their first reason: ``no_character_frame``,
    ``segment_missing``, ``no_target``, ``eyes_invalid``, ``first_of_run`` (a usable frame with no usable frame
    before it). The first frame of a
    segment only provides the previous pose of the second: every segment of n frames gives n − 1 rows, the row
    of frame t holding x = (target_dir[t], 6-number rotations[t−1], eye_dir[t−1]) and y = (rotations[t],
    eye_dir[t]). Segment ids count 0, 1, … per take.

    Parameters
    ----------
    joints : :func:`gazepipe.schemas.joints.joints_arrays` of the take (character frame of each frame).
    seg_idx : indices of the segments to keep, in output order.
    eyes : (valid (N,), unit direction (N, 3)) on the joints rows (:func:`align_eyes`), or ``None`` for the
        LOD dataset, which has no eyes and does not need them valid.
    """
    frame = np.asarray(joints["frame"], dtype=np.int64)
    six = np.asarray(joints["six"], dtype=np.float64)[:, seg_idx].reshape(len(frame), -1)
    target = _unit(np.asarray(joints["target_dir"], dtype=np.float64))
    checks = [("no_character_frame", np.isfinite(np.asarray(joints["char_rot"], dtype=np.float64)).all(axis=1)),
              ("segment_missing", np.isfinite(six).all(axis=1)),
              ("no_target", np.isfinite(target).all(axis=1))]
    parts_prev, parts_cur = [six], [six]
    if eyes is not None:
        eye_ok, eye_dir = eyes
        checks.append(("eyes_invalid", np.asarray(eye_ok, dtype=bool)))
        parts_prev.append(eye_dir)
        parts_cur.append(eye_dir)
    ok = np.ones(len(frame), dtype=bool)
    dropped: dict[str, int] = {}
    for reason, passes in checks:
        dropped[reason] = int((ok & ~passes).sum())
        ok &= passes
    row = np.zeros(len(frame), dtype=bool)
    if len(frame) > 1:
        row[1:] = ok[1:] & ok[:-1] & (np.diff(frame) == 1)
    starts = row & ~np.concatenate([[False], row[:-1]])
    seg = np.cumsum(starts) - 1
    t = np.flatnonzero(row)
    prev = np.concatenate(parts_prev, axis=1)[t - 1]
    cur = np.concatenate(parts_cur, axis=1)[t]
    x = np.concatenate([target[t], prev], axis=1).astype(np.float32)
    y = cur.astype(np.float32)
    lengths = np.bincount(seg[t], minlength=int(starts.sum())) if len(t) else np.zeros(0, dtype=np.int64)
    dropped["first_of_run"] = int((ok & ~row).sum())
    qc = {"frames": int(len(frame)), "usable_frames": int(ok.sum()), "dropped": dropped,
          "segments": int(starts.sum()), "longest_segment_rows": int(lengths.max()) if len(lengths) else 0}
    return TakeRows(segment=seg[t].astype(np.int32), frame=frame[t].astype(np.int32),
                    time_s=np.asarray(joints["time_s"], dtype=np.float64)[t], features={"x": x, "y": y}, qc=qc)


def segment_permutation(segments: list[str]) -> np.ndarray:
    """Index of each segment's mirror partner (left/right names swap, :func:`gazepipe.stages.build.mirror.marker_pairs`
    rules; a central segment is its own partner)."""
    pairs = marker_pairs(segments)
    return np.array([segments.index(pairs.get(s, s)) for s in segments], dtype=np.int64)


def mirror_rnn(features: dict[str, np.ndarray], n_segments: int, with_eyes: bool,
               perm: np.ndarray) -> dict[str, np.ndarray]:
    """Mirror gaze_rnn rows (SPEC §2): directions negate X (:func:`mirror_vectors`), each rotation's 6-number
    form negates the X of forward and up (:func:`mirror_six`, the form of M·R·M), left/right segments swap
    blocks. Only signs flip and blocks move, so mirroring twice gives the rows back bit for bit."""
    def rotations(block: np.ndarray) -> np.ndarray:
        six = block.reshape(len(block), n_segments, 6)[:, perm]
        return mirror_six(six).reshape(len(block), -1)

    x, y = features["x"], features["y"]
    r = 6 * n_segments
    eyes_x = [mirror_vectors(x[:, 3 + r:])] if with_eyes else []
    eyes_y = [mirror_vectors(y[:, r:])] if with_eyes else []
    return {"x": np.concatenate([mirror_vectors(x[:, :3]), rotations(x[:, 3:3 + r]), *eyes_x], axis=1),
            "y": np.concatenate([rotations(y[:, :r]), *eyes_y], axis=1)}


# ------------------------------------------------------------------------------------------------ gaze_map

def gaze_rotation(yaw_rad: float, pitch_rad: float) -> Rotation:
    """Ry(yaw)·Rx(−pitch): yaw positive toward the character's left, pitch positive up (SPEC §2)."""
    return Rotation.from_rotvec([0.0, yaw_rad, 0.0]) * Rotation.from_rotvec([-pitch_rad, 0.0, 0.0])


def angular_speed(r: Rotation, rate_hz: float) -> np.ndarray:
    """|ω| (rad/s) of a rotation sequence by central differences, (T,).

    The first and last frames have no central difference; they take their neighbour's value rather than a
    one-sided difference, which carries twice the noise (on 30 Hz marker data, enough to cross 18°/s alone).
    """
    n = len(r)
    w = np.zeros(n)
    if n < 3:
        if n == 2:
            w[:] = np.linalg.norm((r[1] * r[0].inv()).as_rotvec()) * rate_hz
        return w
    w[1:-1] = np.linalg.norm((r[2:] * r[:-2].inv()).as_rotvec(), axis=1) * rate_hz / 2.0
    w[0], w[-1] = w[1], w[-2]
    return w


def smooth_rotations(r: Rotation, rate_hz: float, cutoff_hz: float | None) -> Rotation:
    """Zero-phase Gaussian low-pass (−3 dB at ``cutoff_hz``, σ = √(ln 2)/(2π f) s) of a rotation sequence: the
    rotation vectors of r(t)·r(0)⁻¹ are filtered (edges reflected, so a still edge stays still) and mapped back.
    ``None`` returns r unchanged. The displacements of a gaze shift stay far below 180°, where rotation
    vectors are smooth in t."""
    if cutoff_hz is None or len(r) < 2:
        return r
    from scipy import ndimage

    sigma = np.sqrt(np.log(2.0)) / (2.0 * np.pi * cutoff_hz) * rate_hz   # samples
    rv = (r * r[0].inv()).as_rotvec()
    rv = ndimage.gaussian_filter1d(rv, sigma, axis=0, mode="reflect", truncate=4.0)
    return Rotation.from_rotvec(rv) * r[0]


def start_frame(r: Rotation, rate_hz: float, threshold_rad_s: float, filter_hz: float | None,
                min_frames: int = 1) -> int:
    """First frame where the angular speed of r (:func:`angular_speed` of :func:`smooth_rotations`) exceeds
    ``threshold_rad_s`` and stays above it for at least ``min_frames`` frames; −1 when it never does."""
    above = angular_speed(smooth_rotations(r, rate_hz, filter_hz), rate_hz) > threshold_rad_s
    m = max(1, int(min_frames))
    if m > 1 and len(above) >= m:
        cs = np.concatenate([[0], np.cumsum(above)])
        above = np.concatenate([(cs[m:] - cs[:-m]) == m, np.zeros(m - 1, dtype=bool)])
    hit = np.flatnonzero(above)
    return int(hit[0]) if len(hit) else -1


def overshoot(disp: Rotation, rate_hz: float, window_s: float, known: int | None = None
              ) -> tuple[float, float, int]:
    """Overshoot of a displacement sequence D(t) (D(0) = identity): (t_β in s from the first frame, β, frame).

    θ(t) = rotvec(D(t))·n with n the unit axis of D(last); ω = dθ/dt by central differences. t_β is the first
    frame j where ω changes sign from + to − and the mean ω over the ``window_s`` before j is > 0 and after it
    < 0 (Pejsa 5.2.2.2), placed between j − 1 and j by linear interpolation; β = θ(t_β)/θ(last) − 1. With no
    such change: (duration, 0, −1). ``known``: D is only known on its first ``known`` frames (and the last):
    the change is sought where both windows lie inside them.
    """
    n = len(disp)
    rv = disp.as_rotvec()
    final = rv[-1]
    norm = float(np.linalg.norm(final))
    end = (n - 1) / rate_hz
    if n < 3 or norm < 1e-9:
        return end, 0.0, -1
    theta = rv @ (final / norm)
    omega = np.gradient(theta) * rate_hz
    m = max(1, int(round(window_s * rate_hz)))
    cs = np.concatenate([[0.0], np.cumsum(omega)])
    i = np.arange(max(1, m), (n if known is None else min(n, known)) - m)
    if not len(i):
        return end, 0.0, -1
    before = (cs[i] - cs[i - m]) / m
    after = (cs[i + m] - cs[i]) / m
    hit = i[(omega[i - 1] > 0) & (omega[i] <= 0) & (before > 0) & (after < 0)]
    if not len(hit):
        return end, 0.0, -1
    j = int(hit[0])
    frac = omega[j - 1] / (omega[j - 1] - omega[j])
    th = theta[j - 1] + frac * (theta[j] - theta[j - 1])
    return (j - 1 + frac) / rate_hz, float(th / theta[-1] - 1.0), j


#: seconds of a rest, next to the crop's first or last frame, whose mean pose stands for that frame's
REST_POSE_S = 0.5


def bridge_rotations(q: np.ndarray, max_run: int) -> tuple[np.ndarray, int]:
    """Quaternions (n, 4) wxyz with their missing (NaN) runs of at most ``max_run`` frames filled by slerp
    between the frames on either side; longer runs, and runs at either end, stay NaN. Returns the filled copy
    and the longest missing run (frames)."""
    ok = np.isfinite(q).all(axis=1)
    out = q.copy()
    runs = true_runs(~ok)
    longest = max((b - a for a, b in runs), default=0)
    keys = np.flatnonzero(ok)
    if len(keys) < 2 or not runs:
        return out, longest
    slerp = Slerp(keys.astype(np.float64), from_wxyz(q[keys]))
    for a, b in runs:
        if a > 0 and b < len(q) and b - a <= max_run:
            out[a:b] = to_wxyz(slerp(np.arange(a, b, dtype=np.float64)))
    return out, longest


#: the ``known`` mask's entries after the segments: the eyes' P+, then the head's overshoot (t_β and β)
MASK_TAIL = ("eyes", "overshoot")


def gaze_map_names(segments: list[str]) -> dict[str, list[str]]:
    """Element names of the gaze_map columns (features, then the masks: ``known``, segments then eyes and
    overshoot; ``start_known``, one per segment)."""
    return {"yaw_deg": ["yaw_deg"], "pitch_deg": ["pitch_deg"], "duration_s": ["duration_s"],
            "start_times": list(segments), "overshoot_time": ["overshoot_time"], "overshoot": ["overshoot"],
            "p_plus": [f"{s}.{c}" for s in (*segments, "eyes") for c in "wxyz"],
            "known": [*segments, *MASK_TAIL], "start_known": list(segments)}


#: the QC name of a segment's start time among ``null_segments`` (the P+ entries are named by the segment)
def start_entry(segment: str) -> str:
    return f"{segment} start"


def gaze_map_row(joints: dict, rests: list, rate_hz: float, yaw_deg: float, pitch_deg: float, *,
                 head: int, start_speed_deg_s: float = 18.0, start_filter_hz: float | None = 2.0,
                 start_min_s: float = 1.0 / 15.0, overshoot_window_s: float = 0.1, max_bridge_s: float = 0.5,
                 path: str | None = None, take: str | None = None) -> TakeRows:
    """The ``gaze_map`` row of one gaze_shift take (Pejsa 5.1, 5.2.2.2; SPEC §3.6), with what can be computed.

    Rotations are taken in the character frame held fixed at the crop's first frame: G(t) = C(0)ᵀ·C(t)·Q(t)
    (C lab-from-character, Q the segment's rotation in the frame's own character frame), so the root's own
    turn counts; parent-relative L = G_parentᵀ·G (the root's L is its G).

    - duration l = (start of the second rest − end of the first rest) / rate, seconds;
    - the first and last frames' rotations (segments and character frame) are the subject's still pose there:
      the mean over the last ``REST_POSE_S`` of the first rest (the joints' ``rest_before``, when the frames
      stage had that rest) and over the crop's last ``REST_POSE_S``, inside the second rest (each over the
      whole rest where those frames lack it); a single frame carries the markers' noise (1–2° on a small
      three-marker segment). A segment's end pose comes from **measured** rotations only (the joints'
      ``rot_measured``: every marker of the segment measured, none gap-filled, the rotation not filled across a
      gap; without that column, rotations not marked ``rot_filled``). A rest is still, so any measured frame in
      it shows the pose. A fill there is estimated from what lies around it: from its edges (outside the rest
      when none of the rest is measured) or from other segments' markers, and such fills were measured 4–10°
      off in rests where their own estimate said 1–2 mm; nothing shows such a pose is the still one. Without a
      measured frame in the rest (for the first pose: nor at the crop's first frame) the segment's end pose is
      unknown;
    - P+ per segment L(last)·L(first)⁻¹ (needs the end poses of the segment and of its parent), and the eyes'
      D_headᵀ·Ry(yaw)·Rx(−pitch), D_head = G_head(last)·G_head(first)⁻¹ (needs the head's end poses): the eyes'
      global displacement is the requested change;
    - start time per segment: first crop frame where the angular speed of L (central differences of L
      low-passed at ``start_filter_hz``, :func:`start_frame`) exceeds ``start_speed_deg_s`` for at least
      ``start_min_s``, as a fraction of l; null when it never does (Pejsa's rule gives 0, which reads as a start
      at the crop's first frame: a real value for the head, not for a spine segment that never moved that fast;
      QC ``no_start`` lists them);
    - overshoot time t_β and amount β of the head's displacement (:func:`overshoot`), t_β a fraction of l
      (1 with β = 0 when there is no overshoot).

    Runs of crop frames without a rotation up to ``max_bridge_s`` are bridged in rotation space
    (:func:`bridge_rotations`) for the angular speeds and counted in QC (``bridged_frames``); a longer run
    leaves the frames from it on unknown (QC ``unbridged_frames``), and an event (a segment's start, the head's
    overshoot) must then be found before it (it is the first one there; after it, it may have happened unseen).

    What cannot be computed is null, not a reason to leave the take out (SPEC §3.6); a row with nothing known
    at all is (:class:`StageError`: the build lists the take as skipped, with the reasons). Feature ``known``
    (bool, segments then ``eyes`` then ``overshoot``, :data:`MASK_TAIL`) says which P+ were computed (NaN
    otherwise), and ``start_known`` (one per segment) which start times were (NaN otherwise: no start found,
    or one that may lie in an unbridgeable hole); each is blended from the examples that know it. The eyes are
    known when the head's global displacement is (their P+ is NaN otherwise). The overshoot (t_β and β, both
    NaN when unknown) is a parameter of the whole motion, masked apart from the head's P+ and start: it needs
    the head's displacement over the crop, so it is known when the head's end poses are and the event is read
    before any unbridgeable hole. QC ``null_segments`` lists what could not be computed (P+ by segment name,
    ``eyes``, ``overshoot``, a start time as ``"<segment> start"``: :func:`start_entry`) and ``null_reasons``
    says why, one line each; ``no_start`` lists the segments whose start is null because they never reached
    the start speed.

    Parameters
    ----------
    joints : :func:`gazepipe.schemas.joints.joints_arrays` of the cropped take ([end of first rest, end of
        second rest)); ``rot_measured`` (N, S) marks rotations from measured markers (else ``rot_filled``
        filled ones; all known ones count as measured when neither is given).
    rests : rest periods [start, stop) in frames of the uncropped take (the clean stage's ``rests``).
    rate_hz : frames per second.
    yaw_deg, pitch_deg : the requested gaze change, degrees.
    head : index of the head segment.

    Raises :class:`StageError` (the reason no row can be computed) when fewer than two rests are given, the crop
    has fewer than 3 frames, l ≤ 0, the character frame is unknown at the crop's first or last frame (every
    rotation is taken in it), or no P+, start time, eyes' P+ nor overshoot could be computed.
    """
    if len(rests) < 2:
        raise StageError(path, f"gaze_map: {len(rests)} rest period(s), need two", take=take)
    quat = np.array(joints["quat"], dtype=np.float64)         # a copy: bridged below
    n, ns = quat.shape[:2]
    if n < 3:
        raise StageError(path, f"gaze_map: the crop has {n} frame(s)", take=take)
    duration = (int(rests[1][0]) - int(rests[0][1])) / rate_hz
    if duration <= 0:
        raise StageError(path, f"gaze_map: rests {rests[:2]} give a duration of {duration:.3f} s", take=take)
    names = list(joints["segments"])
    char_rot = np.array(joints["char_rot"], dtype=np.float64)
    reasons: dict[str, str] = {}
    ends_ok = _end_poses(joints, rests, quat, char_rot, rate_hz, reasons, path, take)
    holes = _Holes(n, rate_hz, max_bridge_s)
    bridged = holes.bridge({"character frame": char_rot, **{f"segment {names[k]!r}": quat[:, k] for k in range(ns)}})
    parents = [int(p) for p in joints["meta"].get("parents", [-1] + list(range(ns - 1)))]
    rc = from_wxyz(char_rot)
    fixed = [rc[0].inv() * rc * from_wxyz(quat[:, k]) for k in range(ns)]
    local = [fixed[k] if parents[k] < 0 else fixed[parents[k]].inv() * fixed[k] for k in range(ns)]

    p_plus, p_ok, eyes_ok = _p_plus(local, fixed, ends_ok, parents, names, head, (yaw_deg, pitch_deg), reasons)
    # an event (a start, the overshoot) read before the first frame that cannot be bridged is the first one;
    # after it, it could have happened unseen
    starts, no_start = _start_times(local, names, parents, holes, duration,
                                    (start_speed_deg_s, start_filter_hz, start_min_s), reasons)
    start_ok = np.isfinite(starts)
    nan4 = np.full(4, np.nan)
    for k in np.flatnonzero(~p_ok).tolist():
        p_plus[k] = nan4
    t_frac, beta, j, ov_ok = _head_overshoot(fixed[head], names[head], holes, overshoot_window_s, duration,
                                             eyes_ok, reasons)

    known = np.array([*p_ok, eyes_ok, ov_ok], dtype=bool)
    mask_names = [*names, *MASK_TAIL]
    if not known.any() and not start_ok.any():
        # nothing to learn from: the row is not written (the build lists the take as skipped, with this reason)
        why = "; ".join(f"{k}: {v}" for k, v in list(reasons.items())[:3])
        raise StageError(path, f"gaze_map: no parameter of the row could be computed ({why})", take=take)
    f32 = np.float32
    feats = {
        "yaw_deg": np.array([yaw_deg], f32), "pitch_deg": np.array([pitch_deg], f32),
        "duration_s": np.array([duration], f32),
        "start_times": starts.astype(f32)[None, :],
        "overshoot_time": np.array([t_frac], f32), "overshoot": np.array([beta], f32),
        "p_plus": np.concatenate(p_plus).astype(f32)[None, :],
        "known": known[None, :],
        "start_known": start_ok[None, :],
    }
    frame = np.asarray(joints["frame"], dtype=np.int64)
    null = [mask_names[i] for i in np.flatnonzero(~known)]
    null += [start_entry(names[k]) for k in np.flatnonzero(~start_ok) if names[k] not in no_start]
    qc = {"crop_frames": int(n), "bridged_frames": int(bridged.sum()),
          "unbridged_frames": int(np.logical_or.reduce([*holes.unknown.values(), np.zeros(n, bool)]).sum()),
          "overshoot_frame": int(frame[j]) if j >= 0 else None,
          "crop_start_vs_rest_end": int(frame[0] - int(rests[0][1])),
          "null_segments": null, "null_reasons": {k: reasons[k] for k in null}, "no_start": no_start}
    return TakeRows(segment=np.zeros(1, np.int32), frame=frame[:1].astype(np.int32),
                    time_s=np.asarray(joints["time_s"], dtype=np.float64)[:1], features=feats, qc=qc)


def _end_poses(joints: dict, rests: list, quat: np.ndarray, char_rot: np.ndarray, rate_hz: float,
               reasons: dict[str, str], path: str | None, take: str | None) -> np.ndarray:
    """Put the subject's still poses at the crop's first and last frames (:func:`gaze_map_row`) into ``quat``
    (N, S, 4) and ``char_rot`` (N, 4), in place; (S,) bool: which segments have both. Why a segment has not is
    in ``reasons``; a missing character frame pose raises :class:`StageError`."""
    n, ns = quat.shape[:2]
    names = list(joints["segments"])
    measured = np.all(np.isfinite(quat), axis=2)
    if joints.get("rot_measured") is not None:
        measured &= np.asarray(joints["rot_measured"], dtype=bool)
    elif joints.get("rot_filled") is not None:
        measured &= ~np.asarray(joints["rot_filled"], dtype=bool)
    # the crop starts where the first rest ends and ends with the second rest, where the subject is still: the
    # first and last poses are the means over those rests (a single frame carries the markers' noise)
    before = joints["meta"].get("rest_before") or {}
    before_quat = before.get("quat") or [None] * ns
    second = max(0, min(n - 1, int(rests[1][0]) - int(np.asarray(joints["frame"])[0])))
    tail = max(second, n - int(round(REST_POSE_S * rate_hz)))

    def last_pose(q: np.ndarray) -> np.ndarray | None:
        last = mean_wxyz(q[tail:], 3)
        return last if last is not None else mean_wxyz(q[second:], 3)

    first_c = before.get("char_rot")
    first_c = np.asarray(first_c, dtype=np.float64) if first_c is not None else (
        char_rot[0] if np.isfinite(char_rot[0]).all() else None)
    last_c = last_pose(char_rot)
    for end, pose in (("first", first_c), ("last", last_c)):
        if pose is None:
            raise StageError(path, f"gaze_map: the crop's {end} frame has no character frame rotation (every "
                                   "rotation is taken in it)", take=take)
    char_rot[0], char_rot[n - 1] = first_c, last_c
    ends_ok = np.zeros(ns, dtype=bool)
    for k in range(ns):
        only: np.ndarray = np.where(measured[:, k, None], quat[:, k], np.nan)
        first = (np.asarray(before_quat[k], dtype=np.float64) if before_quat[k] is not None
                 else only[0] if measured[0, k] else None)
        last = last_pose(only)
        if first is not None:
            quat[0, k] = first
        if last is not None:
            quat[n - 1, k] = last
        ends_ok[k] = first is not None and last is not None
        if not ends_ok[k]:
            where = [("no measured rotation in the rest before the crop nor at its first frame" if before else
                      "no measured rotation at the crop's first frame") if first is None else "",
                     f"no measured rotation in the crop's final rest (frames {second}–{n - 1})"
                     if last is None else ""]
            reasons[names[k]] = "P+: " + "; ".join(w for w in where if w)
    return ends_ok


@dataclass
class _Holes:
    """The crop's runs of frames without a rotation that no bridge reaches, by series (character frame,
    segments), once :meth:`bridge` ran."""

    n: int
    rate_hz: float
    max_bridge_s: float
    unknown: dict[str, np.ndarray] = field(default_factory=dict)

    def bridge(self, series: dict[str, np.ndarray]) -> np.ndarray:
        """Bridge each series' runs without a rotation in place (:func:`bridge_rotations`), up to
        ``max_bridge_s``; longer runs get placeholders (no event is read at or after them) and are remembered.
        (N,) bool: the frames bridged in any series."""
        max_run = int(np.floor(self.max_bridge_s * self.rate_hz + 1e-9))
        bridged = np.zeros(self.n, dtype=bool)
        for series_name, q in series.items():
            ok = np.isfinite(q).all(axis=1)
            if ok.all():
                continue
            q[:], _ = bridge_rotations(q, max_run)
            gone = ~np.isfinite(q).all(axis=1)
            bridged |= ~ok & ~gone
            if gone.any():
                self.unknown[series_name] = gone
                q[gone] = (1.0, 0.0, 0.0, 0.0)       # placeholders: no event is read at or after them
        return bridged

    def known_until(self, *whats: str) -> tuple[int, str | None]:
        """The first frame none of ``whats`` can be bridged to (n when all are known), and which one."""
        firsts: list[tuple[int, str | None]] = [(int(np.argmax(self.unknown[w])), w) for w in whats
                                                if w in self.unknown]
        return min(firsts, key=lambda f: f[0]) if firsts else (self.n, None)

    def cannot(self, quantity: str, what: str) -> str:
        a, b = true_runs(self.unknown[what])[0]
        return (f"{quantity} cannot be computed: crop frames {a}–{b - 1} ({(b - a) / self.rate_hz:.2f} s) have "
                f"no {what} rotation, more than build.max_bridge_s ({self.max_bridge_s:g} s) can bridge, and the "
                "event is not found before them")


def _p_plus(local: list[Rotation], fixed: list[Rotation], ends_ok: np.ndarray, parents: list[int], names: list[str], head: int,
            gaze_deg: tuple[float, float], reasons: dict[str, str]) -> tuple[list[np.ndarray], np.ndarray, bool]:
    """P+ of every segment (wxyz; NaN where unknown), then the eyes'; which segments' are known; whether the
    eyes' is."""
    ns = len(local)
    n = len(fixed[head])
    nan4 = np.full(4, np.nan)
    p_ok = np.array([ends_ok[k] and (parents[k] < 0 or ends_ok[parents[k]]) for k in range(ns)], dtype=bool)
    for k in np.flatnonzero(ends_ok & ~p_ok).tolist():
        reasons[names[k]] = f"P+: it is relative to {names[parents[k]]!r}, whose end pose is unknown"
    p_plus = [to_wxyz(loc[n - 1] * loc[0].inv()) if p_ok[k] else nan4 for k, loc in enumerate(local)]
    eyes_ok = bool(ends_ok[head])
    d_head = fixed[head][n - 1] * fixed[head][0].inv()
    p_plus.append(to_wxyz(d_head.inv() * gaze_rotation(np.deg2rad(gaze_deg[0]), np.deg2rad(gaze_deg[1])))
                  if eyes_ok else nan4)
    if not eyes_ok:
        reasons["eyes"] = f"P+: needs the head's displacement, and {names[head]!r} has an unknown end pose"
    return p_plus, p_ok, eyes_ok


def _start_times(local: list[Rotation], names: list[str], parents: list[int], holes: _Holes, duration: float,
                 rule: tuple[float, float | None, float], reasons: dict[str, str]) -> tuple[np.ndarray, list[str]]:
    """Each segment's start time as a fraction of the duration (NaN where unknown, :func:`start_frame` with
    ``rule``: start speed deg/s, filter Hz, minimum s), and the segments that never reached the start speed."""
    speed_deg_s, filter_hz, min_s = rule
    rate_hz = holes.rate_hz
    thr = np.deg2rad(speed_deg_s)
    starts = np.full(len(local), np.nan)
    no_start: list[str] = []                     # never reached the start speed: null, but known to be so
    min_frames = max(1, int(round(min_s * rate_hz)))
    for k, loc in enumerate(local):
        chain = ["character frame", f"segment {names[k]!r}"]
        if parents[k] >= 0:
            chain.append(f"segment {names[parents[k]]!r}")
        stop, what = holes.known_until(*chain)
        j0 = start_frame(loc[:stop], rate_hz, thr, filter_hz, min_frames) if stop >= 2 else -1
        if j0 >= 0:
            starts[k] = j0 / rate_hz / duration
        elif what is not None:
            reasons[start_entry(names[k])] = holes.cannot("start time", what)
        else:
            no_start.append(names[k])
    return starts, no_start


def _head_overshoot(head_fixed: Rotation, head_name: str, holes: _Holes, window_s: float, duration: float,
                    eyes_ok: bool, reasons: dict[str, str]) -> tuple[float, float, int, bool]:
    """The head's overshoot (:func:`overshoot`): its time as a fraction of the duration, its amount, its frame
    (-1 for none) and whether it is known (NaN, NaN, -1 when not)."""
    disp = head_fixed * head_fixed[0].inv()
    stop, what = holes.known_until("character frame", f"segment {head_name!r}")
    t_beta, beta, j = overshoot(disp, holes.rate_hz, window_s, known=stop)
    t_frac = t_beta / duration if j >= 0 else 1.0
    ov_ok = eyes_ok and not (j < 0 and what is not None)
    if not ov_ok:
        reasons["overshoot"] = (holes.cannot("overshoot", what) if eyes_ok and what is not None else
                                f"needs the head's displacement, and {head_name!r} has an unknown end pose")
        t_frac, beta, j = np.nan, np.nan, -1
    return t_frac, beta, j, ov_ok


def mirror_gaze_map(features: dict[str, np.ndarray], perm: np.ndarray) -> dict[str, np.ndarray]:
    """Mirror gaze_map rows (SPEC §2): yaw negates, pitch stays; every quaternion becomes that of M·R·M
    (:func:`mirror_quat`: w, x, −y, −z), left/right segments swap (their start times and ``known`` entries too);
    the eyes' quaternion stays last, the mask's eyes and overshoot entries stay after the segments; durations
    and overshoot stay. Null (NaN) values stay null where their mask entry moves."""
    out = {k: v.copy() for k, v in features.items()}
    out["yaw_deg"] = np.negative(features["yaw_deg"])
    q = features["p_plus"].reshape(len(features["p_plus"]), -1, 4)
    order = np.append(perm, q.shape[1] - 1)
    out["p_plus"] = mirror_quat(q[:, order]).reshape(features["p_plus"].shape)
    out["start_times"] = features["start_times"][:, perm]
    if "known" in features:
        out["known"] = features["known"][:, np.concatenate([perm, len(perm) + np.arange(len(MASK_TAIL))])]
    if "start_known" in features:
        out["start_known"] = features["start_known"][:, perm]
    return out
