"""Arrow schemas of the four training datasets (SPEC §3.6, §4), built from their sizes.

Every dataset file starts with the identifier columns (``subject``, ``session``, ``take``, ``pose``, ``split``,
``mirrored``, ``segment``, ``frame``, ``time_s``), stored in the file even though ``subject``, ``pose`` and
``take`` also name its folder and file, then its feature columns. Feature groups are fixed-size lists of
float32 (an (N, D) numpy array without copying); per-row scalars of ``gaze_map`` are plain float32 columns.
Identifier strings are plain ``string`` columns: ``pyarrow.dataset`` with hive partitioning merges them with
the folder names as they are; pandas, which infers dictionary-typed partition keys, needs the schema stored in
``_common_metadata`` (see :mod:`gazepipe.io.dataset_files` for both calls).
"""

from __future__ import annotations

import pyarrow as pa

from gazepipe.errors import SchemaError
from gazepipe.schemas.base import read_meta, with_identity

SCHEMA_VERSION = 1
#: gaze_map's own version: 2 added the ``known`` mask, with NaN in the parameters it marks null; 3 the
#: ``start_known`` mask (a start time is null where no start was found, never 0), ``known`` marking P+ alone
GAZE_MAP_SCHEMA_VERSION = 3
DATASETS = ("gaze_rnn", "gaze_rnn_lod", "gaze_map", "face_clean")

#: identifier columns, first in every dataset file, in this order
IDENTIFIERS: tuple[pa.Field, ...] = (
    pa.field("subject", pa.string(), nullable=False),
    pa.field("session", pa.string(), nullable=False),
    pa.field("take", pa.string(), nullable=False),
    pa.field("pose", pa.string(), nullable=False),
    pa.field("split", pa.string(), nullable=False),
    pa.field("mirrored", pa.bool_(), nullable=False),
    pa.field("segment", pa.int32(), nullable=False),
    pa.field("frame", pa.int32(), nullable=False),
    pa.field("time_s", pa.float64(), nullable=False),
)
IDENTIFIER_NAMES: tuple[str, ...] = tuple(f.name for f in IDENTIFIERS)


def vec32(n: int) -> pa.DataType:
    """Fixed-size list of ``n`` float32 values."""
    return pa.list_(pa.float32(), n)


def gaze_rnn_schema(n_in: int, n_out: int, name: str = "gaze_rnn") -> pa.Schema:
    """``gaze_rnn`` / ``gaze_rnn_lod``: ``x`` (n_in) and ``y`` (n_out) per frame."""
    return with_identity(pa.schema([*IDENTIFIERS, pa.field("x", vec32(n_in), nullable=False),
                                    pa.field("y", vec32(n_out), nullable=False)]), name, SCHEMA_VERSION)


def schema_version(name: str) -> int:
    """The schema version of dataset ``name``'s files (and its _dataset.json ``schema_version``)."""
    return GAZE_MAP_SCHEMA_VERSION if name == "gaze_map" else SCHEMA_VERSION


def gaze_map_schema(n_segments: int) -> pa.Schema:
    """``gaze_map``: one row per gaze_shift take; ``p_plus`` holds one w, x, y, z quaternion per segment then the
    eyes (4·(S+1) values), ``start_times`` one fraction of ``duration_s`` per segment.

    ``known`` (S + 2 bools: the segments, then ``eyes``, then ``overshoot``) says which parameters could be
    computed (SPEC §3.6): False for a segment = its 4 ``p_plus`` values are NaN; for ``eyes`` = the eyes' 4
    ``p_plus`` values are NaN; for ``overshoot`` = ``overshoot_time`` and ``overshoot`` are NaN. ``start_known``
    (S bools) marks the ``start_times`` values: False = NaN (no start found, or one that could not be read).
    Every NaN in a row is marked in one of them; ``yaw_deg``, ``pitch_deg`` and ``duration_s`` are never null.
    Nulls are NaN, not Arrow nulls, so each list column stays an (N, D) float32 array.
    """
    f32 = pa.float32()
    return with_identity(pa.schema([
        *IDENTIFIERS,
        pa.field("yaw_deg", f32, nullable=False),
        pa.field("pitch_deg", f32, nullable=False),
        pa.field("duration_s", f32, nullable=False),
        pa.field("start_times", vec32(n_segments), nullable=False),
        pa.field("overshoot_time", f32, nullable=False),
        pa.field("overshoot", f32, nullable=False),
        pa.field("p_plus", vec32(4 * (n_segments + 1)), nullable=False),
        pa.field("known", pa.list_(pa.bool_(), n_segments + 2), nullable=False),
        pa.field("start_known", pa.list_(pa.bool_(), n_segments), nullable=False),
    ]), "gaze_map", GAZE_MAP_SCHEMA_VERSION)


def face_clean_schema(k: int, n_channels: int = 52) -> pa.Schema:
    """``face_clean``: tracked and clean blendshapes, the forward step ``dt_s`` (s) and derivatives 1..k."""
    vec = vec32(n_channels)
    fields = [*IDENTIFIERS, pa.field("dt_s", pa.float64(), nullable=False),
              pa.field("tracked", vec, nullable=False), pa.field("clean", vec, nullable=False)]
    for order in range(1, k + 1):
        fields += [pa.field(f"tracked_d{order}", vec, nullable=False),
                   pa.field(f"clean_d{order}", vec, nullable=False)]
    return with_identity(pa.schema(fields), "face_clean", SCHEMA_VERSION)


def mask_columns(schema: pa.Schema) -> list[str]:
    """Names of the bool list columns (masks, e.g. gaze_map's ``known``) of a dataset schema, in order."""
    return [f.name for f in schema if f.name not in IDENTIFIER_NAMES and pa.types.is_fixed_size_list(f.type)
            and f.type.value_type == pa.bool_()]


def feature_columns(schema: pa.Schema) -> list[str]:
    """Names of the float32 feature columns (lists and scalars) of a dataset schema, in order."""
    out = []
    for f in schema:
        if f.name in IDENTIFIER_NAMES:
            continue
        t = f.type
        if (pa.types.is_fixed_size_list(t) and t.value_type == pa.float32()) or t == pa.float32():
            out.append(f.name)
    return out


def column_width(schema: pa.Schema, name: str) -> int:
    """Number of values per row of a feature column (1 for a scalar)."""
    t = schema.field(name).type
    return t.list_size if pa.types.is_fixed_size_list(t) else 1


def dataset_schema(name: str, sizes: dict[str, int]) -> pa.Schema:
    """The schema of dataset ``name`` from its sizes: ``n_in``/``n_out`` (gaze_rnn, gaze_rnn_lod),
    ``n_segments`` (gaze_map), ``k`` and ``n_channels`` (face_clean)."""
    try:
        if name in ("gaze_rnn", "gaze_rnn_lod"):
            return gaze_rnn_schema(int(sizes["n_in"]), int(sizes["n_out"]), name)
        if name == "gaze_map":
            return gaze_map_schema(int(sizes["n_segments"]))
        if name == "face_clean":
            return face_clean_schema(int(sizes["k"]), int(sizes.get("n_channels", 52)))
    except KeyError as exc:
        raise SchemaError(None, f"dataset {name!r}: size {exc.args[0]!r} missing") from None
    raise SchemaError(None, f"unknown dataset {name!r} (known: {', '.join(DATASETS)})")


def sizes_of(table: pa.Table | pa.Schema) -> dict[str, int]:
    """The sizes stored in a dataset table's ``gazepipe.meta`` (see :func:`dataset_schema`)."""
    return {k: int(v) for k, v in read_meta(table).get("sizes", {}).items()}
