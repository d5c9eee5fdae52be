"""gazepipe's training datasets, declared for the engine (:func:`gazepipe.dag.declare` registers them): which takes feed each, which stages' tables it
reads, the ``build`` parameters, each dataset's per-take stage that makes a take's rows, and the build that
merges them and publishes the dataset (SPEC §3.6, §4, §7).

A dataset's rows are made take by take, in the take's own unit on the worker that ran the take: the stage
``rows_<dataset>`` (:func:`gazepipe.stages.build.stage.take_part`) writes the take's dataset table (rows, mirrored
copies, identifiers, the split its key draws) as ``takes/<session>/<take>/rows_<dataset>.parquet`` and what the
dataset needs of it (shape, frame rate, why it gives no rows, counts, QC, input hashes, the per-column moments of
the statistics) as ``rows_<dataset>_part.parquet`` (one JSON text; its unit record keeps only rows, split and
problem: the report reads and hashes every take's records). The dataset's build then only merges those parts in
(session, take) order (:class:`gazepipe.stages.build.stage.DatasetMerge`: the same statistics, bit for bit, as
one process would compute), moves the takes that fill an empty split (their files made again with the new
split) and places the take files (linked, not copied) with the side files.
"""

from __future__ import annotations

import json
from collections import Counter
from typing import Any

import pyarrow as pa

from gazepipe.errors import StageError
from gazepipe.io.dataset_files import StagedDatasetWriter
from gazepipe.io.parquet import read_schema, read_table
from gazepipe.model import Session, Take
from gazepipe.pipeline import registry
from gazepipe.pipeline.builds import DatasetContext, DatasetResult
from gazepipe.pipeline.registry import (
    Dataset,
    ParamGroup,
    Stage,
    UnitContext,
    UnitResult,
    params_from,
)
from gazepipe.pipeline.state import OutLayout
from gazepipe.schemas.base import read_meta
from gazepipe.schemas.dataset_tables import DATASETS
from gazepipe.stages.build.qc import RowsQC
from gazepipe.stages.build.stage import (
    KINDS,
    BuildParams,
    BuiltDataset,
    DatasetMerge,
    TakePart,
    TakeTables,
    check_dataset,
    take_part,
    with_split,
)

BUILD_VERSION = "5"
ROWS_VERSION = "2"
#: per-take tables each dataset reads, and the stages that write them
NEEDS: dict[str, tuple[str, ...]] = {
    "gaze_rnn": ("frames", "eyes"), "gaze_rnn_lod": ("frames",), "gaze_map": ("frames", "clean"),
    "face_clean": ("face",),
}
OPTIONAL = {"gaze_rnn": ("eyes",)}
#: the table of each stage a dataset's rows read (:func:`_take_inputs`; the cleaned markers for their metadata)
TABLE_OF = {"frames": "joints", "eyes": "eyes", "face": "face", "clean": "markers"}
#: a dataset whose take-level optional input no contributing take has is skipped (not failed), with the reason
NEEDS_ANY: dict[str, tuple[tuple[str, str], ...]] = {"gaze_rnn": (("eyes", "no take has eye tracking"),)}
#: each dataset's per-take stage, and the name of the table it writes
ROWS: dict[str, str] = {name: f"rows_{name}" for name in DATASETS}
#: each dataset's per-take table of the take's part (:class:`TakePart` as JSON, in one row): apart from the unit
#: record, which the report reads (and hashes) for every take
PARTS: dict[str, str] = {name: f"rows_{name}_part" for name in DATASETS}
PART = pa.schema([pa.field("part", pa.string(), nullable=False)], metadata={b"gazepipe.table": b"dataset_part"})
#: the table of a take that gives a dataset no rows (why is in its part and its unit's record)
NO_ROWS = pa.schema([], metadata={b"gazepipe.table": b"no_rows"})


def _upstream(name: str, session: Session, take: Take) -> set[str]:
    """The stages dataset ``name`` reads that apply to the take (those a run plans for it)."""
    return {st for st in NEEDS[name] if registry.get(st).applies(session, take)}


def _take_inputs(layout: OutLayout, session: str, take: str, stages: set[str]) -> dict[str, Any]:
    """One take's tables for its rows, read from their files and schema-checked, as the build read them."""
    store = registry.table_store()
    got: dict[str, Any] = {}
    for stage, table in (("frames", "joints"), ("eyes", "eyes"), ("face", "face")):
        if stage in stages:
            path = layout.table(session, take, table)
            got[table] = store.read(path)
            store.check(got[table], path, table)
    if "clean" in stages:  # the rest periods are in the cleaned markers' metadata: the schema is enough
        got["meta"] = {"rests": read_meta(read_schema(layout.table(session, take, "markers"))).get("rests", [])}
    return got


def _rows_stage(name: str):
    """The run of stage ``rows_<name>``: one take's part of dataset ``name``."""
    def run(ctx: UnitContext) -> UnitResult:
        session, take = ctx.session, ctx.take
        stages = _upstream(name, session, take)
        layout = OutLayout(ctx.out_dir)
        tt = TakeTables(session=session.id, subject=session.subject, take=take, markerset=session.markerset,
                        loader=lambda: _take_inputs(layout, session.id, take.id, stages))
        params = params_from(BuildParams, registry.group_values("build", ctx.all_params))
        part = take_part(name, tt, params, known=stages)   # the units' fingerprints stand for those tables
        table = part.table if part.table is not None else NO_ROWS.empty_table()
        facts = pa.Table.from_arrays([pa.array([json.dumps(part.to_json(), sort_keys=True)], pa.string())],
                                     schema=PART)
        qc = RowsQC(rows=part.facts.rows if part.facts is not None else 0, split=part.split,
                    problem=part.problem or part.fatal).to_record()
        return UnitResult(tables={ROWS[name]: (table, table.schema), PARTS[name]: (facts, PART)}, qc=qc)

    run.__qualname__ = run.__name__ = f"run_rows_{name}"
    return run


