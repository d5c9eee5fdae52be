"""Plan and run units of work (one stage on one take): fingerprints, skip-when-up-to-date, failures kept apart.

Planning happens in the calling process and only stats files (the hash cache avoids re-reading unchanged
inputs), so a run with nothing to do costs little. Each take with work becomes one job — its stages in order —
submitted to an executor; a job writes its outputs atomically and records every unit as it finishes, so a run
killed at any moment loses only the unit in progress.
"""

from __future__ import annotations

import contextlib
import functools
import os
import time
import traceback
import uuid
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import pyarrow as pa

from gazepipe import __version__
from gazepipe.blas import one_blas_thread
from gazepipe.errors import GazepipeError, InputError, SchemaError, printable
from gazepipe.pipeline import registry
from gazepipe.pipeline.atomic import atomic_paths
from gazepipe.pipeline.codehash import code_of, library_changes
from gazepipe.pipeline.hashing import HashCache, sha256_file, sha256_json
from gazepipe.pipeline.lock import pid_alive
from gazepipe.pipeline.registry import (
    SessionContext,
    SessionLike,
    SessionStage,
    Stage,
    TableBatches,
    TakeLike,
    UnitContext,
    UnitResult,
)
from gazepipe.pipeline.state import OutLayout, read_json

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


@dataclass
class UnitPlan:
    """One unit: its fingerprint, whether it must run, and why."""

    session: str
    take: str
    stage: str
    fingerprint: str
    components: dict[str, Any]
    run: bool
    reason: str
    error: str = ""     # set when the unit failed before on the same inputs and is not retried
    #: the code that makes its outputs (:func:`code_identity`): its stage's and its upstream units'
    code: str = ""


@dataclass
class UnitOutcome:
    session: str
    take: str
    stage: str
    status: str                 # ok | failed | skipped (up to date) | blocked (an upstream unit failed)
    reason: str = ""
    error: str = ""
    traceback: str = ""
    duration_s: float = 0.0
    warnings: list[str] = field(default_factory=list)


#: the take named in the plan and outcome of a session stage's unit (it belongs to every take of the session)
SESSION_UNIT = "*"


@dataclass
class SessionJob:
    """A session's session-stage units in order (run before its takes' units); picklable."""

    out: str
    session: SessionLike
    units: list[UnitPlan]
    params: dict[str, Any]
    parent_pid: int | None = None
    dag: tuple[str, ...] = ()


@dataclass
class TakeJob:
    """A take's units in stage order; picklable, so any executor can run it."""

    out: str
    session: SessionLike
    take: TakeLike
    units: list[UnitPlan]
    params: dict[str, Any]
    parent_pid: int | None = None   # the run's process, for local workers: they stop when it is gone
    dag: tuple[str, ...] = ()       # the modules that register the stages (:func:`registry.modules`)
    #: run after the units, on the same worker: ``after(out, session_id, take, parent_pid)`` (a picklable
    #: module-level function; what the run's report needs from the take); its errors are ignored
    after: Callable[[str, str, Any, int | None], None] | None = None
    #: session stages whose unit failed: the take's units that read them are not run
    failed_session: frozenset[str] = frozenset()


# --------------------------------------------------------------------------------------------- planning

def stage_params(stage: Stage, params: dict[str, Any]) -> dict[str, Any]:
    """The values of the parameters ``stage`` uses (defaults overridden by ``params``)."""
    return {k: params.get(f"{stage.name}.{k}", v) for k, v in stage.params.items()}


def _take_config(session: SessionLike, take: TakeLike) -> dict[str, Any]:
    """The take's settings with paths relative to the session folder (moving the folder changes nothing)."""
    cfg = asdict(cast("DataclassInstance", take))   # a TakeLike's settings are its dataclass fields
    for k, v in cfg.items():
        if isinstance(v, str) and os.path.isabs(v):
            cfg[k] = os.path.relpath(v, session.root)
    return cfg


#: the components that say which code a unit runs: apart from its fingerprint (:func:`code_identity`)
CODE_COMPONENTS = ("code", "libraries")


