"""Live Link Face CSV reader.

A Live Link Face take is ``Timecode, BlendShapeCount``, the 52 ARKit blendshapes (PascalCase), then
``HeadYaw, HeadPitch, HeadRoll`` and the left and right eyes' yaw, pitch and roll. Angles are radians: in the
real take in ``corpus/livelinkface`` the eyes' pitch runs 0.14-0.29 with yaw within ±0.1, which is 8-17° and
±6° as radians and would be a fraction of a degree as degrees.

The timecode is ``HH:MM:SS:FF.fff``: FF counts frames at the timecode rate (60 by default) and ``.fff`` is a
fraction of a frame. The capture rate is not in the file (a 30 Hz capture on a 60 fps timecode steps by 2);
frames the phone dropped show up as larger steps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from gazepipe.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, normalise_name
from gazepipe.errors import InputError, printable
from gazepipe.io.tracks import read_columns, read_header
from gazepipe.model import FaceTrack
from gazepipe.timebase import snap_rate

__all__ = ["FaceTrack", "parse_timecodes", "read_livelinkface"]

_TC = r"^(\d{1,2}):(\d{2}):(\d{2}):(\d{2,3})(?:\.(\d+))?$"
_WHAT = "Live Link Face CSV"


def parse_timecodes(timecode: np.ndarray, timecode_fps: float, *, path: str | Path | None = None,
                    key: str = "Timecode") -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Turn ``HH:MM:SS:FF[.fff]`` strings into timecode frames since midnight plus a fraction of a frame.

    FF counts ``round(timecode_fps)`` labels a second (non-drop-frame); a take that crosses midnight (one step
    from 23:59:59 back to 00:00:00) keeps counting past 24 h, with a warning.

    Returns
    -------
    tc_frame : (N,) int64 whole timecode frames since midnight.
    subframe : (N,) float64 fraction of a frame in [0, 1).
    warnings : one-line notes.
    """
    fps = float(timecode_fps)
    nominal = int(round(fps))
    if not np.isfinite(fps) or fps <= 0 or nominal < 1:
        raise InputError(path, f"timecode_fps must be a positive rate, got {timecode_fps!r}")
    s = pd.Series(timecode, dtype=str)
    parts = s.str.extract(_TC)
    bad = parts[0].isna().to_numpy()
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise InputError(path, f"{_WHAT}: timecode {s.iloc[r][:30]!r} in data row {r + 1} is not "
                               "HH:MM:SS:FF.fff", key=key)
    hh, mm, ss, ff = (parts[i].astype(np.int64).to_numpy() for i in range(4))
    out = (hh >= 24) | (mm >= 60) | (ss >= 60) | (ff >= nominal)
    if out.any():
        r = int(np.flatnonzero(out)[0])
        raise InputError(path, f"{_WHAT}: timecode {s.iloc[r]!r} in data row {r + 1} is out of range "
                               f"(FF counts {nominal} frames a second)", key=key)
    subframe = ("0." + parts[4].fillna("0")).astype(np.float64).to_numpy()
    tc_frame = ((hh * 60 + mm) * 60 + ss) * nominal + ff
    warnings: list[str] = []
    if tc_frame.size > 1:
        step = np.diff(tc_frame) + np.diff(subframe)
        day = 86400 * nominal
        wrap = (step <= 0) & (step + day > 0) & (step + day <= nominal)
        if wrap.sum() == 1:
            r = int(np.flatnonzero(wrap)[0]) + 1
            tc_frame[r:] += day
            step[r - 1] += day
            warnings.append(f"timecode crosses midnight at data row {r + 1}; counted on past 24 h")
        elif wrap.sum() > 1:
            r = int(np.flatnonzero(wrap)[1]) + 2
            raise InputError(path, f"{_WHAT}: timecode wraps past midnight twice (data row {r})", key=key)
        back = step <= 0
        if back.any():
            r = int(np.flatnonzero(back)[0]) + 2
            raise InputError(path, f"{_WHAT}: timecode does not increase at data row {r} "
                                   f"({s.iloc[r - 2]} then {s.iloc[r - 1]})", key=key)
    return tc_frame, subframe, warnings


def _estimate_rate(median_step_s: float) -> float:
    est = 1.0 / median_step_s
    whole = round(est)
    if whole >= 1 and abs(est - whole) <= 0.01 * est:
        est = float(whole)
    return snap_rate(est)


