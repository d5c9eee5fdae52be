"""Marker trajectories from text exports: Vicon Nexus CSV, Qualisys QTM TSV and a plain wide CSV.

Layouts read here:

* Vicon Nexus "Trajectories" block (other blocks such as ``Devices`` or ``Model Outputs`` may come before or
  after it, separated by a blank line)::

      Trajectories
      100
      ,,Subj:LASI,,,Subj:RASI,,,
      Frame,Sub Frame,X,Y,Z,X,Y,Z
      ,,mm,mm,mm,mm,mm,mm
      1,0,12.5,-3.25,1001.0,,,

  Empty cells are gaps. Columns other than X/Y/Z under a marker (velocities ``X'`` …) are ignored.
* Qualisys QTM TSV export: ``KEY<TAB>value…`` header lines (``NO_OF_FRAMES``, ``FREQUENCY``,
  ``MARKER_NAMES`` …), optionally a ``Frame<TAB>Time<TAB>M1 X…`` column row, then data rows with or without
  the Frame and Time columns. QTM writes missing samples as empty cells or, in older versions, as 0: an
  exact (0, 0, 0) sample in a marker that is elsewhere non-zero is a gap (the C3D rule of SPEC §1).
* Wide CSV: ``frame``, ``time`` (seconds), then ``<marker>_x``, ``<marker>_y``, ``<marker>_z``; empty cells
  are gaps. :func:`write_wide_csv` writes it.

The rate comes from the file; the ``rate_hz`` argument is used when the file has none (a file rate that
disagrees with ``rate_hz`` is kept and noted in ``Markers.warnings``).

In every layout a data row must have as many fields as the header (trailing empty fields aside): a shorter
row is a truncated file or a broken row, and its missing values are not gaps to fill; blank lines are skipped.

The frame column (Vicon's ``Frame``, QTM's ``Frame``, the wide CSV's ``frame``) is checked, never ignored: frame
numbers must be whole, within 0 - 2^31-1 and strictly increasing (a duplicate or a step back is refused with the
line it is on). Frames missing between two rows are dropped frames: their rows become gaps (all markers NaN), so
that every row keeps its own frame number and time, and a warning names the file, the lines and the frames. A
file with more frames missing than rows present is refused (a broken frame column, not a capture). A sample with
only some of its X, Y, Z, or an infinite one, and a coordinate farther than
:data:`gazepipe.io.limits.MAX_ABS_MM` from the origin, become gaps with a warning. Lines over
:data:`gazepipe.io.limits.MAX_LINE_BYTES` are refused before the file is read into memory.
"""

from __future__ import annotations

import csv
import io
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv

from gazepipe.errors import InputError, printable
from gazepipe.io.c3d import make_unique
from gazepipe.io.limits import (
    MAX_ABS_MM,
    MAX_FRAME,
    check_line_lengths,
    coordinate_span,
    exact_floats,
    rate_problem,
    span_problem,
)
from gazepipe.model import Markers
from gazepipe.timebase import implausible_rate, snap_rate, stated_rate, unit_scale_to_mm

VICON_BLOCKS = ("Trajectories", "Devices", "Model Outputs", "Joints", "Segments", "Global Angle")
#: what the first line of a Vicon Nexus export starts with: a block's title (any case: Nexus 1.x writes
#: ``TRAJECTORIES``, ``ANALOG``) or Nexus 1.x's ``Title`` header line
VICON_FIRST_CELLS = frozenset(b.lower() for b in VICON_BLOCKS) | {"analog", "title"}

_PARSE_ERRORS = (ValueError, KeyError, IndexError, TypeError, OverflowError, UnicodeDecodeError,
                 csv.Error, pd.errors.ParserError, pd.errors.EmptyDataError)


class _Bad(Exception):
    """A format problem found while parsing (message: short phrase)."""


@dataclass(frozen=True)
class TextLayout:
    """Where a text export keeps its marker coordinates (what :mod:`gazepipe.io.filled_text` rewrites).

    The data rows are the non-blank lines of ``raw[start:stop]``, fields separated by ``sep``; row ``t`` holds
    marker ``m``'s X, Y, Z in fields ``cols[m]`` ((M, 3) int), in ``units`` (as found; None when the file does
    not say). ``rows``: the row of ``Markers`` each data row holds ((N,) int, increasing) when the frame column
    leaves frames out (the rows between are gaps with no line in the file); None when data row t is row t.
    """

    sep: str
    start: int
    stop: int
    cols: np.ndarray
    units: str | None
    rows: np.ndarray | None = None


def _read_raw(path: Path) -> bytes:
    check_line_lengths(path, what="marker export")
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except OSError as e:
        raise InputError(path, f"cannot read file ({e.strerror or e})") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise InputError(path, "UTF-16 text (a byte-order mark FF FE or FE FF); save the export as UTF-8 CSV")
    if b"\x00" in raw:
        raise InputError(path, "binary data in a text export (NUL bytes)")
    return raw


def _text(b: bytes) -> str:
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("latin-1")


class _Lines:
    """Line access over the raw bytes from a start offset: header lines are decoded one at a time, the
    (large) data part stays bytes and goes to pandas as it is."""

    def __init__(self, raw: bytes, start: int = 0) -> None:
        if start == 0 and raw.startswith(b"\xef\xbb\xbf"):
            start = 3
        self.raw = raw
        self.starts = [start]

    def offset(self, i: int) -> int:
        """Byte offset where line ``i`` starts (the file size past the last line)."""
        while len(self.starts) <= i:
            last = self.starts[-1]
            nl = self.raw.find(b"\n", last) if last < len(self.raw) else -1
            self.starts.append(len(self.raw) if nl < 0 else nl + 1)
        return self.starts[i]

    def __getitem__(self, i: int) -> str | None:
        a, b = self.offset(i), self.offset(i + 1)
        if a >= len(self.raw):
            return None
        return _text(self.raw[a:b]).rstrip("\r\n")

    def before(self, i: int) -> str:
        """Line ``i`` where a later line is known to exist."""
        text = self[i]
        assert text is not None
        return text


class _ByteRange(io.RawIOBase):
    """``raw[start:stop]`` as a readable stream, without copying it (a slice of a large export would double
    what the reader holds)."""

    def __init__(self, raw: bytes, start: int, stop: int) -> None:
        self._view = memoryview(raw)[start:stop]
        self._pos = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:
        n = min(len(buf), len(self._view) - self._pos)
        buf[:n] = self._view[self._pos: self._pos + n]
        self._pos += n
        return n