def fingerprint(comp: dict[str, Any]) -> str:
    """A unit's fingerprint: the hash of its inputs and settings (its components but its code's), which the
    datasets cite as the provenance of the tables they are made from."""
    return sha256_json({k: v for k, v in comp.items() if k not in CODE_COMPONENTS})


def code_identity(comp: dict[str, Any], upstream: dict[str, str]) -> str:
    """A unit's code identity: the hash of its stage's code and libraries (``comp``) and its upstream units' code
    identities (``upstream``, by name). A unit is up to date only while both its fingerprint and its code
    identity are what its record says: an edit of the code a stage runs re-runs it and its readers."""
    return sha256_json({**{k: comp[k] for k in CODE_COMPONENTS}, "upstream": upstream})


def session_key(name: str) -> str:
    """How a take unit's fingerprint names a session stage among its upstream units."""
    return f"session:{name}"


def plan_session(session: SessionLike, stages: Sequence[SessionStage], params: dict[str, Any],
                 layout: OutLayout, hashes: HashCache, force: bool = False) -> list[UnitPlan]:
    """Fingerprint every session stage that applies to ``session`` and decide whether it must run (plans with
    take :data:`SESSION_UNIT`)."""
    plans: list[UnitPlan] = []
    fps: dict[str, str] = {}
    codes: dict[str, str] = {}
    running: set[str] = set()
    for st in stages:
        if not st.applies(session):
            continue
        check = registry.source_check()
        sources = {os.path.relpath(p, session.root): hashes.hash(p, check) for p in st.sources(session)}
        code = code_of(st.run, hashes.code)
        comp = {
            "stage": st.name, "version": st.version, "code": code.digest, "libraries": dict(code.libraries),
            "params": {f"{g}.{k}": v for g in st.uses for k, v in registry.group_values(g, params).items()},
            "sources": sources, "upstream": {u: fps[u] for u in st.requires if u in fps},
        }
        fps[st.name] = fingerprint(comp)
        codes[st.name] = code_identity(comp, {u: codes[u] for u in st.requires if u in codes})
        plans.append(_decide(session, SESSION_UNIT, st.name, comp, (fps[st.name], codes[st.name]),
                             layout.session_record(session.id, st.name),
                             [layout.session_table(session.id, o) for o in st.outputs], running, force, hashes))
    return plans


def plan_take(session: SessionLike, take: TakeLike, stages: Sequence[Stage], params: dict[str, Any],
              layout: OutLayout, hashes: HashCache, force: bool = False,
              session_units: Sequence[UnitPlan] = ()) -> list[UnitPlan]:
    """Fingerprint every applicable stage of ``take`` and decide whether it must run. ``session_units``: the
    plans of the take's session stages (:func:`plan_session`); a take stage that reads one re-runs when it
    runs."""
    plans: list[UnitPlan] = []
    fps: dict[str, str] = {session_key(u.stage): u.fingerprint for u in session_units}
    codes: dict[str, str] = {session_key(u.stage): u.code for u in session_units}
    running: set[str] = {session_key(u.stage) for u in session_units if u.run}
    for st in stages:
        if not st.applies(session, take):
            continue
        check = registry.source_check()
        sources = {os.path.relpath(p, session.root): hashes.hash(p, check) for p in st.sources(session, take)}
        upstream = [*st.requires, *map(session_key, st.session_requires)]
        code = code_of(st.run, hashes.code)
        comp = {
            "stage": st.name, "version": st.version, "code": code.digest, "libraries": dict(code.libraries),
            "params": stage_params(st, params),
            "take": _take_config(session, take), "sources": sources,
            "upstream": {u: fps[u] for u in upstream if u in fps},
        }
        if st.groups:
            comp["groups"] = {g: registry.group_values(g, params) for g in st.groups}
        fps[st.name] = fingerprint(comp)
        codes[st.name] = code_identity(comp, {u: codes[u] for u in upstream if u in codes})
        plans.append(_decide(session, take.id, st.name, comp, (fps[st.name], codes[st.name]),
                             layout.record(session.id, take.id, st.name),
                             [layout.table(session.id, take.id, o) for o in st.outputs], running, force, hashes))
    return plans