def read_livelinkface(path: str | Path, *, rate_hz: float | None = None, timecode_fps: float = 60) -> FaceTrack:
    """Read a Live Link Face CSV.

    Parameters
    ----------
    path : the CSV file.
    rate_hz : capture rate in Hz (the take's ``rate_hz``). ``None``: estimated from the median timecode step,
        with a warning. When given, it is cross-checked against the median step (warning past 2 %).
    timecode_fps : frames a second the timecode's FF field counts (default 60).

    Returns
    -------
    FaceTrack with blendshapes in canonical ARKit order and spelling, times from the timecode (exact integer
    frame arithmetic plus the sub-frame fraction), capture frame indices with dropped frames counted, head and
    eye angles in radians (head NaN when head tracking was off, i.e. all zero).

    Raises
    ------
    InputError : missing/empty file, missing blendshape or Timecode column, garbage or non-increasing
        timecodes, empty or non-numeric cells. One line, naming the file.
    """
    path = Path(path)
    header = read_header(path)
    canon_of: dict[str, str] = {}
    raw_of: dict[str, str] = {}
    tc_col = None
    count_col = None
    unknown = []
    for raw in header:
        low = raw.lower()
        if low == "timecode":
            tc_col = raw
            continue
        if low == "blendshapecount":
            count_col = raw
            continue
        c = normalise_name(raw)
        if c is None:
            unknown.append(raw)
            continue
        if c in raw_of:
            raise InputError(path, f"{_WHAT}: columns {raw_of[c]!r} and {raw!r} are the same channel", key=c)
        raw_of[c] = raw
        canon_of[raw] = c
    if tc_col is None:
        raise InputError(path, f"{_WHAT}: missing required column", key="Timecode")
    missing = [n for n in ARKIT_NAMES if n not in raw_of]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise InputError(path, f"{_WHAT}: missing blendshape column{more}", key=missing[0])

    required = [tc_col] + [raw_of[n] for n in ARKIT_NAMES]
    optional = [raw_of[n] for n in HEAD_NAMES + EYE_NAMES if n in raw_of]
    if count_col:
        optional.append(count_col)
    cols, warnings = read_columns(path, required, optional, text=(tc_col,), what=_WHAT)
    if unknown:
        shown = ", ".join(printable(u) for u in unknown[:5]) + (" …" if len(unknown) > 5 else "")
        warnings.append(f"ignored {len(unknown)} unknown column(s): {shown}")

    timecode = cols[tc_col]
    n = timecode.size
    tc_frame, subframe, tc_warn = parse_timecodes(timecode, timecode_fps, path=path, key=tc_col)
    warnings += tc_warn
    fps = float(timecode_fps)
    time_s = ((tc_frame - tc_frame[0]).astype(np.float64) + (subframe - subframe[0])) / fps

    dt = np.diff(time_s)
    if rate_hz is None:
        if n < 2:
            raise InputError(path, f"{_WHAT}: one row and no rate_hz: cannot tell the capture rate")
        rate = _estimate_rate(float(np.median(dt)))
        warnings.append(f"capture rate not given; {rate:g} Hz from the median timecode step")
    else:
        rate = snap_rate(float(rate_hz))
        if not np.isfinite(rate) or rate <= 0:
            raise InputError(path, f"rate_hz must be a positive rate, got {rate_hz!r}")
        if n > 1:
            implied = 1.0 / float(np.median(dt))
            if abs(implied / rate - 1.0) > 0.02:
                warnings.append(f"rate_hz is {rate:g} Hz but the median timecode step implies {implied:.4g} Hz")

    k = np.rint(dt * rate).astype(np.int64)
    irregular = int(np.count_nonzero((np.abs(dt * rate - k) > 0.25) | (k < 1)))
    if irregular:
        warnings.append(f"{irregular} timecode step(s) are not a whole number of capture frames at {rate:g} Hz")
    k = np.maximum(k, 1)
    gaps = k > 1
    dropped = int((k[gaps] - 1).sum())
    if dropped:
        warnings.append(f"{dropped} dropped capture frame(s) in {int(gaps.sum())} gap(s) "
                        f"(largest {int(k.max()) - 1})")
    frame_index = np.concatenate([[0], np.cumsum(k)]).astype(np.int64)

    values = np.stack([cols[raw_of[c]] for c in ARKIT_NAMES], axis=1).astype(np.float32)

    def angles(names: tuple[str, ...], label: str) -> np.ndarray:
        if not all(c in raw_of for c in names):
            warnings.append(f"no {label} rotation columns; {label} angles missing")
            return np.full((n, len(names)), np.nan)
        a = np.stack([cols[raw_of[c]] for c in names], axis=1)
        if not np.any(a):
            warnings.append(f"{label} rotations are all zero ({label} tracking was off); {label} angles missing")
            return np.full((n, len(names)), np.nan)
        return a

    head = angles(HEAD_NAMES, "head")
    eyes = angles(EYE_NAMES, "eye")

    count = None
    if count_col and count_col in cols:
        negative = cols[count_col] < 0
        if negative.any():
            r = int(np.argmax(negative))
            raise InputError(path, f"{_WHAT}: negative count {cols[count_col][r]:g} in data row {r + 1}",
                             key=count_col)
        bc = np.unique(cols[count_col])
        if bc.size == 1 and float(bc[0]).is_integer():
            count = int(bc[0])

    return FaceTrack(
        timecode=timecode, tc_frame=tc_frame, tc_subframe=subframe, time_s=time_s, timecode_fps=fps,
        rate_hz=rate, frame_index=frame_index, values=values, head=head, eyes=eyes, dropped_frames=dropped,
        blendshape_count=count, warnings=warnings,
    )
