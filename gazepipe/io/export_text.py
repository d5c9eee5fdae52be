"""Marker text exports written for the capture programs and spreadsheets (``gazepipe export``): a Vicon Nexus
"Trajectories" CSV and a Qualisys QTM 3D TSV, in the layouts :mod:`gazepipe.io.marker_csv` reads.

Positions are millimetres, written in shortest round-trip form (a read gives the same float64 values); gaps are
empty cells; frame numbers are the capture's own.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv

from gazepipe.errors import InputError, printable


def _rows(frames: np.ndarray, lead: Sequence[np.ndarray], xyz: np.ndarray, valid: np.ndarray) -> pa.Table:
    """The data rows: the ``lead`` columns (frame number, …), then X, Y, Z of each marker (NaN → empty)."""
    t, m = valid.shape
    flat = np.where(valid[..., None], xyz, np.nan).reshape(t, 3 * m)
    arrays = [pa.array(np.asarray(frames, dtype=np.int64))] + [pa.array(c) for c in lead]
    arrays += [pa.array(flat[:, j], from_pandas=True) for j in range(3 * m)]
    return pa.table(arrays, names=[f"c{j}" for j in range(len(arrays))])


def _check_labels(path: Path, labels: Sequence[str], forbidden: str, what: str) -> None:
    """Refuse (:class:`InputError` naming ``path``) a label holding a character of ``forbidden``."""
    for lab in labels:
        if any(ch in lab for ch in forbidden):
            raise InputError(path, f"marker label {printable(lab)!r} holds {what}, which this format cannot hold: "
                                   "export to .c3d instead")


def _write(path: Path, head: list[list[str]], rows: pa.Table, delimiter: str) -> None:
    text = io.StringIO()
    csv.writer(text, delimiter=delimiter, lineterminator="\n").writerows(head)
    try:
        with open(path, "wb") as fh:
            fh.write(text.getvalue().encode("utf-8"))
            pa_csv.write_csv(rows, fh, pa_csv.WriteOptions(include_header=False, delimiter=delimiter,
                                                           quoting_style="needed"))
    except OSError as e:
        raise InputError(path, f"cannot write file ({e.strerror or e})") from None


def write_nexus_csv(path: str | Path, labels: Sequence[str], xyz: np.ndarray, valid: np.ndarray, *,
                    rate_hz: float, first_frame: int) -> None:
    """Write a Vicon Nexus "Trajectories" CSV: the block title, the rate, a row of marker names, ``Frame, Sub
    Frame, X, Y, Z …``, a units row (mm), then one row per frame (frame numbers from ``first_frame``, sub frame 0).

    ``xyz`` (T, M, 3) mm; ``valid`` (T, M): the samples written (others are empty cells). pandas reads it with
    ``pd.read_csv(path, skiprows=[0, 1, 2, 4])`` (columns ``Frame``, ``Sub Frame``, ``X``, ``Y``, ``Z``, ``X.1`` …).
    """
    t, m = np.asarray(valid).shape
    _check_labels(Path(path), labels, "\r\n", "a line break")
    head = [["Trajectories"], [repr(float(rate_hz))],
            ["", ""] + [c for lab in labels for c in (lab, "", "")],
            ["Frame", "Sub Frame"] + ["X", "Y", "Z"] * m,
            ["", ""] + ["mm"] * (3 * m)]
    frames = int(first_frame) + np.arange(t, dtype=np.int64)
    _write(Path(path), head, _rows(frames, [np.zeros(t, dtype=np.int64)], xyz, np.asarray(valid, bool)), ",")


def write_qtm_tsv(path: str | Path, labels: Sequence[str], xyz: np.ndarray, valid: np.ndarray, *,
                  rate_hz: float, first_frame: int, events: Sequence[tuple[str, int]] = (),
                  trajectory_types: Sequence[str] | None = None) -> None:
    """Write a Qualisys QTM 3D TSV: the header (``NO_OF_FRAMES``, ``FREQUENCY``, ``EVENT`` lines with their frame
    and time, ``MARKER_NAMES``, ``TRAJECTORY_TYPES``), a ``Frame, Time, <marker> X …`` row, then one row per frame.

    ``events``: (label, source frame) pairs; times are seconds since the file's first frame, as in the Time
    column. ``trajectory_types``: QTM's word for each marker (``Measured``, ``Gap-filled``, ``Mixed``). pandas
    reads the rows with ``pd.read_csv(path, sep="\\t", skiprows=N)``, N the header lines before the ``Frame`` row.
    """
    t, m = np.asarray(valid).shape
    _check_labels(Path(path), list(labels) + [label for label, _ in events], "\t\r\n\"", "a tab, a quote or a line break")
    rate = float(rate_hz)
    head = [["NO_OF_FRAMES", str(t)], ["NO_OF_CAMERAS", "0"], ["NO_OF_MARKERS", str(m)],
            ["FREQUENCY", repr(rate)], ["NO_OF_ANALOG", "0"], ["ANALOG_FREQUENCY", "0"],
            ["DESCRIPTION", "--"], ["DATA_INCLUDED", "3D"]]
    head += [["EVENT", label, str(int(f)), repr((int(f) - int(first_frame)) / rate)] for label, f in events]
    head.append(["MARKER_NAMES", *labels])
    if trajectory_types is not None:
        head.append(["TRAJECTORY_TYPES", *trajectory_types])
    head.append(["Frame", "Time"] + [f"{lab} {a}" for lab in labels for a in "XYZ"])
    frames = int(first_frame) + np.arange(t, dtype=np.int64)
    times = np.arange(t, dtype=np.float64) / rate
    _write(Path(path), head, _rows(frames, [times], xyz, np.asarray(valid, bool)), "\t")


def qtm_header_lines(path: str | Path) -> int:
    """The number of lines before the ``Frame`` row of a QTM TSV this module wrote (pandas' ``skiprows``)."""
    with open(path, encoding="utf-8") as fh:
        for i, line in enumerate(fh):
            if line.startswith("Frame\t"):
                return i
    raise InputError(path, "no Frame row (not a QTM TSV written by gazepipe export)")