def _decide(session: SessionLike, take_id: str, stage: str, comp: dict[str, Any], ids: tuple[str, str],
            record_path: Path, outputs: list[Path], running: set[str], force: bool, hashes: HashCache) -> UnitPlan:
    """A unit's plan: whether it must run (adding it to ``running``) and why, or the error it failed with
    before on the same inputs (``ids``: its fingerprint and code identity)."""
    fp, code = ids
    reason = _why(stage, comp, ids, record_path, outputs, running, force,
                  lambda rel: hashes.hash(os.path.join(session.root, rel)))
    error = ""
    if reason:
        running.add(stage)
    else:
        rec = read_json(record_path) or {}
        if rec.get("status") == "failed":
            error = rec.get("error", "failed")
    return UnitPlan(session.id, take_id, stage, fp, comp, bool(reason),
                    reason or ("failed earlier on these same inputs (--force retries)" if error else "up to date"),
                    error, code)


def _why(stage: str, comp: dict[str, Any], ids: tuple[str, str], record_path: Path, outputs: list[Path],
         running: set[str], force: bool, hash_of: Callable[[str], str]) -> str:
    """Why a unit must run, or '' when it is up to date (``ids``: its fingerprint and code identity;
    ``hash_of`` hashes a path relative to the session, for the inputs the unit's last run found it needed,
    :attr:`UnitResult.read`)."""
    if force:
        return "--force"
    rec = read_json(record_path)
    if not isinstance(rec, dict) or "fingerprint" not in rec:
        return "never ran"
    same = [rec["fingerprint"], rec.get("code")] == list(ids)
    if rec.get("status") != "ok":
        if same and not rec.get("retry", True):
            return ""   # an input problem: the same inputs fail the same way
        return "failed last time"
    if same:
        return _what_moved(rec, outputs, hash_of)
    return _what_changed(stage, comp, rec, ids, running)


def _what_moved(rec: dict[str, Any], outputs: list[Path], hash_of: Callable[[str], str]) -> str:
    """For a unit whose record matches its identity: an input it found it needed that changed since, or an
    output that changed on disk or is gone ('' when none)."""
    for rel, digest in (rec.get("read") or {}).items():
        try:
            if hash_of(rel) != digest:
                return f"input changed: {rel}"
        except GazepipeError:
            return f"input {rel} unreadable"
    sizes = rec.get("outputs", {})
    for p in outputs:
        try:
            if p.stat().st_size != sizes.get(p.name):
                return f"output {p.name} changed on disk"
        except FileNotFoundError:
            return f"output {p.name} missing"
    return ""


def _what_changed(stage: str, comp: dict[str, Any], rec: dict[str, Any], ids: tuple[str, str],
                  running: set[str]) -> str:
    """Which component of a unit's identity differs from its record's, the first of: version, code,
    libraries, parameters, inputs, take settings, upstream units."""
    old = rec.get("components", {})
    if old.get("version") != comp["version"]:
        return f"stage version {old.get('version')} -> {comp['version']}"
    if old.get("code") != comp["code"]:
        return "stage code changed"
    libraries = library_changes(old.get("libraries"), comp["libraries"])
    if libraries:
        return "libraries changed: " + libraries
    changed = [k if "." in k else f"{stage}.{k}"   # a session stage's parameters are named with their group
               for k in comp["params"] if old.get("params", {}).get(k) != comp["params"][k]]
    changed += [f"{g}.{k}" for g, values in comp.get("groups", {}).items() for k in values
                if old.get("groups", {}).get(g, {}).get(k) != values[k]]
    if changed:
        return "parameters changed: " + ", ".join(changed)
    files = [k for k in comp["sources"] if old.get("sources", {}).get(k) != comp["sources"][k]]
    if files:
        return "input changed: " + ", ".join(files)
    if old.get("take") != comp.get("take"):
        return "take settings changed"
    ups = [u for u in comp["upstream"] if u in running or old.get("upstream", {}).get(u) != comp["upstream"][u]]
    if ups:
        return "upstream re-runs: " + ", ".join(ups)
    return "fingerprint changed" if rec["fingerprint"] != ids[0] else "upstream code changed"


# -------------------------------------------------------------------------------------------- execution