#: data rows parsed at a time by :func:`_numbers` (bounds the parser's own buffers)
_CHUNK_ROWS = 1 << 15


def _numbers(raw: bytes, start: int, stop: int, sep: str, n_cols: int) -> np.ndarray:
    """Parse the numeric rows ``raw[start:stop]`` into a (rows, n_cols) float64 array; empty cells are NaN.

    Rows are parsed :data:`_CHUNK_ROWS` at a time straight into the result, so memory is the file, the result
    and one chunk.
    """
    if not re.search(rb"\S", memoryview(raw)[start:stop]):
        return np.zeros((0, n_cols))
    kw: dict[str, Any] = dict(sep=sep, header=None, keep_default_na=False, skip_blank_lines=True, engine="c",
                              names=range(max(n_cols, 1)), index_col=False, on_bad_lines="error",
                              encoding="latin-1")
    src = (raw, start, stop)
    with warnings.catch_warnings():
        # pandas only warns when a row has more cells than there are names: the row is malformed unless
        # the extra cells are empty (trailing separators), which are then dropped and the block re-read
        warnings.simplefilter("error", pd.errors.ParserWarning)
        for attempt in range(2):
            try:
                try:  # fast path: every cell a number or empty
                    return _numbers_fast(*src, n_cols, kw)
                except ValueError:
                    pass
                df = pd.read_csv(io.BytesIO(src[0][src[1]:src[2]]), dtype=str, **kw)
                break
            except (pd.errors.ParserWarning, pd.errors.ParserError) as e:
                if attempt:
                    detail = " ".join(str(e).split())[:120]
                    raise _Bad(f"a data row does not fit {n_cols} columns ({detail})") from None
                block = re.sub(rb"[" + re.escape(sep.encode()) + rb" \r]+$", b"", raw[start:stop], flags=re.M)
                src = (block, 0, len(block))
    df = df.fillna("").apply(lambda c: c.str.strip())
    num = df.apply(pd.to_numeric, errors="coerce")
    empty = (df == "") | df.isin(["NaN", "nan", "NAN", "-nan"])
    bad = num.isna() & ~empty
    if bad.to_numpy().any():
        r, c = np.argwhere(bad.to_numpy())[0]
        raise _Bad(f"non-numeric value {df.iat[r, c][:20]!r} in data row {r + 1}, column {c + 1}")
    # the numbers themselves from Python's correctly rounded parser (pandas' own may be an ulp off)
    out = np.full(df.shape, np.nan)
    cells = ~empty.to_numpy()
    out[cells] = df.to_numpy(dtype=object)[cells].astype(np.float64)
    return out


def _numbers_fast(raw: bytes, start: int, stop: int, n_cols: int, kw: dict) -> np.ndarray:
    """:func:`_numbers` when every cell is a number or empty (ValueError otherwise)."""
    out = np.empty((raw.count(b"\n", start, stop) + 1, n_cols))   # at most this many rows
    n = 0
    chunks = pd.read_csv(io.BufferedReader(_ByteRange(raw, start, stop), 1 << 20), dtype=np.float64,
                         na_values=["", "NaN", "nan"], chunksize=_CHUNK_ROWS, **kw, **exact_floats())
    with chunks:
        for chunk in chunks:
            k = len(chunk)
            out[n: n + k] = chunk.to_numpy(dtype=np.float64)[:, :n_cols]
            n += k
    return out[:n]   # a view: the rows never written were never touched


def _check_fields(raw: bytes, start: int, stop: int, sep: str, first_line: int, header: int,
                  required: int | None = None, expected: str | None = None) -> None:
    """Raise :class:`_Bad` naming the first data row with fewer or more fields than the header.

    Parameters
    ----------
    raw : the whole file; the data rows are ``raw[start:stop]``, the first of them on line ``first_line``
        (1-based).
    sep : the field separator.
    header : the number of fields of the header row.
    required : fewest fields a row may have (default ``header``; less when the header ends in empty fields).
    expected : how to name the count in the message (default ``header has <header>``).

    Blank lines are skipped. Trailing empty fields beyond ``header`` are allowed (exporters end rows with a
    separator); a short row is not: it is a truncated file or a broken row, whose missing values must not
    become gaps. A short last row of the file is named as a probable truncation.
    """
    required = header if required is None else required
    sep_b = sep.encode()
    pos, k = start, 0
    # one pass of C-level bytes.find/count per line: 3x faster than numpy passes over every byte (20,000 rows,
    # 35 MB: 0.06 s against 0.18 s) and no copies of the file
    while pos < stop:
        end = raw.find(b"\n", pos, stop)
        end = stop if end < 0 else end
        n_seps = raw.count(sep_b, pos, end)
        if not required - 1 <= n_seps <= header - 1:
            line = raw[pos:end].rstrip(b"\r")
            if line.strip():                                # not a blank line
                _field_problem(raw, end, line, sep, first_line + k, header, required, expected)
        pos, k = end + 1, k + 1


def _field_problem(raw: bytes, end: int, line: bytes, sep: str, line_no: int, header: int, required: int,
                   expected: str | None) -> None:
    """Raise :class:`_Bad` for a row whose field count is off, unless only trailing empty fields are extra."""
    text = _text(line)
    cells = next(csv.reader([text], delimiter=sep)) if '"' in text else text.split(sep)
    n = len(cells)
    while n > header and not cells[n - 1].strip():
        n -= 1                                              # trailing separators
    if required <= n <= header:
        return
    what = expected or f"header has {header if n > header else required}"
    if n > header:
        hint = f" (the row does not fit {header} columns)"
    else:
        hint = " (file truncated?)" if not raw[end:].strip() else ""
    raise _Bad(f"line {line_no}: {len(cells)} fields, {what}{hint}")


def _last_named(header: list[str]) -> int:
    """The number of header fields up to the last non-empty one."""
    return max((j + 1 for j, c in enumerate(header) if c.strip()), default=0)


