"""Live Link Face CSV reader.

A Live Link Face take is ``Timecode, BlendShapeCount``, the 52 ARKit blendshapes (PascalCase), then
``HeadYaw, HeadPitch, HeadRoll`` and the left and right eyes' yaw, pitch and roll. Angles are radians: in the
real take in ``corpus/livelinkface`` the eyes' pitch runs 0.14-0.29 with yaw within ±0.1, which is 8-17° and
±6° as radians and would be a fraction of a degree as degrees.

The timecode is ``HH:MM:SS:FF.fff``: FF counts frames at the timecode rate (60 by default) and ``.fff`` is a
fraction of a frame. The capture rate is not in the file (a 30 Hz capture on a 60 fps timecode steps by 2);
frames the phone dropped show up as larger steps.

While ARKit has lost the face, the app writes the timecode and a ``BlendShapeCount`` of 0 and nothing else
(``12:22:06:30.534,0``). Such rows are kept as invalid rows (``FaceTrack.valid`` False, NaN values), counted and
flagged in a warning, as OpenFace's ``success == 0`` rows are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from gazepipe.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, normalise_name
from gazepipe.errors import InputError, printable
from gazepipe.io.tracks import lost_rows, read_columns, read_header
from gazepipe.model import FaceTrack
from gazepipe.timebase import implausible_rate, snap_rate, stated_rate

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


def _channels(path: Path, header: list[str]) -> tuple[str, str | None, dict[str, str], list[str]]:
    """The timecode column, the ``BlendShapeCount`` column (None when absent), canonical channel -> column name,
    and the columns that are no channel; InputError when two columns are one channel or one is missing."""
    raw_of: dict[str, str] = {}
    tc_col = count_col = None
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
    if tc_col is None:
        raise InputError(path, f"{_WHAT}: missing required column", key="Timecode")
    missing = [n for n in ARKIT_NAMES if n not in raw_of]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise InputError(path, f"{_WHAT}: missing blendshape column{more}", key=missing[0])
    return tc_col, count_col, raw_of, unknown


def _capture_rate(path: Path, time_s: np.ndarray, rate_hz: float | None, warnings: list[str]) -> float:
    """The capture rate: ``rate_hz`` as stated (checked against the median timecode step), else estimated from
    that step; a rate ARKit face tracking cannot have is noted."""
    n = time_s.size
    dt = np.diff(time_s)
    if rate_hz is None:
        if n < 2:
            raise InputError(path, f"{_WHAT}: one row and no rate_hz: cannot tell the capture rate")
        rate = _estimate_rate(float(np.median(dt)))
        warnings.append(f"capture rate not given; {rate:g} Hz from the median timecode step")
    else:
        rate = stated_rate(float(rate_hz))
        if not np.isfinite(rate) or rate <= 0:
            raise InputError(path, f"rate_hz must be a positive rate, got {rate_hz!r}")
        if n > 1:
            implied = 1.0 / float(np.median(dt))
            if abs(implied / rate - 1.0) > 0.02:
                warnings.append(f"rate_hz is {rate:g} Hz but the median timecode step implies {implied:.4g} Hz")
    odd = implausible_rate(rate, "face")
    if odd is not None:
        warnings.append(f"capture rate {odd}: check the take's rate_hz and timecode_fps (the timecode's FF counts "
                        "timecode_fps frames a second)")
    return rate


def _frame_steps(dt: np.ndarray, rate: float, warnings: list[str]) -> tuple[np.ndarray, int]:
    """Capture frame of every row (0 at the first) from the timecode steps ``dt`` (s) at ``rate``, and the
    number of frames dropped between rows."""
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
    return np.concatenate([[0], np.cumsum(k)]).astype(np.int64), dropped


def _lost_note(lost: np.ndarray, timecode: np.ndarray) -> str:
    """The warning for rows written while the face was lost."""
    r = int(np.argmax(lost))
    runs = int(np.count_nonzero(np.diff(np.concatenate([[0], lost.astype(np.int8)])) == 1))
    return (f"{int(lost.sum())} of {lost.size} rows in {runs} stretch(es) were written while tracking was lost "
            f"(BlendShapeCount 0 and no values; first at data row {r + 1}, timecode {timecode[r]}): kept as "
            "invalid rows")


def _angles(cols: dict[str, np.ndarray], raw_of: dict[str, str], names: tuple[str, ...], label: str,
            valid: np.ndarray, warnings: list[str]) -> np.ndarray:
    """(N, len(names)) radians; NaN when the columns are absent, on invalid rows, and everywhere when every valid
    row is zero (that tracking was off)."""
    n = valid.size
    if not all(c in raw_of for c in names):
        warnings.append(f"no {label} rotation columns; {label} angles missing")
        return np.full((n, len(names)), np.nan)
    a = np.stack([cols[raw_of[c]] for c in names], axis=1)
    if not np.any(a[valid]):
        warnings.append(f"{label} rotations are all zero ({label} tracking was off); {label} angles missing")
        return np.full((n, len(names)), np.nan)
    a[~valid] = np.nan
    return a


def _blendshape_count(path: Path, count: np.ndarray | None, valid: np.ndarray, key: str | None) -> int | None:
    """The file's ``BlendShapeCount`` when every valid row gives the same whole number, else None."""
    if count is None:
        return None
    negative = count < 0
    if negative.any():
        r = int(np.argmax(negative))
        raise InputError(path, f"{_WHAT}: negative count {count[r]:g} in data row {r + 1}", key=key)
    bc = np.unique(count[valid])
    return int(bc[0]) if bc.size == 1 and float(bc[0]).is_integer() else None