def _loader(layout: OutLayout, written: dict[Path, pa.Table] | None = None) -> Callable[[str, str, str], pa.Table]:
    """A function reading a take's table by name, schema-checked (by the registered table store); ``written``
    holds tables this process just wrote (by path), returned instead of reading the file back, checked as
    well."""
    def load(session_id: str, take_id: str, name: str) -> pa.Table:
        return _read_checked(layout.table(session_id, take_id, name), name, written)
    return load


def _batch_loader(layout: OutLayout, written: dict[Path, pa.Table] | None = None
                  ) -> Callable[[str, str, str], TableBatches]:
    """:func:`_loader` a row group at a time (:class:`TableBatches`): by the table store's ``read_batches``,
    each batch checked as it is read; a table this process just wrote (``written``), or with a store that reads
    only whole tables, checked whole and handed out in batches."""
    def load(session_id: str, take_id: str, name: str) -> TableBatches:
        path = layout.table(session_id, take_id, name)
        store = registry.table_store()
        if store.read_batches is None or (written and path in written):
            whole = _read_checked(path, name, written)
            return TableBatches(whole.schema, whole.num_rows, iter(whole.to_batches()))
        return store.read_batches(path, name)
    return load


#: tables a process keeps after writing them, for the take's later units to read without reading the file
#: back, up to this size each (bytes in memory): a longer one (a long take's markers) is read back, so a unit
#: does not carry an earlier unit's whole table beside its own arrays
WRITTEN_MAX_BYTES = 64 * 2**20


def _remember(written: dict[Path, pa.Table], tables: dict[Path, pa.Table | TableBatches]) -> None:
    """Keep the tables just written that later units may take from memory (:data:`WRITTEN_MAX_BYTES`)."""
    for path, table in tables.items():
        written.pop(path, None)
        if isinstance(table, pa.Table) and table.nbytes <= WRITTEN_MAX_BYTES:
            written[path] = table


def _session_loader(layout: OutLayout, written: dict[Path, pa.Table] | None = None) -> Callable[[str, str], pa.Table]:
    """A function reading a session stage's table by name, schema-checked (see :func:`_loader`)."""
    def load(session_id: str, name: str) -> pa.Table:
        return _read_checked(layout.session_table(session_id, name), name, written)
    return load


def _read_checked(path: Path, name: str, written: dict[Path, pa.Table] | None) -> pa.Table:
    store = registry.table_store()
    table = written.get(path) if written else None
    if table is None:
        table = store.read(path)
    store.check(table, path, name)
    return table


def release_memory() -> None:
    """Hand memory freed by earlier work back to the system: Arrow's pool, then the C heap (glibc only). A
    worker that ran many takes otherwise keeps its high-water mark through the dataset builds."""
    import ctypes
    import gc

    gc.collect()
    pa.default_memory_pool().release_unused()
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def run_take_job(job: TakeJob) -> list[UnitOutcome]:
    """Run a take's units in order; record each; a failure blocks the units that depend on it."""
    registry.ensure(job.dag)
    layout = OutLayout(Path(job.out))
    outcomes: list[UnitOutcome] = []
    failed: set[str] = set()
    written: dict[Path, pa.Table] = {}   # this take's tables written so far: later units need not read them back
    for plan in job.units:
        if job.parent_pid is not None and not pid_alive(job.parent_pid):
            break  # the run died (its lock with it): write nothing more, a new run may already be going
        st = registry.get(plan.stage)
        if any(u in failed for u in st.requires) or any(u in job.failed_session for u in st.session_requires):
            failed.add(st.name)
            outcomes.append(UnitOutcome(plan.session, plan.take, plan.stage, "blocked",
                                        reason="an upstream stage failed"))
            continue
        if not plan.run:
            if plan.error:  # failed before on exactly these inputs: not retried without --force
                failed.add(st.name)
                outcomes.append(UnitOutcome(plan.session, plan.take, plan.stage, "failed", reason=plan.reason,
                                            error=plan.error))
                continue
            outcomes.append(UnitOutcome(plan.session, plan.take, plan.stage, "skipped", reason=plan.reason))
            continue
        ctx: UnitContext[Any, Any] = UnitContext(
            job.session, job.take, stage_params(st, job.params), layout.root, _loader(layout, written), job.params,
            session_loader=_session_loader(layout), batch_loader=_batch_loader(layout, written),
            inputs=frozenset(st.inputs),
            session_inputs=frozenset(st.session_inputs))
        out = _run_unit(st.name, st.outputs, functools.partial(st.run, ctx), plan, job.session, _files_of(job),
                        layout, written)
        if out.status == "failed":
            failed.add(st.name)
        outcomes.append(out)
    if job.after is not None and (job.parent_pid is None or pid_alive(job.parent_pid)):
        written.clear()
        with contextlib.suppress(Exception):   # the report computes it again when it needs it
            job.after(job.out, job.session.id, job.take, job.parent_pid)
    return outcomes