class _Rows:
    """Where the data rows of a text export are, to name the line a problem is on."""

    def __init__(self, raw: bytes, start: int, stop: int, first_line: int) -> None:
        self.raw, self.start, self.stop, self.first_line = raw, start, stop, first_line

    def lines(self, rows: list[int]) -> dict[int, int]:
        """File line numbers (1-based) of data rows ``rows`` (0-based; blank lines are not rows). One pass over
        the lines up to the last asked for: called only to word a refusal or a warning."""
        want = sorted(set(rows))
        found: dict[int, int] = {}
        pos, line, row = self.start, self.first_line, 0
        while want and pos < self.stop:
            end = self.raw.find(b"\n", pos, self.stop)
            end = self.stop if end < 0 else end
            if self.raw[pos:end].strip():
                if row == want[0]:
                    found[row] = line
                    want.pop(0)
                row += 1
            pos, line = end + 1, line + 1
        return found

    def line(self, row: int) -> str:
        n = self.lines([row]).get(row)
        return f"line {n}" if n is not None else f"data row {row + 1}"


def _frame_rows(frames: np.ndarray, where: _Rows, name: str, notes: list[str]) -> tuple[int, np.ndarray | None]:
    """Check a frame column; return the first frame number and, when frames are missing between rows, the row
    of ``Markers`` each data row goes to (None when the rows are consecutive frames).

    Raises :class:`_Bad` naming the line of the first empty, fractional, out-of-range, repeated or decreasing
    frame number, and when more frames are missing than there are rows. Missing frames are noted in ``notes``
    (dropped frames: the file, the lines and the frames of the first gaps).
    """
    f = np.asarray(frames, dtype=np.float64)
    bad = ~np.isfinite(f)
    if bad.any():
        raise _Bad(f"{where.line(int(np.argmax(bad)))}: no frame number")
    bad = f != np.floor(f)
    if bad.any():
        r = int(np.argmax(bad))
        raise _Bad(f"{where.line(r)}: frame number {f[r]:.10g} is not a whole number")
    bad = (f < 0) | (f > MAX_FRAME)
    if bad.any():
        r = int(np.argmax(bad))
        raise _Bad(f"{where.line(r)}: frame number {f[r]:.10g} is out of range (0 to {MAX_FRAME})")
    fi = f.astype(np.int64)
    steps = np.diff(fi)
    back = steps <= 0
    if back.any():
        r = int(np.argmax(back)) + 1
        what = "repeated" if steps[r - 1] == 0 else "going back"
        raise _Bad(f"{where.line(r)}: frame numbers are not strictly increasing (frame {fi[r - 1]} then "
                   f"{fi[r]}: {what})")
    missing = int(fi[-1] - fi[0] + 1 - fi.size) if fi.size else 0
    if missing <= 0:
        return int(fi[0]) if fi.size else 1, None
    gaps = np.flatnonzero(steps > 1)
    if missing > fi.size:
        r = int(gaps[np.argmax(steps[gaps])]) + 1
        raise _Bad(f"{where.line(r)}: frame numbers jump from {fi[r - 1]} to {fi[r]}; {missing} frames missing "
                   f"against {fi.size} rows present (a broken frame column?)")
    at = where.lines([int(g) for g in gaps[:3]] + [int(g) + 1 for g in gaps[:3]])
    def span(a: int, b: int) -> str:
        return f"frame {a}" if a == b else f"frames {a}-{b}"

    shown = ", ".join(f"lines {at.get(int(g), '?')}-{at.get(int(g) + 1, '?')} ({span(fi[g] + 1, fi[g + 1] - 1)})"
                      for g in gaps[:3])
    more = f" and {gaps.size - 3} more" if gaps.size > 3 else ""
    notes.append(f"{printable(name)}: {missing} dropped frame(s) in {gaps.size} gap(s), kept as gap rows: between "
                 f"{shown}{more}")
    return int(fi[0]), fi - fi[0]


