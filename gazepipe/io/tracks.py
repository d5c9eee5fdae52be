"""The numeric-CSV reading the eye and face track readers share.

The containers they fill live in the model (:class:`~gazepipe.model.EyeTrack` from
:func:`gazepipe.io.openface.read_openface`, :class:`~gazepipe.model.FaceTrack` from
:func:`gazepipe.io.livelinkface.read_livelinkface`, :class:`~gazepipe.model.VideoProbe` from
:func:`gazepipe.io.video.probe_video`): stages use them without depending on a reader.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gazepipe.errors import InputError
from gazepipe.io.limits import MAX_LINE_BYTES, check_line_lengths, exact_floats
from gazepipe.model import EyeTrack, FaceTrack, VideoProbe

__all__ = ["EyeTrack", "FaceTrack", "VideoProbe", "lost_rows", "read_columns", "read_header"]


def _not_text(path: Path) -> str:
    """Why a CSV file did not decode: UTF-16 text (a byte-order mark FF FE or FE FF), or not text."""
    try:
        with open(path, "rb") as f:
            head = f.read(2)
    except OSError:
        head = b""
    if head in (b"\xff\xfe", b"\xfe\xff"):
        return "UTF-16 text (a byte-order mark FF FE or FE FF); save the file as UTF-8 CSV"
    return "not a text CSV file"


def read_header(path: Path) -> list[str]:
    """Column names of a CSV file's first line, stripped of spaces (InputError when unreadable or empty, or when
    the line is longer than :data:`~gazepipe.io.limits.MAX_LINE_BYTES`: only that much is read)."""
    try:
        with open(path, encoding="utf-8-sig", newline="") as f:
            first = f.readline(MAX_LINE_BYTES + 1)
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, not a file") from None
    except UnicodeDecodeError:
        raise InputError(path, _not_text(path)) from None
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None
    if len(first) > MAX_LINE_BYTES:
        raise InputError(path, f"line 1 (the header) is longer than {MAX_LINE_BYTES >> 20} MiB, more than any CSV "
                               "track file holds (a broken file?)")
    if not first.strip():
        raise InputError(path, "empty file (no header line)")
    return [c.strip() for c in next(csv.reader([first]))]


def read_columns(path: str | Path, required: Sequence[str], optional: Sequence[str] = (), *,  # noqa: C901
                 text: tuple[str, ...] = (), what: str = "CSV",
                 lost_when_zero: str | None = None) -> tuple[dict[str, np.ndarray], list[str]]:
    """Read named columns of a numeric CSV whose names and values may be padded with spaces.

    Columns are found by name after stripping spaces, never by position. Numeric columns come back as float64,
    ``text`` columns as str. A row that is incomplete only because the file ends early (the last row) is dropped
    with a warning; any other empty, non-numeric or infinite cell is an :class:`InputError` naming the column and
    row.

    Parameters
    ----------
    path : the file.
    required : column names that must be present.
    optional : column names read when present.
    text : names (among ``required``/``optional``) read as strings.
    what : the kind of file, for messages.
    lost_when_zero : a numeric column whose 0, with every other numeric cell of the row empty, marks a row the
        tracker wrote while it had lost the face (Live Link Face's ``BlendShapeCount``: ``12:22:06:30.534,0``).
        Such rows are kept with NaN in those cells, for the caller to flag (:func:`lost_rows`).

    Returns
    -------
    columns : name -> (N,) array, for every required column and the optional ones present.
    warnings : one-line notes.
    """
    path = Path(path)
    header = read_header(path)
    check_line_lengths(path, what=what)
    pos: dict[str, int] = {}
    for i, name in enumerate(header):
        if name in required or name in optional:
            if name in pos:
                raise InputError(path, f"{what}: column appears twice", key=name)
            pos[name] = i
    missing = [c for c in required if c not in pos]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise InputError(path, f"{what}: missing required column{more}", key=missing[0])
    order = sorted(pos, key=pos.__getitem__)
    dtypes = {pos[c]: (str if c in text else np.float64) for c in order}
    kw: dict[str, Any] = dict(usecols=[pos[c] for c in order], header=None, skiprows=1, skipinitialspace=True,
                              keep_default_na=False, na_values=[""], encoding="utf-8-sig", engine="c")
    try:
        df = _read_table(path, dtypes, kw, len(header) if lost_when_zero is not None else None)
    except pd.errors.EmptyDataError:
        raise InputError(path, f"{what}: no data rows") from None
    except UnicodeDecodeError:  # a ValueError too: caught first
        raise InputError(path, f"{what}: not a UTF-8 text file") from None
    except ValueError as e:
        if isinstance(e, pd.errors.ParserError):
            raise InputError(path, f"{what}: malformed CSV: {str(e).splitlines()[0]}") from None
        short = _short_first_row(path, what, len(header), max(pos.values()) + 1)
        if short is not None:
            raise short from None
        try:
            err = _junk_error(path, what, order, pos, text, kw)
        except (ValueError, pd.errors.ParserError):
            err = InputError(path, f"{what}: unreadable numeric data")
        raise err from None
    if len(df) == 0:
        raise InputError(path, f"{what}: no data rows")
    cols = {c: df[pos[c]].to_numpy() for c in order}
    warnings: list[str] = []
    bad = _empty_cells(cols, text, lost_when_zero)
    if bad.any():
        rows = np.flatnonzero(bad)
        if rows.size == 1 and rows[0] == len(df) - 1 and len(df) > 1:
            warnings.append("last row is incomplete (file cut short?); dropped")
            cols = {c: v[:-1] for c, v in cols.items()}
        else:
            r = int(rows[0])
            col = next(c for c in order if (pd.isna(cols[c][r]) if c in text else np.isnan(cols[c][r])))
            raise InputError(path, f"{what}: empty or NaN cell in data row {r + 1}", key=col)
    for c in order:
        if c not in text and np.isinf(cols[c]).any():
            r = int(np.argmax(np.isinf(cols[c])))
            raise InputError(path, f"{what}: infinite value {cols[c][r]} in data row {r + 1}", key=c)
    for c in text:
        if c in cols:
            cols[c] = np.asarray([s.strip() for s in cols[c]], dtype=str)
    return cols, warnings


def _empty_cells(cols: dict[str, np.ndarray], text: Sequence[str], lost_when_zero: str | None) -> np.ndarray:
    """(N,) bool: rows with an empty or NaN cell, other than the rows a tracker wrote without data
    (:func:`lost_rows` of ``lost_when_zero``)."""
    bad = np.zeros(len(next(iter(cols.values()))), dtype=bool)
    for c, v in cols.items():
        bad |= pd.isna(v) if c in text else np.isnan(v)
    if lost_when_zero is not None and lost_when_zero in cols:
        bad &= ~lost_rows(cols, lost_when_zero, text)
    return bad


def _read_table(path: Path, dtypes: dict, kw: dict[str, Any], n_header: int | None) -> pd.DataFrame:
    """The columns ``kw`` asks for, as pandas parses them. pandas sizes the table by the first data row; when it
    is shorter than the columns asked for and ``n_header`` is given (rows without data may come first: see
    ``lost_when_zero``), the table is sized by the header instead."""
    try:
        return pd.read_csv(path, dtype=dtypes, **kw, **exact_floats())
    except ValueError as e:
        if n_header is None or isinstance(e, pd.errors.ParserError | UnicodeDecodeError):
            raise
        try:
            return pd.read_csv(path, dtype=dtypes, names=range(n_header), **kw, **exact_floats())
        except (ValueError, pd.errors.ParserError):
            raise e from None


def lost_rows(cols: dict[str, np.ndarray], flag: str, text: Sequence[str] = ()) -> np.ndarray:
    """(N,) bool: the rows of :func:`read_columns`' ``cols`` whose ``flag`` column is 0 and whose other numeric
    columns are all empty (NaN): rows a tracker wrote without data (see ``lost_when_zero``)."""
    lost = cols[flag] == 0
    for c, v in cols.items():
        if c != flag and c not in text:
            lost &= np.isnan(v)
    return lost


def _short_first_row(path: Path, what: str, n_header: int, need: int) -> InputError | None:
    """The InputError for a first data row with fewer fields than the columns read (pandas sizes the table by
    it and refuses), e.g. a file cut short inside its first row; None when the first row is long enough."""
    try:
        with open(path, "rb") as f:
            f.readline(MAX_LINE_BYTES + 1)
            first = f.readline(MAX_LINE_BYTES + 1)
            more = bool(f.read(1))
    except OSError:
        return None
    text = first.decode("utf-8", "replace").rstrip("\r\n")
    n = len(next(csv.reader([text]), []))
    if n >= need:
        return None
    hint = "" if more else " (file cut short?)"
    return InputError(path, f"{what}: data row 1 has {n} fields, the header has {n_header}{hint}")


def _junk_error(path: Path, what: str, order: list[str], pos: dict[str, int], text: tuple[str, ...],
                kw: dict) -> InputError:
    """The InputError for the first non-numeric cell (slow path, only after a failed fast parse)."""
    df = pd.read_csv(path, dtype=str, **kw)
    for c in order:
        if c in text:
            continue
        raw = df[pos[c]]
        num = pd.to_numeric(raw.str.strip(), errors="coerce")
        bad = np.flatnonzero(num.isna().to_numpy() & raw.notna().to_numpy())
        if bad.size:
            r = int(bad[0])
            cell = str(raw.iloc[r]).strip()[:20]
            return InputError(path, f"{what}: non-numeric value {cell!r} in data row {r + 1}", key=c)
    return InputError(path, f"{what}: unreadable numeric data")
