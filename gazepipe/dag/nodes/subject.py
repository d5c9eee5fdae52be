"""The ``subject_geometry`` session stage's run: the subject's marker geometry, pooled from every subject capture
of the session (:func:`gazepipe.stages.clean.subject.pool_subject`), that each take's label swaps are judged
against."""

from __future__ import annotations

from collections.abc import Iterator

from gazepipe.dag.nodes.common import SessionUnitContext, given, read_capture, subject_captures
from gazepipe.errors import GazepipeError
from gazepipe.model import Markers, MarkerSet, Session
from gazepipe.pipeline.registry import UnitResult


def _captures(session: Session, ms: MarkerSet) -> Iterator[tuple[str, Markers]]:
    """Each subject capture of the session, read when drawn; one that cannot be read is passed over (its own
    take fails)."""
    for take in subject_captures(session):
        try:
            yield take.id, read_capture(take, ms)
        except GazepipeError:
            continue


def run_subject_geometry(ctx: SessionUnitContext) -> UnitResult:
    from gazepipe.schemas.poses import ARRAYS, geometry_to_table
    from gazepipe.stages.clean.subject import pool_subject, references_arrays

    ms = given(ctx.session.markerset, "markerset")
    refs, used = pool_subject(_captures(ctx.session, ms), ms.target, ms.clapper)
    table = geometry_to_table(list(refs.labels) if refs else [], references_arrays(refs), used)
    return UnitResult(tables={"subject_geometry": (table, ARRAYS)}, qc={"takes": len(used)})