def _coordinate_columns(arr: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(T, M, 3) coordinates from the parsed rows ``arr`` (T, C) and each marker's X, Y, Z columns ``cols``
    (M, 3): a view when they are consecutive columns (the usual layout), else a copy."""
    flat = np.asarray(cols, dtype=np.int64).reshape(-1)
    if flat.size and np.array_equal(flat, np.arange(flat[0], flat[0] + flat.size)):
        return arr[:, flat[0]: flat[0] + flat.size].reshape(arr.shape[0], -1, 3)
    return arr[:, flat].reshape(arr.shape[0], -1, 3)


def _with_gap_rows(xyz: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    """(T, M, 3) coordinates with all-NaN rows where frames are missing (``rows``: see :func:`_frame_rows`)."""
    if rows is None:
        return xyz
    full = np.full((int(rows[-1]) + 1, *xyz.shape[1:]), np.nan)
    full[rows] = xyz
    return full


def _written_rate(cell: str, what: str) -> str | None:
    """A rate cell's text (None when empty); :class:`_Bad` naming ``what`` when it is not a number."""
    text = cell.strip()
    if not text:
        return None
    try:
        float(text)
    except ValueError:
        raise _Bad(f"{what} reads {text[:20]!r}, not a number") from None
    return text


def _resolve_rate(file_rate: str | float | None, rate_hz: float | None, notes: list[str],
                  what: str = "the file's rate") -> float:
    """The capture rate: the file's (``what`` names where it was found; text as written, or a rate measured from
    a time column), else ``rate_hz``; either refused outside :data:`~gazepipe.io.limits.MIN_RATE_HZ` -
    :data:`~gazepipe.io.limits.MAX_RATE_HZ`. A written rate is taken as written (:func:`stated_rate`: only an NTSC
    rate written rounded, such as 29.97, becomes exactly N·1000/1001); a rate implausible for a marker capture is
    noted."""
    if isinstance(file_rate, str):
        file_rate = stated_rate(file_rate)
    if file_rate is not None:
        problem = rate_problem(file_rate)
        if problem is not None:
            raise _Bad(f"{what}: {problem}")
    if rate_hz is not None:
        try:
            problem = rate_problem(float(rate_hz))
        except (TypeError, ValueError):
            problem = "not a number"
        if problem is not None:
            raise _Bad(f"the given rate_hz {rate_hz!r}: {problem}")
    if file_rate is None:
        if rate_hz is None:
            raise _Bad("no frame rate in the file and none given (a take's rate_hz in session.toml, or --rate-hz)")
        rate = stated_rate(float(rate_hz))
    else:
        rate = file_rate
        if rate_hz is not None and abs(stated_rate(float(rate_hz)) - rate) > 5e-4 * rate:
            notes.append(f"file rate {rate:g} Hz used, not the given {float(rate_hz):g} Hz")
    odd = implausible_rate(rate, "mocap")
    if odd is not None:
        notes.append(f"{what}: {odd}; check the file's rate")
    return rate


def _first_at(mask: np.ndarray, labels: list[str], first_frame: int) -> str:
    """`` (first at frame F, marker M)`` for the first True sample of a (T, M) mask."""
    t, m = divmod(int(np.argmax(mask.ravel())), mask.shape[1])
    return f" (first at frame {int(first_frame) + t}, marker {printable(labels[m])})"


def _finish(labels: list[str], xyz: np.ndarray, *, rate: float, first_frame: int, units: str | None,
            default_units: str, fmt: str, notes: list[str], zero_gaps: bool = False,
            model_outputs: list[str] | None = None) -> Markers:
    """Unique labels, gap mask (any non-finite coordinate), conversion to mm (``xyz`` is changed in place)."""
    labels, renamed = make_unique(labels)
    if renamed:
        shown = ", ".join(f"{old!r} -> {printable(new)}" for _, old, new in renamed[:12])
        notes.append(f"{len(renamed)} empty or duplicate labels renamed: {shown}"
                     + (" …" if len(renamed) > 12 else ""))
    try:
        to_mm = unit_scale_to_mm(units, default_units)
    except KeyError:
        raise _Bad(f"unknown units {units!r}") from None
    finite = np.isfinite(xyz)
    valid = finite.all(axis=2)
    infinite = np.isinf(xyz).any(axis=2)
    partial = finite.any(axis=2) & ~valid & ~infinite
    if infinite.any():
        notes.append(f"{int(infinite.sum())} samples with an infinite coordinate made gaps"
                     + _first_at(infinite, labels, first_frame))
    if partial.any():
        notes.append(f"{int(partial.sum())} samples with only some of X, Y, Z made gaps (first at frame "
                     f"{int(first_frame) + int(np.argmax(partial.any(axis=1)))})")
    del finite, infinite, partial
    if zero_gaps:
        zero = valid & (xyz == 0).all(axis=2)
        valid &= ~(zero & (valid & ~zero).any(axis=0)[None, :])
    # in place, a component at a time: a long export's coordinates are the largest thing the reader holds
    if to_mm != 1.0:
        xyz *= to_mm
    xyz[~valid] = np.nan
    near = np.abs(xyz[..., 0]) <= MAX_ABS_MM
    near &= np.abs(xyz[..., 1]) <= MAX_ABS_MM
    near &= np.abs(xyz[..., 2]) <= MAX_ABS_MM
    far = valid & ~near
    del near
    if far.any():
        cols = np.flatnonzero(far.any(axis=0))
        shown = ", ".join(printable(labels[i]) for i in cols[:12]) + (" …" if cols.size > 12 else "")
        notes.append(f"{int(far.sum())} samples farther than {MAX_ABS_MM:,.0f} mm from the origin (corrupted "
                     f"values) made gaps{_first_at(far, labels, first_frame)}, in {cols.size} markers: {shown}")
        valid &= ~far
        xyz[far] = np.nan
    found = span_problem(*coordinate_span(xyz, valid))
    if found is not None:
        shown = f"the file's units {units!r}" if units is not None else f"units {default_units!r} (assumed)"
        if found[0]:
            raise _Bad(f"{found[1]}; {shown} or the values are implausible")
        notes.append(f"{found[1]}; check {shown}")
    if valid.size and not valid.any():
        notes.append("every marker sample is invalid (100 % gaps)")
    return Markers(labels=labels, xyz=xyz, valid=valid, rate_hz=rate, first_frame=int(first_frame),
                   units=units, source_format=fmt, model_outputs=list(model_outputs or []), warnings=notes)


def _guard(path: Path, fn, *args, **kwargs):
    try:
        return fn(*args, **kwargs)
    except InputError:
        raise
    except _Bad as e:
        raise InputError(path, str(e)) from None
    except _PARSE_ERRORS as e:
        raise InputError(path, f"malformed file ({type(e).__name__}: {e})") from None


# ---------------------------------------------------------------------------------------------- Vicon

def strip_subject_prefix(labels: list[str], wanted: list[str] | tuple[str, ...] | None = None) -> list[str]:
    """Drop the ``Subject:`` prefix of Vicon marker names.

    With ``wanted`` (the markerset's names), a label is stripped only when it is not itself wanted and its
    part after the last ``:`` is. Without it every prefix is stripped. A strip that would make two labels
    equal is not done.
    """
    wanted_set = set(wanted) if wanted is not None else None
    out = []
    for lab in labels:
        short = lab.rsplit(":", 1)[-1]
        if short != lab and (wanted_set is None or (lab not in wanted_set and short in wanted_set)):
            out.append(short)
        else:
            out.append(lab)
    counts: dict[str, int] = {}
    for lab in out:
        counts[lab] = counts.get(lab, 0) + 1
    return [new if counts[new] == 1 else old for old, new in zip(labels, out, strict=True)]


# the block title, at the start of a line (or after the UTF-8 byte-order mark Excel writes): ``Trajectories``
# (Nexus 2) or ``TRAJECTORIES`` (Nexus 1.x)
_TRAJ_LINE = re.compile(rb"(?m)^(?:\xef\xbb\xbf)?[ \t]*(?:Trajectories|TRAJECTORIES)[ \t]*(?:,[^\r\n]*)?\r?$")
_BLANK_LINE = re.compile(rb"(?m)^[ \t,\r]*$")
_CONTENT = re.compile(rb"[^ \t,\r\n]")
#: the frame column's name: ``Frame`` (Nexus 2), ``Field #`` (Nexus 1.x)
_FRAME_COLUMNS = ("frame", "field #")
#: model outputs by name, for a block without a units row (Nexus 1.x writes Plug-in Gait's angles, forces,
#: moments and powers among the trajectories): the names C3D files list in POINT:ANGLES, FORCES, MOMENTS and
#: POWERS end so (``LHipAngles``, ``LAbsAnkleAngle``, ``LGroundReactionForce``, ``LNormalisedGRF``,
#: ``LKneeMoment``, ``LAnklePower``, optionally with a model suffix such as ``_CGM_2.4``)
_MODEL_OUTPUT_NAME = re.compile(r"(?:Angles?|Force|Moment|Power|GRF)(?:_[\w.]+)?$")


@dataclass(frozen=True)
class _ViconColumns:
    """What a 'Trajectories' block's header rows say: each marker's X, Y, Z columns, its units, and what is no
    marker."""

    labels: list[str]
    cols: list[list[int]]
    units: str | None
    model_outputs: list[str]       # X/Y/Z groups that are model outputs (angles, forces …), left out
    skipped: list[tuple[str, str]]  # named column groups without X/Y/Z (magnitudes, counts …), left out: (name,
                                    # its components)


def _is_length(unit: str) -> bool:
    try:
        unit_scale_to_mm(unit)
    except KeyError:
        return False
    return True


def _vicon_columns(names: list[str], comps: list[str], units_row: list[str] | None) -> _ViconColumns:
    """Sort a 'Trajectories' block's named column groups into markers, model outputs and other columns.

    A group is the columns from a name in the names row to the next name. A group with X, Y and Z columns is a
    marker, unless its units (when the block has a units row) are not lengths, or (without one) its name is a
    model output's (:data:`_MODEL_OUTPUT_NAME`). A group without them (Nexus's trajectory magnitudes, ``| S:LASI |``
    over ``Magnitude( X )``, or its ``Trajectory Count``) is no marker. Columns other than X/Y/Z in a marker's
    group (velocities ``X'`` …) are ignored. Raises :class:`_Bad` for markers in different length units.
    """
    starts = [i for i, n in enumerate(names) if n and i >= 1]
    labels: list[str] = []
    cols: list[list[int]] = []
    model_outputs: list[str] = []
    skipped: list[tuple[str, str]] = []
    for k, c0 in enumerate(starts):
        c1 = starts[k + 1] if k + 1 < len(starts) else max(len(comps), len(names))
        span: dict[str, int] = {}
        for c in range(c0, min(c1, len(comps))):
            span.setdefault(comps[c], c)
        if not all(a in span for a in ("X", "Y", "Z")):
            shown = ", ".join(comps[c] for c in range(c0, min(c1, len(comps))) if comps[c])
            skipped.append((names[c0], shown or "no component"))
            continue
        xyz = [span["X"], span["Y"], span["Z"]]
        found = {units_row[c] for c in xyz if c < len(units_row) and units_row[c]} if units_row is not None else set()
        short = names[c0].rsplit(":", 1)[-1]
        if (found and not all(_is_length(u) for u in found)) or (units_row is None and _MODEL_OUTPUT_NAME.search(short)):
            model_outputs.append(names[c0])
            continue
        labels.append(names[c0])
        cols.append(xyz)
    in_units = {units_row[c] for cc in cols for c in cc if c < len(units_row) and units_row[c]} \
        if units_row is not None else set()
    if len(in_units) > 1:
        raise _Bad(f"mixed units {sorted(in_units)}")
    return _ViconColumns(labels, cols, in_units.pop() if in_units else None, model_outputs, skipped)


def _left_out_notes(found: _ViconColumns, notes: list[str]) -> None:
    """Notes naming the column groups of a 'Trajectories' block that are not read as markers."""
    def shown(items: list[str]) -> str:
        return ", ".join(printable(x) for x in items[:6]) + (f" and {len(items) - 6} more" if len(items) > 6 else "")

    if found.skipped:
        magnitudes = [name for name, _ in found.skipped if name.startswith("|") and name.endswith("|")]
        others = [f"{name!r} ({what})" for name, what in found.skipped if name not in set(magnitudes)]
        parts = ([f"{len(magnitudes)} trajectory magnitude(s) ({shown(magnitudes[:1])} …)"] if magnitudes else [])
        parts += [shown(others)] if others else []
        notes.append(f"{len(found.skipped)} column group(s) of the 'Trajectories' block without X/Y/Z columns "
                     f"skipped: {', '.join(parts)}")
    if found.model_outputs:
        notes.append(f"{len(found.model_outputs)} model output(s) in the 'Trajectories' block (angles, forces, "
                     f"moments, powers) left out of the markers: {shown(found.model_outputs)}")
    unlabeled = [lab for lab in found.labels if re.fullmatch(r"\*\d+", lab.rsplit(":", 1)[-1])]
    if unlabeled:
        notes.append(f"{len(unlabeled)} unlabeled trajectories (*N) read as markers: {shown(unlabeled)}")


def has_trajectories_block(path: Path) -> bool:
    """Whether a text file has a Vicon 'Trajectories' block title line anywhere (searched without reading the file
    into memory: a Nexus export may carry megabytes of Devices data before it)."""
    import mmap

    try:
        with open(path, "rb") as fh:
            if os.fstat(fh.fileno()).st_size == 0:
                return False
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                return _TRAJ_LINE.search(mm) is not None
    except (OSError, ValueError):
        return False


def _block_end(path: Path, raw: bytes, start: int, first_line: int, notes: list[str]) -> int:
    """Where the data rows of the 'Trajectories' block that start at ``raw[start]`` (line ``first_line``,
    1-based) end.

    Nexus separates blocks with a blank line, the next block starting with its title (``Devices``, ``Model
    Outputs`` …), never with a number. A blank line followed by a row whose first cell is a number is
    inside the data (a hand-edited or re-saved file): it is skipped, with a note naming the file and the
    line, so that no data row is dropped. Such a line must be empty: one of spaces or separators only is
    refused (the rows' reader would read it as a row without a frame number).
    """
    pos, stop = start, len(raw)
    skipped: list[tuple[int, int]] = []               # (first, last) line of each run of blank lines
    line, counted = first_line, start                   # line number at byte offset ``counted``
    while (blank := _BLANK_LINE.search(raw, pos)) is not None:
        content = _CONTENT.search(raw, blank.end())
        if content is None:                             # blank lines to the end of the file
            stop = blank.start()
            break
        nxt = raw.rfind(b"\n", 0, content.start()) + 1
        end = raw.find(b"\n", nxt)
        cell = _text(raw[nxt: end if end >= 0 else len(raw)]).split(",", 1)[0].strip()
        try:
            float(cell)
        except ValueError:                              # the next block's title
            stop = blank.start()
            break
        line += raw.count(b"\n", counted, blank.start())
        counted = blank.start()
        if raw[blank.start(): nxt].strip():
            raise _Bad(f"line {line}: a row of empty cells inside the 'Trajectories' data rows (data rows "
                       "follow it)")
        skipped.append((line, line + raw.count(b"\n", blank.start(), nxt) - 1))
        pos = nxt
    if skipped:
        shown = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in skipped[:5])
        more = f" and {len(skipped) - 5} more" if len(skipped) > 5 else ""
        notes.append(f"{printable(path.name)}: {sum(b - a + 1 for a, b in skipped)} blank line(s) inside the "
                     f"'Trajectories' data rows skipped (lines {shown}{more})")
    return stop


