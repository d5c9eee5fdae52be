"""The ``eyes`` stage (SPEC §3.5, Klein 5.2 and 9): OpenFace gaze into the character frame.

Steps, all pure functions on arrays:

1. :func:`gate` on the video clock: a sample is valid when ``success`` and ``confidence >= min_confidence`` and
   not a blink and both gaze vectors exist; invalid runs of at most ``max_eye_gap_s`` between two valid samples
   are filled by slerp (per eye); longer runs and runs at either end stay invalid.
2. :func:`cyclopean`: the normalised mean of both eyes (OpenFace cannot resolve vergence, Klein 5.2).
3. Resampling onto the mocap frames through the sync stage's clock map t_mocap = offset + ratio · t_video and
   its ``resample_to_mocap``: directions by slerp between the two neighbouring video samples, confidence the
   minimum of the two; a frame is valid only when both are valid; no extrapolation.
4. :func:`camera_to_character`: v_head = R · v_cam with R the camera rotation, then v_char = R_head · v_head.
5. When R is not configured, :func:`estimate_camera_rotation_lagged`: least-squares rotation between the
   OpenFace gaze and the direction from the eyes' centre to the target in head axes, over frames where the gaze
   rests on the target, robustly trimmed (:func:`estimate_camera_rotation`). The eyes trail a moving target by
   about 0.2 s, so the gaze at t is paired with the target at t − lag and the lag is fitted too; pairing with
   the current target biases R by degrees whenever the target keeps moving.

Axes. OpenFace's camera: x right, y down, z forward (out of the lens). The head segment: X the subject's left,
Y up, Z forward (out of the face). A head-mounted camera in front of the face looks back at it, so:

- camera z (away from the lens, into the face) is head −Z: a subject looking into the lens gives (0, 0, −1) in
  camera axes and must give head forward (0, 0, 1);
- camera x (image right) is the subject's left, head +X (the image's left shows the subject's right eye, which
  is why OpenFace's ``gaze_0`` is the right eye);
- camera y (image down) is head −Y.

So R = diag(1, −1, −1): the 180° rotation about the head's Y axis (diag(−1, 1, −1), turning the camera round to
face the subject) composed with the 180° rotation about the optical axis that flips x and y (diag(−1, −1, 1),
image axes "right, down" to "left, up"): Ry(180°) · Rz(180°) = diag(1, −1, −1) = Rx(180°), quaternion
(w, x, y, z) = (0, 1, 0, 0), :data:`CAMERA_FACING_FACE`. A real mount adds its tilt and turn: R = R_mount · that.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.errors import StageError
from gazepipe.stages.rotations import from_wxyz, to_wxyz
from gazepipe.stages.sync import ClockMap, resample_to_mocap
from gazepipe.timebase import snap_rate

__all__ = [
    "CAMERA_FACING_FACE",
    "GATE_REASONS",
    "CameraEstimate",
    "EyesParams",
    "EyesResult",
    "Gated",
    "angle_between",
    "camera_to_character",
    "camera_to_head",
    "combine_camera_estimates",
    "cyclopean",
    "estimate_camera_rotation",
    "estimate_camera_rotation_lagged",
    "eyes_take",
    "fixation_frames",
    "gate",
    "head_to_character",
    "slerp_vectors",
]

#: camera → head rotation (w, x, y, z) of a camera straight in front of the face looking back at it
CAMERA_FACING_FACE = np.array([0.0, 1.0, 0.0, 0.0])

#: why a video sample is gated out, by code (first failing rule in this order wins)
GATE_REASONS = ("valid", "success", "confidence", "blink", "no_gaze")

_EPS = 1e-12


@dataclass(frozen=True)
class EyesParams:
    """Parameters of the eyes stage (SPEC §3.5); speeds in degrees per second, times in seconds.

    Attributes
    ----------
    min_confidence : OpenFace confidence at or above which a sample can be valid.
    max_eye_gap_s : longest invalid run (between two valid samples) filled by slerp.
    head_segment : the head segment's name in the joints; ``None`` = ``"head"``, else the last segment.
    smooth_s : moving-average window of the directions whose central differences give angular speeds (used
        only to choose the frames of the camera-rotation fit).
    max_target_speed_deg_s : fastest the target may move (lab axes when the joints give the character frame's
        orientation, else character axes; after the lag) for a frame to enter the fit: during pursuit the eyes
        trail a moving target, more the faster it goes.
    max_gaze_speed_deg_s : fastest the gaze may move in camera axes (saccades are far faster; pursuit and the
        vestibulo-ocular reflex during head turns are slower).
    settle_s : frames this soon after a faster target move stay out (the eyes land after the catch-up saccade).
    max_eccentricity_deg : frames whose target lies further than this from the head's forward axis stay out (the
        eyes rotate at most about 45-50 degrees in the head; beyond that they do not reach the target).
    max_lag_s : longest eye-behind-target delay searched; the eyes follow a target about 0.2 s late.
    keep_percentile : after each fit, frames whose error is above this percentile are left out of the next fit.
    refit_iterations : number of trimmed re-fits after the first fit.
    min_fixation_frames : fewest fixation frames needed to estimate the camera rotation.
    min_target_spread_deg : below this RMS spread of the target directions the estimate is poorly conditioned
        (a warning in QC).
    """

    min_confidence: float = 0.8
    max_eye_gap_s: float = 0.1
    head_segment: str | None = None
    smooth_s: float = 0.2
    max_target_speed_deg_s: float = 30.0
    max_gaze_speed_deg_s: float = 60.0
    settle_s: float = 0.15
    max_eccentricity_deg: float = 50.0
    max_lag_s: float = 0.5
    keep_percentile: float = 75.0
    refit_iterations: int = 3
    min_fixation_frames: int = 30
    min_target_spread_deg: float = 5.0


@dataclass
class Gated:
    """Gated and gap-filled eye samples on the video clock (output of :func:`gate`).

    Attributes
    ----------
    time_s : (N,) float64 video-clock seconds.
    video_frame : (N,) int64 video frame index of each row (missing rows show as jumps).
    gaze_left, gaze_right : (N, 3) unit vectors, camera axes, subject's own eyes; NaN where invalid.
    gaze : (N, 3) cyclopean direction, camera axes; NaN where invalid.
    valid : (N,) bool, measured or filled.
    filled : (N,) bool, filled by slerp.
    reason : (N,) uint8 index into :data:`GATE_REASONS` (why the raw sample failed the gate; 0 = it passed).
    confidence : (N,) float64: OpenFace's where measured, the minimum of the two bracketing samples where filled,
        OpenFace's (possibly junk) elsewhere.
    rate_hz : video frame rate, from the frame numbers and timestamps.
    max_gap_frames : longest run of missing video frames that is filled (from ``max_eye_gap_s``).
    qc : JSON-ready record.
    """

    time_s: np.ndarray
    video_frame: np.ndarray
    gaze_left: np.ndarray
    gaze_right: np.ndarray
    gaze: np.ndarray
    valid: np.ndarray
    filled: np.ndarray
    reason: np.ndarray
    confidence: np.ndarray
    rate_hz: float
    max_gap_frames: int
    qc: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])


class CameraEstimate(NamedTuple):
    """Result of :func:`estimate_camera_rotation`.

    quat : (4,) w, x, y, z rotation from camera axes to head axes (v_head = R · v_cam).
    residual_deg : median angle between the rotated gaze and the target direction over the fixation frames.
    n_used : frames in the final (trimmed) fit.
    """

    quat: np.ndarray
    residual_deg: float
    n_used: int


@dataclass
class EyesResult:
    """Eye direction per mocap frame (output of :func:`eyes_take`).

    Attributes
    ----------
    eye_dir_char : (N, 3) unit cyclopean gaze direction in the character frame; NaN where not ``valid``.
    eye_dir_head : (N, 3) the same in the head segment's axes; NaN where the eye data are invalid.
    valid : (N,) bool: both neighbouring video samples valid (measured or filled), the frame covered by the video,
        and a head rotation present.
    confidence : (N,) float64 minimum of the two neighbouring video samples' confidence (a frame exactly on a
        sample takes that sample's); NaN without coverage.
    covered : (N,) bool, the frame lies within the video's time span.
    camera_rotation : (4,) w, x, y, z camera → head rotation used.
    camera_source : ``"configured"`` or ``"estimated"``.
    gated : the video-clock :class:`Gated` samples.
    qc : JSON-ready record.
    """

    eye_dir_char: np.ndarray
    eye_dir_head: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray
    covered: np.ndarray
    camera_rotation: np.ndarray
    camera_source: str
    gated: Gated
    qc: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.valid.shape[0])


# ---------------------------------------------------------------------------------------------------------------
# vector helpers


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in radians between vectors (..., 3), robust near 0 and π; NaN where either is NaN."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > _EPS, v / n, np.nan)


def slerp_vectors(p: np.ndarray, q: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Spherical interpolation of unit vectors: the point a fraction ``f`` along the great arc from p to q.

    Parameters
    ----------
    p, q : (N, 3) unit vectors (finite).
    f : (N,) fractions (0 gives p, 1 gives q).

    The arc is the rotation about p × q by f times the angle between them; antipodal pairs (no unique arc) and
    identical vectors give p.
    """
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    f = np.asarray(f, dtype=np.float64)
    if p.shape[0] == 0:
        return np.empty((0, 3))
    axis = np.cross(p, q)
    s = np.linalg.norm(axis, axis=1)
    ang = np.arctan2(s, np.sum(p * q, axis=1))
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where((s > _EPS)[:, None], axis / s[:, None], 0.0)
    return Rotation.from_rotvec(axis * (f * ang)[:, None]).apply(p)


