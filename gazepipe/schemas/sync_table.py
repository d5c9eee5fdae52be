"""The ``sync`` table (:data:`~gazepipe.schemas.tracks.SYNC`) from a sync result, and what the eyes stage reads
back from it: the clock map and how long the video lasts."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from gazepipe.schemas.base import attach_meta, read_meta
from gazepipe.schemas.tracks import SYNC


class _Clap(Protocol):
    @property
    def time_s(self) -> float: ...

    @property
    def confidence(self) -> float: ...


class _Clock(Protocol):
    @property
    def offset_s(self) -> float: ...

    @property
    def ratio(self) -> float: ...


class SyncLike(Protocol):
    """What the table is built from (:class:`gazepipe.stages.sync.stage.SyncResult`)."""

    @property
    def clock(self) -> _Clock: ...

    @property
    def mocap_claps(self) -> Sequence[_Clap]: ...

    @property
    def video_claps(self) -> Sequence[_Clap | None]: ...


def sync_to_table(res: SyncLike, video_frames: int, video_nominal_fps: float | None) -> pa.Table:
    """One row per mocap clap (its video clap's columns NaN where none was found), the clock map repeated on
    every row; the video's frame count and nominal rate in the metadata."""
    n = len(res.mocap_claps)
    rows = {
        "clap": np.arange(n, dtype=np.int32),
        "mocap_s": np.array([c.time_s for c in res.mocap_claps]),
        "video_s": np.array([np.nan if v is None else v.time_s for v in res.video_claps]),
        "confidence_mocap": np.array([c.confidence for c in res.mocap_claps]),
        "confidence_video": np.array([np.nan if v is None else v.confidence for v in res.video_claps]),
        "offset_s": np.full(n, res.clock.offset_s),
        "ratio": np.full(n, res.clock.ratio),
    }
    return attach_meta(pa.Table.from_pydict(rows, schema=SYNC), {"video_frames": int(video_frames),
                                                                  "video_nominal_fps": video_nominal_fps})


def clock_of(table: pa.Table) -> tuple[float, float, int]:
    """The clock map t_mocap = offset + ratio · t_video: ``(offset_s, ratio, claps)``."""
    return (float(table.column("offset_s")[0].as_py()), float(table.column("ratio")[0].as_py()), table.num_rows)


def video_seconds(meta: dict[str, Any]) -> float:
    """How long a take's video lasts (s), from the sync table's metadata (NaN when it does not say)."""
    try:
        return float(meta["video_frames"]) / float(meta["video_nominal_fps"])
    except (KeyError, TypeError, ValueError, ZeroDivisionError):
        return float("nan")


def video_facts(table: pa.Table) -> tuple[float, Any, Any]:
    """The video as the sync table's metadata gives it: its length on the video clock (s, NaN unknown), its
    frame count and its nominal rate (None when not said)."""
    meta = read_meta(table)
    return video_seconds(meta), meta.get("video_frames"), meta.get("video_nominal_fps")