def _cells(line: str | None) -> list[str]:
    return [c.strip() for c in next(csv.reader([line]), [])] if line is not None else []


def _parse_vicon(path: Path, raw: bytes, rate_hz: float | None, strip_prefix: bool | list[str],
                 default_units: str) -> tuple[Markers, TextLayout]:
    found = _TRAJ_LINE.search(raw)
    if found is None:
        raise _Bad("no 'Trajectories' block (export trajectories from Nexus)")
    lines = _Lines(raw, found.start())
    if lines[4] is None:
        raise _Bad("'Trajectories' block truncated before its data")
    file_rate = _written_rate(lines.before(1).split(",", 1)[0], "rate line")
    names, comps = _cells(lines.before(2)), _cells(lines.before(3))
    if len(comps) < 2 or comps[0].lower() not in _FRAME_COLUMNS:
        raise _Bad("the row after the marker names does not start with 'Frame' (or Nexus 1.x's 'Field #')")
    # Nexus 2 writes a units row (``,,mm,mm,mm``) before the data; Nexus 1.x does not (its data start at once)
    units_row: list[str] | None = _cells(lines[4])
    try:
        float((units_row or [""])[0])
        units_row = None                                # a frame number: the first data row
    except ValueError:
        pass
    columns = _vicon_columns(names, comps, units_row)
    labels, cols, units = columns.labels, columns.cols, columns.units
    if not labels:
        raise _Bad("no marker names in the 'Trajectories' block"
                   + (f" ({len(columns.model_outputs) + len(columns.skipped)} column group(s), none of them a "
                      "marker's X/Y/Z)" if columns.model_outputs or columns.skipped else ""))

    # data rows run to the first blank line followed by the next block's title (or nothing), or to the end
    n_head = 4 if units_row is None else 5
    data_start = lines.offset(n_head)
    n_cols = max(len(comps), 1 + max(c for cc in cols for c in cc))
    title_line = raw.count(b"\n", 0, found.start()) + 1
    first_line = title_line + n_head
    notes: list[str] = []
    stop = _block_end(path, raw, data_start, first_line, notes)
    _check_fields(raw, data_start, stop, ",", first_line, n_cols, required=_last_named(comps))
    arr = _numbers(raw, data_start, stop, ",", n_cols)
    xyz = _coordinate_columns(arr, np.asarray(cols)) if arr.shape[0] else np.zeros((0, len(labels), 3))
    if xyz.shape[0] == 0:
        raise _Bad("no data rows in the 'Trajectories' block")
    first, rows = _frame_rows(arr[:, 0], _Rows(raw, data_start, stop, first_line), path.name, notes)
    del arr
    xyz = _with_gap_rows(xyz, rows)
    rate = _resolve_rate(file_rate, rate_hz, notes, f"line {title_line + 1}, the rate line")
    _left_out_notes(columns, notes)
    if strip_prefix is True:
        labels = strip_subject_prefix(labels)
    elif isinstance(strip_prefix, list | tuple):
        labels = strip_subject_prefix(labels, strip_prefix)
    markers = _finish(labels, xyz, rate=rate, first_frame=first, units=units,
                      default_units=default_units, fmt="vicon_csv", notes=notes,
                      model_outputs=columns.model_outputs)
    return markers, TextLayout(",", data_start, stop, np.asarray(cols, dtype=np.int64), units, rows)


