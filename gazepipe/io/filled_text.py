"""Writing a gap-filled text export back in its own layout (the text counterpart of
:func:`gazepipe.io.c3d.write_filled_c3d`).

A Vicon Nexus CSV, QTM TSV or wide CSV is copied byte for byte except the coordinate cells of the samples that
were filled (or taken out as spikes): header lines, other blocks (Devices, Model Outputs), extra columns, line
endings, separators and every measured value stay as they were, so the file goes back into the program that
wrote it. Filled values are written in the file's units with as many decimals as the file's own numbers use.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from gazepipe.errors import InputError
from gazepipe.io.marker_csv import TextLayout, read_text_export
from gazepipe.model import Markers, filled_samples
from gazepipe.timebase import unit_scale_to_mm

#: decimals written when the file's numbers show none (whole millimetres: 3 keeps micrometres)
_DEFAULT_DECIMALS = 3
#: the file's decimals are read from this many data rows
_SAMPLE_ROWS = 200
_DECIMALS = re.compile(rb"\.(\d+)")


def write_filled_text(src: str | Path, dest: str | Path, markers: Markers, fmt: str, *,
                      removed: np.ndarray | None = None, original: tuple[Markers, TextLayout, bytes] | None = None,
                      default_units: str = "mm") -> int:
    """Write ``dest`` as a copy of the text export ``src`` (``fmt``: ``vicon_csv``, ``qtm_tsv`` or
    ``wide_csv``) in which only the samples that ``markers`` fills, or that ``removed`` (T, M) takes out, are
    changed; return how many samples were written.

    ``markers`` must be what :func:`gazepipe.io.capture.read_markers` returns for ``src`` (same markers, same
    order, mm) with gaps filled. A sample that is a gap in ``src`` and valid in ``markers``, or marked in
    ``removed`` and valid in ``markers``, gets its three cells rewritten in the file's units; a sample marked in
    ``removed`` and invalid in ``markers`` gets empty cells (a gap in every one of these formats).

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
    text = _cell_text(markers.xyz / to_mm, write & valid, _decimals(lines, rows, layout))
    for t in np.flatnonzero(write.any(axis=1)):
        i = int(line_of[t])
        lines[i] = _rewrite_row(lines[i], layout, np.flatnonzero(write[t]), text, t)
    Path(dest).write_bytes(raw[:layout.start] + b"\n".join(lines) + raw[layout.stop:])
    return int(write.sum())


def _decimals(lines: list[bytes], rows: list[int], layout: TextLayout) -> int:
    """Most decimals of the coordinate cells in the first ``_SAMPLE_ROWS`` data rows (``_DEFAULT_DECIMALS``
    when none has any; a Frame or Time column does not count)."""
    sep = layout.sep.encode()
    cols = layout.cols.reshape(-1)
    found = [0]
    for i in rows[:_SAMPLE_ROWS]:
        fields = lines[i].rstrip(b"\r").split(sep)
        found += [len(m.group(1)) for c in cols[cols < len(fields)].tolist()
                  if (m := _DECIMALS.search(fields[c])) is not None]
    return min(max(found), 9) if max(found) else _DEFAULT_DECIMALS


def _cell_text(values: np.ndarray, filled: np.ndarray, decimals: int) -> dict[tuple[int, int], list[bytes]]:
    """The three cells of every filled sample (values (T, M, 3) in the file's units), keyed (frame, marker)."""
    t_idx, m_idx = np.nonzero(filled)
    flat = np.round(values[t_idx, m_idx], decimals).reshape(-1)
    cells = [f"{v:.{decimals}f}".encode("ascii") for v in (flat + 0.0)]   # + 0.0: no "-0.000"
    return {(int(t), int(m)): cells[3 * k:3 * k + 3] for k, (t, m) in enumerate(zip(t_idx, m_idx, strict=True))}


def _rewrite_row(line: bytes, layout: TextLayout, markers: np.ndarray, text: dict, t: int | np.integer) -> bytes:
    """One data row with the cells of ``markers`` replaced: their filled values, or empty for a gap."""
    end = b"\r" if line.endswith(b"\r") else b""
    fields = line[:len(line) - len(end)].split(layout.sep.encode())
    need = int(layout.cols[markers].max()) + 1
    if len(fields) < need:   # rows may omit trailing empty fields
        fields += [b""] * (need - len(fields))
    for m in markers.tolist():
        cells = text.get((t, m), [b"", b"", b""])
        for c, cell in zip(layout.cols[m].tolist(), cells, strict=True):
            fields[c] = cell
    return layout.sep.encode().join(fields) + end
