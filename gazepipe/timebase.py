"""Rates, units and time helpers shared by readers and stages."""

from __future__ import annotations

import math

import numpy as np

#: millimetres per unit, for every unit a capture file may declare
UNIT_TO_MM: dict[str, float] = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "dm": 100.0, "in": 25.4}


def unit_scale_to_mm(units: str | None, default: str = "mm") -> float:
    """Factor that turns values in ``units`` into millimetres.

    ``None`` or an empty string falls back to ``default``. Raises ``KeyError`` for an unknown unit.
    """
    u = (units or default or "mm").strip().lower()
    u = {"millimeters": "mm", "millimetres": "mm", "meters": "m", "metres": "m",
         "centimeters": "cm", "centimetres": "cm", "inches": "in"}.get(u, u)
    return UNIT_TO_MM[u]


def snap_rate(rate_hz: float) -> float:
    """Return the exact rate for a nominal one.

    A rate within 0.05 % of N·1000/1001 Hz for a whole N (29.97, 59.94, 119.88 …) is taken as exactly that;
    any other rate is returned unchanged.
    """
    r = float(rate_hz)
    if not math.isfinite(r) or r <= 0:
        return r
    n = round(r * 1001.0 / 1000.0)
    if n >= 1:
        exact = n * 1000.0 / 1001.0
        if abs(r - exact) <= 5e-4 * exact and abs(r - n) > 5e-4 * n:
            return exact
    return r


def frame_times(n_frames: int, rate_hz: float) -> np.ndarray:
    """Time in seconds of each frame, 0 at the first frame (float64, shape (n_frames,))."""
    return np.arange(n_frames, dtype=np.float64) / float(rate_hz)


def video_rate(rate_hz: float) -> float:
    """A measured video rate snapped to N·1000/1001 (:func:`snap_rate`) or to a whole N within 0.05 %: OpenFace
    writes timestamps rounded to the millisecond, which alone moves a 60 Hz estimate off 60."""
    r = snap_rate(rate_hz)
    n = round(r)
    return float(n) if r == rate_hz and n >= 1 and abs(r - n) <= 5e-4 * n else r


def video_frames(t: np.ndarray, frame: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Video frame index per row and the frame period in seconds, from a video track's timestamps.

    With frame numbers, the period is the time span over the frame span; without, the median positive time
    step, and indices follow from the timestamps. The rate is snapped by :func:`video_rate`. The period is NaN
    when the timestamps never advance.
    """
    n = t.shape[0]
    if frame is not None and n >= 2 and frame[-1] > frame[0] and t[-1] > t[0]:
        rate = video_rate((frame[-1] - frame[0]) / (t[-1] - t[0]))
        return np.asarray(frame, dtype=np.int64), 1.0 / rate
    steps = np.diff(t)
    steps = steps[steps > 0]
    if steps.size == 0:
        return np.arange(n, dtype=np.int64), float("nan")
    dt = 1.0 / video_rate(1.0 / float(np.median(steps)))
    return np.round((t - t[0]) / dt).astype(np.int64), dt
