"""The clean unit's tables: the cleaned, cropped ``markers``, the first rest period as ``neutral`` (the frames
stage's rest pose, with which samples were measured) and the take's ``rest_speed``."""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np
import pyarrow as pa

from gazepipe.model import Markers
from gazepipe.schemas.markers import MARKERS_CLEAN, REST_SPEED, markers_to_table, rest_speed_to_table


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


def clean_tables(res: CleanedLike, raw: Markers) -> dict[str, tuple[pa.Table, pa.Schema]]:
    """The tables of a cleaned take (``res``), by name with their schemas; ``raw``: the take's raw markers (only
    their labels, rate and first frame are read: without a rest, ``neutral`` is an empty table of them)."""
    kept = dataclasses.replace(res.markers, first_frame=raw.first_frame)
    meta = {"crop": list(res.crop), "rests": [list(r) for r in res.rests], "stabilised": True}
    tables = {"markers": (markers_to_table(kept, frames=res.frames, fill_code=res.fill_code, spike=res.spike,
                                           fill_error_mm=res.fill_error_mm, meta=meta),
                          MARKERS_CLEAN)}
    # the first rest with its fill codes: which of its samples were measured (the frames stage's rest pose)
    if res.neutral is not None:
        a, b = res.rests[0] if res.rests else (0, res.neutral.n_frames)
        neutral = dataclasses.replace(res.neutral, first_frame=raw.first_frame)
        tables["neutral"] = (markers_to_table(neutral, frames=np.arange(a, b), fill_code=res.neutral_fill_code,
                                              meta={"rest": [a, b]}), MARKERS_CLEAN)
    else:
        tables["neutral"] = (markers_to_table(raw, fill_code=np.zeros(raw.valid.shape, np.int8),
                                              meta={"rest": None}), MARKERS_CLEAN)
    tables["rest_speed"] = (rest_speed_to_table(res.speed_mm_s), REST_SPEED)
    return tables
