"""Dataset-level units: each registered dataset (:class:`~gazepipe.pipeline.registry.Dataset`) is built from
every take that feeds it, after the takes ran.

A dataset's fingerprint covers the build's version and parameters and, for every contributing take, the
fingerprints of the units that produced its tables; it is rebuilt only when one of them changes. Takes whose
units failed are left out (and named in the record), so one bad take never blocks a dataset.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
import traceback
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gazepipe import __version__
from gazepipe.errors import GazepipeError
from gazepipe.pipeline import registry
from gazepipe.pipeline.codehash import code_of
from gazepipe.pipeline.hashing import sha256_json
from gazepipe.pipeline.lock import pid_alive
from gazepipe.pipeline.registry import Dataset, SessionLike, TakeLike
from gazepipe.pipeline.runner import UnitOutcome, UnitPlan, _loader, os_problem
from gazepipe.pipeline.state import OutLayout, read_json


@dataclass
class DatasetPlan:
    name: str
    fingerprint: str
    components: dict[str, Any]
    takes: list[tuple[SessionLike, TakeLike, dict[str, str]]]   # contributing takes, their units' fingerprints
    run: bool
    reason: str
    error: str = ""     # set when the build failed before on the same inputs and is not retried
    dag: tuple[str, ...] = ()   # the modules that register the datasets (:func:`registry.modules`)
    #: takes the dataset applies to that cannot feed it (a unit it needs failed or never ran): (session, take,
    #: why); with no contributing take at all the build only removes what an earlier build published
    left_out: list[tuple[str, str, str]] = field(default_factory=list)


class RunGone(Exception):
    """The run that submitted a dataset job to a local worker is gone: stop without writing anything."""


@dataclass
class DatasetContext:
    """Everything a dataset's build may use.

    Attributes
    ----------
    name : the dataset.
    takes : the contributing takes, each with the fingerprints of its units (by stage).
    params : the values of the dataset's parameter group.
    load : ``load(session, take, table)``: a take's table, schema-checked.
    table_path : ``table_path(session, take, table)``: where that table lies (to read its schema alone, or to
        place the file itself).
    root : the folder the dataset is published under (``OUT/datasets``; the dataset is ``root / name``).
    tmp : a path of its own, beside ``root``'s file system, to stage the dataset in before publishing it.
    write_bytes : an atomic writer of small files (``write_bytes(path, data)``).
    check_alive : call before every write: raises :class:`RunGone` when the run that asked for the build is gone.
    """

    name: str
    takes: list[tuple[SessionLike, TakeLike, dict[str, str]]]
    params: dict[str, Any]
    load: Callable[[str, str, str], Any]
    table_path: Callable[[str, str, str], Path]
    root: Path
    tmp: Path
    write_bytes: Callable[[Path, bytes], None]
    check_alive: Callable[[], None]


@dataclass
class DatasetResult:
    """What a build published: its files (under ``root / name``), extra fields for its run record, warnings;
    ``skipped``: why the dataset was not built at all (its inputs are not in the session: no take has eye
    tracking, …), which is not a failure."""

    outputs: list[Path]
    record: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    skipped: str = ""


def _unpublish(layout: OutLayout, name: str) -> bool:
    """Remove dataset ``name``'s folder, if any: renamed away first (readers never see half a dataset), then
    deleted. Whether there was one."""
    folder = layout.root / "datasets" / name
    if not folder.exists():
        return False
    layout.tmp.mkdir(parents=True, exist_ok=True)
    gone = layout.tmp / f"{name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.removed"
    os.replace(folder, gone)
    shutil.rmtree(gone, ignore_errors=True)
    return True


def _record_path(layout: OutLayout, name: str) -> Path:
    return layout.state / "datasets" / f"{name}.json"


#: the units each take's tables come from: their fingerprints and code identities, by (session, take, stage)
_Ids = dict[tuple[str, str, str], tuple[str, str]]


def plan_datasets(sessions: Sequence[SessionLike], layout: OutLayout, take_plans: Sequence[UnitPlan],
                  params: dict[str, Any], force: bool = False, optimistic: bool = False) -> list[DatasetPlan]:
    """Which datasets have takes to build from, and whether each must be rebuilt.

    A take contributes when every unit writing a table the dataset needs has an ``ok`` record whose
    fingerprint and code identity equal the planned ones (it is up to date, or ran successfully in this run).
    ``optimistic`` (for ``--dry-run``) counts units that are about to run as successful.
    """
    ids: _Ids = {(p.session, p.take, p.stage): (p.fingerprint, p.code) for p in take_plans}
    planned = {(p.session, p.take, p.stage) for p in take_plans if p.run} if optimistic else set()
    plans = []
    for ds in registry.datasets():
        name = ds.name
        takes: list[tuple[SessionLike, TakeLike, dict[str, str]]] = []
        left: list[tuple[str, str, str]] = []
        for s in sessions:
            for t in s.takes:
                if ds.applies(s, t):
                    units, why = _take_units(ds, s.id, t.id, layout, ids, planned)
                    if why:
                        left.append((s.id, t.id, why))
                    else:
                        takes.append((s, t, units))
        rec = read_json(_record_path(layout, name))
        if not takes and not isinstance(rec, dict) and not (layout.root / "datasets" / name).exists():
            continue   # nothing to build and nothing built before
        own = code_of(ds.run)
        comp = {"dataset": name, "version": ds.version, "code": own.digest, "libraries": dict(own.libraries),
                "params": registry.group_values(ds.params, params) if ds.params else {},
                "takes": sorted([s.id, t.id, u] for s, t, u in takes),
                # the code that made the takes' tables (the units' fingerprints cover their inputs only)
                "takes_code": sorted([s.id, t.id, {st: ids[(s.id, t.id, st)][1] for st in u}] for s, t, u in takes)}
        fingerprint = sha256_json(comp)
        reason, error = _build_reason(name, comp, fingerprint, rec, bool(takes), layout, force)
        plans.append(DatasetPlan(name, fingerprint, comp, takes, bool(reason),
                                 reason or ("failed earlier on these same inputs" if error else "up to date"), error,
                                 registry.modules(), left))
    return plans


def _take_units(ds: Dataset, session: str, take: str, layout: OutLayout, ids: _Ids,
                planned: set[tuple[str, str, str]]) -> tuple[dict[str, str], str]:
    """The fingerprints (by stage) of the units of a take that dataset ``ds`` reads, or why the take cannot feed
    it (a unit it needs never ran, failed or is not up to date; units in ``planned`` count as up to date)."""
    units: dict[str, str] = {}
    for stage in ds.needs:
        key = (session, take, stage)
        if key not in ids:
            if stage in ds.optional:
                continue
            return units, f"no {stage} stage for it"
        if key not in planned:
            rec = read_json(layout.record(session, take, stage))
            if not isinstance(rec, dict):
                return units, f"its {stage} stage never ran"
            if rec.get("status") != "ok":
                return units, f"its {stage} stage failed: {rec.get('error', '?')}"
            if (rec.get("fingerprint"), rec.get("code")) != ids[key]:
                return units, f"its {stage} stage is not up to date with its inputs"
        units[stage] = ids[key][0]
    return units, ""


def _build_reason(name: str, comp: dict[str, Any], fingerprint: str, rec: Any, has_takes: bool,
                  layout: OutLayout, force: bool) -> tuple[str, str]:
    """Why dataset ``name`` must be built (``rec``: its record) or '', and the error it failed with before on
    these same inputs (or '')."""
    published = (layout.root / "datasets" / name).exists()
    if not has_takes:
        reason = "no take can feed it" if (isinstance(rec, dict) and rec.get("status") == "ok") or published else ""
        return reason, "" if reason else (rec or {}).get("error", "no take can feed it")
    if force:
        return "--force", ""
    if not isinstance(rec, dict):
        return "never built", ""
    if rec.get("status") == "skipped" and rec.get("fingerprint") == fingerprint:
        return "", ""   # skipped on these same inputs: nothing to build
    if rec.get("status") != "ok":
        if rec.get("fingerprint") == fingerprint and not rec.get("retry", True):
            return "", rec.get("error", "failed")
        return "failed last time", ""
    if rec.get("fingerprint") != fingerprint:
        old = rec.get("components", {})
        changed = [why for key, why in (("code", "code changed"), ("libraries", "libraries changed"),
                                        ("params", "parameters changed"), ("takes", "its takes changed"),
                                        ("takes_code", "its takes' code changed")) if old.get(key) != comp[key]]
        return (changed or ["fingerprint changed"])[0], ""
    if not all((layout.root / "datasets" / name / f).is_file() for f in rec.get("outputs", {})):
        return "an output file is missing", ""
    return "", ""


def run_dataset(plan: DatasetPlan, layout: OutLayout, params: dict[str, Any],
                parent_pid: int | None = None) -> UnitOutcome:
    """Build one dataset (its registered ``run`` stages it and publishes it), record it.

    ``parent_pid``: the run's process when this runs in a local worker; when that process is gone (its lock
    with it) the build stops before publishing anything or writing its record.
    """
    registry.ensure(plan.dag)
    t0, cpu0 = time.perf_counter(), time.process_time()
    ds = next(d for d in registry.datasets() if d.name == plan.name)
    outcome = UnitOutcome("-", "-", f"build:{plan.name}", "ok", reason=plan.reason)
    record: dict[str, Any] = {"dataset": plan.name, "fingerprint": plan.fingerprint, "components": plan.components,
                              "gazepipe_version": __version__,
                              "left_out": [{"session": s, "take": t, "reason": why} for s, t, why in plan.left_out]}

    def check_alive() -> None:
        if parent_pid is not None and not pid_alive(parent_pid):
            raise RunGone

    ctx = DatasetContext(name=plan.name, takes=plan.takes,
                         params=registry.group_values(ds.params, params) if ds.params else {},
                         load=_loader(layout), table_path=layout.table, root=layout.root / "datasets",
                         tmp=layout.tmp / f"{plan.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.part",
                         write_bytes=layout.write_bytes, check_alive=check_alive)
    try:
        if not plan.takes:
            reasons = "; ".join(f"{s}/{t}: {why}" for s, t, why in plan.left_out[:3]) or "no take applies"
            raise GazepipeError(None, f"no take can feed it ({reasons})")
        missing = next((why for stage, why in ds.needs_any
                        if not any(stage in units for _, _, units in plan.takes)), "")
        result = DatasetResult(outputs=[], skipped=missing) if missing else ds.run(ctx)
        root = ctx.root / plan.name
        if result.skipped:
            # what an earlier build published came from inputs the session no longer has
            with contextlib.suppress(OSError):
                _unpublish(layout, plan.name)
            outcome.status, outcome.reason = "skipped", f"skipped: {result.skipped}"
            record.update(status="skipped", reason=result.skipped, outputs={})
        else:
            record.update(status="ok", outputs={str(p.relative_to(root)): p.stat().st_size for p in result.outputs})
        record.update(result.record)
        outcome.warnings = list(result.warnings)
    except RunGone:
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: the run stopped"
        return outcome
    except GazepipeError as exc:
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: {exc.one_line()}"
        record["retry"] = False
    except OSError as exc:   # the disk, not the inputs: retried next time
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: {os_problem(exc, ctx.root / plan.name)}"
        outcome.traceback = traceback.format_exc()
    except MemoryError:   # the machine, not the inputs: retried next time
        outcome.status = "failed"
        outcome.error = f"dataset {plan.name}: out of memory while building; build it alone or on a larger machine"
        outcome.traceback = traceback.format_exc()
    except Exception as exc:  # a bug: recorded, the run goes on
        outcome.status = "failed"
        outcome.error = f"dataset {plan.name}: internal error: {type(exc).__name__}: {exc}"
        outcome.traceback = traceback.format_exc()
    removed = False
    if outcome.status == "failed":
        # what an earlier build published came from other inputs: it must not pass for this build's result
        with contextlib.suppress(OSError):
            removed = _unpublish(layout, plan.name)
        if removed:
            outcome.error += f" (the dataset built before from other inputs is removed: datasets/{plan.name})"
        record.update(status="failed", error=outcome.error)
    outcome.duration_s = time.perf_counter() - t0
    record["duration_s"] = round(outcome.duration_s, 4)
    # the CPU seconds of the process while it ran (the unit's own under the serial and process executors,
    # which run one at a time per process)
    record["cpu_s"] = round(time.process_time() - cpu0, 4)
    path = _record_path(layout, plan.name)
    try:
        layout.write_json(path, record)
    except OSError as exc:   # built but not recorded: the next run builds it again
        outcome.status, outcome.error = "failed", f"dataset {plan.name}: {os_problem(exc, path)}"
    return outcome