def run_session_job(job: SessionJob) -> list[UnitOutcome]:
    """Run a session's session-stage units in order; record each; a failure blocks the units that need it."""
    registry.ensure(job.dag)
    layout = OutLayout(Path(job.out))
    outcomes: list[UnitOutcome] = []
    failed: set[str] = set()
    written: dict[Path, pa.Table] = {}
    for plan in job.units:
        if job.parent_pid is not None and not pid_alive(job.parent_pid):
            break
        st = registry.get_session_stage(plan.stage)
        if any(u in failed for u in st.requires):
            failed.add(st.name)
            outcomes.append(UnitOutcome(plan.session, plan.take, plan.stage, "blocked",
                                        reason="an upstream stage failed"))
        elif not plan.run:
            if plan.error:
                failed.add(st.name)
            outcomes.append(UnitOutcome(plan.session, plan.take, plan.stage, "failed" if plan.error else "skipped",
                                        reason=plan.reason, error=plan.error))
        else:
            ctx: SessionContext[Any] = SessionContext(job.session, {}, layout.root,
                                                      _session_loader(layout, written), job.params,
                                                      inputs=frozenset(st.inputs))
            out = _run_unit(st.name, st.outputs, functools.partial(st.run, ctx), plan, job.session, [],
                            layout, written)
            if out.status == "failed":
                failed.add(st.name)
            outcomes.append(out)
    return outcomes


def _unit_paths(layout: OutLayout, plan: UnitPlan) -> tuple[Callable[[str], Path], Path, str]:
    """Where a unit's tables and record go, and how its errors name it (``take S/T`` or ``session S``)."""
    if plan.take == SESSION_UNIT:
        return (lambda name: layout.session_table(plan.session, name), layout.session_record(plan.session, plan.stage),
                f"session {plan.session}")
    return (lambda name: layout.table(plan.session, plan.take, name), layout.record(plan.session, plan.take, plan.stage),
            f"take {plan.session}/{plan.take}")


def _write_tables(tables: dict[str, tuple[pa.Table | TableBatches, Any]], table_path: Callable[[str], Path], tmp_dir: Path,
                  store: registry.TableStore, writing: list[Path]) -> dict[str, int]:
    """Write a unit's ``tables`` (name → (table, schema)) to their paths: every one written first, then fsynced
    and renamed together, their folder fsynced once. Returns each file's size by file name; ``writing`` ends
    with the path being written when an error is raised."""
    names = sorted(tables)
    finals = [table_path(name) for name in names]
    with atomic_paths(finals, tmp_dir) as temporaries:
        for name, final, tmp in zip(names, finals, temporaries, strict=True):
            writing.append(final)
            table, schema = tables[name]
            store.write(table, tmp, schema)
    writing.clear()
    return {final.name: final.stat().st_size for final in finals}


