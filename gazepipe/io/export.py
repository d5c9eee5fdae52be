"""Writing markers back to the formats users look at (C3D, wide CSV)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gazepipe.errors import ConfigError, InputError
from gazepipe.io.c3d import write_c3d
from gazepipe.io.marker_csv import write_wide_csv
from gazepipe.io.parquet import read_table
from gazepipe.model import Markers
from gazepipe.schemas.markers import MARKERS_CLEAN, MARKERS_RAW, table_to_markers


def write_markers(path: Path, markers: Markers, times: np.ndarray | None = None) -> None:
    """Write ``markers`` as C3D (``.c3d``) or a plain wide CSV (``.csv``; ``times``: its time column, s);
    invalid samples become gaps."""
    suffix = path.suffix.lower()
    if suffix == ".c3d":
        write_c3d(path, markers)
    elif suffix == ".csv":
        write_wide_csv(path, markers, times)
    else:
        raise ConfigError(path, f"cannot write '{suffix or 'no extension'}': use .c3d or .csv")


def export_markers(out: Path, take: str, session: str | None, dest: Path, table: str = "markers") -> tuple[Path, int]:
    """Export one take's ``markers`` (or ``markers_raw``) table from an output folder to ``dest``.

    Rows dropped by cropping are not written; the file's first frame is the first kept source frame, so
    frame numbers still match the capture.
    """
    base = out / "takes"
    if session is None:
        found = sorted(p.parent.name for p in base.glob(f"*/{take}"))
        if not found:
            raise ConfigError(out, f"no take {take!r} in this output folder (`gazepipe status {out}` lists them)")
        if len(found) > 1:
            raise ConfigError(out, f"take {take!r} is in several sessions ({', '.join(found)}): pass --session")
        session = found[0]
    path = base / session / take / f"{table}.parquet"
    if not path.is_file() and (path.parent / "face.parquet").is_file():
        raise ConfigError(out, f"take {take!r} is a face take: it has blendshape tracks (face.parquet), no markers")
    if not path.is_file():
        raise InputError(path, f"not found: has `gazepipe {'clean' if table == 'markers' else 'ingest'}` run?")
    markers, frames, _, _ = table_to_markers(read_table(path, MARKERS_CLEAN if table == "markers" else MARKERS_RAW))
    if len(frames) and not np.array_equal(frames, np.arange(frames[0], frames[0] + len(frames))):
        raise InputError(path, "rows are not consecutive frames")
    if len(frames):
        markers.first_frame = int(markers.first_frame + frames[0])
    # the CSV's time column as in the take's tables: seconds since the capture's first frame
    write_markers(dest, markers, np.asarray(frames, dtype=np.float64) / markers.rate_hz)
    return dest, markers.n_frames
