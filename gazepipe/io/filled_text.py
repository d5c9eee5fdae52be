"""Writing a gap-filled text export back in its own layout (the text counterpart of
:func:`gazepipe.io.c3d.write_filled_c3d`).

A Vicon Nexus CSV, QTM TSV or wide CSV is copied byte for byte except the coordinate cells of the samples that
were filled (or taken out as spikes): header lines, other blocks (Devices, Model Outputs), extra columns, line
endings, separators and every measured value stay as they were, so the file goes back into the program that
wrote it. New cells are written in the file's own style (:class:`CellStyle`, read from its coordinate cells):
in its units; with a fixed number of decimals where the file writes one (QTM's ``%.3f``), else with as many
significant digits as its numbers carry (Nexus writes 6: ``-276.862``, ``44.1628``; its 1.x exports up to 10,
tiny values as ``6.22E-14``); and a sample made a gap is spelled as the file spells its gaps (empty cells,
``nan``, QTM's old ``0.000``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.marker_csv import TextLayout, read_text_export
from gazepipe.model import Markers, filled_samples
from gazepipe.timebase import unit_scale_to_mm

#: decimals written when the file's numbers show none (whole millimetres: 3 keeps micrometres)
_DEFAULT_DECIMALS = 3
#: the file's number style is read from this many data rows
_SAMPLE_ROWS = 200
#: a decimal number as text: sign, integer digits, fraction digits, exponent (letter and value)
_NUMBER = re.compile(rb"^\s*[-+]?(\d*)(?:\.(\d*))?(?:([eE])[-+]?\d+)?\s*$")
#: cells that are gaps, as spelled by the formats' writers (NaN in any case, ``-nan``)
_NAN_CELLS = frozenset({b"nan", b"NaN", b"NAN", b"-nan", b"-NaN"})


@dataclass(frozen=True)
class CellStyle:
    """How a text export writes its coordinates.

    ``decimals``: a fixed number of decimals (``%.{decimals}f``), or None; ``digits``: otherwise, the significant
    digits of the general format (``%.{digits}g``, trailing zeros dropped, exponent form for tiny values with
    ``exponent`` as its letter); ``gap``: the text of a gap cell.
    """

    decimals: int | None
    digits: int
    exponent: str
    gap: bytes

    def cell(self, v: float) -> bytes:
        """``v`` (a finite number in the file's units) as the file would write it."""
        v = v + 0.0                                             # no "-0"
        if self.decimals is not None:
            text = f"{round(v, self.decimals) + 0.0:.{self.decimals}f}"
        else:
            text = f"{v:.{self.digits}{'G' if self.exponent == 'E' else 'g'}}"
        return text.encode("ascii")


def write_filled_text(src: str | Path, dest: str | Path, markers: Markers, fmt: str, *,
                      removed: np.ndarray | None = None, original: tuple[Markers, TextLayout, bytes] | None = None,
                      default_units: str = "mm") -> int:
    """Write ``dest`` as a copy of the text export ``src`` (``fmt``: ``vicon_csv``, ``qtm_tsv`` or
    ``wide_csv``) in which only the samples that ``markers`` fills, or that ``removed`` (T, M) takes out, are
    changed; return how many samples were written.

    ``markers`` must be what :func:`gazepipe.io.capture.read_markers` returns for ``src`` (same markers, same
    order, mm) with gaps filled. A sample that is a gap in ``src`` and valid in ``markers``, or marked in
    ``removed`` and valid in ``markers``, gets its three cells rewritten in the file's units and style
    (:func:`cell_style`); a sample marked in ``removed`` and invalid in ``markers`` is written as the file writes
    its gaps (empty cells when it has none).

    ``original``: what :func:`gazepipe.io.marker_csv.read_text_export` returned for ``src`` (read again when
    not given).

    Rows the reader added for dropped frames (frame numbers missing from the file) have no line to write into:
    their samples are not written, and not counted.

    Raises :class:`InputError` (naming ``src``) when ``markers`` does not match the file.
    """
    p = Path(src)
    if original is None:
        original = read_text_export(p, fmt, rate_hz=markers.rate_hz, default_units=default_units)
    orig, layout, raw = original
    try:
        write, valid = filled_samples(orig, markers, removed)
    except ValueError as e:
        raise InputError(p, str(e)) from None
    in_file = np.arange(orig.n_frames) if layout.rows is None else np.asarray(layout.rows, dtype=np.int64)
    line_of = np.full(orig.n_frames, -1, dtype=np.int64)
    has_line = np.zeros(orig.n_frames, dtype=bool)
    has_line[in_file] = True
    write = write & has_line[:, None]
    if not write.any():
        Path(dest).write_bytes(raw)
        return 0
    to_mm = unit_scale_to_mm(layout.units, default_units)
    lines = raw[layout.start:layout.stop].split(b"\n")
    rows = [i for i, ln in enumerate(lines) if ln.strip()]   # the reader skips blank lines
    if len(rows) != in_file.size:
        raise InputError(p, f"{len(rows)} data rows found where the reader saw {in_file.size}")
    line_of[in_file] = rows
    style = cell_style(lines, rows, layout, _first_gaps(orig.valid, has_line, line_of))
    text = _cell_text(markers.xyz / to_mm, write & valid, style)
    gap = [style.gap] * 3
    for t in np.flatnonzero(write.any(axis=1)):
        i = int(line_of[t])
        lines[i] = _rewrite_row(lines[i], layout, np.flatnonzero(write[t]), text, t, gap)
    Path(dest).write_bytes(raw[:layout.start] + b"\n".join(lines) + raw[layout.stop:])
    return int(write.sum())


def _first_gaps(valid: np.ndarray, has_line: np.ndarray, line_of: np.ndarray, n: int = 64) -> list[tuple[int, int]]:
    """(line, marker) of the first ``n`` gap samples of the file that have a line (where its gaps are spelled)."""
    t_idx, m_idx = np.nonzero(~valid & has_line[:, None])
    return [(int(line_of[t]), int(m)) for t, m in zip(t_idx[:n], m_idx[:n], strict=True)]


def cell_style(lines: list[bytes], rows: list[int], layout: TextLayout,
               gaps: Sequence[tuple[int, int]] = ()) -> CellStyle:
    """The style of a text export's coordinate cells, from those of its first ``_SAMPLE_ROWS`` data rows
    (``lines``: the data block split at ``\\n``; ``rows``: the indices of its data rows) and of the gap samples
    ``gaps`` ((line, marker) pairs: the file's gaps, the first whose three cells read alike gives the spelling).

    Fixed decimals when every number there has the same (at least one) and none has an exponent;
    ``_DEFAULT_DECIMALS`` when none has decimals; otherwise the most significant digits any has.
    """
    sep = layout.sep.encode()
    cols = layout.cols.reshape(-1)
    decimals: set[int] = set()
    digits, exponent = 1, ""
    for i in rows[:_SAMPLE_ROWS]:
        fields = lines[i].rstrip(b"\r").split(sep)
        for c in cols[cols < len(fields)].tolist():
            m = _NUMBER.match(fields[c])
            if m is None or not (m.group(1) or m.group(2)):
                continue
            whole, frac = m.group(1), m.group(2) or b""
            if m.group(3):
                exponent = m.group(3).decode()
            decimals.add(len(frac))
            digits = max(digits, len((whole + frac).lstrip(b"0")))
    gap = _gap_text(lines, layout, gaps)
    if not exponent and max(decimals, default=0) == 0:
        return CellStyle(decimals=_DEFAULT_DECIMALS, digits=digits, exponent=exponent, gap=gap)
    if not exponent and len(decimals) == 1:
        return CellStyle(decimals=min(decimals.pop(), 9), digits=digits, exponent=exponent, gap=gap)
    return CellStyle(decimals=None, digits=min(digits, 17), exponent=exponent, gap=gap)


def _gap_text(lines: list[bytes], layout: TextLayout, gaps: Sequence[tuple[int, int]]) -> bytes:
    """How the file spells a gap: the text of the first gap sample whose three cells read alike and are empty, a
    NaN or a number (QTM's zeros), else an empty cell."""
    sep = layout.sep.encode()
    for i, m in gaps:
        fields = lines[i].rstrip(b"\r").split(sep)
        cells = [fields[c].strip() if c < len(fields) else b"" for c in layout.cols[m].tolist()]
        if cells[0] == cells[1] == cells[2] and (not cells[0] or cells[0] in _NAN_CELLS or _NUMBER.match(cells[0])):
            return cells[0]
    return b""


def _cell_text(values: np.ndarray, filled: np.ndarray, style: CellStyle) -> dict[tuple[int, int], list[bytes]]:
    """The three cells of every filled sample (values (T, M, 3) in the file's units), keyed (frame, marker)."""
    t_idx, m_idx = np.nonzero(filled)
    cells = [style.cell(float(v)) for v in values[t_idx, m_idx].reshape(-1)]
    return {(int(t), int(m)): cells[3 * k:3 * k + 3] for k, (t, m) in enumerate(zip(t_idx, m_idx, strict=True))}


def _rewrite_row(line: bytes, layout: TextLayout, markers: np.ndarray, text: dict, t: int | np.integer,
                 gap: list[bytes]) -> bytes:
    """One data row with the cells of ``markers`` replaced: their filled values, or ``gap`` for a gap."""
    end = b"\r" if line.endswith(b"\r") else b""
    fields = line[:len(line) - len(end)].split(layout.sep.encode())
    need = int(layout.cols[markers].max()) + 1
    if len(fields) < need:   # rows may omit trailing empty fields
        fields += [b""] * (need - len(fields))
    for m in markers.tolist():
        cells = text.get((t, m), gap)
        for c, cell in zip(layout.cols[m].tolist(), cells, strict=True):
            fields[c] = cell
    return layout.sep.encode().join(fields) + end