def read_livelinkface(path: str | Path, *, rate_hz: float | None = None, timecode_fps: float = 60) -> FaceTrack:
    """Read a Live Link Face CSV.

    Parameters
    ----------
    path : the CSV file.
    rate_hz : capture rate in Hz (the take's ``rate_hz``), taken as stated
        (:func:`~gazepipe.timebase.stated_rate`). ``None``: estimated from the median timecode step, with a
        warning. When given, it is cross-checked against the median step (warning past 2 %). A rate ARKit face
        tracking cannot have (:data:`~gazepipe.timebase.PLAUSIBLE_HZ`) is noted.
    timecode_fps : frames a second the timecode's FF field counts (default 60).

    Returns
    -------
    FaceTrack with blendshapes in canonical ARKit order and spelling, times from the timecode (exact integer
    frame arithmetic plus the sub-frame fraction), capture frame indices with dropped frames counted, head and
    eye angles in radians (head NaN when head tracking was off, i.e. all zero), and ``valid`` False on the rows
    written while tracking was lost (their values NaN).

    Raises
    ------
    InputError : missing/empty file, missing blendshape or Timecode column, garbage or non-increasing
        timecodes, empty or non-numeric cells (other than a lost-tracking row's). One line, naming the file.
    """
    path = Path(path)
    tc_col, count_col, raw_of, unknown = _channels(path, read_header(path))
    required = [tc_col] + [raw_of[n] for n in ARKIT_NAMES]
    optional = [raw_of[n] for n in HEAD_NAMES + EYE_NAMES if n in raw_of]
    if count_col:
        optional.append(count_col)
    cols, warnings = read_columns(path, required, optional, text=(tc_col,), what=_WHAT, lost_when_zero=count_col)
    if unknown:
        shown = ", ".join(printable(u) for u in unknown[:5]) + (" …" if len(unknown) > 5 else "")
        warnings.append(f"ignored {len(unknown)} unknown column(s): {shown}")

    timecode = cols[tc_col]
    n = timecode.size
    tc_frame, subframe, tc_warn = parse_timecodes(timecode, timecode_fps, path=path, key=tc_col)
    warnings += tc_warn
    fps = float(timecode_fps)
    time_s = ((tc_frame - tc_frame[0]).astype(np.float64) + (subframe - subframe[0])) / fps
    rate = _capture_rate(path, time_s, rate_hz, warnings)
    frame_index, dropped = _frame_steps(np.diff(time_s), rate, warnings)

    lost = lost_rows(cols, count_col, (tc_col,)) if count_col and count_col in cols else np.zeros(n, dtype=bool)
    if lost.any():
        warnings.append(_lost_note(lost, timecode))
    valid = ~lost
    values = np.stack([cols[raw_of[c]] for c in ARKIT_NAMES], axis=1).astype(np.float32)
    head = _angles(cols, raw_of, HEAD_NAMES, "head", valid, warnings)
    eyes = _angles(cols, raw_of, EYE_NAMES, "eye", valid, warnings)
    count = _blendshape_count(path, cols.get(count_col) if count_col else None, valid, count_col)

    return FaceTrack(
        timecode=timecode, tc_frame=tc_frame, tc_subframe=subframe, time_s=time_s, timecode_fps=fps,
        rate_hz=rate, frame_index=frame_index, values=values, head=head, eyes=eyes, dropped_frames=dropped,
        blendshape_count=count, warnings=warnings, valid=valid,
    )
