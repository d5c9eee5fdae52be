"""The clean stage's run: a take's raw markers cleaned (:func:`gazepipe.stages.clean.stage.clean_markers`) into
its ``markers``, ``neutral`` and ``rest_speed`` tables (:func:`gazepipe.schemas.clean_tables.clean_tables`)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import pyarrow as pa

from gazepipe.dag.nodes.common import TakeContext, given
from gazepipe.pipeline.registry import TableBatches, UnitResult, params_from

if TYPE_CHECKING:
    from gazepipe.stages.clean.swaps import SubjectReferences


def subject_references(table: pa.Table) -> SubjectReferences | None:
    """The subject's marker geometry from the session's ``subject_geometry`` table; None when no capture could be
    read."""
    from gazepipe.schemas.poses import table_to_geometry
    from gazepipe.stages.clean.subject import references_from

    return references_from(*table_to_geometry(table))


def _bytes(n: int) -> str:
    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else f"{n / 2**20:.0f} MiB"


def _check_memory(ctx: TakeContext) -> None:
    """Refuse a take whose marker samples (from the table's footer) need more memory to clean than is free:
    before anything is loaded, rather than killed (or swapping) an hour in."""
    from gazepipe.errors import ResourceError
    from gazepipe.io.parquet import count_rows
    from gazepipe.pipeline.resources import available_memory_bytes
    from gazepipe.pipeline.state import OutLayout
    from gazepipe.stages.clean.stage import clean_memory_bytes

    samples = count_rows(OutLayout(ctx.out_dir).table(ctx.session.id, ctx.take.id, "markers_raw"))
    need, free = clean_memory_bytes(samples or 0), available_memory_bytes()
    if free is not None and need > free:
        raise ResourceError(ctx.take.mocap, f"{samples:,} marker samples need about {_bytes(need)} to clean, "
                                            f"more than the {_bytes(free)} free: split the take, or run it alone "
                                            "on a larger machine", take=ctx.take.id)


def run_clean(ctx: TakeContext) -> UnitResult:
    from gazepipe.schemas.clean_tables import clean_tables
    from gazepipe.schemas.markers import MarkersBatches, batches_to_markers
    from gazepipe.stages.clean.stage import CleanParams, clean_markers

    _check_memory(ctx)
    params = params_from(CleanParams, ctx.params)
    ms = given(ctx.session.markerset, "markerset")
    refs = subject_references(ctx.load_session("subject_geometry")) if params.repair_swaps else None
    # the raw table read a row group at a time into the take's arrays, which the stage then cleans in place:
    # a long take's positions are held once, never beside its whole table
    stored = ctx.load_batches("markers_raw")
    raw = batches_to_markers(stored.schema, stored.num_rows, stored.batches)[0]
    res = clean_markers(raw, ms, ctx.take.kind, params, path=ctx.take.mocap, take=ctx.take.id, references=refs,
                        in_place=True)
    # the raw markers' arrays are the stage's now: only their labels, rate and first frame are read below
    raw = dataclasses.replace(raw, xyz=raw.xyz[:0].copy(), valid=raw.valid[:0].copy())
    qc = dict(res.qc)
    # a long take's markers table is written as its batches are made: never whole beside the stage's arrays
    tables = {name: (TableBatches(*table) if isinstance(table, MarkersBatches) else table, schema)
              for name, (table, schema) in clean_tables(res, raw).items()}
    return UnitResult(tables=tables, qc=qc, warnings=list(qc.get("warnings", [])))
