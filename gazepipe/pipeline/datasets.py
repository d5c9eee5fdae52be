"""Dataset-level units: each training dataset is built from every take that feeds it, after the takes ran.

A dataset's fingerprint covers the build's version and parameters and, for every contributing take, the
fingerprints of the units that produced its tables; it is rebuilt only when one of them changes. Takes whose
units failed are left out (and named in the record), so one bad take never blocks a dataset.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time
import traceback
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from gazepipe import __version__
from gazepipe.errors import GazepipeError
from gazepipe.io.datasets import StagedDatasetWriter
from gazepipe.io.parquet import read_schema
from gazepipe.model import Session, Take
from gazepipe.pipeline.hashing import sha256_json
from gazepipe.pipeline.runner import UnitOutcome, UnitPlan, _alive, _loader, release_memory
from gazepipe.pipeline.state import OutLayout, read_json
from gazepipe.schemas.base import read_meta
from gazepipe.schemas.datasets import DATASETS
from gazepipe.stages.build import KINDS, BuildParams, TakeTables, build_dataset

BUILD_VERSION = "1"
#: per-take tables each dataset reads, and the stages that write them
NEEDS: dict[str, tuple[str, ...]] = {
    "gaze_rnn": ("frames", "eyes"), "gaze_rnn_lod": ("frames",), "gaze_map": ("frames", "clean"),
    "face_clean": ("face",),
}
OPTIONAL = {"gaze_rnn": ("eyes",)}


def build_params(params: dict[str, Any]) -> BuildParams:
    kw = {}
    for f in dataclasses.fields(BuildParams):
        key = f"build.{f.name}"
        if key in params:
            kw[f.name] = params[key]
    return BuildParams(**kw)


def default_build_params() -> dict[str, Any]:
    return {f"build.{k}": v for k, v in BuildParams().to_dict().items()}


@dataclass
class DatasetPlan:
    name: str
    fingerprint: str
    components: dict[str, Any]
    takes: list[tuple[Session, Take, dict[str, str]]]   # contributing takes with their units' fingerprints
    run: bool
    reason: str
    error: str = ""     # set when the build failed before on the same inputs and is not retried


def _record_path(layout: OutLayout, name: str) -> Path:
    return layout.state / "datasets" / f"{name}.json"


def plan_datasets(sessions: Sequence[Session], layout: OutLayout, take_plans: Sequence[UnitPlan],
                  params: dict[str, Any], force: bool = False, optimistic: bool = False) -> list[DatasetPlan]:
    """Which datasets have takes to build from, and whether each must be rebuilt.

    A take contributes when every unit writing a table the dataset needs has an ``ok`` record whose
    fingerprint equals the planned one (it is up to date, or ran successfully in this run). ``optimistic``
    (for ``--dry-run``) counts units that are about to run as successful.
    """
    planned_to_run = {(p.session, p.take, p.stage) for p in take_plans if p.run}
    fp = {(p.session, p.take, p.stage): p.fingerprint for p in take_plans}
    bp = build_params(params)
    plans = []
    for name in DATASETS:
        takes = []
        for s in sessions:
            for t in s.takes:
                if t.kind != KINDS[name]:
                    continue
                units: dict[str, str] = {}
                ok = True
                for stage in NEEDS[name]:
                    key = (s.id, t.id, stage)
                    if key not in fp:
                        if stage in OPTIONAL.get(name, ()):
                            continue
                        ok = False
                        break
                    if optimistic and key in planned_to_run:
                        units[stage] = fp[key]
                        continue
                    rec = read_json(layout.record(s.id, t.id, stage))
                    if not (isinstance(rec, dict) and rec.get("status") == "ok" and rec.get("fingerprint") == fp[key]):
                        ok = False
                        break
                    units[stage] = fp[key]
                if ok:
                    takes.append((s, t, units))
        if not takes:
            continue
        comp = {"dataset": name, "version": BUILD_VERSION, "params": bp.to_dict(),
                "takes": sorted([s.id, t.id, u] for s, t, u in takes)}
        fingerprint = sha256_json(comp)
        rec = read_json(_record_path(layout, name))
        reason = error = ""
        if force:
            reason = "--force"
        elif not isinstance(rec, dict):
            reason = "never built"
        elif rec.get("status") != "ok":
            if rec.get("fingerprint") == fingerprint and not rec.get("retry", True):
                error = rec.get("error", "failed")
            else:
                reason = "failed last time"
        elif rec.get("fingerprint") != fingerprint:
            old = rec.get("components", {})
            reason = ("parameters changed" if old.get("params") != comp["params"] else
                      "its takes changed" if old.get("takes") != comp["takes"] else "fingerprint changed")
        elif not all((layout.root / "datasets" / name / f).is_file() for f in rec.get("outputs", {})):
            reason = "an output file is missing"
        plans.append(DatasetPlan(name, fingerprint, comp, takes, bool(reason),
                                 reason or ("failed earlier on these same inputs" if error else "up to date"), error))
    return plans


def _take_inputs(load, layout: OutLayout, session: str, take: str, units: dict[str, str]) -> dict[str, Any]:
    """One take's tables for the build (read when the build reaches the take)."""
    got: dict[str, Any] = {}
    for stage, table in (("frames", "joints"), ("eyes", "eyes"), ("face", "face")):
        if stage in units:
            got[table] = load(session, take, table)
    if "clean" in units:  # the rest periods are in the cleaned markers' metadata: the schema is enough
        got["meta"] = {"rests": read_meta(read_schema(layout.table(session, take, "markers"))).get("rests", [])}
    return got