def read_vicon_csv(path: str | Path, *, rate_hz: float | None = None,
                   strip_prefix: bool | list[str] = False, default_units: str = "mm") -> Markers:
    """Read the "Trajectories" block of a Vicon Nexus CSV export.

    Parameters
    ----------
    path : the .csv file.
    rate_hz : rate used when the file's rate line is empty.
    strip_prefix : False keeps ``Subject:Marker`` names; True strips every prefix; a list of wanted names
        strips a prefix only where that yields a wanted name (see :func:`strip_subject_prefix`).
    default_units : used when the units row is empty.

    Returns
    -------
    Markers in mm (NaN at gaps); ``first_frame`` is the first row's Frame number.
    """
    p = Path(path)
    return _guard(p, _parse_vicon, p, _read_raw(p), rate_hz, strip_prefix, default_units)[0]


# ------------------------------------------------------------------------------------------------ QTM

_QTM_KEY = re.compile(r"^[A-Z][A-Z0-9_]*$")


def _parse_qtm(path: Path, raw: bytes, rate_hz: float | None, default_units: str) -> tuple[Markers, TextLayout]:  # noqa: C901
    lines = _Lines(raw)
    header: dict[str, list[str]] = {}
    i = 0
    while (line := lines[i]) is not None and i < 10000:
        cells = line.split("\t")
        key = cells[0].strip()
        if not _QTM_KEY.match(key):
            break
        header.setdefault(key, [c.strip() for c in cells[1:]])
        i += 1
    if "MARKER_NAMES" not in header:
        raise _Bad("no MARKER_NAMES line (not a QTM 3D TSV export)")
    labels = [n for n in header["MARKER_NAMES"]]
    while labels and labels[-1] == "":
        labels.pop()
    if not labels:
        raise _Bad("MARKER_NAMES lists no markers")
    m = len(labels)
    for key, values in header.items():
        value = values[0] if values else ""
        if key.startswith("NO_OF_") and value and not value.isdigit():
            raise _Bad(f"{key} reads {value[:20]!r}, not a count (a whole number, 0 or more)")
    declared = header.get("NO_OF_MARKERS", [""])[0]
    if declared and int(declared) != m:
        raise _Bad(f"NO_OF_MARKERS says {declared} but MARKER_NAMES lists {m}")
    freq = _written_rate(header.get("FREQUENCY", [""])[0], "FREQUENCY")
    file_rate = None if freq is None else stated_rate(freq)

    while (line := lines[i]) is not None and not line.strip():
        i += 1
    col_names: list[str] | None = None
    if (line := lines[i]) is not None and line.split("\t", 1)[0].strip().lower() in ("frame", "time"):
        col_names = [c.strip() for c in line.split("\t")]
        i += 1
    first_row = lines[i] or ""
    n_cells = len(first_row.split("\t"))
    if col_names is not None:
        lead = [c.lower() for c in col_names[:2]]
        n_lead = 2 if lead == ["frame", "time"] else 1
        n_cols = max(len(col_names), n_lead + 3 * m)
        _check_fields(raw, lines.offset(i), len(raw), "\t", i + 1, n_cols,
                      required=max(_last_named(col_names), n_lead + 3 * m))
    else:
        # rows are the coordinates, optionally after Frame and Time, optionally with a trailing tab
        extra = n_cells - 3 * m
        if extra not in (0, 1, 2, 3):
            raise _Bad(f"data rows have {n_cells} cells, expected {3 * m} (+ Frame, Time)")
        n_lead = extra - extra % 2
        n_cols = n_lead + 3 * m
        _check_fields(raw, lines.offset(i), len(raw), "\t", i + 1, n_cols,
                      expected=f"expected {n_cols} ({'Frame, Time and ' if n_lead else ''}3 per marker)")
    arr = _numbers(raw, lines.offset(i), len(raw), "\t", n_cols)
    if arr.shape[0] == 0:
        raise _Bad("no data rows")
    xyz = arr[:, n_lead: n_lead + 3 * m].reshape(-1, m, 3)
    n_frames = header.get("NO_OF_FRAMES", [""])[0]
    notes: list[str] = []
    if n_frames.isdigit() and int(n_frames) != xyz.shape[0]:
        notes.append(f"NO_OF_FRAMES says {n_frames} but the file has {xyz.shape[0]} data rows")
    has_frame = n_lead == 2 if col_names is None else col_names[0].lower() == "frame"
    has_time = col_names is not None and col_names[0].lower() == "time"
    where = _Rows(raw, lines.offset(i), len(raw), i + 1)
    first, rows = 1, None
    if has_frame:
        first, rows = _frame_rows(arr[:, 0], where, path.name, notes)
        time_at = 1 if (n_lead == 2 if col_names is None else [c.lower() for c in col_names[:2]] == ["frame", "time"]) \
            else None
        if time_at is not None:
            _check_frame_times(arr[:, time_at], rows, where, file_rate, notes)
    elif has_time:
        _check_times(arr[:, 0], where)
    del arr
    xyz = _with_gap_rows(xyz, rows)
    rate = _resolve_rate(file_rate, rate_hz, notes, "FREQUENCY")
    markers = _finish(labels, xyz, rate=rate, first_frame=first, units=None, default_units=default_units,
                      fmt="qtm_tsv", notes=notes, zero_gaps=True)
    cols = n_lead + np.arange(3 * m, dtype=np.int64).reshape(m, 3)
    return markers, TextLayout("\t", lines.offset(i), len(raw), cols, None, rows)