def cyclopean(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The cyclopean gaze direction: the normalised mean of both eyes' unit vectors, (N, 3).

    Any axes (camera axes in this stage). NaN where either eye is NaN or the mean vanishes.
    """
    return _unit(np.asarray(left, dtype=np.float64) + np.asarray(right, dtype=np.float64))


# ---------------------------------------------------------------------------------------------------------------
# gating


def _video_rate(rate: float) -> float:
    """A measured video rate snapped to N·1000/1001 (SPEC §1) or to a whole N within 0.05 %: OpenFace writes
    timestamps rounded to the millisecond, which alone moves a 60 Hz estimate off 60."""
    r = snap_rate(rate)
    n = round(r)
    return float(n) if r == rate and n >= 1 and abs(r - n) <= 5e-4 * n else r


def _video_frames(t: np.ndarray, frame: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Video frame index per row and the frame period in seconds.

    With frame numbers, the period is the time span over the frame span; without, the median positive time
    step, and indices follow from the timestamps. The rate is snapped by :func:`_video_rate`.
    """
    n = t.shape[0]
    if frame is not None and n >= 2 and frame[-1] > frame[0] and t[-1] > t[0]:
        rate = _video_rate((frame[-1] - frame[0]) / (t[-1] - t[0]))
        return np.asarray(frame, dtype=np.int64), 1.0 / rate
    steps = np.diff(t)
    steps = steps[steps > 0]
    if steps.size == 0:
        return np.arange(n, dtype=np.int64), float("nan")
    dt = 1.0 / _video_rate(1.0 / float(np.median(steps)))
    return np.round((t - t[0]) / dt).astype(np.int64), dt


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop (exclusive) rows of the runs of True in a 1-D mask."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def gate(eye: Any, *, min_confidence: float = 0.8, max_eye_gap_s: float = 0.1) -> Gated:
    """Gate OpenFace samples and fill short invalid runs by slerp, on the video clock (SPEC §3.5).

    Parameters
    ----------
    eye : an :class:`~gazepipe.io.tracks.EyeTrack` or any object with ``time_s`` (N,), ``success`` (N,),
        ``confidence`` (N,), ``gaze_left``/``gaze_right`` (N, 3) unit camera-axes vectors, ``blink`` (N,) or
        ``None``, and optionally ``frame`` (N,) video frame numbers.
    min_confidence : a sample needs ``confidence >= min_confidence``.
    max_eye_gap_s : invalid runs lasting at most this long (n missing video frames last n / rate) between two
        valid samples are filled; the two bracketing samples are slerped per eye at the filled rows' times.
        Runs touching either end are never filled (no extrapolation).

    Returns
    -------
    :class:`Gated`. QC: ``gated_share`` (raw samples failing the gate), ``gated_by`` (share per reason, the first
    failing rule in the order success, confidence, blink, no gaze vector), ``filled_samples``,
    ``invalid_share`` (after filling), ``longest_invalid_run_s`` (after filling, missing video frames included),
    ``missing_video_frames``.
    """
    t = np.asarray(eye.time_s, dtype=np.float64)
    n = t.shape[0]
    success = np.asarray(eye.success, dtype=bool)
    conf = np.asarray(eye.confidence, dtype=np.float64)
    left = np.asarray(eye.gaze_left, dtype=np.float64).reshape(n, 3)
    right = np.asarray(eye.gaze_right, dtype=np.float64).reshape(n, 3)
    blink_raw = getattr(eye, "blink", None)
    blink = np.zeros(n, dtype=bool) if blink_raw is None else np.asarray(blink_raw, dtype=bool)
    frame_raw = getattr(eye, "frame", None)
    fidx, dt = _video_frames(t, None if frame_raw is None else np.asarray(frame_raw))

    finite = np.isfinite(left).all(axis=1) & np.isfinite(right).all(axis=1)
    reason = np.zeros(n, dtype=np.uint8)
    # lowest priority first, so the first failing rule in GATE_REASONS order is what remains
    reason[~finite] = 4
    reason[blink] = 3
    reason[~(conf >= min_confidence)] = 2   # NaN confidence fails too
    reason[~success] = 1
    measured = reason == 0

    max_gap_frames = int(np.floor(max_eye_gap_s / dt + 1e-6)) if np.isfinite(dt) else 0
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(measured, idx, -1)) if n else idx
    nxt = np.minimum.accumulate(np.where(measured, idx, n)[::-1])[::-1] if n else idx
    bracketed = ~measured & (prev >= 0) & (nxt < n)
    a = np.clip(prev, 0, max(n - 1, 0))
    b = np.clip(nxt, 0, max(n - 1, 0))
    filled = bracketed & (fidx[b] - fidx[a] - 1 <= max_gap_frames) if n else bracketed

    out_l = np.where(measured[:, None], left, np.nan)
    out_r = np.where(measured[:, None], right, np.nan)
    confidence = conf.copy()
    if filled.any():
        fa, fb = a[filled], b[filled]
        span = t[fb] - t[fa]
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(span > 0, (t[filled] - t[fa]) / span, 0.0)
        frac = np.clip(frac, 0.0, 1.0)
        out_l[filled] = slerp_vectors(left[fa], left[fb], frac)
        out_r[filled] = slerp_vectors(right[fa], right[fb], frac)
        confidence[filled] = np.minimum(conf[fa], conf[fb])
    valid = measured | filled
    gaze = cyclopean(out_l, out_r)

    qc = _gate_qc(n, reason, filled, valid, fidx, dt, blink_raw is None)
    qc.update(min_confidence=float(min_confidence), max_eye_gap_s=float(max_eye_gap_s))
    return Gated(time_s=t, video_frame=fidx, gaze_left=out_l, gaze_right=out_r, gaze=gaze, valid=valid,
                 filled=filled, reason=reason, confidence=confidence, rate_hz=float(1.0 / dt),
                 max_gap_frames=max_gap_frames, qc=qc)


