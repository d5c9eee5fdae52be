"""The canonical per-take markers tables (``markers_raw`` from ingest, ``markers`` from clean).

Long format, marker-major: one row per (marker, frame), all frames of the first marker first, so a column
reshapes to (M, T) without a sort. ``frame`` is the 0-based row of the take's capture file (kept through
cropping), ``source_frame`` the file's own frame number, ``time_s`` seconds since the file's first frame.
Positions are millimetres in the lab frame (``markers`` tables: after root stabilisation, see ``meta``), stored
as float32: a C3D stores them so (float storage), and its rounding, under 2e-4 mm at 2 m, is far below any
marker's noise; readers get float64 (:func:`table_to_markers`).
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pyarrow as pa

from gazepipe.errors import SchemaError
from gazepipe.model import FILL_NAMES, Markers
from gazepipe.schemas.base import attach_meta, read_meta, with_identity

#: 2 stores positions as float32
SCHEMA_VERSION = 2
#: the cleaned table's own version: 2 added the ``spike`` and ``fill_error_mm`` columns; 3 float32 positions;
#: 4 the ``swap_repaired`` fill value
CLEAN_SCHEMA_VERSION = 4

_COMMON = [
    pa.field("marker", pa.dictionary(pa.int32(), pa.string()), nullable=False),
    pa.field("frame", pa.int32(), nullable=False),
    pa.field("source_frame", pa.int64(), nullable=False),
    pa.field("time_s", pa.float64(), nullable=False),
    pa.field("x", pa.float32()),
    pa.field("y", pa.float32()),
    pa.field("z", pa.float32()),
    pa.field("valid", pa.bool_(), nullable=False),
]

MARKERS_RAW = with_identity(pa.schema(_COMMON), "markers_raw", SCHEMA_VERSION)
MARKERS_CLEAN = with_identity(
    pa.schema([*_COMMON, pa.field("fill", pa.dictionary(pa.int8(), pa.string()), nullable=False),
               pa.field("spike", pa.bool_(), nullable=False), pa.field("fill_error_mm", pa.float32())]),
    "markers", CLEAN_SCHEMA_VERSION)


def markers_to_table(markers: Markers, *, frames: np.ndarray | None = None, fill_code: np.ndarray | None = None,
                     spike: np.ndarray | None = None, fill_error_mm: np.ndarray | None = None,
                     meta: dict[str, Any] | None = None) -> pa.Table:
    """Arrow table of ``markers``.

    Parameters
    ----------
    frames : (T,) original 0-based frame index of each row (default ``0..T-1``); used after cropping.
    fill_code : (T, M) int8 codes of :data:`gazepipe.model.FILL_CODES`; given → a ``markers`` table, else
        ``markers_raw``.
    spike : (T, M) bool, measured samples the clean stage removed as spikes (``markers`` tables; default none).
    fill_error_mm : (T, M) estimated error of each filled sample, mm (``markers`` tables; NaN, stored as null,
        where measured, unfilled or without an estimate; default none).
    meta : extra table-level facts stored with the rate, labels and source information.
    """
    T, M = markers.valid.shape
    frames = np.arange(T, dtype=np.int32) if frames is None else np.asarray(frames, dtype=np.int32)
    valid = markers.valid.T.reshape(-1)
    invalid = ~valid
    # one coordinate at a time, marker-major: a long take's positions are not copied whole once more
    pos_masked = [pa.array(np.ascontiguousarray(markers.xyz[:, :, k].T, dtype=np.float32).reshape(-1),
                           mask=invalid) for k in range(3)]
    marker_idx = np.repeat(np.arange(M, dtype=np.int32), T)
    cols: dict[str, pa.Array] = {
        "marker": pa.DictionaryArray.from_arrays(pa.array(marker_idx, pa.int32()), pa.array(markers.labels, pa.string())),
        "frame": pa.array(np.tile(frames, M)),
        "source_frame": pa.array(np.tile(frames.astype(np.int64) + markers.first_frame, M)),
        "time_s": pa.array(np.tile(frames / markers.rate_hz, M)),
        "x": pos_masked[0], "y": pos_masked[1], "z": pos_masked[2],
        "valid": pa.array(valid),
    }
    schema = MARKERS_RAW
    if fill_code is not None:
        codes = np.asarray(fill_code, dtype=np.int8).T.reshape(-1)
        cols["fill"] = pa.DictionaryArray.from_arrays(pa.array(codes, pa.int8()), pa.array(FILL_NAMES, pa.string()))
        cols["spike"] = pa.array(np.zeros(M * T, dtype=bool) if spike is None
                                 else np.asarray(spike, dtype=bool).T.reshape(-1))
        err = (np.full(M * T, np.nan) if fill_error_mm is None
               else np.asarray(fill_error_mm, dtype=np.float64).T.reshape(-1)).astype(np.float32)
        cols["fill_error_mm"] = pa.array(err, mask=~np.isfinite(err))
        schema = MARKERS_CLEAN
    table = pa.Table.from_pydict(cols, schema=schema)
    info = {
        "labels": list(markers.labels), "rate_hz": markers.rate_hz, "first_frame": int(markers.first_frame),
        "units_found": markers.units, "source_format": markers.source_format,
        "model_outputs": list(markers.model_outputs), "warnings": list(markers.warnings),
        "n_frames": int(T),
    }
    info.update(meta or {})
    return attach_meta(table, info)


def check_markers_meta(table: pa.Table, path: str | None = None) -> None:
    """Raise :class:`SchemaError` unless the table's metadata agrees with its rows (labels × frames, marker-major,
    a known rate): a table can match its schema and still be cut short or carry edited metadata."""
    try:
        meta = read_meta(table)
    except ValueError:
        raise SchemaError(path, "unreadable gazepipe metadata") from None
    labels = meta.get("labels")
    if not isinstance(labels, list) or not all(isinstance(x, str) for x in labels) or len(set(labels)) != len(labels):
        raise SchemaError(path, "metadata 'labels' is not a list of distinct marker names")
    rate = meta.get("rate_hz")
    if not isinstance(rate, int | float) or isinstance(rate, bool) or not rate > 0:
        raise SchemaError(path, "metadata 'rate_hz' is not a positive number")
    if not isinstance(meta.get("first_frame"), int) or isinstance(meta.get("first_frame"), bool):
        raise SchemaError(path, "metadata 'first_frame' is not a whole number")
    m = len(labels)
    if m == 0 or table.num_rows % m:
        raise SchemaError(path, f"{table.num_rows} rows do not make {m} markers x whole frames")
    t = table.num_rows // m
    marker = cast(pa.DictionaryArray, table.column("marker").combine_chunks())   # checked against the schema
    idx = marker.indices.to_numpy(zero_copy_only=False) if t else np.zeros(0, np.int64)
    # a table of no frames (a take without a rest) comes back from Parquet with an empty dictionary
    if (t and len(marker.dictionary) != m) or not np.array_equal(idx, np.repeat(np.arange(m), t)):
        raise SchemaError(path, "rows are not marker-major in the order of the metadata's labels")
    frames = table.column("frame").to_numpy()
    if t and not np.array_equal(frames.reshape(m, t), np.broadcast_to(frames[:t], (m, t))):
        raise SchemaError(path, "markers do not share the same frames")


def fill_codes(table: pa.Table) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``(labels, frames, fill)`` of a cleaned markers table of which only ``frame`` and ``fill`` need be read:
    fill is (T, M) int8 codes (:data:`gazepipe.model.FILL_CODES`)."""
    labels = list(read_meta(table)["labels"])
    m = len(labels)
    t = table.num_rows // m if m else 0
    frames = table.column("frame").to_numpy()[:t].astype(np.int64)
    fill = cast(pa.DictionaryArray, table.column("fill").combine_chunks()).indices.to_numpy(zero_copy_only=False)
    return labels, frames, fill.astype(np.int8).reshape(m, t).T


