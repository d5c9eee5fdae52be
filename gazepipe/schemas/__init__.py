"""Arrow schemas of every table gazepipe writes; checked on write and on read."""

from __future__ import annotations

import pyarrow as pa

from gazepipe.schemas.base import read_meta
from gazepipe.schemas.joints import joints_schema
from gazepipe.schemas.markers import MARKERS_CLEAN, MARKERS_RAW, REST_SPEED
from gazepipe.schemas.poses import ARRAYS, MARKER_STACK
from gazepipe.schemas.tracks import EYES, SYNC, face_schema

#: tables whose schema does not depend on the session
FIXED_SCHEMAS: dict[str, pa.Schema] = {"markers_raw": MARKERS_RAW, "markers": MARKERS_CLEAN,
                                       "neutral": MARKERS_CLEAN, "eyes": EYES, "sync": SYNC,
                                       "subject_geometry": ARRAYS, "neutral_poses": MARKER_STACK,
                                       "rest_speed": REST_SPEED}


def expected_schema(name: str, table: pa.Table) -> pa.Schema | None:
    """The schema a stored table called ``name`` must match; sized tables are rebuilt from their metadata."""
    if name in FIXED_SCHEMAS:
        return FIXED_SCHEMAS[name]
    if name == "joints":
        return joints_schema(len(read_meta(table).get("segments", [])))
    if name == "face":
        return face_schema(int(read_meta(table).get("k", 1)))
    return None