def _has_lod(session: Session) -> bool:
    """Whether the session's markerset names the level-of-detail segments (``[lod]``) gaze_rnn_lod keeps."""
    return session.markerset is not None and bool(session.markerset.lod_segments)


def _rows_applies(name: str):
    def applies(session: Session, take: Take) -> bool:
        return _feeds(name)(session, take) and all(registry.get(st).applies(session, take)
                                                   for st in NEEDS[name] if st not in OPTIONAL.get(name, ()))
    return applies


def _part(ctx: DatasetContext, session: str, take: str, units: dict[str, str]) -> TakePart:
    """A take's part as its ``rows_<dataset>`` unit stored it, with the fingerprints of the units it was made
    from as its input hashes."""
    stage = ROWS[ctx.name]
    table = ctx.load(session, take, PARTS[ctx.name])
    if table.schema.names != PART.names or table.num_rows != 1:
        raise StageError(f"datasets/{ctx.name}", f"take {session}/{take}: its {PARTS[ctx.name]} table holds no part")
    part = TakePart.from_json(json.loads(table.column("part")[0].as_py()))
    if part.facts is not None:
        part.facts.hashes = {**{k: v for k, v in units.items() if k != stage}, **part.facts.hashes}
    return part


def run_build(ctx: DatasetContext) -> DatasetResult:
    """Merge the takes' parts of dataset ``ctx.name``, then stage its files (each take's, made by its unit) and
    publish them whole; on any failure the staging folder is removed and nothing is published."""
    params = params_from(BuildParams, ctx.params)
    check_dataset(ctx.name, params)
    takes = sorted(ctx.takes, key=lambda stu: (stu[0].id, stu[1].id))
    twice = sorted(k for k, c in Counter((s.id, t.id) for s, t, _ in takes).items() if c > 1)
    if twice:
        raise StageError(f"datasets/{ctx.name}", f"take {twice[0][1]!r} of session {twice[0][0]!r} is given twice")
    writer = StagedDatasetWriter(ctx.root, ctx.name, ctx.tmp, ctx.write_bytes)
    try:
        merge = DatasetMerge(ctx.name, params)
        kept = [p for p in (_part(ctx, s.id, t.id, units) for s, t, units in takes) if merge.add(p)]
        merge.rebalance()
        for part in kept:
            ctx.check_alive()
            path, split = ctx.table_path(part.session, part.take, ROWS[ctx.name]), merge.split[part.key]
            if split == part.split:
                writer.place(part.key, split, path)
            else:   # moved to fill an empty split: its file made again with the new split
                writer(part.key, with_split(read_table(path, merge.schema), split, merge.schema))
        assert merge.schema is not None
        built = BuiltDataset(name=ctx.name, tables={}, info=merge.info(), schema=merge.schema)
        ctx.check_alive()
        written = writer.commit(built)
    except BaseException:
        writer.abort()
        raise
    skipped = built.info.get("skipped", [])
    # the dataset card's warnings (a take moved between splits, an empty split, mixed frame rates) go to the
    # run's log too, one line each
    return DatasetResult(outputs=written, record={"counts": built.info.get("counts"), "skipped": skipped},
                         warnings=[f"{ctx.name}: take {s['session']}/{s['take']} left out: {s['reason']}"
                                   for s in skipped] + [f"{ctx.name}: {w}" for w in built.info.get("warnings", [])])


def _feeds(name: str):
    """Which takes feed dataset ``name``: those of its kind (gaze_rnn_lod: of sessions whose markerset has
    ``[lod]``; a markerset without it asks for no level-of-detail dataset)."""
    def applies(session: Session, take: Take) -> bool:
        return take.kind == KINDS[name] and (name != "gaze_rnn_lod" or _has_lod(session))
    return applies


#: the ``build`` parameters, which belong to no take stage
PARAM_GROUPS: tuple[ParamGroup, ...] = (
    ParamGroup(name="build", params_class=BuildParams, problems=lambda values: BuildParams(**values).problems()),
)
#: each dataset's per-take stage (after the take stages whose tables it reads)
ROW_STAGES: tuple[Stage, ...] = tuple(
    Stage(name=ROWS[name], version=ROWS_VERSION, inputs=tuple(TABLE_OF[st] for st in NEEDS[name]),
          outputs=(ROWS[name], PARTS[name]),
          applies=_rows_applies(name), sources=lambda s, t: [], run=_rows_stage(name), groups=("build",),
          help=f"the take's rows of dataset {name} (mirrored copies, its split) and their partial statistics")
    for name in DATASETS)
#: the datasets, each built from its takes' rows after the takes ran
DATASET_DECLARATIONS: tuple[Dataset, ...] = tuple(
    Dataset(name=name, version=BUILD_VERSION, needs=(*NEEDS[name], ROWS[name]), optional=OPTIONAL.get(name, ()),
            needs_any=NEEDS_ANY.get(name, ()), applies=_feeds(name), run=run_build, params="build")
    for name in DATASETS)
