"""The face stage's run: a take's tracked and clean Live Link Face tracks aligned on timecode
(:func:`gazepipe.stages.face.stage.align_face`) into its ``face`` table."""

from __future__ import annotations

from gazepipe.dag.nodes.common import TakeContext, file_notes, given
from gazepipe.pipeline.registry import UnitResult, params_from


def run_face(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.livelinkface import read_livelinkface
    from gazepipe.schemas.face_table import face_to_table
    from gazepipe.schemas.tracks import face_schema
    from gazepipe.stages.face.params import FaceParams
    from gazepipe.stages.face.stage import align_face

    take = ctx.take
    tracked_path, clean_path = given(take.tracked, "tracked"), given(take.clean, "clean")
    tracked = read_livelinkface(tracked_path, rate_hz=take.rate_hz, timecode_fps=take.timecode_fps)
    clean = read_livelinkface(clean_path, rate_hz=take.rate_hz, timecode_fps=take.timecode_fps)
    aligned = align_face(tracked, clean, params_from(FaceParams, ctx.params), paths=(tracked_path, clean_path))
    qc = dict(aligned.qc)
    warnings = file_notes(ctx.session, tracked_path, tracked.warnings) + file_notes(ctx.session, clean_path,
                                                                                   clean.warnings)
    qc["warnings"] = warnings
    table = face_to_table(aligned, meta={"rate_hz": tracked.rate_hz, "timecode_fps": take.timecode_fps})
    return UnitResult(tables={"face": (table, face_schema(aligned.k))}, qc=qc, warnings=warnings)