def read_qtm_tsv(path: str | Path, *, rate_hz: float | None = None, default_units: str = "mm") -> Markers:
    """Read a Qualisys QTM 3D TSV export (mm unless ``default_units`` says otherwise; QTM writes mm)."""
    p = Path(path)
    return _guard(p, _parse_qtm, p, _read_raw(p), rate_hz, default_units)[0]


# ----------------------------------------------------------------------------------------- wide CSV

def rate_from_times(t: np.ndarray, rows: np.ndarray | None = None) -> tuple[float, bool]:
    """Rate (Hz) implied by a time column in seconds, and whether the steps are even.

    The mean step gives the rate; one within 0.05 % of a whole number is taken as that number (times
    written with few decimals), then :func:`snap_rate` applies. ``rows``: the frame index of each time when
    frames are missing between them (see :func:`_frame_rows`), so that a dropped frame is not a slower rate.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2 or not np.isfinite(t).all():
        raise _Bad("the time column needs at least two finite values")
    d = np.diff(t)
    if (d <= 0).any():
        row = int(np.argmax(d <= 0)) + 2
        raise _Bad(f"the time column is not strictly increasing (data row {row})")
    r: float
    steps: float | np.ndarray
    if rows is None:
        r = (t.size - 1) / (t[-1] - t[0])
        steps = 1.0
    else:
        r = float(rows[-1] - rows[0]) / (t[-1] - t[0])
        steps = np.diff(rows).astype(np.float64)
    ri = round(r)
    if ri >= 1 and abs(r - ri) <= 5e-4 * r:
        r = float(ri)
    even = bool(np.all(np.abs(d * r - steps) < 0.5))
    return snap_rate(r), even


def _check_times(t: np.ndarray, where: _Rows) -> None:
    """Raise :class:`_Bad` at the first empty or non-increasing value of a time column (no frame column)."""
    t = np.asarray(t, dtype=np.float64)
    bad = ~np.isfinite(t)
    if bad.any():
        raise _Bad(f"{where.line(int(np.argmax(bad)))}: no time value")
    back = np.diff(t) <= 0
    if back.any():
        r = int(np.argmax(back)) + 1
        raise _Bad(f"{where.line(r)}: the time column is not strictly increasing ({t[r - 1]:.10g} s then "
                   f"{t[r]:.10g} s)")


def _check_frame_times(t: np.ndarray, rows: np.ndarray | None, where: _Rows, file_rate: float | None,
                       notes: list[str]) -> None:
    """Check a time column that comes beside a frame column (the frames place the rows; the times must agree).

    A missing or non-finite time, or one that goes back, is refused at its line; a step that disagrees with
    its frame step by more than half a frame (a repeated time included: times written with too few decimals
    for the rate), and a rate that disagrees with the file's, are noted with the first line. ``rows``: each
    data row's frame index (None when consecutive).
    """
    t = np.asarray(t, dtype=np.float64)
    bad = ~np.isfinite(t)
    if bad.any():
        raise _Bad(f"{where.line(int(np.argmax(bad)))}: no time value")
    back = np.diff(t) < 0
    if back.any():
        r = int(np.argmax(back)) + 1
        raise _Bad(f"{where.line(r)}: the time column goes back ({t[r - 1]:.10g} s then {t[r]:.10g} s)")
    if t.size < 2 or t[-1] <= t[0]:
        return
    frames = np.diff(rows).astype(np.float64) if rows is not None else np.ones(t.size - 1)
    per = np.diff(t) / frames
    step = float(np.median(per))
    if not step > 0:  # most steps repeat a time (too few decimals): the mean step is the rate's
        step = float((t[-1] - t[0]) / frames.sum())
    off = np.abs(per - step) * frames > 0.5 * step
    if off.any():
        r = int(np.argmax(off)) + 1
        notes.append(f"{where.line(r)}: the time column steps {per[r - 1] * frames[r - 1]:.6g} s over "
                     f"{frames[r - 1]:.0f} frame(s), not {step * frames[r - 1]:.6g} s ({int(off.sum())} such "
                     "step(s)); the frame numbers place the rows")
    if file_rate and abs(1.0 / (step * file_rate) - 1.0) > 0.005:
        notes.append(f"the time column steps {step:.6g} s a frame ({1.0 / step:.6g} Hz) but the file's rate is "
                     f"{file_rate:g} Hz; the file's rate is used")


def _parse_wide(path: Path, raw: bytes, rate_hz: float | None, default_units: str) -> tuple[Markers, TextLayout]:
    lines = _Lines(raw)
    if lines[0] is None or not lines[0].strip():
        raise _Bad("empty file or empty header line")
    head = next(csv.reader([lines[0]]), [])
    cols = [c.strip() for c in head]
    low = [c.lower() for c in cols]
    labels: list[str] = []
    where: dict[str, dict[str, int]] = {}
    for j, c in enumerate(cols):
        mt = re.match(r"^(.*)_([xyzXYZ])$", c)
        if mt and mt.group(1):
            name = mt.group(1)
            if name not in where:
                where[name] = {}
                labels.append(name)
            if mt.group(2).lower() in where[name]:
                raise _Bad(f"column {c!r} appears twice")
            where[name][mt.group(2).lower()] = j
    if not labels:
        raise _Bad("no <marker>_x/_y/_z columns in the header")
    for name in labels:
        if set(where[name]) != {"x", "y", "z"}:
            raise _Bad(f"marker {name!r} lacks one of its _x/_y/_z columns")
    _check_fields(raw, lines.offset(1), len(raw), ",", 2, len(cols), required=_last_named(cols))
    arr = _numbers(raw, lines.offset(1), len(raw), ",", len(cols))
    if arr.shape[0] == 0:
        raise _Bad("no data rows")
    idx = np.array([[where[n]["x"], where[n]["y"], where[n]["z"]] for n in labels])
    xyz = _coordinate_columns(arr, idx)
    notes: list[str] = []
    rows_at = _Rows(raw, lines.offset(1), len(raw), 2)
    first, rows = 1, None
    if "frame" in low:
        first, rows = _frame_rows(arr[:, low.index("frame")], rows_at, path.name, notes)
    file_rate = None
    if "time" in low:
        _check_times(arr[:, low.index("time")], rows_at)
        if arr.shape[0] >= 2:
            file_rate, even = rate_from_times(arr[:, low.index("time")], rows)
            if not even:
                notes.append("uneven steps in the time column")
    del arr
    xyz = _with_gap_rows(xyz, rows)
    rate = _resolve_rate(file_rate, rate_hz, notes, "the rate of the time column")
    markers = _finish(labels, xyz, rate=rate, first_frame=first, units=None, default_units=default_units,
                      fmt="wide_csv", notes=notes)
    return markers, TextLayout(",", lines.offset(1), len(raw), idx.astype(np.int64), None, rows)


def read_wide_csv(path: str | Path, *, rate_hz: float | None = None, default_units: str = "mm") -> Markers:
    """Read a wide marker CSV (``frame``, ``time``, ``<marker>_x/_y/_z``); rate from ``time`` or ``rate_hz``."""
    p = Path(path)
    return _guard(p, _parse_wide, p, _read_raw(p), rate_hz, default_units)[0]


def read_text_export(path: str | Path, fmt: str, *, rate_hz: float | None = None,
                     default_units: str = "mm") -> tuple[Markers, TextLayout, bytes]:
    """Read a Vicon CSV, QTM TSV or wide CSV (``fmt``: ``vicon_csv``, ``qtm_tsv``, ``wide_csv``) as its reader
    does, with the layout of its data rows and the file's bytes (labels keep Vicon's ``Subject:`` prefix)."""
    p = Path(path)
    raw = _read_raw(p)
    if fmt == "vicon_csv":
        markers, layout = _guard(p, _parse_vicon, p, raw, rate_hz, False, default_units)
    elif fmt == "qtm_tsv":
        markers, layout = _guard(p, _parse_qtm, p, raw, rate_hz, default_units)
    elif fmt == "wide_csv":
        markers, layout = _guard(p, _parse_wide, p, raw, rate_hz, default_units)
    else:
        raise ValueError(f"not a text export format: {fmt!r}")
    return markers, layout, raw


def write_wide_csv(path: str | Path, markers: Markers, times: np.ndarray | None = None) -> None:
    """Write markers as a wide CSV: ``frame`` (source frame), ``time`` (s; ``times``, default 0 at the first
    row), ``<label>_x/_y/_z`` in mm.

    Gaps are empty cells. Floats are written in shortest round-trip form, so a read gives the same values.
    """
    t, m = markers.valid.shape
    xyz = np.where(markers.valid[..., None], markers.xyz, np.nan).reshape(t, 3 * m)
    columns = ["frame", "time"] + [f"{lab}_{a}" for lab in markers.labels for a in "xyz"]
    arrays = [pa.array(markers.source_frame), pa.array(markers.time_s if times is None else times)]
    arrays += [pa.array(xyz[:, j], from_pandas=True) for j in range(3 * m)]
    table = pa.table(arrays, names=[f"c{j}" for j in range(len(columns))])
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow(columns)
    with open(Path(path), "wb") as fh:
        fh.write(head.getvalue().encode("utf-8"))
        pa_csv.write_csv(table, fh, pa_csv.WriteOptions(include_header=False, quoting_style="needed"))
