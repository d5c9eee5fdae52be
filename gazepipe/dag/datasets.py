"""gazepipe's training datasets, registered with the engine: which takes feed each, which stages' tables it
reads, the ``build`` parameters, and the build that stages a dataset and publishes it (SPEC §3.6, §4)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import gazepipe.dag.takes  # noqa: F401  (the stages the datasets read from are registered first)
from gazepipe.io.datasets import StagedDatasetWriter
from gazepipe.io.parquet import read_schema
from gazepipe.model import Session, Take
from gazepipe.pipeline.datasets import DatasetContext, DatasetResult
from gazepipe.pipeline.registry import Dataset, ParamGroup, register_dataset, register_params
from gazepipe.schemas.base import read_meta
from gazepipe.schemas.datasets import DATASETS
from gazepipe.stages.build.stage import KINDS, BuildParams, TakeTables, build_dataset

BUILD_VERSION = "4"
#: per-take tables each dataset reads, and the stages that write them
NEEDS: dict[str, tuple[str, ...]] = {
    "gaze_rnn": ("frames", "eyes"), "gaze_rnn_lod": ("frames",), "gaze_map": ("frames", "clean"),
    "face_clean": ("face",),
}
OPTIONAL = {"gaze_rnn": ("eyes",)}


def _take_inputs(ctx: DatasetContext, session: str, take: str, units: dict[str, str]) -> dict[str, Any]:
    """One take's tables for the build (read when the build reaches the take)."""
    got: dict[str, Any] = {}
    for stage, table in (("frames", "joints"), ("eyes", "eyes"), ("face", "face")):
        if stage in units:
            got[table] = ctx.load(session, take, table)
    if "clean" in units:  # the rest periods are in the cleaned markers' metadata: the schema is enough
        got["meta"] = {"rests": read_meta(read_schema(ctx.table_path(session, take, "markers"))).get("rests", [])}
    return got


def run_build(ctx: DatasetContext) -> DatasetResult:
    """Build dataset ``ctx.name`` one take at a time into a staging folder, then publish it whole; on any
    failure the staging folder is removed and nothing is published."""
    writer = StagedDatasetWriter(ctx.root, ctx.name, ctx.tmp, ctx.write_bytes)

    def sink(key: tuple[str, str], table) -> None:
        ctx.check_alive()
        writer(key, table)

    try:
        inputs = [TakeTables(session=s.id, subject=s.subject, take=t, markerset=s.markerset, hashes=dict(units),
                             loader=functools.partial(_take_inputs, ctx, s.id, t.id, units))
                  for s, t, units in ctx.takes]
        built = build_dataset(ctx.name, inputs, BuildParams(**ctx.params), sink=sink)
        ctx.check_alive()
        written = writer.commit(built)
    except BaseException:
        writer.abort()
        raise
    skipped = built.info.get("skipped", [])
    return DatasetResult(outputs=written, record={"counts": built.info.get("counts"), "skipped": skipped},
                         warnings=[f"{ctx.name}: take {s['session']}/{s['take']} left out: {s['reason']}"
                                   for s in skipped])


def _feeds(name: str):
    def applies(session: Session, take: Take) -> bool:
        return take.kind == KINDS[name]
    return applies


register_params(ParamGroup(
    name="build", params=BuildParams().to_dict(),
    rules={f.name: dict(f.metadata) for f in dataclasses.fields(BuildParams)},
    problems=lambda values: BuildParams(**values).problems(),
))
for _name in DATASETS:
    register_dataset(Dataset(name=_name, version=BUILD_VERSION, needs=NEEDS[_name], optional=OPTIONAL.get(_name, ()),
                             applies=_feeds(_name), run=run_build, params="build"))
