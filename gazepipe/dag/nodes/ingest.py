"""The ingest stage's run: a take's capture read into the ``markers_raw`` table, named as the markerset names
its markers."""

from __future__ import annotations

from gazepipe.dag.nodes.common import TakeContext, file_notes, given
from gazepipe.pipeline.registry import UnitResult


def run_ingest(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.capture import read_markers
    from gazepipe.io.session_toml import session_labels
    from gazepipe.schemas.markers import MARKERS_RAW, markers_to_table
    from gazepipe.stages.ingest_qc import ingest_record, required_markers

    take, ms = ctx.take, ctx.session.markerset
    mocap = given(take.mocap, "mocap")
    markers = read_markers(mocap, rate_hz=take.rate_hz, default_units=ms.units if ms else "mm")
    meta: dict = {}
    if ms is not None:
        need = required_markers(ms, take.kind, take.video is not None)
        labels, notes = session_labels(ms, markers.labels, mocap, take.id, required=need)
        markers.warnings.extend(notes)
        if labels != markers.labels:
            meta["renamed_labels"] = {a: b for a, b in zip(markers.labels, labels, strict=True) if a != b}
            markers.labels = labels
    table = markers_to_table(markers, meta=meta)
    return UnitResult(tables={"markers_raw": (table, MARKERS_RAW)}, qc=ingest_record(markers),
                      warnings=file_notes(ctx.session, mocap, markers.warnings))
