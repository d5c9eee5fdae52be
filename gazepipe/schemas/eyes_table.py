"""The ``eyes`` table (:data:`~gazepipe.schemas.tracks.EYES`): one row per ``joints`` row."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.schemas.base import attach_meta
from gazepipe.schemas.joints import fixed_list
from gazepipe.schemas.tracks import EYES


def eyes_to_table(ja: dict[str, Any], valid: np.ndarray, filled: np.ndarray, confidence: np.ndarray,
                  eye_dir_char: np.ndarray, eye_dir_head: np.ndarray, meta: dict[str, Any]) -> pa.Table:
    """The eyes table on the rows of the ``joints`` table whose arrays are ``ja``
    (:func:`gazepipe.schemas.joints.joints_arrays`): per frame ``valid``, ``filled``, ``confidence`` and the
    (N, 3) unit gaze directions in the character frame and the head's axes; ``meta``: table-level facts."""
    table = pa.Table.from_pydict({
        "frame": pa.array(ja["frame"].astype(np.int64).astype(np.int32)),
        "source_frame": pa.array(ja["source_frame"].astype(np.int64)),
        "time_s": pa.array(ja["time_s"]),
        "valid": pa.array(valid),
        "filled": pa.array(filled),
        "confidence": pa.array(confidence),
        "eye_dir_char": fixed_list(eye_dir_char, 3, np.float32),
        "eye_dir_head": fixed_list(eye_dir_head, 3, np.float32),
    }, schema=EYES)
    return attach_meta(table, meta)
