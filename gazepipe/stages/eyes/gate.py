"""The eyes stage's first steps (SPEC §3.5): gating OpenFace samples on the video clock, filling short invalid runs
by slerp, and the cyclopean gaze; with the unit-vector helpers the other eyes modules use.

A sample is valid when ``success`` and ``confidence >= min_confidence`` and not a blink and both gaze vectors
exist; invalid runs of at most ``max_eye_gap_s`` between two valid samples are filled by slerp (per eye); longer
runs and runs at either end stay invalid. The cyclopean gaze is the normalised mean of both eyes (OpenFace cannot
resolve vergence, Klein 5.2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gazepipe.stages.geometry import slerp_vectors, unit_or_nan
from gazepipe.timebase import video_frames

__all__ = ["GATE_REASONS", "Gated", "cyclopean", "gate"]

#: why a video sample is gated out, by code (first failing rule in this order wins)
GATE_REASONS = ("valid", "success", "confidence", "blink", "no_gaze")


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


def cyclopean(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The cyclopean gaze direction: the normalised mean of both eyes' unit vectors, (N, 3).

    Any axes (camera axes in this stage). NaN where either eye is NaN or the mean vanishes.
    """
    return unit_or_nan(np.asarray(left, dtype=np.float64) + np.asarray(right, dtype=np.float64))


# ---------------------------------------------------------------------------------------------------------------
# gating


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and stop (exclusive) rows of the runs of True in a 1-D mask."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def gate(eye: Any, *, min_confidence: float = 0.8, max_eye_gap_s: float = 0.1) -> Gated:
    """Gate OpenFace samples and fill short invalid runs by slerp, on the video clock (SPEC §3.5).

    Parameters
    ----------
    eye : an :class:`~gazepipe.model.EyeTrack` or any object with ``time_s`` (N,), ``success`` (N,),
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
    fidx, dt = video_frames(t, None if frame_raw is None else np.asarray(frame_raw))

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
    qc: dict[str, Any] = {
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

