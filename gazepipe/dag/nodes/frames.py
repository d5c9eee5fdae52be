"""The frames stage's run: a take's segment orientations against its neutral sources
(:func:`gazepipe.stages.frames.neutral.frames_with_fallback`), written as its ``joints`` table."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa

from gazepipe.dag.nodes.common import TakeContext, given
from gazepipe.model import FILL_CODES
from gazepipe.pipeline.registry import UnitResult, params_from


def _measured(fill: np.ndarray | None) -> np.ndarray | None:
    """Which samples of a cleaned markers table were measured, (T, M) bool (fill code ``measured`` or
    ``swap_repaired``; None when the table has no fill codes)."""
    return None if fill is None else np.isin(fill, [FILL_CODES["measured"], FILL_CODES["swap_repaired"]])


def _take_markers(table: pa.Table):
    from gazepipe.schemas.markers import fill_errors, table_to_markers
    from gazepipe.stages.frames.neutral import TakeMarkers

    markers, frames, fill, _ = table_to_markers(table)
    return TakeMarkers(markers, frames, _measured(fill), fill_errors(table))


def _own_rest(table: pa.Table):
    from gazepipe.schemas.markers import table_to_markers
    from gazepipe.stages.frames.neutral import OwnRest

    markers, frames, fill, meta = table_to_markers(table)
    return OwnRest(markers, frames, meta.get("rest"), _measured(fill))


def run_frames(ctx: TakeContext) -> UnitResult:
    from gazepipe.schemas.joints import joints_schema, joints_to_table
    from gazepipe.schemas.poses import table_to_stack
    from gazepipe.stages.frames.neutral import frames_with_fallback
    from gazepipe.stages.frames.stage import FramesParams

    ms = given(ctx.session.markerset, "markerset")
    take = _take_markers(ctx.load("markers"))
    poses = table_to_stack(ctx.load_session("neutral_poses"))
    joints, source = frames_with_fallback(take, _own_rest(ctx.load("neutral")), poses, ms, ctx.take.kind,
                                          params_from(FramesParams, ctx.params), path=ctx.take.mocap,
                                          take_id=ctx.take.id)
    qc = dict(joints.qc)
    qc["neutral_source"] = source
    meta: dict[str, Any] = {"neutral_source": source}
    if joints.rest_before is not None:
        meta["rest_before"] = joints.rest_before
    table = joints_to_table(joints, take.frames, meta=meta)
    return UnitResult(tables={"joints": (table, joints_schema(len(joints.segments)))}, qc=qc,
                      warnings=list(qc.get("warnings", [])))