def _gate_qc(n: int, reason: np.ndarray, filled: np.ndarray, valid: np.ndarray, fidx: np.ndarray, dt: float,
             no_blink: bool) -> dict:
    share = (lambda k: float(k) / n) if n else (lambda k: 0.0)
    # longest invalid stretch in video frames: runs of invalid rows plus the missing frames around them,
    # and missing frames between two valid rows
    longest = 0
    missing = 0
    if n:
        hop = np.diff(fidx) - 1
        missing = int(np.maximum(hop, 0).sum())
        starts, stops = _runs(~valid)
        if starts.size:
            before = np.where(starts > 0, fidx[np.maximum(starts - 1, 0)], fidx[starts] - 1)
            after = np.where(stops < n, fidx[np.minimum(stops, n - 1)], fidx[stops - 1] + 1)
            longest = int(np.max(after - before - 1))
        gaps_between_valid = hop[valid[:-1] & valid[1:]]
        if gaps_between_valid.size:
            longest = max(longest, int(gaps_between_valid.max()))
    qc = {
        "samples": int(n),
        "video_rate_hz": float(1.0 / dt) if np.isfinite(dt) else None,
        "gated_share": share(np.count_nonzero(reason)),
        "gated_by": {name: share(np.count_nonzero(reason == i)) for i, name in enumerate(GATE_REASONS) if i},
        "filled_samples": int(np.count_nonzero(filled)),
        "invalid_share": share(np.count_nonzero(~valid)),
        "longest_invalid_run_s": float(longest * dt) if np.isfinite(dt) else 0.0,
        "missing_video_frames": missing,
        "warnings": [],
    }
    if no_blink:
        qc["warnings"].append("no blink information (no AU45 column): blinks are not masked")
    return qc


