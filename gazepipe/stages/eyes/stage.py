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

The steps live in their own modules (see the package); this module composes them per take
(:func:`eyes_take`).

Axes: see :mod:`~gazepipe.stages.eyes.camera` (the camera of a head-mounted rig looks back at the face:
:data:`CAMERA_FACING_FACE`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazepipe.errors import StageError
from gazepipe.stages.eyes.camera import (
    _target_spread_deg,
    camera_to_head,
    head_to_character,
)
from gazepipe.stages.eyes.gate import Gated, gate
from gazepipe.stages.eyes.lag import check_camera_rotation, estimate_camera_rotation_lagged, world_targets
from gazepipe.stages.eyes.params import SHORT_VIDEO_SHARE, EyesParams
from gazepipe.stages.eyes.qc import EyesQC
from gazepipe.stages.geometry import from_wxyz, to_wxyz
from gazepipe.stages.sync.clock import ClockMap, resample_to_mocap


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

    Directions and confidence through the sync stage's :func:`~gazepipe.stages.sync.clock.resample_to_mocap` (slerp
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




def _head_index(names: list[str], head_segment: str | None, path: Any, take: str | None) -> int:
    if head_segment is not None:
        if head_segment not in names:
            raise StageError(path, f"eyes: head segment {head_segment!r} is not in the joints", take=take)
        return names.index(head_segment)
    return names.index("head") if "head" in names else len(names) - 1


@dataclass(frozen=True)
class HeadMotion:
    """What the eyes stage reads of a take's segment orientations (the ``joints`` table, or a
    :class:`~gazepipe.stages.frames.stage.Joints`): ``segments`` names, ``quat`` (N, S, 4) w, x, y, z in the
    character frame, ``rate_hz``, and optionally ``target_dir`` (N, 3) from the eyes' centre and ``char_rot``
    (N, 4), the lab-from-character rotation."""

    segments: tuple[str, ...]
    quat: np.ndarray
    rate_hz: float
    target_dir: np.ndarray | None = None
    char_rot: np.ndarray | None = None


def _short_video(video: tuple[Any, ...] | None, take_s: float, take: str | None) -> None:
    """Raise the error that names the video when it lasts less than :data:`SHORT_VIDEO_SHARE` of the take."""
    if video is None or video[0] is None or not video[1] < SHORT_VIDEO_SHARE * take_s:
        return
    raise StageError(video[0], f"eyes: cannot estimate the camera rotation: the video lasts {video[1]:.1f} s, "
                               f"the take's frames {take_s:.1f} s (a video far shorter than its take: the wrong "
                               "or a cut file?)", take=take)


#: how far (share) the eye tracking's frame rate may be from the video's tag before the tag is named as wrong
TAG_TOLERANCE = 0.01


def eye_track_rate(eye: Any) -> float | None:
    """The frame rate the eye tracking was timed at (OpenFace times its rows by the video's frame rate tag): its
    frame numbers over its timestamps; None when it cannot tell."""
    f = np.asarray(getattr(eye, "frame", ()), dtype=np.float64)
    t = np.asarray(getattr(eye, "time_s", ()), dtype=np.float64)
    if f.size < 2 or t.size != f.size or not t[-1] > t[0]:
        return None
    return float((f[-1] - f[0]) / (t[-1] - t[0]))


def tag_mismatch(video: tuple[Any, ...] | None, eye: Any) -> str | None:
    """What is wrong when the video's frame rate tag (``video[3]``, fps) is not the rate its eye tracking was
    timed at: a video re-tagged after OpenFace ran, or the eye tracking of another file. None when they agree or
    either is unknown."""
    fps = float(video[3]) if video is not None and len(video) > 3 and video[3] else None
    rate = eye_track_rate(eye)
    if fps is None or rate is None or not np.isfinite(fps) or abs(rate / fps - 1.0) <= TAG_TOLERANCE:
        return None
    return (f"the video is tagged {fps:g} fps but its eye tracking was timed at {rate:.4g} fps (a frame rate tag "
            "that is not the camera's, or the eye tracking of another video)")


def _video_at_fault(video: tuple[Any, ...] | None, take_s: float, eye: Any, take: str | None) -> None:
    """Raise the error naming the video when the camera rotation cannot be estimated because of it: a video far
    shorter than its take (:func:`_short_video`), or one whose frame rate tag its eye tracking contradicts."""
    _short_video(video, take_s, take)
    why = tag_mismatch(video, eye)
    if why is not None and video is not None and video[0] is not None:
        raise StageError(video[0], f"eyes: cannot estimate the camera rotation: {why}", take=take)


def eyes_take(eye: Any, joints: HeadMotion | Any, mocap_time_s: np.ndarray, clock: Any = None, *,
              camera_rotation: np.ndarray | None = None, params: EyesParams | None = None,
              path: Any = None, take: str | None = None,
              video: tuple[Any, ...] | None = None) -> EyesResult:
    """Eye direction per mocap frame of one take (SPEC §3.5).

    Parameters
    ----------
    eye : the take's :class:`~gazepipe.model.EyeTrack` (video clock).
    joints : the take's :class:`~gazepipe.stages.frames.stage.Joints` (``segments``, ``quat`` (N, S, 4) in the
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
    video : the take's head-camera video, its duration (s) and optionally its frame count and its frame rate
        tag (fps), for error messages: a camera rotation that cannot be estimated while the video lasts less
        than :data:`SHORT_VIDEO_SHARE` of the take, or while its tag contradicts the rate its eye tracking was
        timed at, is the video's fault (the error names it), not the eyes file's (the pipeline warns of the
        second, naming the video, when the rotation is estimated anyway: :func:`tag_mismatch`).

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

    warnings = list(g.qc["warnings"])
    if clock is None:
        warnings.append("no clock map: video and mocap clocks taken as the same")

    # the camera rotation: configured, or fitted together with the eyes' delay behind the target
    rate = float(joints.rate_hz)
    tdir = getattr(joints, "target_dir", None)
    tdir_char = np.full((n, 3), np.nan) if tdir is None else np.asarray(tdir, dtype=np.float64)
    char_rot = getattr(joints, "char_rot", None)
    char_rot = None if char_rot is None else np.asarray(char_rot, dtype=np.float64)
    lag: float | None = None
    residual: float | None = None
    if camera_rotation is None:
        if not eye_valid.any():
            _video_at_fault(video, n / rate, eye, take)
            raise StageError(path, f"eyes: cannot estimate the camera rotation: no frame has valid eye data "
                             f"({int(np.count_nonzero(covered))} of {n} frames covered by the video, "
                             f"{g.qc['gated_share']:.0%} of the video's samples gated out)", take=take)
        try:
            est, lag = estimate_camera_rotation_lagged(gaze_cam, head_q, tdir_char, rate, eye_valid,
                                                       char_rot=char_rot, params=p)
        except ValueError as e:
            _video_at_fault(video, n / rate, eye, take)
            raise StageError(path, f"eyes: cannot estimate the camera rotation: {e}", take=take) from None
        r_cam, source, residual, n_used = est.quat, "estimated", est.residual_deg, est.n_used
    else:
        r_cam = to_wxyz(from_wxyz(np.asarray(camera_rotation, dtype=np.float64)))
        source = "configured"
        residual, lag, n_used = check_camera_rotation(gaze_cam, r_cam, head_q, tdir_char, char_rot, eye_valid,
                                                      rate, p)
    tdir_head = np.einsum("nji,nj->ni", world_targets(head_q, tdir_char, None)[0], tdir_char)
    seen = eye_valid & np.isfinite(tdir_head).all(axis=1)
    spread = _target_spread_deg(tdir_head[seen]) if np.count_nonzero(seen) >= 3 else None
    if source == "estimated" and spread is not None and spread < p.min_target_spread_deg:
        warnings.append(f"target directions spread only {spread:.1f} deg in head axes: "
                              "the camera rotation is poorly determined")

    eye_dir_head = np.where(eye_valid[:, None], camera_to_head(gaze_cam, r_cam), np.nan)
    eye_dir_char = head_to_character(eye_dir_head, head_q)
    valid = eye_valid & head_ok
    eye_dir_char[~valid] = np.nan

    gq = g.qc                                   # the gate's counts, on the video's samples
    qc = EyesQC(
        samples=gq["samples"], video_rate_hz=gq["video_rate_hz"], gated_share=gq["gated_share"],
        gated_by=gq["gated_by"], filled_samples=gq["filled_samples"], invalid_share=gq["invalid_share"],
        longest_invalid_run_s=gq["longest_invalid_run_s"], missing_video_frames=gq["missing_video_frames"],
        min_confidence=gq["min_confidence"], max_eye_gap_s=gq["max_eye_gap_s"], warnings=tuple(warnings),
        frames=int(n),
        valid_frames=int(np.count_nonzero(valid)),
        valid_share=float(np.count_nonzero(valid) / n) if n else 0.0,
        frames_without_coverage=int(np.count_nonzero(~covered)),
        frames_without_head=int(np.count_nonzero(covered & ~head_ok)),
        clock_offset_s=float(cmap.offset_s),
        clock_ratio=float(cmap.ratio),
        camera_rotation=(float(r_cam[0]), float(r_cam[1]), float(r_cam[2]), float(r_cam[3])),
        camera_rotation_source=source,
        camera_residual_deg=residual,
        camera_frames_used=int(n_used),
        eye_lag_s=lag,
        camera_target_spread_deg=spread,
    ).to_record()
    return EyesResult(eye_dir_char=eye_dir_char, eye_dir_head=eye_dir_head, valid=valid, confidence=conf,
                      covered=covered, camera_rotation=r_cam, camera_source=source, gated=g, qc=qc)
