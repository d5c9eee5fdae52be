"""Per-take ``eyes`` (eyes stage), ``face`` (face stage) and ``sync`` (sync stage) tables.

``eyes``: one row per kept mocap frame (the same rows as ``joints``): the cyclopean gaze direction (unit) in
the character frame and in the head segment's axes, its confidence (minimum of the two video samples around the
frame), ``valid`` (gated in and covered by video) and ``filled`` (bridged by slerp over a short invalid run).

``face``: one row per tracked Live Link Face frame that has a clean counterpart and a forward time step:
``dt_s`` = t[n+1] − t[n] (s), the 52 ARKit blendshapes of both tracks (ARKit order, names in ``meta.names``)
and their forward derivatives of order 1..K (per second^k), ``tracked_d1`` … ``clean_dK``.

``sync``: one row per clap: its time on both clocks, its confidence, and the clock map t_mocap = offset +
ratio · t_video (repeated on every row).
"""

from __future__ import annotations

import pyarrow as pa

from gazepipe.schemas.base import with_identity

#: 2: the eye directions are float32 (unit vectors: rounding under 1e-5°, far below the tracker's degrees)
SCHEMA_VERSION = 2
N_BLENDSHAPES = 52

_EYES_FIELDS: list[pa.Field] = [
    pa.field("frame", pa.int32(), nullable=False),
    pa.field("source_frame", pa.int64(), nullable=False),
    pa.field("time_s", pa.float64(), nullable=False),
    pa.field("valid", pa.bool_(), nullable=False),
    pa.field("filled", pa.bool_(), nullable=False),
    pa.field("confidence", pa.float64()),
    pa.field("eye_dir_char", pa.list_(pa.float32(), 3)),
    pa.field("eye_dir_head", pa.list_(pa.float32(), 3)),
]
EYES = with_identity(pa.schema(_EYES_FIELDS), "eyes", SCHEMA_VERSION)

_SYNC_FIELDS: list[pa.Field] = [
    pa.field("clap", pa.int32(), nullable=False),
    pa.field("mocap_s", pa.float64(), nullable=False),
    pa.field("video_s", pa.float64(), nullable=False),
    pa.field("confidence_mocap", pa.float64(), nullable=False),
    pa.field("confidence_video", pa.float64(), nullable=False),
    pa.field("offset_s", pa.float64(), nullable=False),
    pa.field("ratio", pa.float64(), nullable=False),
]
SYNC = with_identity(pa.schema(_SYNC_FIELDS), "sync", SCHEMA_VERSION)


def face_schema(k: int) -> pa.Schema:
    """The ``face`` table for derivatives up to order ``k``."""
    vec = pa.list_(pa.float32(), N_BLENDSHAPES)
    fields: list[pa.Field] = [
        pa.field("frame", pa.int64(), nullable=False),
        pa.field("timecode", pa.string(), nullable=False),
        pa.field("time_s", pa.float64(), nullable=False),
        pa.field("dt_s", pa.float64(), nullable=False),
        pa.field("tracked", vec),
        pa.field("clean", vec),
    ]
    for order in range(1, k + 1):
        fields += [pa.field(f"tracked_d{order}", vec), pa.field(f"clean_d{order}", vec)]
    return with_identity(pa.schema(fields), "face", SCHEMA_VERSION)