# ---------------------------------------------------------------------------------------------------------------
# axes


def camera_to_head(gaze_cam: np.ndarray, r_cam_to_head: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from camera axes to head axes: v_head = R · v_cam (R as w, x, y, z); NaN stays NaN."""
    v = np.asarray(gaze_cam, dtype=np.float64)
    return from_wxyz(r_cam_to_head).as_matrix().dot(v.T).T if v.size else v.reshape(-1, 3).copy()


def head_to_character(v_head: np.ndarray, head_rot_char: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from head axes to the character frame: v_char = R_head · v_head per frame.

    ``head_rot_char`` (N, 4) w, x, y, z is the head segment's rotation in the character frame; rows where it or
    the vector is not finite give NaN.
    """
    v = np.asarray(v_head, dtype=np.float64)
    q = np.asarray(head_rot_char, dtype=np.float64)
    out = np.full(v.shape, np.nan)
    ok = np.isfinite(v).all(axis=1) & np.isfinite(q).all(axis=1)
    if ok.any():
        out[ok] = from_wxyz(q[ok]).apply(v[ok])
    return out


def camera_to_character(gaze_cam: np.ndarray, r_cam_to_head: np.ndarray, head_rot_char: np.ndarray) -> np.ndarray:
    """Directions (N, 3) from camera axes into the character frame: v_char = R_head · R · v_cam.

    Parameters
    ----------
    gaze_cam : (N, 3) unit vectors in OpenFace camera axes (x right, y down, z forward).
    r_cam_to_head : (4,) w, x, y, z camera → head rotation (see the module docstring for the worked example of
        a camera in front of the face: :data:`CAMERA_FACING_FACE`).
    head_rot_char : (N, 4) w, x, y, z head rotation in the character frame.
    """
    return head_to_character(camera_to_head(gaze_cam, r_cam_to_head), head_rot_char)


# ---------------------------------------------------------------------------------------------------------------
# camera rotation estimate


def _smooth_dirs(v: np.ndarray, k: int) -> np.ndarray:
    """Centred moving average of unit vectors over k frames, renormalised; NaN if any in the window is NaN."""
    if k <= 1:
        return v
    ok = np.isfinite(v).all(axis=1)
    vz = np.where(ok[:, None], v, 0.0)
    from scipy.ndimage import uniform_filter1d

    s = uniform_filter1d(vz, k, axis=0, mode="constant", cval=0.0)
    cnt = uniform_filter1d(ok.astype(np.float64), k, mode="constant", cval=0.0)
    return np.where((cnt > 1.0 - 1e-9)[:, None], _unit(s), np.nan)


def _angular_speed(v: np.ndarray, rate_hz: float) -> np.ndarray:
    """Angular speed in degrees per second of a direction series, central differences; NaN at the ends."""
    out = np.full(v.shape[0], np.nan)
    if v.shape[0] >= 3:
        out[1:-1] = np.rad2deg(angle_between(v[2:], v[:-2])) * rate_hz / 2.0
    return out


def _odd(x: float) -> int:
    k = max(1, int(round(x)))
    return k if k % 2 else k + 1


def fixation_frames(gaze_cam: np.ndarray, target_dir_head: np.ndarray, rate_hz: float,
                    params: EyesParams | None = None, *, target_dir_world: np.ndarray | None = None) -> np.ndarray:
    """Frames (N,) bool where the gaze plausibly rests on the target (for the camera-rotation fit).

    Speeds come from directions smoothed over ``smooth_s``. A frame qualifies when the gaze (camera axes) moves
    slower than ``max_gaze_speed_deg_s`` (no saccade), the target (``target_dir_world``, else head axes) slower
    than ``max_target_speed_deg_s`` and not faster at any time in the last ``settle_s``, and the target lies
    within ``max_eccentricity_deg`` of the head's forward axis (+Z).
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    th = np.asarray(target_dir_head, dtype=np.float64)
    tw = th if target_dir_world is None else np.asarray(target_dir_world, dtype=np.float64)
    n = g.shape[0]
    if n == 0:
        return np.zeros(0, dtype=bool)
    k = _odd(p.smooth_s * rate_hz)
    sg = _angular_speed(_smooth_dirs(g, k), rate_hz)
    st = _angular_speed(_smooth_dirs(tw, k), rate_hz)
    idx = np.arange(n)
    moving = ~(st <= p.max_target_speed_deg_s)            # NaN counts as moving
    last_move = np.maximum.accumulate(np.where(moving, idx, -n - 1))
    settled = (idx - last_move) > p.settle_s * rate_hz
    with np.errstate(invalid="ignore"):
        central = th[:, 2] >= np.cos(np.deg2rad(p.max_eccentricity_deg))
    return (sg <= p.max_gaze_speed_deg_s) & settled & central


def estimate_camera_rotation(gaze_cam: np.ndarray, target_dir_head: np.ndarray,
                             weights: np.ndarray | None = None, *, rate_hz: float | None = None,
                             params: EyesParams | None = None,
                             target_dir_world: np.ndarray | None = None) -> CameraEstimate:
    """Least-squares camera → head rotation from gaze and target directions while the gaze rests on the target.

    Parameters
    ----------
    gaze_cam : (N, 3) unit gaze vectors in camera axes, per mocap frame (NaN where invalid).
    target_dir_head : (N, 3) unit vectors from the eyes' centre (head centre, never the head markers' centroid:
        SPEC §3.5) to the target, in head axes.
    weights : (N,) non-negative weights or a bool mask; zero / False leaves a frame out. Default: all ones.
    rate_hz : the frames' rate; when given, frames are further restricted to :func:`fixation_frames`.
    params : :class:`EyesParams` (fixation rules, trimming, minimum frames).
    target_dir_world : (N, 3) the target direction in lab or character axes, for the target-speed rule of
        :func:`fixation_frames` (default: head axes).

    Returns
    -------
    :class:`CameraEstimate` (quaternion w, x, y, z with target ≈ R · gaze; the median residual angle in degrees
    over all candidate frames under the final rotation; the frames in the final fit).

    Method: ``Rotation.align_vectors`` (weighted Wahba / Kabsch) on the candidates, then ``refit_iterations``
    times: keep the candidates whose error is at most the ``keep_percentile`` percentile and re-fit. This drops
    frames where the eyes had not yet arrived, blinks that slipped through, and OpenFace outliers.

    Raises
    ------
    ValueError : fewer than ``min_fixation_frames`` candidate frames.
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    tdir = np.asarray(target_dir_head, dtype=np.float64)
    w = np.ones(g.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    cand = np.isfinite(g).all(axis=1) & np.isfinite(tdir).all(axis=1) & np.isfinite(w) & (w > 0)
    if rate_hz is not None:
        cand &= fixation_frames(g, tdir, rate_hz, p, target_dir_world=target_dir_world)
    n_cand = int(np.count_nonzero(cand))
    need = max(p.min_fixation_frames, 3)
    if n_cand < need:
        raise ValueError(f"only {n_cand} fixation frame(s) with valid gaze and target; need {need}")
    gi, ti, wi = g[cand], tdir[cand], w[cand]
    keep = np.ones(n_cand, dtype=bool)
    rot = Rotation.identity()
    for it in range(p.refit_iterations + 1):
        rot, _ = Rotation.align_vectors(ti[keep], gi[keep], weights=wi[keep])
        if it == p.refit_iterations:
            break
        err = angle_between(rot.apply(gi), ti)
        new = err <= np.percentile(err, p.keep_percentile)
        if np.count_nonzero(new) < 3 or np.array_equal(new, keep):
            break
        keep = new
    err = angle_between(rot.apply(gi), ti)
    return CameraEstimate(quat=to_wxyz(rot), residual_deg=float(np.rad2deg(np.median(err))),
                          n_used=int(np.count_nonzero(keep)))


def _delayed(v: np.ndarray, shift_frames: float) -> np.ndarray:
    """Directions (N, 3) as they were ``shift_frames`` frames earlier (fractional: interpolated between the two
    frames and renormalised); NaN before the first frame."""
    n = v.shape[0]
    pos = np.arange(n) - shift_frames
    i0 = np.floor(pos).astype(np.int64)
    f = (pos - i0)[:, None]
    ok = (i0 >= 0) & (i0 < n)
    i0c = np.clip(i0, 0, n - 1)
    i1c = np.clip(i0 + 1, 0, n - 1)
    out = _unit((1.0 - f) * v[i0c] + f * v[i1c]) if f.any() else v[i0c].copy()
    out[~ok] = np.nan
    return out


@dataclass
class _LagFit:
    lag_s: float
    residual_deg: float
    estimate: CameraEstimate | None
    frames: np.ndarray


def _lag_search(score, rate_hz: float, max_lag_s: float) -> _LagFit:
    """Best of ``score(shift_frames) -> _LagFit | None`` over whole frames 0..max_lag, then quarter frames
    around the best whole frame."""
    kmax = max(0, int(np.floor(max_lag_s * rate_hz + 1e-9)))
    fits = [f for k in range(kmax + 1) if (f := score(float(k))) is not None]
    if not fits:
        return score(0.0, raise_errors=True)   # re-run the zero lag to raise its error
    best = min(fits, key=lambda f: f.residual_deg)
    k0 = best.lag_s * rate_hz
    for d in (-0.75, -0.5, -0.25, 0.25, 0.5, 0.75):
        if 0.0 <= k0 + d <= kmax and (f := score(k0 + d)) is not None and f.residual_deg < best.residual_deg:
            best = f
    return best


def _world_targets(head_q: np.ndarray, target_dir_char: np.ndarray, char_rot: np.ndarray | None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: world-from-head rotations as (N, 3, 3) matrices (NaN where undefined) and the target direction
    in world axes (lab when ``char_rot`` is given and finite, else character axes)."""
    n = head_q.shape[0]
    w_head = np.full((n, 3, 3), np.nan)
    tw = np.full((n, 3), np.nan)
    use_lab = char_rot is not None and np.isfinite(char_rot).all(axis=1).any()
    c_ok = np.isfinite(char_rot).all(axis=1) if use_lab else np.ones(n, dtype=bool)
    ok = np.isfinite(head_q).all(axis=1) & c_ok
    if ok.any():
        r = from_wxyz(head_q[ok])
        if use_lab:
            r = from_wxyz(char_rot[ok]) * r
        w_head[ok] = r.as_matrix()
    okt = c_ok & np.isfinite(target_dir_char).all(axis=1)
    if okt.any():
        tw[okt] = from_wxyz(char_rot[okt]).apply(target_dir_char[okt]) if use_lab else target_dir_char[okt]
    return w_head, tw


def estimate_camera_rotation_lagged(gaze_cam: np.ndarray, head_rot_char: np.ndarray, target_dir_char: np.ndarray,
                                    rate_hz: float, weights: np.ndarray | None = None, *,
                                    char_rot: np.ndarray | None = None, params: EyesParams | None = None
                                    ) -> tuple[CameraEstimate, float]:
    """Camera → head rotation and the eyes' delay behind the target, fitted together.

    The eyes follow a moving target about 0.2 s late (Klein's subjects follow a pole that keeps moving), so the
    gaze at time t is paired with the target direction at t − lag, carried in world axes (lab, through
    ``char_rot``, where the eyes hold still while the head turns; else character axes) and rotated into the head
    axes at t. For each lag from 0 to ``max_lag_s`` (whole frames, then quarter frames around the best) the
    robust fit of :func:`estimate_camera_rotation` runs on that lag's fixation frames; the lag with the smallest
    median residual wins.

    Parameters
    ----------
    gaze_cam : (N, 3) unit gaze in camera axes per mocap frame, NaN where invalid.
    head_rot_char : (N, 4) w, x, y, z head rotation in the character frame.
    target_dir_char : (N, 3) unit direction from the eyes' centre to the target, character frame.
    rate_hz : mocap rate.
    weights : (N,) weights or mask (e.g. the eye validity).
    char_rot : (N, 4) w, x, y, z lab-from-character rotation, optional.

    Returns
    -------
    (:class:`CameraEstimate`, lag in seconds).

    Raises
    ------
    ValueError : no lag gives ``min_fixation_frames`` frames.
    """
    p = params or EyesParams()
    g = np.asarray(gaze_cam, dtype=np.float64)
    w_head, tw = _world_targets(np.asarray(head_rot_char, dtype=np.float64),
                                np.asarray(target_dir_char, dtype=np.float64),
                                None if char_rot is None else np.asarray(char_rot, dtype=np.float64))

    def score(shift: float, raise_errors: bool = False) -> _LagFit | None:
        twl = _delayed(tw, shift)
        th = np.einsum("nji,nj->ni", w_head, twl)         # head-from-world = transpose
        try:
            est = estimate_camera_rotation(g, th, weights, rate_hz=rate_hz, params=p, target_dir_world=twl)
        except ValueError:
            if raise_errors:
                raise
            return None
        return _LagFit(shift / rate_hz, est.residual_deg, est, th)

    best = _lag_search(score, rate_hz, p.max_lag_s)
    return best.estimate, best.lag_s


def combine_camera_estimates(quats: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """One camera rotation for a session from per-take estimates (the camera does not move between takes).

    Parameters
    ----------
    quats : (K, 4) w, x, y, z estimates, e.g. from the session's ``gaze_follow`` takes.
    weights : (K,) e.g. each estimate's ``n_used``; default equal.

    Returns
    -------
    (quaternion w, x, y, z of the weighted mean rotation (``Rotation.mean``), the largest angle in degrees
    between an estimate and that mean: a check that the takes agree).
    """
    r = from_wxyz(np.atleast_2d(np.asarray(quats, dtype=np.float64)))
    mean = r.mean(weights=None if weights is None else np.asarray(weights, dtype=np.float64))
    return to_wxyz(mean), float(np.rad2deg(np.max((r * mean.inv()).magnitude())))


def _target_spread_deg(v: np.ndarray) -> float:
    """RMS angle of directions (N, 3) from their normalised mean, degrees."""
    m = _unit(v.mean(axis=0))
    return float(np.rad2deg(np.sqrt(np.mean(angle_between(v, m[None, :]) ** 2))))


# ---------------------------------------------------------------------------------------------------------------
# composition


def _clock(clock: Any) -> ClockMap:
    """The sync stage's clock map for ``clock`` (a ClockMap, anything with ``offset_s`` and ``ratio``, or
    ``None`` for the identity)."""
    if isinstance(clock, ClockMap):
        return clock
    if clock is None:
        return ClockMap(offset_s=0.0, ratio=1.0, n_claps=0)
    return ClockMap(offset_s=float(clock.offset_s), ratio=float(clock.ratio), n_claps=0)


def _resample(g: Gated, mocap_time_s: np.ndarray, clock: ClockMap
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gated samples onto mocap times: (gaze (M, 3), valid (M,), confidence (M,), covered (M,)).

    Directions and confidence through the sync stage's :func:`~gazepipe.stages.sync.resample_to_mocap` (slerp
    between the two neighbouring video samples; the smaller confidence of the two; nothing past either end).
    A frame is valid only when both neighbours are valid (measured or filled) and they are no further apart
    than a fillable gap (missing video rows); an exact hit on one sample still needs its neighbour.
    """
    m = mocap_time_s.shape[0]
    n = g.n_samples
    if n < 2 or m == 0:
        return np.full((m, 3), np.nan), np.zeros(m, dtype=bool), np.full(m, np.nan), np.zeros(m, dtype=bool)
    gaze, covered = resample_to_mocap(g.time_s, g.gaze, "direction", mocap_time_s, clock)
    conf, _ = resample_to_mocap(g.time_s, g.confidence, "confidence", mocap_time_s, clock)
    tv = clock.to_mocap(g.time_s)
    i0 = np.clip(np.searchsorted(tv, mocap_time_s, side="right") - 1, 0, n - 2)
    i1 = i0 + 1
    near = (g.video_frame[i1] - g.video_frame[i0] - 1) <= g.max_gap_frames
    valid = covered & g.valid[i0] & g.valid[i1] & near & np.isfinite(gaze).all(axis=1)
    gaze[~valid] = np.nan
    return gaze, valid, conf, covered


def _check_rotation(gaze_cam: np.ndarray, r_cam: np.ndarray, head_q: np.ndarray, tdir_char: np.ndarray,
                    char_rot: np.ndarray | None, weights: np.ndarray, rate_hz: float, p: EyesParams
                    ) -> tuple[float | None, float | None, int]:
    """Median residual (degrees), eye lag (s) and frames of a configured rotation over the fixation frames
    (the lag searched as in :func:`estimate_camera_rotation_lagged`); ``None`` when too few frames."""
    w_head, tw = _world_targets(head_q, tdir_char, char_rot)
    v_head = camera_to_head(gaze_cam, r_cam)

    def score(shift: float, raise_errors: bool = False) -> _LagFit | None:
        twl = _delayed(tw, shift)
        th = np.einsum("nji,nj->ni", w_head, twl)
        ok = (np.asarray(weights, dtype=bool) & np.isfinite(v_head).all(axis=1) & np.isfinite(th).all(axis=1)
              & fixation_frames(gaze_cam, th, rate_hz, p, target_dir_world=twl))
        if np.count_nonzero(ok) < max(p.min_fixation_frames, 3):
            if raise_errors:
                raise ValueError("too few fixation frames")
            return None
        res = float(np.rad2deg(np.median(angle_between(v_head[ok], th[ok]))))
        return _LagFit(shift / rate_hz, res, None, ok)

    try:
        best = _lag_search(score, rate_hz, p.max_lag_s)
    except ValueError:
        return None, None, 0
    return best.residual_deg, best.lag_s, int(np.count_nonzero(best.frames))


def _head_index(names: list[str], head_segment: str | None, path: Any, take: str | None) -> int:
    if head_segment is not None:
        if head_segment not in names:
            raise StageError(path, f"eyes: head segment {head_segment!r} is not in the joints", take=take)
        return names.index(head_segment)
    return names.index("head") if "head" in names else len(names) - 1


def eyes_take(eye: Any, joints: Any, mocap_time_s: np.ndarray, clock: Any = None, *,
              camera_rotation: np.ndarray | None = None, params: EyesParams | None = None,
              path: Any = None, take: str | None = None) -> EyesResult:
    """Eye direction per mocap frame of one take (SPEC §3.5).

    Parameters
    ----------
    eye : the take's :class:`~gazepipe.io.tracks.EyeTrack` (video clock).
    joints : the take's :class:`~gazepipe.stages.frames.Joints` (``segments``, ``quat`` (N, S, 4) in the
        character frame, ``target_dir`` (N, 3) from the eyes' centre, ``rate_hz``, and optionally ``char_rot``
        (N, 4), the lab-from-character rotation, so target motion is judged in lab axes).
    mocap_time_s : (N,) mocap-clock seconds of the joints' rows (0 at the mocap file's first frame).
    clock : the sync stage's clock map (attributes ``offset_s``, ``ratio``: t_mocap = offset + ratio · t_video);
        ``None`` when both clocks are the same.
    camera_rotation : (4,) w, x, y, z camera → head rotation from the markerset's ``[camera]`` (or a session
        estimate, :func:`combine_camera_estimates`); ``None`` estimates it from this take together with the
        eyes' lag behind the target (:func:`estimate_camera_rotation_lagged`).
    params : :class:`EyesParams`.
    path, take : for error messages.

    Returns
    -------
    :class:`EyesResult`. A video sample that failed the gate and was not filled never contributes to a valid
    frame. QC adds to the gate's record: frames, valid frames, frames without video coverage, frames without a
    head rotation, the clock map, the camera rotation and its source, its residual angle (median over the
    fixation frames; also for a configured rotation, as a check), the frames used, the eyes' lag behind the
    target (s), and the spread of the target directions in head axes (degrees; small = poorly conditioned).

    Raises
    ------
    StageError : the head segment is missing, the time array does not match the joints, or the camera rotation
        has to be estimated and the take has too few fixation frames.
    """
    p = params or EyesParams()
    g = gate(eye, min_confidence=p.min_confidence, max_eye_gap_s=p.max_eye_gap_s)
    mt = np.asarray(mocap_time_s, dtype=np.float64)
    quat_all = np.asarray(joints.quat, dtype=np.float64)
    n = quat_all.shape[0]
    if mt.shape != (n,):
        raise StageError(path, f"eyes: {mt.shape[0] if mt.ndim == 1 else mt.shape} mocap times for {n} "
                         f"joint frames", take=take)
    head_q = quat_all[:, _head_index(list(joints.segments), p.head_segment, path, take)]
    head_ok = np.isfinite(head_q).all(axis=1)
    cmap = _clock(clock)
    gaze_cam, eye_valid, conf, covered = _resample(g, mt, cmap)

    qc = dict(g.qc)
    qc["warnings"] = list(g.qc["warnings"])
    if clock is None:
        qc["warnings"].append("no clock map: video and mocap clocks taken as the same")

    # the camera rotation: configured, or fitted together with the eyes' delay behind the target
    rate = float(joints.rate_hz)
    tdir_char = np.asarray(getattr(joints, "target_dir", np.full((n, 3), np.nan)), dtype=np.float64)
    char_rot = getattr(joints, "char_rot", None)
    char_rot = None if char_rot is None else np.asarray(char_rot, dtype=np.float64)
    lag: float | None = None
    residual: float | None = None
    if camera_rotation is None:
        if not eye_valid.any():
            raise StageError(path, f"eyes: cannot estimate the camera rotation: no frame has valid eye data "
                             f"({int(np.count_nonzero(covered))} of {n} frames covered by the video, "
                             f"{g.qc['gated_share']:.0%} of the video's samples gated out)", take=take)
        try:
            est, lag = estimate_camera_rotation_lagged(gaze_cam, head_q, tdir_char, rate, eye_valid,
                                                       char_rot=char_rot, params=p)
        except ValueError as e:
            raise StageError(path, f"eyes: cannot estimate the camera rotation: {e}", take=take) from None
        r_cam, source, residual, n_used = est.quat, "estimated", est.residual_deg, est.n_used
    else:
        r_cam = to_wxyz(from_wxyz(np.asarray(camera_rotation, dtype=np.float64)))
        source = "configured"
        residual, lag, n_used = _check_rotation(gaze_cam, r_cam, head_q, tdir_char, char_rot, eye_valid, rate, p)
    tdir_head = np.einsum("nji,nj->ni", _world_targets(head_q, tdir_char, None)[0], tdir_char)
    seen = eye_valid & np.isfinite(tdir_head).all(axis=1)
    spread = _target_spread_deg(tdir_head[seen]) if np.count_nonzero(seen) >= 3 else None
    if source == "estimated" and spread is not None and spread < p.min_target_spread_deg:
        qc["warnings"].append(f"target directions spread only {spread:.1f} deg in head axes: "
                              "the camera rotation is poorly determined")

    eye_dir_head = np.where(eye_valid[:, None], camera_to_head(gaze_cam, r_cam), np.nan)
    eye_dir_char = head_to_character(eye_dir_head, head_q)
    valid = eye_valid & head_ok
    eye_dir_char[~valid] = np.nan

    qc.update({
        "frames": int(n),
        "valid_frames": int(np.count_nonzero(valid)),
        "valid_share": float(np.count_nonzero(valid) / n) if n else 0.0,
        "frames_without_coverage": int(np.count_nonzero(~covered)),
        "frames_without_head": int(np.count_nonzero(covered & ~head_ok)),
        "clock_offset_s": float(cmap.offset_s),
        "clock_ratio": float(cmap.ratio),
        "camera_rotation": [float(x) for x in r_cam],
        "camera_rotation_source": source,
        "camera_residual_deg": residual,
        "camera_frames_used": int(n_used),
        "eye_lag_s": lag,
        "camera_target_spread_deg": spread,
    })
    return EyesResult(eye_dir_char=eye_dir_char, eye_dir_head=eye_dir_head, valid=valid, confidence=conf,
                      covered=covered, camera_rotation=r_cam, camera_source=source, gated=g, qc=qc)
