"""Conversion of an aligned face take (:class:`gazepipe.stages.face.stage.FaceAligned`) to the ``face`` table."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.schemas.base import attach_meta
from gazepipe.schemas.tracks import N_BLENDSHAPES, face_schema


def _vec32(values: np.ndarray) -> pa.FixedSizeListArray:
    flat = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
    return pa.FixedSizeListArray.from_arrays(pa.array(flat), N_BLENDSHAPES)


def face_to_table(face, meta: dict[str, Any] | None = None) -> pa.Table:
    """The ``face`` table of an aligned take (rows = aligned tracked frames with a forward step)."""
    cols: dict[str, pa.Array] = {
        "frame": pa.array(np.asarray(face.frame_index, dtype=np.int64)),
        "timecode": pa.array([str(t) for t in face.timecode], pa.string()),
        "time_s": pa.array(np.asarray(face.time_s, dtype=np.float64)),
        "dt_s": pa.array(np.asarray(face.dt_s, dtype=np.float64)),
        "tracked": _vec32(face.tracked),
        "clean": _vec32(face.clean),
    }
    for order in range(1, face.k + 1):
        cols[f"tracked_d{order}"] = _vec32(face.d_tracked[:, order - 1])
        cols[f"clean_d{order}"] = _vec32(face.d_clean[:, order - 1])
    table = pa.Table.from_pydict(cols, schema=face_schema(face.k))
    info = {"names": list(face.names), "k": int(face.k)}
    info.update(meta or {})
    return attach_meta(table, info)
