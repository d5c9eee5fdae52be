"""The per-take ``joints`` table (frames stage): one row per kept mocap frame.

Rotations are in the character frame of that frame (SPEC §2): ``quat`` the global rotation of each segment
(w, x, y, z per segment, segments in markerset order). ``head_centre`` mm and ``target_dir`` (unit) are in the
character frame; ``char_origin`` (mm, lab) and ``char_rot`` (lab-from-character, w, x, y, z) place the character
frame in the lab. ``rot_filled`` says per segment whether its rotation was filled across a gap of its markers
rather than measured, ``rot_measured`` whether it comes from measured marker samples only (every marker of
the segment measured, none gap-filled, and the rotation not filled). The number of segments lives in the list sizes and in ``meta.segments``; every list
column names its elements in its field metadata.

Stored as float32: a unit quaternion's float32 rounding is under 1e-5°, a millimetre position's under
2e-4 mm at 2 m, both far below the markers' own noise. The parent-relative rotations (``quat_local``) and the
6-number form (``six``: forward R·ẑ then up R·ŷ per segment) follow from ``quat`` and the parents, so they are
not stored: :func:`joints_arrays` derives them.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pyarrow as pa

from gazepipe.schemas.base import attach_meta, read_meta, with_element_names, with_identity

#: 2 added ``rot_filled``; 3 float32, ``quat_local`` and ``six`` derived on reading instead of stored;
#: 4 added ``rot_measured``
SCHEMA_VERSION = 4


def _vec(n: int) -> pa.DataType:
    return pa.list_(pa.float32(), n)


def joints_schema(n_segments: int) -> pa.Schema:
    s = n_segments
    fields: list[pa.Field] = [
        pa.field("frame", pa.int32(), nullable=False),
        pa.field("source_frame", pa.int64(), nullable=False),
        pa.field("time_s", pa.float64(), nullable=False),
        pa.field("valid", pa.bool_(), nullable=False),
        pa.field("quat", _vec(4 * s)),
        pa.field("head_centre", _vec(3)),
        pa.field("target_dir", _vec(3)),
        pa.field("char_origin", _vec(3)),
        pa.field("char_rot", _vec(4)),
        pa.field("rot_filled", pa.list_(pa.bool_(), s), nullable=False),
        pa.field("rot_measured", pa.list_(pa.bool_(), s), nullable=False),
    ]
    return with_identity(pa.schema(fields), "joints", SCHEMA_VERSION)


def fixed_list(values: np.ndarray, width: int, dtype: type = np.float64) -> pa.FixedSizeListArray:
    """(N, ...) float array → a fixed-size list column of ``width`` values of ``dtype`` per row."""
    flat: np.ndarray = np.ascontiguousarray(values, dtype=dtype).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat), width)


def list_to_numpy(column: pa.ChunkedArray | pa.Array, width: int) -> np.ndarray:
    """A fixed-size list column → (N, width) array (NaN stays NaN)."""
    arr = cast(pa.FixedSizeListArray, column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column)
    return arr.flatten().to_numpy(zero_copy_only=False).reshape(-1, width)


def joints_to_table(joints, frames: np.ndarray, meta: dict[str, Any] | None = None) -> pa.Table:
    """Arrow table of a :class:`gazepipe.stages.frames.stage.Joints`; ``frames`` = original frame index of each row."""
    n, s = joints.quat.shape[:2]
    frames = np.asarray(frames, dtype=np.int64)
    filled = (np.zeros((n, s), dtype=bool) if getattr(joints, "rot_filled", None) is None
              else np.asarray(joints.rot_filled, dtype=bool))
    # without its own record every known rotation that was not filled counts as measured
    measured = (np.isfinite(joints.quat).all(axis=2) & ~filled if getattr(joints, "rot_measured", None) is None
                else np.asarray(joints.rot_measured, dtype=bool))
    cols = {
        "frame": pa.array(frames.astype(np.int32)),
        "source_frame": pa.array(frames + int(joints.first_frame)),
        "time_s": pa.array(frames / joints.rate_hz),
        "valid": pa.array(np.asarray(joints.valid, dtype=bool)),
        "quat": fixed_list(joints.quat, 4 * s, np.float32),
        "head_centre": fixed_list(joints.head_centre, 3, np.float32),
        "target_dir": fixed_list(joints.target_dir, 3, np.float32),
        "char_origin": fixed_list(joints.char_origin, 3, np.float32),
        "char_rot": fixed_list(joints.char_rot, 4, np.float32),
        "rot_filled": pa.FixedSizeListArray.from_arrays(pa.array(filled.reshape(-1)), s),
        "rot_measured": pa.FixedSizeListArray.from_arrays(pa.array(measured.reshape(-1)), s),
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
            "head_centre": list("xyz"), "target_dir": list("xyz"), "char_origin": list("xyz"),
            "char_rot": list("wxyz"), "rot_filled": segs, "rot_measured": segs}


def quat_six(quat: np.ndarray) -> np.ndarray:
    """The 6-number form (forward R·ẑ, then up R·ŷ) of unit quaternions w, x, y, z (..., 4) → (..., 6)."""
    q = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    fwd = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    up = np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], axis=-1)
    return np.concatenate([fwd, up], axis=-1)


def quat_local(quat: np.ndarray, parents: list[int]) -> np.ndarray:
    """Parent-relative rotations q_parent⁻¹ · q (w ≥ 0) of global quaternions (N, S, 4); a root keeps its own."""
    quat = np.asarray(quat, dtype=np.float64)
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    out = quat.copy()
    for j, p in enumerate(parents):
        if p < 0:
            continue
        a, b = quat[:, p], quat[:, j]
        aw, av = a[:, :1], -a[:, 1:]                      # the parent's conjugate
        bw, bv = b[:, :1], b[:, 1:]
        w = aw * bw - np.sum(av * bv, axis=1, keepdims=True)
        v = aw * bv + bw * av + np.cross(av, bv)
        out[:, j] = np.concatenate([w, v], axis=1)
    return np.where(out[..., :1] < 0, -out, out)


def joints_arrays(table: pa.Table) -> dict[str, Any]:
    """The joints table as float64 arrays: quat (N, S, 4), head_centre, target_dir, …, and the derived quat_local
    (N, S, 4) and six (N, S, 6)."""
    meta = read_meta(table)
    s = len(meta["segments"])
    out: dict[str, Any] = {"meta": meta, "segments": meta["segments"]}
    for name in ("frame", "source_frame", "time_s", "valid"):
        out[name] = table.column(name).to_numpy()
    for name, shape in (("quat", (s, 4)), ("head_centre", (3,)), ("target_dir", (3,)), ("char_origin", (3,)),
                        ("char_rot", (4,))):
        width = int(np.prod(shape))
        out[name] = list_to_numpy(table.column(name), width).astype(np.float64).reshape(-1, *shape)
    out["quat_local"] = quat_local(out["quat"], [int(p) for p in meta.get("parents", [-1] + list(range(s - 1)))])
    out["six"] = quat_six(out["quat"])
    for name in ("rot_filled", "rot_measured"):
        lists = cast(pa.FixedSizeListArray, table.column(name).combine_chunks())
        out[name] = lists.flatten().to_numpy(zero_copy_only=False).reshape(-1, s).astype(bool)
    return out
