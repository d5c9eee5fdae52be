"""One entry point for marker capture files, and the summary behind ``gazepipe inspect``."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from gazepipe.errors import InputError
from gazepipe.io.c3d import duplicate_trajectories, read_c3d_info
from gazepipe.io.c3d_meta import HEAD_BYTES
from gazepipe.io.marker_csv import (
    VICON_FIRST_CELLS,
    has_trajectories_block,
    read_qtm_tsv,
    read_vicon_csv,
    read_wide_csv,
)
from gazepipe.io.signatures import not_a_capture
from gazepipe.model import Markers

FORMATS = ("c3d", "vicon_csv", "qtm_tsv", "wide_csv")

_QTM_KEY = re.compile(r"^[A-Z][A-Z0-9_]*$")
_WIDE_COLUMN = re.compile(r"^.+_[xyzXYZ]$")


def track_format(header: Iterable[str]) -> str | None:
    """``"openface"`` or ``"livelinkface"`` when a CSV's header cells are those of an OpenFace eye-tracking or a
    Live Link Face blendshape file, else ``None``."""
    cells = {c.strip() for c in header}
    if {"gaze_0_x", "confidence"} <= cells:
        return "openface"
    if "Timecode" in cells and cells & {"BlendShapeCount", "BlendshapeCount"}:
        return "livelinkface"
    return None


def track_file_format(path: str | Path) -> str | None:
    """:func:`track_format` of a file's first line; ``None`` when it cannot be read (the marker readers then
    say why)."""
    try:
        with open(path, "rb") as fh:
            first = fh.read(4096).decode("latin-1").lstrip("\ufeff\xef\xbb\xbf").split("\n", 1)[0]
    except OSError:
        return None
    return track_format(first.split(","))


def sniff_format(path: str | Path) -> str:
    """Name the format of a capture file from its first bytes, falling back on its extension.

    Returns one of :data:`FORMATS`; raises InputError when the file is missing or not a marker file.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except FileNotFoundError:
        raise InputError(p, "file not found") from None
    except OSError as e:
        raise InputError(p, f"cannot read file ({e.strerror or e})") from None
    ext = p.suffix.lower()
    other = not_a_capture(p)
    if other is not None:
        raise InputError(p, f"not a capture file ({other}; marker captures are C3D, Vicon CSV, QTM TSV or wide CSV)")
    if ext == ".c3d" or (len(head) >= 2 and head[1] == 0x50 and b"\x00" in head):
        return "c3d"
    text = head.decode("latin-1").lstrip("\ufeff\xef\xbb\xbf")
    track = track_format(text.split("\n", 1)[0].split(","))
    if track == "openface":
        raise InputError(p, "an OpenFace eye-tracking CSV, not a marker capture (give it to a session's takes "
                            "as `eyes`; fill reads C3D, Vicon CSV, QTM TSV and wide CSV)")
    if track == "livelinkface":
        raise InputError(p, "a Live Link Face blendshape CSV, not a marker capture (give it to a `face` "
                            "take as `tracked` or `clean`; fill reads C3D, Vicon CSV, QTM TSV and wide CSV)")
    lines = text.splitlines()
    first = next((ln for ln in lines if ln.strip(" \t,\r")), "")
    if first.split(",", 1)[0].strip().strip('"').lower() in VICON_FIRST_CELLS:
        return "vicon_csv"
    if _qtm_header(lines):
        return "qtm_tsv"
    if ext in (".csv", ".txt") and _wide_header(first):
        return "wide_csv"
    if has_trajectories_block(p):      # a Nexus export whose first lines are something else
        return "vicon_csv"
    if ext in (".csv", ".txt"):
        return "wide_csv"
    if ext == ".tsv":
        return "qtm_tsv"
    raise InputError(p, f"unknown capture format (extension {ext or 'none'!r}; expected .c3d, .csv or .tsv)")


def _qtm_header(lines: list[str]) -> bool:
    """Whether the leading ``KEY<TAB>value`` lines of a text (QTM's header, however long) name QTM's keys."""
    for ln in lines:
        key = ln.split("\t", 1)[0].strip()
        if key in ("NO_OF_FRAMES", "MARKER_NAMES", "FREQUENCY"):
            return True
        if not _QTM_KEY.match(key):
            return False
    return False