def _run_unit(stage: str, outputs: Sequence[str], run: Callable[[], UnitResult], plan: UnitPlan,
              session: SessionLike, files: list[str], layout: OutLayout,
              written: dict[Path, pa.Table] | None = None) -> UnitOutcome:
    """Run one unit (``run``: the stage's work on its context), write its tables atomically and its record."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    store = registry.table_store()
    table_path, record_path, who = _unit_paths(layout, plan)
    record: dict[str, Any] = {"session": plan.session, "take": plan.take, "stage": plan.stage,
                              "fingerprint": plan.fingerprint, "code": plan.code, "components": plan.components,
                              "gazepipe_version": __version__}
    outcome = UnitOutcome(plan.session, plan.take, plan.stage, "ok", reason=plan.reason)
    writing: list[Path] = []   # the output being written, for an I/O error's message
    try:
        # one BLAS thread whatever the executor: results must not depend on where a unit ran (a multi-threaded
        # BLAS sums in another order), and takes already run in parallel
        with one_blas_thread():
            result = run()
        missing = [o for o in outputs if o not in result.tables]
        if missing:
            raise RuntimeError(f"stage {stage} produced no {missing}")
        sizes = _write_tables(result.tables, table_path, layout.tmp, store, writing)
        if written is not None:
            _remember(written, {table_path(name): table for name, (table, _) in result.tables.items()})
        record.update(status="ok", outputs=sizes, qc=result.qc, warnings=result.warnings,
                      read={os.path.relpath(p, session.root): sha256_file(p) for p in sorted(set(result.read))})
        outcome.warnings = list(result.warnings)
    except GazepipeError as exc:
        if plan.take == SESSION_UNIT and exc.take is None:
            outcome.status, outcome.error = "failed", f"{who}: stage {stage}: {exc.one_line()}"
        else:   # a take is (session, take): name both
            if exc.take is None or exc.take == plan.take:
                exc.take = f"{plan.session}/{plan.take}"
            elif plan.take == SESSION_UNIT and "/" not in exc.take:   # one of the session's takes
                exc.take = f"{plan.session}/{exc.take}"
            outcome.status, outcome.error = "failed", exc.one_line()
        # the inputs are at fault (the same inputs fail the same way), unless the machine was (memory)
        record["retry"] = bool(getattr(exc, "retry", False))
        if isinstance(exc, SchemaError | InputError):
            outcome.traceback = traceback.format_exc()
    except OSError as exc:   # the disk, not the take: full, read-only, no permission; retried next time
        record["retry"] = True
        outcome.status = "failed"
        outcome.error = f"{who}: stage {stage}: {os_problem(exc, writing[-1] if writing else None)}"
        outcome.traceback = traceback.format_exc()
    except MemoryError:   # the machine, not the take: tried again next time
        record["retry"] = True
        outcome.status = "failed"
        outcome.error = (f"{who}: stage {stage}: out of memory "
                         f"(inputs: {', '.join(files) or 'none'}); run it alone or on a larger machine")
        outcome.traceback = traceback.format_exc()
    except Exception as exc:  # a bug: the take fails, the run goes on, --debug shows the traceback
        record["retry"] = True
        outcome.status = "failed"
        outcome.error = f"{who}: stage {stage}: internal error: {type(exc).__name__}: {exc}"
        outcome.traceback = traceback.format_exc()
    if outcome.status == "failed":
        record.update(status="failed", error=outcome.error)
        for name in outputs:  # a failed unit leaves no output that disagrees with its inputs
            with contextlib.suppress(FileNotFoundError):
                table_path(name).unlink()
    outcome.duration_s = time.perf_counter() - t0
    record["duration_s"] = round(outcome.duration_s, 4)
    # the CPU seconds of the process while it ran (the unit's own under the serial and process executors,
    # which run one at a time per process)
    record["cpu_s"] = round(time.process_time() - cpu0, 4)
    try:
        layout.write_json(record_path, record)
    except OSError as exc:   # the unit's outputs stand unrecorded: the next run does it again
        outcome.status = "failed"
        outcome.error = f"{who}: stage {stage}: {os_problem(exc, record_path)}"
    return outcome


def _files_of(job: TakeJob) -> list[str]:
    """The take's input files as the user listed them (relative to the session folder)."""
    take = job.take
    files = getattr(take, "files", ())
    return [printable(os.path.relpath(f, job.session.root)) for f in files]


def os_problem(exc: OSError, writing: Path | None = None) -> str:
    """An I/O error as a phrase naming its file: the one the error names (``PATH: Permission denied``), else
    the one being written (``cannot write PATH: No space left on device``)."""
    why = exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
    if exc.filename:
        return f"{exc.filename}: {why}"
    return f"cannot write {writing}: {why}" if writing else f"I/O error: {why}"


def new_run_id() -> str:
    return time.strftime("%Y%m%dT%H%M%S", time.gmtime()) + "-" + uuid.uuid4().hex[:6]