def table_to_markers(table: pa.Table) -> tuple[Markers, np.ndarray, np.ndarray | None, dict[str, Any]]:
    """Inverse of :func:`markers_to_table`: ``(markers, frames, fill_code or None, meta)``."""
    meta = read_meta(table)
    labels = list(meta["labels"])
    M = len(labels)
    n = table.num_rows
    T = n // M if M else 0
    frames = table.column("frame").to_numpy()[:T].astype(np.int64)
    xyz = np.empty((T, M, 3))
    for k, axis in enumerate("xyz"):        # one coordinate at a time: the take is not held twice as floats
        xyz[:, :, k] = table.column(axis).to_numpy(zero_copy_only=False).reshape(M, T).T
    valid = table.column("valid").to_numpy(zero_copy_only=False).reshape(M, T).T
    xyz[~valid] = np.nan
    fill = None
    if "fill" in table.column_names:
        codes = cast(pa.DictionaryArray, table.column("fill").combine_chunks()).indices
        fill = codes.to_numpy(zero_copy_only=False).astype(np.int8).reshape(M, T).T
    markers = Markers(labels=labels, xyz=xyz, valid=valid, rate_hz=float(meta["rate_hz"]),
                      first_frame=int(meta["first_frame"]), units=meta.get("units_found"),
                      source_format=meta.get("source_format", ""), model_outputs=list(meta.get("model_outputs", [])),
                      warnings=list(meta.get("warnings", [])))
    return markers, frames, fill, meta


#: the clean stage's rest-speed trace: the subject's mean marker speed per frame of the uncropped take (mm/s, NaN
#: where unknown), which its rests and crop were found on; the report plots it
_REST_SPEED_FIELDS: list[pa.Field] = [pa.field("frame", pa.int32(), nullable=False),
                                      pa.field("speed_mm_s", pa.float64())]
REST_SPEED = with_identity(pa.schema(_REST_SPEED_FIELDS), "rest_speed", 1)


def rest_speed_to_table(speed_mm_s: np.ndarray) -> pa.Table:
    """Arrow table (:data:`REST_SPEED`) of a take's rest-speed trace, (T,) mm/s, one row per frame."""
    speed = np.asarray(speed_mm_s, dtype=np.float64)
    return pa.Table.from_pydict({"frame": pa.array(np.arange(speed.size, dtype=np.int32)),
                                 "speed_mm_s": pa.array(speed, mask=~np.isfinite(speed))}, schema=REST_SPEED)


def fill_errors(table: pa.Table) -> np.ndarray | None:
    """(T, M) float64 estimated error (mm) of each filled sample of a cleaned markers table (its
    ``fill_error_mm`` column, :func:`markers_to_table`): NaN where measured, unfilled or filled without an
    estimate; None when the table has no such column (the ``neutral`` table, a raw table)."""
    if "fill_error_mm" not in table.column_names:
        return None
    m = len(read_meta(table)["labels"])
    t = table.num_rows // m if m else 0
    col = table.column("fill_error_mm").combine_chunks()
    err = col.to_numpy(zero_copy_only=False).astype(np.float64)   # nulls come back as NaN
    return err.reshape(m, t).T