def _wide_header(line: str) -> bool:
    """Whether a CSV's first line names ``<marker>_x``-style columns (a wide CSV's header)."""
    return any(_WIDE_COLUMN.match(c.strip()) for c in line.split(","))


def _read(path: Path, rate_hz: float | None, default_units: str) -> tuple[Markers, dict[str, Any]]:
    fmt = sniff_format(path)
    if fmt == "c3d":
        m, info = read_c3d_info(path, default_units=default_units)
        if rate_hz is not None and abs(float(rate_hz) - m.rate_hz) > 5e-4 * m.rate_hz:
            m.warnings.append(f"file rate {m.rate_hz:g} Hz used, not the given {float(rate_hz):g} Hz")
        return m, info
    reader = {"vicon_csv": read_vicon_csv, "qtm_tsv": read_qtm_tsv, "wide_csv": read_wide_csv}[fmt]
    m = reader(path, rate_hz=rate_hz, default_units=default_units)
    return m, {"reader": "pandas", "units": m.units}


def read_markers(path: str | Path, *, rate_hz: float | None = None, default_units: str = "mm") -> Markers:
    """Read any accepted marker capture (.c3d, Vicon/wide .csv, QTM .tsv) into canonical Markers (mm).

    ``rate_hz`` serves files that carry no rate; ``default_units`` files that do not name their units.
    Every failure is an InputError naming the file.
    """
    return _read(Path(path), rate_hz, default_units)[0]


def _streamed_c3d(p: Path, rate_hz: float | None, over_bytes: int | None = None) -> dict[str, Any] | None:
    """:func:`inspect_capture`'s summary of a C3D file too large to hold decoded (more than ``over_bytes``,
    :data:`~gazepipe.io.c3d_summary.STREAM_OVER_BYTES` by default), read in one streaming pass; None for any
    other file (read whole)."""
    from gazepipe.io.c3d_meta import MetaError, parse_c3d_meta
    from gazepipe.io.c3d_summary import STREAM_OVER_BYTES, summarise_c3d

    limit = STREAM_OVER_BYTES if over_bytes is None else over_bytes
    if sniff_format(p) != "c3d":
        return None
    try:
        with open(p, "rb") as fh:
            lay = parse_c3d_meta(fh.read(HEAD_BYTES)).layout(os.fstat(fh.fileno()).st_size)
    except (OSError, MetaError, ValueError):
        return None   # the full read says what is wrong
    if lay.n_frames * lay.n_points * 3 * 8 <= limit:
        return None
    out = summarise_c3d(p)
    if out is not None and rate_hz is not None and abs(float(rate_hz) - out["rate_hz"]) > 5e-4 * out["rate_hz"]:
        out["warnings"].append(f"file rate {out['rate_hz']:g} Hz used, not the given {float(rate_hz):g} Hz")
    return out


def inspect_capture(path: str | Path, *, rate_hz: float | None = None) -> dict[str, Any]:
    """Summarise a capture file (what ``gazepipe inspect`` prints).

    Keys: path, format, reader, rate_hz, frames, first_frame, duration_s, units (as found, None if absent),
    n_markers, markers (list of {label, gap_fraction}), model_outputs, duplicates (groups of labels with
    bit-identical trajectories), warnings; for C3D also processor, storage and analog_channels.
    """
    p = Path(path)
    streamed = _streamed_c3d(p, rate_hz)
    if streamed is not None:
        return streamed
    m, info = _read(p, rate_hz, "mm")
    gaps = m.gap_fraction()
    out: dict[str, Any] = {
        "path": str(p),
        "format": m.source_format,
        "reader": info.get("reader"),
        "rate_hz": m.rate_hz,
        "frames": m.n_frames,
        "first_frame": m.first_frame,
        "duration_s": m.n_frames / m.rate_hz,
        "units": info.get("units"),
        "n_markers": m.n_markers,
        "markers": [{"label": lab, "gap_fraction": float(g)} for lab, g in zip(m.labels, gaps, strict=True)],
        "model_outputs": list(m.model_outputs),
        "duplicates": duplicate_trajectories(m),
        "warnings": list(m.warnings),
    }
    for key in ("processor", "storage", "analog_channels"):
        if key in info:
            out[key] = info[key]
    return out
