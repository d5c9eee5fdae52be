"""The clean unit's tables: the cleaned, cropped ``markers``, the first rest period as ``neutral`` (the frames
stage's rest pose, with which samples were measured) and the take's ``rest_speed``."""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np
import pyarrow as pa

from gazepipe.model import Markers
from gazepipe.schemas.markers import (
    BATCH_ROWS,
    MARKERS_CLEAN,
    REST_SPEED,
    MarkersBatches,
    markers_batches,
    markers_to_table,
    rest_speed_to_table,
)


class CleanedLike(Protocol):
    """What the tables are built from (:class:`gazepipe.stages.clean.stage.CleanResult`)."""

    markers: Markers
    frames: np.ndarray
    fill_code: np.ndarray
    spike: np.ndarray
    fill_error_mm: np.ndarray
    crop: tuple[int, int]
    rests: list[tuple[int, int]]
    speed_mm_s: np.ndarray
    neutral: Markers | None
    neutral_fill_code: np.ndarray | None


def clean_tables(res: CleanedLike, raw: Markers) -> dict[str, tuple[pa.Table | MarkersBatches, pa.Schema]]:
    """The tables of a cleaned take (``res``), by name with their schemas; ``raw``: the take's raw markers (only
    their labels, rate and first frame are read: without a rest, ``neutral`` is an empty table of them). A
    markers table of more than :data:`~gazepipe.schemas.markers.BATCH_ROWS` rows is given as its batches,
    made while it is written (:func:`_markers_table`)."""
    kept = dataclasses.replace(res.markers, first_frame=raw.first_frame)
    meta = {"crop": list(res.crop), "rests": [list(r) for r in res.rests], "stabilised": True}
    tables = {"markers": (_markers_table(kept, frames=res.frames, fill_code=res.fill_code, spike=res.spike,
                                           fill_error_mm=res.fill_error_mm, meta=meta),
                          MARKERS_CLEAN)}
    # the first rest with its fill codes: which of its samples were measured (the frames stage's rest pose)
    if res.neutral is not None:
        a, b = res.rests[0] if res.rests else (0, res.neutral.n_frames)
        neutral = dataclasses.replace(res.neutral, first_frame=raw.first_frame)
        tables["neutral"] = (_markers_table(neutral, frames=np.arange(a, b), fill_code=res.neutral_fill_code,
                                              meta={"rest": [a, b]}), MARKERS_CLEAN)
    else:
        tables["neutral"] = (markers_to_table(raw, fill_code=np.zeros(raw.valid.shape, np.int8),
                                              meta={"rest": None}), MARKERS_CLEAN)
    tables["rest_speed"] = (rest_speed_to_table(res.speed_mm_s), REST_SPEED)
    return tables


def _markers_table(markers: Markers, **columns: Any) -> pa.Table | MarkersBatches:
    """A cleaned markers table (:func:`~gazepipe.schemas.markers.markers_to_table`'s ``columns``): whole when
    short (a later unit of the take may take it from memory), else its batches, made as the engine writes
    them, so a long take's table is never held whole beside its arrays (the same bytes either way)."""
    if markers.valid.size <= BATCH_ROWS:
        return markers_to_table(markers, **columns)
    return markers_batches(markers, **columns)
