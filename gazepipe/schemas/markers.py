"""The canonical per-take markers tables (``markers_raw`` from ingest, ``markers`` from clean).

Long format, marker-major: one row per (marker, frame), all frames of the first marker first, so a column
reshapes to (M, T) without a sort. ``frame`` is the 0-based row of the take's capture file (kept through
cropping), ``source_frame`` the file's own frame number, ``time_s`` seconds since the file's first frame.
Positions are millimetres in the lab frame (``markers`` tables: after root stabilisation, see ``meta``), stored
as float32: a C3D stores them so (float storage), and its rounding, under 2e-4 mm at 2 m, is far below any
marker's noise; readers get float64 (:func:`table_to_markers`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any, NamedTuple, cast

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


#: rows per record batch of :func:`markers_batches` (any size writes the same file: the writer cuts row groups
#: of its own size, :func:`gazepipe.io.parquet.write_batches`; a table of :func:`markers_to_table` has a chunk
#: per row group, whose bytes ``pq.write_table`` writes)
BATCH_ROWS = 1024 * 1024


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
    # made a batch at a time (a long take's temporaries stay within a batch), one chunk per batch
    schema, _, batches = markers_batches(markers, frames=frames, fill_code=fill_code, spike=spike,
                                         fill_error_mm=fill_error_mm, meta=meta)
    return pa.Table.from_batches(list(batches), schema)


class MarkersBatches(NamedTuple):
    """A markers table as its record batches (:func:`markers_batches`): its schema with its metadata, its rows
    in all and the batches, made as they are read (the engine's ``TableBatches``)."""

    schema: pa.Schema
    num_rows: int
    batches: Iterator[pa.RecordBatch]


def markers_batches(markers: Markers, *, frames: np.ndarray | None = None, fill_code: np.ndarray | None = None,
                    spike: np.ndarray | None = None, fill_error_mm: np.ndarray | None = None,
                    meta: dict[str, Any] | None = None, rows: int | None = BATCH_ROWS) -> MarkersBatches:
    """:func:`markers_to_table` a batch of ``rows`` rows at a time (None: one batch): ``(schema with its
    metadata, rows in all, the batches)``, made as they are read, so a long take's table is never held whole.
    The arrays must stay unchanged until the batches are read."""
    T, M = markers.valid.shape
    frames = np.arange(T, dtype=np.int32) if frames is None else np.asarray(frames, dtype=np.int32)
    schema = MARKERS_RAW if fill_code is None else MARKERS_CLEAN
    info = {
        "labels": list(markers.labels), "rate_hz": markers.rate_hz, "first_frame": int(markers.first_frame),
        "units_found": markers.units, "source_format": markers.source_format,
        "model_outputs": list(markers.model_outputs), "warnings": list(markers.warnings),
        "n_frames": int(T),
    }
    info.update(meta or {})
    schema = attach_meta(schema.empty_table(), info).schema
    step = max(1, rows or M * T)
    batches = (_markers_batch(schema, markers, frames, fill_code, spike, fill_error_mm, lo, min(M * T, lo + step))
               for lo in range(0, max(M * T, 1), step))
    return MarkersBatches(schema, M * T, batches)


def _markers_batch(schema: pa.Schema, markers: Markers, frames: np.ndarray, fill_code: np.ndarray | None,
                   spike: np.ndarray | None, fill_error_mm: np.ndarray | None, lo: int, hi: int) -> pa.RecordBatch:
    """Rows ``lo:hi`` of :func:`markers_to_table` (marker-major: row ``r`` is frame ``r % T`` of marker
    ``r // T``)."""
    T, M = markers.valid.shape
    r = np.arange(lo, hi, dtype=np.int64)
    m, t = (r // T, r % T) if T else (r, r)
    f = frames[t]
    valid = markers.valid[t, m]
    invalid = ~valid
    pos = [pa.array(markers.xyz[t, m, k].astype(np.float32), mask=invalid) for k in range(3)]
    cols: dict[str, pa.Array] = {
        "marker": pa.DictionaryArray.from_arrays(pa.array(m.astype(np.int32), pa.int32()),
                                                 pa.array(markers.labels, pa.string())),
        "frame": pa.array(f),
        "source_frame": pa.array(f.astype(np.int64) + markers.first_frame),
        "time_s": pa.array(f / markers.rate_hz),
        "x": pos[0], "y": pos[1], "z": pos[2],
        "valid": pa.array(valid),
    }
    if fill_code is not None:
        codes = np.asarray(fill_code, dtype=np.int8)[t, m]
        cols["fill"] = pa.DictionaryArray.from_arrays(pa.array(codes, pa.int8()), pa.array(FILL_NAMES, pa.string()))
        cols["spike"] = pa.array(np.zeros(r.size, dtype=bool) if spike is None else np.asarray(spike, dtype=bool)[t, m])
        err = (np.full(r.size, np.nan) if fill_error_mm is None
               else np.asarray(fill_error_mm, dtype=np.float64)[t, m]).astype(np.float32)
        cols["fill_error_mm"] = pa.array(err, mask=~np.isfinite(err))
    return pa.RecordBatch.from_pydict(cols, schema=schema)


def check_markers_meta(table: pa.Table, path: str | None = None) -> None:
    """Raise :class:`SchemaError` unless the table's metadata agrees with its rows (labels × frames, marker-major,
    a known rate): a table can match its schema and still be cut short or carry edited metadata."""
    m, t = _checked_shape(table.schema, table.num_rows, path)
    marker = cast(pa.DictionaryArray, table.column("marker").combine_chunks())   # checked against the schema
    idx = marker.indices.to_numpy(zero_copy_only=False) if t else np.zeros(0, np.int64)
    # a table of no frames (a take without a rest) comes back from Parquet with an empty dictionary
    if (t and len(marker.dictionary) != m) or not np.array_equal(idx, np.repeat(np.arange(m), t)):
        raise SchemaError(path, "rows are not marker-major in the order of the metadata's labels")
    frames = table.column("frame").to_numpy()
    if t and not np.array_equal(frames.reshape(m, t), np.broadcast_to(frames[:t], (m, t))):
        raise SchemaError(path, "markers do not share the same frames")


def _checked_shape(schema: pa.Schema, num_rows: int, path: str | None) -> tuple[int, int]:
    """``(markers, frames)`` of a markers table of ``num_rows`` rows whose metadata (in ``schema``) is checked."""
    try:
        meta = read_meta(schema)
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
    if m == 0 or num_rows % m:
        raise SchemaError(path, f"{num_rows} rows do not make {m} markers x whole frames")
    return m, num_rows // m


def checked_markers_batches(schema: pa.Schema, num_rows: int, batches: Iterable[pa.RecordBatch],
                            path: str | None = None) -> Iterator[pa.RecordBatch]:
    """:func:`check_markers_meta` of a table read a batch at a time: its metadata at once (a
    :class:`SchemaError` before any batch), each batch's rows as it passes (the first marker's rows give the
    frames every other marker must share), and the rows' count at the end."""
    m, t = _checked_shape(schema, num_rows, path)
    return _checked_rows(pa.array(read_meta(schema)["labels"], pa.string()), t, num_rows, batches, path)


def _checked_rows(labels: pa.Array, t: int, num_rows: int, batches: Iterable[pa.RecordBatch],
                  path: str | None) -> Iterator[pa.RecordBatch]:
    m = len(labels)
    frames = np.zeros(t, np.int64)
    lo = 0
    for batch in batches:
        r = np.arange(lo, lo + batch.num_rows, dtype=np.int64)
        if r.size:
            marker = cast(pa.DictionaryArray, batch.column("marker"))
            if (r[-1] >= m * t or not marker.dictionary.equals(labels)
                    or not np.array_equal(marker.indices.to_numpy(zero_copy_only=False), r // t)):
                raise SchemaError(path, "rows are not marker-major in the order of the metadata's labels")
            f = batch.column("frame").to_numpy(zero_copy_only=False)
            first = r < t
            frames[r[first]] = f[first]
            if not np.array_equal(f, frames[r % t]):
                raise SchemaError(path, "markers do not share the same frames")
        lo += batch.num_rows
        yield batch
    if lo != num_rows:
        raise SchemaError(path, f"{lo} rows read of the {num_rows} the file holds")


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
    return _markers(meta, xyz, valid), frames, fill, meta


def batches_to_markers(schema: pa.Schema, num_rows: int, batches: Iterable[pa.RecordBatch]
                       ) -> tuple[Markers, np.ndarray]:
    """:func:`table_to_markers` of a table given a batch at a time (``schema`` with its metadata,
    ``num_rows`` rows in all): ``(markers, frames)``, the same arrays, without the table ever held whole (its
    fill codes are not read)."""
    meta = read_meta(schema)
    M = len(meta["labels"])
    T = num_rows // M if M else 0
    frames = np.zeros(T, np.int64)
    xyz = np.empty((T, M, 3))
    valid = np.zeros((T, M), dtype=bool)
    lo = 0
    for batch in batches:
        r = np.arange(lo, lo + batch.num_rows, dtype=np.int64)
        m, t = r // max(T, 1), r % max(T, 1)
        first = r < T
        frames[t[first]] = batch.column("frame").to_numpy(zero_copy_only=False)[first]
        for k, axis in enumerate("xyz"):
            xyz[t, m, k] = batch.column(axis).to_numpy(zero_copy_only=False)
        valid[t, m] = batch.column("valid").to_numpy(zero_copy_only=False)
        lo += batch.num_rows
    xyz[~valid] = np.nan
    return _markers(meta, xyz, valid), frames


def _markers(meta: dict[str, Any], xyz: np.ndarray, valid: np.ndarray) -> Markers:
    return Markers(labels=list(meta["labels"]), xyz=xyz, valid=valid, rate_hz=float(meta["rate_hz"]),
                   first_frame=int(meta["first_frame"]), units=meta.get("units_found"),
                   source_format=meta.get("source_format", ""), model_outputs=list(meta.get("model_outputs", [])),
                   warnings=list(meta.get("warnings", [])))


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
