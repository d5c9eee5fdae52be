"""The ``neutral_poses`` session stage's run: the session's neutral poses, cleaned once for every take's frames
(:func:`gazepipe.stages.frames.neutral.session_poses`)."""

from __future__ import annotations

import os
from functools import partial
from typing import TYPE_CHECKING

from gazepipe.dag.nodes.common import (
    SessionUnitContext,
    given,
    neutral_take,
    read_capture,
    subject_take,
)
from gazepipe.model import MarkerSet, Take
from gazepipe.pipeline.registry import UnitResult, params_from

if TYPE_CHECKING:
    from gazepipe.stages.frames.neutral import Capture


def _capture(take: Take, ms: MarkerSet) -> Capture:
    """A take's capture, read (:func:`read_capture`) only when drawn."""
    return take.id, take.kind, take.mocap, partial(read_capture, take, ms)


def run_neutral_poses(ctx: SessionUnitContext) -> UnitResult:
    from gazepipe.dag.nodes.clean import subject_references
    from gazepipe.schemas.poses import MARKER_STACK, stack_to_table
    from gazepipe.stages.clean.stage import CleanParams
    from gazepipe.stages.frames.neutral import session_poses
    from gazepipe.stages.frames.stage import FramesParams

    session = ctx.session
    ms = given(session.markerset, "markerset")
    clean_params = params_from(CleanParams, ctx.params_of("clean"))
    frames_params = params_from(FramesParams, ctx.params_of("frames"))
    refs = subject_references(ctx.load("subject_geometry")) if clean_params.repair_swaps else None
    neutral = neutral_take(session)
    others = (_capture(t, ms) for t in session.takes if t.kind != "neutral" and subject_take(session, t))
    got = session_poses(_capture(neutral, ms) if neutral else None, others, ms, clean_params, frames_params, refs)
    warnings = list(got.warnings)
    if ms.head_centre is None and ms.eye_offset_mm is None:   # once for the session, not on each of its takes
        where = os.path.relpath(ms.path, session.root) if ms.path and session.root else ms.path
        warnings.append(f"{where}: no head_centre marker and no eye_offset_mm: the eyes' centre is the head "
                        "markers' centroid in every take of the session")
    qc = {"sources": [p.label for p in got.poses], "segments_without_neutral": got.without_neutral,
          "warnings": warnings}
    return UnitResult(tables={"neutral_poses": (stack_to_table(got.poses), MARKER_STACK)}, qc=qc, warnings=warnings)