class _RunGone(Exception):
    """The run that submitted a dataset job to a local worker is gone: stop without writing anything."""


def run_dataset(plan: DatasetPlan, layout: OutLayout, params: dict[str, Any],
                parent_pid: int | None = None) -> UnitOutcome:
    """Build one dataset, write it atomically, record it.

    ``parent_pid``: the run's process when this runs in a local worker; when that process is gone (its lock
    with it) the build stops before publishing anything or writing its record.
    """
    release_memory()  # what the takes run before in this process left behind
    t0 = time.perf_counter()
    load = _loader(layout)
    outcome = UnitOutcome("-", "-", f"build:{plan.name}", "ok", reason=plan.reason)
    record: dict[str, Any] = {"dataset": plan.name, "fingerprint": plan.fingerprint, "components": plan.components,
                              "gazepipe_version": __version__}
    writer = StagedDatasetWriter(layout.root / "datasets", plan.name,
                                 layout.tmp / f"{plan.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.part",
                                 layout.write_bytes)

    def sink(key: tuple[str, str, str], table) -> None:
        if parent_pid is not None and not _alive(parent_pid):
            raise _RunGone
        writer(key, table)

    try:
        inputs = [TakeTables(session=s.id, subject=s.subject, take=t, markerset=s.markerset, hashes=dict(units),
                             loader=functools.partial(_take_inputs, load, layout, s.id, t.id, units))
                  for s, t, units in plan.takes]
        with threadpool_limits(limits=1):  # as for take units: results independent of the BLAS thread count
            built = build_dataset(plan.name, inputs, build_params(params), sink=sink)
        if parent_pid is not None and not _alive(parent_pid):
            raise _RunGone
        written = writer.commit(built)
        root = layout.root / "datasets" / plan.name
        record.update(status="ok", outputs={str(p.relative_to(root)): p.stat().st_size for p in written},
                      counts=built.info.get("counts"), skipped=built.info.get("skipped", []))
        outcome.warnings = [f"{plan.name}: take {s['take']} left out: {s['reason']}"
                            for s in built.info.get("skipped", [])]
    except _RunGone:
        writer.abort()
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: the run stopped"
        return outcome
    except GazepipeError as exc:
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: {exc.one_line()}"
        record["retry"] = False
    except Exception as exc:  # a bug: recorded, the run goes on
        outcome.status = "failed"
        outcome.error = f"dataset {plan.name}: internal error: {type(exc).__name__}: {exc}"
        outcome.traceback = traceback.format_exc()
    if outcome.status == "failed":
        writer.abort()
        record.update(status="failed", error=outcome.error)
    outcome.duration_s = time.perf_counter() - t0
    record["duration_s"] = round(outcome.duration_s, 4)
    layout.write_json(_record_path(layout, plan.name), record)
    return outcome
