"""Session tables: several takes' marker poses stacked (``neutral_poses``), and named arrays computed once for
a session (``subject_geometry``).

Long format: one row per (source, marker, frame), each source's rows marker-major as in the markers tables
(:mod:`gazepipe.schemas.markers`). Positions are millimetres in the lab frame, stored as float64: these poses
are what other stages calibrate against, and they must reach them with the bits they were computed with. The
metadata lists the sources in order (``sources``: label, take, role, labels, rate, first frame, frames).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.model import Markers
from gazepipe.schemas.base import attach_meta, read_meta, with_identity

SCHEMA_VERSION = 1

MARKER_STACK = with_identity(pa.schema([
    pa.field("source", pa.int32(), nullable=False),
    pa.field("marker", pa.dictionary(pa.int32(), pa.string()), nullable=False),
    pa.field("frame", pa.int32(), nullable=False),
    pa.field("x", pa.float64()),
    pa.field("y", pa.float64()),
    pa.field("z", pa.float64()),
    pa.field("valid", pa.bool_(), nullable=False),
]), "marker_stack", SCHEMA_VERSION)


@dataclass(frozen=True)
class PoseSource:
    """One source of a stack: a label for people (``neutral take N``), the take it comes from, its role (what
    the stage that wrote it means by it) and its markers (frames: rows of the source, 0-based)."""

    label: str
    take: str
    role: str
    markers: Markers


def stack_to_table(sources: list[PoseSource], meta: dict[str, Any] | None = None) -> pa.Table:
    """Arrow table (:data:`MARKER_STACK`) of ``sources``, in order; ``meta``: extra table-level facts."""
    labels = sorted({lab for s in sources for lab in s.markers.labels})
    code = {lab: i for i, lab in enumerate(labels)}
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("source", "marker", "frame", "x", "y", "z", "valid")}
    for i, s in enumerate(sources):
        m = s.markers
        n_t, n_m = m.valid.shape
        parts["source"].append(np.full(n_t * n_m, i, dtype=np.int32))
        parts["marker"].append(np.repeat(np.array([code[lab] for lab in m.labels], dtype=np.int32), n_t))
        parts["frame"].append(np.tile(np.arange(n_t, dtype=np.int32), n_m))
        for k, axis in enumerate("xyz"):
            parts[axis].append(np.ascontiguousarray(m.xyz[:, :, k].T).reshape(-1))
        parts["valid"].append(np.ascontiguousarray(m.valid.T).reshape(-1))
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    cols: dict[str, pa.Array] = {
        "source": pa.array(cat["source"].astype(np.int32)),
        "marker": pa.DictionaryArray.from_arrays(cat["marker"].astype(np.int32), pa.array(labels, pa.string())),
        "frame": pa.array(cat["frame"].astype(np.int32)),
        **{axis: pa.array(cat[axis].astype(np.float64), mask=~np.isfinite(cat[axis])) for axis in "xyz"},
        "valid": pa.array(cat["valid"].astype(bool)),
    }
    listed = [{"label": s.label, "take": s.take, "role": s.role, "labels": list(s.markers.labels),
               "rate_hz": s.markers.rate_hz, "first_frame": s.markers.first_frame, "units": s.markers.units,
               "frames": int(s.markers.n_frames)} for s in sources]
    return attach_meta(pa.Table.from_pydict(cols, schema=MARKER_STACK), {**(meta or {}), "sources": listed})


def table_to_stack(table: pa.Table) -> list[PoseSource]:
    """Inverse of :func:`stack_to_table`: the sources in order, positions as written."""
    listed = read_meta(table).get("sources", [])
    xyz_all = [table.column(axis).to_numpy(zero_copy_only=False) for axis in "xyz"]
    valid_all = table.column("valid").to_numpy(zero_copy_only=False)
    out, start = [], 0
    for s in listed:
        n_t, n_m = int(s["frames"]), len(s["labels"])
        stop = start + n_t * n_m
        xyz = np.stack([a[start:stop].reshape(n_m, n_t).T for a in xyz_all], axis=-1)
        valid = valid_all[start:stop].reshape(n_m, n_t).T
        markers = Markers(labels=list(s["labels"]), xyz=xyz, valid=valid, rate_hz=float(s["rate_hz"]),
                          first_frame=int(s["first_frame"]), units=s.get("units"))
        out.append(PoseSource(s["label"], s["take"], s["role"], markers))
        start = stop
    return out


ARRAYS = with_identity(pa.schema([
    pa.field("name", pa.string(), nullable=False),
    pa.field("dtype", pa.string(), nullable=False),
    pa.field("shape", pa.list_(pa.int64()), nullable=False),
    pa.field("data", pa.binary(), nullable=False),
]), "arrays", 1)


def arrays_to_table(arrays: dict[str, np.ndarray], meta: dict[str, Any] | None = None) -> pa.Table:
    """Arrow table (:data:`ARRAYS`) of named numeric arrays, one row each, with their exact bytes (a result a
    stage computes once for a session and other stages read back bit for bit); ``meta``: table-level facts."""
    names = list(arrays)
    values = [np.ascontiguousarray(arrays[n]) for n in names]
    table = pa.Table.from_pydict({
        "name": pa.array(names, pa.string()),
        "dtype": pa.array([v.dtype.str for v in values], pa.string()),
        "shape": pa.array([list(v.shape) for v in values], pa.list_(pa.int64())),
        "data": pa.array([v.tobytes() for v in values], pa.binary()),
    }, schema=ARRAYS)
    return attach_meta(table, meta or {})


def table_to_arrays(table: pa.Table) -> dict[str, np.ndarray]:
    """Inverse of :func:`arrays_to_table`: the arrays by name, as written."""
    out = {}
    for name, dtype, shape, data in zip(*(table.column(c).to_pylist() for c in ("name", "dtype", "shape", "data")),
                                        strict=True):
        out[name] = np.frombuffer(data, dtype=np.dtype(dtype)).reshape(shape).copy()
    return out


def geometry_to_table(labels: list[str], arrays: dict[str, np.ndarray], takes: list[str]) -> pa.Table:
    """The ``subject_geometry`` table: the subject's marker references as named arrays (none when no capture
    could be read), the markers they are of (``labels``) and the takes they come from in the metadata."""
    return arrays_to_table(arrays, {"takes": takes, "labels": labels})


def table_to_geometry(table: pa.Table) -> tuple[list[str], dict[str, np.ndarray]]:
    """Inverse of :func:`geometry_to_table`: the labels and the arrays (no labels: no references)."""
    labels = list(read_meta(table).get("labels") or [])
    return labels, (table_to_arrays(table) if labels else {})
