"""Rates, units and time helpers shared by readers and stages."""

from __future__ import annotations

import math
from decimal import Decimal, InvalidOperation

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


#: the frame rates that have an NTSC variant N·1000/1001: multiples of 24 (film) and 30 (video). The 1000/1001
#: slowdown came with NTSC colour television; the rates derived from it are 23.976, 29.97, 47.952, 59.94,
#: 119.88, 239.76 … A capture genlocked to such video runs at one of them; 70·1000/1001 = 69.93 is nobody's rate.
NTSC_BASES: tuple[int, ...] = (24, 30)


def ntsc_rate(n: int) -> float | None:
    """N·1000/1001 Hz when the whole rate ``n`` has an NTSC variant (:data:`NTSC_BASES`), else None."""
    if n >= 1 and any(n % b == 0 for b in NTSC_BASES):
        return n * 1000.0 / 1001.0
    return None


def snap_rate(rate_hz: float, rel_tol: float = 5e-4) -> float:
    """The exact rate for a measured one (from timestamps or steps, not a rate a file states: see
    :func:`stated_rate`).

    A rate within ``rel_tol`` of N·1000/1001 Hz for an N that has an NTSC variant (:func:`ntsc_rate`: 29.97,
    59.94, 119.88 …), and not within ``rel_tol`` of N itself, is taken as exactly N·1000/1001; any other rate is
    returned unchanged.
    """
    r = float(rate_hz)
    if not math.isfinite(r) or r <= 0:
        return r
    n = round(r * 1001.0 / 1000.0)
    exact = ntsc_rate(n)
    if exact is not None and abs(r - exact) <= rel_tol * exact and abs(r - n) > rel_tol * n:
        return exact
    return r


def written_digits(rate: float | str, *, float32: bool = False) -> str:
    """A rate as the file wrote it: ``rate`` itself when it is text, else the shortest decimal that reads back
    as the same float (as the same 32-bit float when ``float32``: C3D stores rates as 4-byte reals)."""
    if isinstance(rate, str):
        return rate.strip()
    if float32:
        return np.format_float_positional(np.float32(rate), unique=True, trim="-")
    return repr(float(rate))


def stated_rate(rate: float | str, *, float32: bool = False) -> float:
    """The rate a file or a setting states, in Hz: as written, except an NTSC rate written rounded.

    The written value (:func:`written_digits`) stands for any rate within half a unit of its last digit. When
    that interval holds N·1000/1001 for an N with an NTSC variant (:func:`ntsc_rate`) and does not hold N itself,
    the rate is taken as exactly N·1000/1001 (``29.97`` and ``29.970`` are 30000/1001 Hz, ``59.9`` is
    60000/1001 Hz); otherwise it is the written value (``69.9`` stays 69.9 Hz, ``60`` stays 60 Hz). A rate that
    is not a finite positive number is returned as read, for the caller to refuse.

    Parameters
    ----------
    rate : the rate as text (a CSV's rate cell) or as a number (a TOML value, a command-line option).
    float32 : ``rate`` was stored as a 32-bit float (a C3D's POINT:RATE): its shortest 32-bit decimal is what
        was written.
    """
    text = written_digits(rate, float32=float32)
    try:
        written = Decimal(text)
    except InvalidOperation:
        return float(rate) if not isinstance(rate, str) else math.nan
    value = float(written)
    if not (written.is_finite() and math.isfinite(value) and value > 0):
        return value
    exponent = written.as_tuple().exponent
    assert isinstance(exponent, int)            # a finite Decimal's exponent is a number
    half = 0.5 * 10.0 ** min(exponent, 300)
    n = round(value * 1001.0 / 1000.0)
    exact = ntsc_rate(n)
    # a hair over half a unit: the decimal and its binary float differ by an ulp
    slack = half * (1.0 + 1e-9)
    if exact is not None and abs(value - exact) <= slack and abs(value - n) > slack:
        return exact
    return value


#: the rates (Hz) a kind of track can have: outside them the rate is more likely a broken clock or a misread
#: file than a capture. ``video``: face cameras and OpenFace (webcams 5 fps and up; phones' slow motion at most
#: 240 fps); ``face``: ARKit face tracking (Live Link Face), which runs at 60 Hz at most; ``mocap``: optical
#: marker capture (below 10 Hz there is no motion capture system; above 10 kHz the readers refuse the file).
PLAUSIBLE_HZ: dict[str, tuple[float, float]] = {"video": (5.0, 300.0), "face": (10.0, 60.0 * 1.01),
                                                "mocap": (10.0, 10_000.0)}


def implausible_rate(rate_hz: float, kind: str) -> str | None:
    """Why ``rate_hz`` is implausible for a ``kind`` of track (a key of :data:`PLAUSIBLE_HZ`), or None when it
    is within its range."""
    lo, hi = PLAUSIBLE_HZ[kind]
    if not math.isfinite(rate_hz) or lo <= rate_hz <= hi:
        return None
    what = {"video": "a face video", "face": "ARKit face tracking", "mocap": "a marker capture"}[kind]
    return f"{rate_hz:.6g} Hz is implausible for {what} ({lo:g}-{hi:.4g} Hz)"


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
