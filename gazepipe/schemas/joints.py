"""The per-take ``joints`` table (frames stage): one row per kept mocap frame.

Rotations are in the character frame of that frame (SPEC §2): ``quat`` global and ``quat_local``
parent-relative (w, x, y, z per segment, segments in markerset order), ``six`` the 6-number form (forward then up
per segment). ``head_centre`` mm and ``target_dir`` (unit) are in the character frame; ``char_origin`` (mm, lab)
and ``char_rot`` (lab-from-character, w, x, y, z) place the character frame in the lab. ``rot_filled`` says per
segment whether its rotation was filled across a gap of its markers rather than measured. The number of segments
lives in the list sizes and in ``meta.segments``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.schemas.base import attach_meta, read_meta, with_element_names, with_identity

#: 2 added ``rot_filled``
SCHEMA_VERSION = 2


def _vec(n: int) -> pa.DataType:
    return pa.list_(pa.float64(), n)


def joints_schema(n_segments: int) -> pa.Schema:
    s = n_segments
    return with_identity(pa.schema([
        pa.field("frame", pa.int32(), nullable=False),
        pa.field("source_frame", pa.int64(), nullable=False),
        pa.field("time_s", pa.float64(), nullable=False),
        pa.field("valid", pa.bool_(), nullable=False),
        pa.field("quat", _vec(4 * s)),
        pa.field("quat_local", _vec(4 * s)),
        pa.field("six", _vec(6 * s)),
        pa.field("head_centre", _vec(3)),
        pa.field("target_dir", _vec(3)),
        pa.field("char_origin", _vec(3)),
        pa.field("char_rot", _vec(4)),
        pa.field("rot_filled", pa.list_(pa.bool_(), s), nullable=False),
    ]), "joints", SCHEMA_VERSION)


def fixed_list(values: np.ndarray, width: int) -> pa.FixedSizeListArray:
    """(N, ...) float array → a fixed-size list column of ``width`` float64 values per row (no copy)."""
    flat = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat), width)


def list_to_numpy(column: pa.ChunkedArray | pa.Array, width: int) -> np.ndarray:
    """A fixed-size list column → (N, width) array (NaN stays NaN)."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    return arr.flatten().to_numpy(zero_copy_only=False).reshape(-1, width)


def joints_to_table(joints, frames: np.ndarray, meta: dict[str, Any] | None = None) -> pa.Table:
    """Arrow table of a :class:`gazepipe.stages.frames.stage.Joints`; ``frames`` = original frame index of each row."""
    n, s = joints.quat.shape[:2]
    frames = np.asarray(frames, dtype=np.int64)
    cols = {
        "frame": pa.array(frames.astype(np.int32)),
        "source_frame": pa.array(frames + int(joints.first_frame)),
        "time_s": pa.array(frames / joints.rate_hz),
        "valid": pa.array(np.asarray(joints.valid, dtype=bool)),
        "quat": fixed_list(joints.quat, 4 * s),
        "quat_local": fixed_list(joints.quat_local, 4 * s),
        "six": fixed_list(joints.six, 6 * s),
        "head_centre": fixed_list(joints.head_centre, 3),
        "target_dir": fixed_list(joints.target_dir, 3),
        "char_origin": fixed_list(joints.char_origin, 3),
        "char_rot": fixed_list(joints.char_rot, 4),
        "rot_filled": pa.FixedSizeListArray.from_arrays(pa.array(
            (np.zeros((n, s), dtype=bool) if getattr(joints, "rot_filled", None) is None
             else np.asarray(joints.rot_filled, dtype=bool)).reshape(-1)), s),
    }
    table = pa.Table.from_pydict(cols, schema=with_element_names(joints_schema(s), element_names(joints.segments)))
    info = {"segments": list(joints.segments), "parents": [int(p) for p in joints.parents],
            "rate_hz": float(joints.rate_hz), "first_frame": int(joints.first_frame)}
    info.update(meta or {})
    return attach_meta(table, info)


def element_names(segments: list[str]) -> dict[str, list[str]]:
    """The element names of the joints table's list columns, e.g. ``pelvis.w``, ``pelvis.fwd.x``, ``x``."""
    segs = list(segments)
    return {"quat": [f"{g}.{c}" for g in segs for c in "wxyz"],
            "quat_local": [f"{g}.{c}" for g in segs for c in "wxyz"],
            "six": [f"{g}.{a}.{c}" for g in segs for a in ("fwd", "up") for c in "xyz"],
            "head_centre": list("xyz"), "target_dir": list("xyz"), "char_origin": list("xyz"),
            "char_rot": list("wxyz"), "rot_filled": segs}


def joints_arrays(table: pa.Table) -> dict[str, Any]:
    """The joints table as arrays: quat (N, S, 4), quat_local, six (N, S, 6), head_centre, target_dir, … ."""
    meta = read_meta(table)
    s = len(meta["segments"])
    out: dict[str, Any] = {"meta": meta, "segments": meta["segments"]}
    for name in ("frame", "source_frame", "time_s", "valid"):
        out[name] = table.column(name).to_numpy()
    for name, shape in (("quat", (s, 4)), ("quat_local", (s, 4)), ("six", (s, 6)), ("head_centre", (3,)),
                        ("target_dir", (3,)), ("char_origin", (3,)), ("char_rot", (4,))):
        width = int(np.prod(shape))
        out[name] = list_to_numpy(table.column(name), width).reshape(-1, *shape)
    out["rot_filled"] = (table.column("rot_filled").combine_chunks().flatten().to_numpy(zero_copy_only=False)
                         .reshape(-1, s).astype(bool))
    return out
