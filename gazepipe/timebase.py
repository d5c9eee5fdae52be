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
