"""Bounds the readers apply before they trust, allocate for or parse what a file declares.

Each bound is far above anything a real capture or configuration needs, and low enough that a file beyond it
is refused in bounded memory and time instead of exhausting the machine:

* :data:`MAX_LINE_BYTES`: a text line (CSV header or row, TSV row) over 1 MiB. The widest real exports are a
  few tens of kB a row (a Vicon Nexus row of 300 markers with velocities and accelerations is under 40 kB; a
  Live Link Face row under 2 kB; an OpenFace row about 6 kB). Lines are measured with a bounded streaming read
  (:func:`check_line_lengths`) before pandas sees the file.
* :data:`MAX_TOML_BYTES`, :data:`MAX_TOML_DEPTH`: a session.toml or markerset.toml over 1 MiB (a session of
  5,000 takes is about 1 MB), or nested deeper than 16 arrays or tables (the files need 4).
* :data:`MAX_ID_CHARS`: a session, subject or take id over 100 characters. Ids name output folders and files
  (with suffixes and temporary-file prefixes), and most file systems refuse a name over 255 bytes.
* :data:`MIN_RATE_HZ`, :data:`MAX_RATE_HZ`: a capture rate outside 1 Hz - 10 kHz. Optical systems record at
  30 Hz - 2 kHz (a few high-speed modes reach 10 kHz); below 1 Hz there is no motion to learn from, and a rate
  near 0 or 1e30 only makes every time or frame count absurd downstream.
* :data:`MAX_ABS_MM`: a coordinate farther than 1 km (1e6 mm) from the lab origin. The largest optical or
  inertial capture volumes span tens of metres; beyond 1e6 mm a float32 coordinate (the C3D storage) no longer
  resolves a tenth of a millimetre (its step there is 0.06 mm, 0.125 mm past 2^20 mm), so such a value is a
  corrupted sample, not a measurement. It becomes a gap, with a warning naming the markers.
* :data:`MIN_REACH_MM`, :data:`MAX_EXTENT_MM`: a capture whose valid samples all lie within 1 mm of the origin,
  or span more than 100 m. A person in a capture volume moves over metres, some markers a metre or more from
  the lab origin; markers that never leave a 1 mm ball around it are a scale or unit that shrank the capture
  (a ``POINT:SCALE`` of 1e-30, a file in km), and are refused. The largest optical or inertial volumes span
  tens of metres: a span beyond 100 m is a scale or unit that blew it up (a coordinate in micrometres read
  as mm), and is warned of (the samples themselves are still within :data:`MAX_ABS_MM`).
* :data:`MIN_RATE_HZ`, :data:`MAX_RATE_HZ` hold for every rate a file or a session gives, not only C3D's
  (:func:`rate_problem`).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import InputError

MAX_LINE_BYTES = 1 << 20
MAX_TOML_BYTES = 1 << 20
MAX_TOML_DEPTH = 16
MAX_ID_CHARS = 100
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 10_000.0
MAX_ABS_MM = 1e6
MIN_REACH_MM = 1.0
MAX_EXTENT_MM = 1e5
#: the largest frame number a text export or an OpenFace CSV may carry (exporters count frames in 32 bits)
MAX_FRAME = 2**31 - 1

_CHUNK = 4 << 20   # bytes read at a time by check_line_lengths
_SPAN_SAMPLES = 1 << 16   # samples (frames x markers) looked at a time by coordinate_span


def rate_problem(rate: float) -> str | None:
    """Why a capture rate (Hz) is implausible (outside :data:`MIN_RATE_HZ` - :data:`MAX_RATE_HZ`, or not a
    finite number), or None when it is within them."""
    if MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        return None
    return (f"{rate:.6g} Hz is outside {MIN_RATE_HZ:g} Hz - {MAX_RATE_HZ / 1000:g} kHz, the range of a motion "
            "capture")


def coordinate_span(xyz: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis least and greatest coordinate (two (3,) arrays, mm) of the valid samples of ``xyz`` (T, M, 3)
    that are not exactly (0, 0, 0) (``valid`` (T, M)); +inf and -inf where there is none.

    Looked at about :data:`_SPAN_SAMPLES` samples at a time (a few MB), so a long capture is not copied whole.
    Spans of parts of a capture combine with ``numpy.fmin`` / ``numpy.fmax``.
    """
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    step = max(1, _SPAN_SAMPLES // max(1, xyz.shape[1]))
    for a in range(0, xyz.shape[0], step):
        sub = xyz[a: a + step]
        use = valid[a: a + step] & (sub != 0).any(axis=2)
        if use.any():
            pts = sub[use]
            lo = np.fmin(lo, pts.min(axis=0))
            hi = np.fmax(hi, pts.max(axis=0))
    return lo, hi


def span_problem(lo: np.ndarray, hi: np.ndarray) -> tuple[bool, str] | None:
    """What is implausible about a capture's span (:func:`coordinate_span`): ``(True, why)`` when every
    sample lies within :data:`MIN_REACH_MM` of the origin (a refusal), ``(False, why)`` when the samples span
    more than :data:`MAX_EXTENT_MM` (a warning); None when the span is that of a capture, or empty."""
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return None
    reach = float(np.max(np.maximum(np.abs(lo), np.abs(hi))))
    if reach < MIN_REACH_MM:
        return True, (f"every marker sample lies within {reach:.3g} mm of the origin (less than "
                      f"{MIN_REACH_MM:g} mm: no capture of a person)")
    extent = float(np.max(hi - lo))
    if extent > MAX_EXTENT_MM:
        return False, (f"the marker samples span {extent / 1000:,.0f} m (more than {MAX_EXTENT_MM / 1000:,.0f} "
                       "m: no capture volume is that large)")
    return None


@functools.cache
def exact_floats() -> dict[str, Any]:
    """``pandas.read_csv`` keyword arguments (C engine) that parse every float to the nearest double, whatever the pandas version.

    Before pandas 3.1 the C parser's default converter can be one unit in the last place off on some inputs;
    its ``"round_trip"`` converter is Python's, correctly rounded. From 3.1 on every converter is correctly
    rounded and the argument is deprecated, so none is passed.
    """
    import pandas as pd

    try:
        major, minor = (int(part) for part in pd.__version__.split(".")[:2])
    except ValueError:
        return {"float_precision": "round_trip"}
    return {"float_precision": "round_trip"} if (major, minor) < (3, 1) else {}


def check_line_lengths(path: str | Path, limit: int = MAX_LINE_BYTES, what: str = "text file") -> None:
    """Raise :class:`InputError` as soon as a line of ``path`` longer than ``limit`` bytes is seen.

    The file is read in 4 MiB chunks, so memory stays bounded whatever the file holds (a gigabyte without a
    newline is refused after the first MiB past the limit). Missing or unreadable files are left to the
    caller's own read, which names the problem.
    """
    p = Path(path)
    try:
        fh = open(p, "rb")  # closed by the with-block below
    except OSError:
        return
    with fh:
        run = 0            # bytes of the current line seen so far
        lines = 0          # complete lines before the current one
        while True:
            try:
                chunk = fh.read(_CHUNK)
            except OSError:
                return
            if not chunk:
                return
            nl = np.flatnonzero(np.frombuffer(chunk, dtype=np.uint8) == 10)
            if nl.size:
                lengths = np.diff(nl, prepend=-1 - run) - 1
                long = np.flatnonzero(lengths > limit)
                if long.size:
                    _too_long(p, lines + int(long[0]) + 1, limit, what)
                lines += int(nl.size)
                run = len(chunk) - int(nl[-1]) - 1
            else:
                run += len(chunk)
            if run > limit:
                _too_long(p, lines + 1, limit, what)


def _too_long(path: Path, line: int, limit: int, what: str) -> None:
    size = f"{limit // (1 << 20)} MiB" if limit % (1 << 20) == 0 else f"{limit} bytes"
    raise InputError(path, f"line {line} is longer than {size}, more than any {what} holds (a broken file?)")
