"""A whole run: lock the output folder, plan every unit, run the takes that have work, build the datasets, record
the run. The stages and datasets are those registered (:mod:`gazepipe.pipeline.registry`; gazepipe's are
registered by :mod:`gazepipe.dag`)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from gazepipe.errors import ConfigError, GazepipeError
from gazepipe.pipeline import registry
from gazepipe.pipeline.atomic import clear_stale_temporaries
from gazepipe.pipeline.builds import plan_datasets, run_dataset
from gazepipe.pipeline.codehash import code_of
from gazepipe.pipeline.events import EventLog
from gazepipe.pipeline.executors import check_executor, make_executor
from gazepipe.pipeline.hashing import HashCache
from gazepipe.pipeline.lock import OutputLock
from gazepipe.pipeline.registry import SessionLike
from gazepipe.pipeline.runner import (
    SESSION_UNIT,
    SessionJob,
    TakeJob,
    UnitOutcome,
    UnitPlan,
    new_run_id,
    os_problem,
    plan_session,
    plan_take,
    run_session_job,
    run_take_job,
)
from gazepipe.pipeline.state import OutLayout, read_json

#: ``until`` value that runs every take stage and then builds the datasets (as ``None`` does)
BUILD = "build"


@dataclass
class RunSummary:
    run_id: str
    outcomes: list[UnitOutcome] = field(default_factory=list)
    plans: list[UnitPlan] = field(default_factory=list)
    #: the run's own writes that failed (its records, its report), one line each
    io_errors: list[str] = field(default_factory=list)
    #: the files those were about (a file that failed once is not tried again in the run)
    io_failed: set[str] = field(default_factory=set)

    def count(self, status: str, *, datasets: bool | None = None) -> int:
        """Outcomes with ``status``: of take units only (``datasets=False``), datasets only (``True``), or
        both (``None``)."""
        return sum(o.status == status for o in self.outcomes
                   if (datasets is None or is_dataset(o) == datasets) and (datasets is not False or not is_session(o)))

    def end_message(self) -> tuple[str, dict[str, int]]:
        """The line that ends a run and its counts. Take units (a stage on a take, what ``run_start`` counts)
        and datasets are counted apart: ``ran``, ``up_to_date``, ``failed``, ``blocked`` (not run after an
        upstream failure) are take units; ``datasets_built``, ``datasets_up_to_date``, ``datasets_skipped`` (the
        sessions lack their inputs), ``datasets_failed`` datasets."""
        n = {"ran": self.count("ok", datasets=False), "up_to_date": self.count("skipped", datasets=False),
             "failed": self.count("failed", datasets=False), "blocked": self.count("blocked", datasets=False),
             "datasets_built": self.count("ok", datasets=True),
             "datasets_up_to_date": self.count("skipped", datasets=True) - self.datasets_not_needed(),
             "datasets_skipped": self.datasets_not_needed(),
             "datasets_failed": self.count("failed", datasets=True)}
        msg = f"done: {n['ran']} take units ran, {n['up_to_date']} up to date, {n['failed']} failed"
        n_session = sum(o.status == "failed" for o in self.outcomes if is_session(o))
        if n_session:
            n["session_failed"] = n_session
            msg += f", {n_session} session unit{'s' if n_session > 1 else ''} failed"
        if n["blocked"]:
            msg += f", {n['blocked']} not run after a failure"
        if any(n[k] for k in ("datasets_built", "datasets_up_to_date", "datasets_skipped", "datasets_failed")):
            skipped = f", {n['datasets_skipped']} skipped (inputs missing)" if n["datasets_skipped"] else ""
            msg += (f"; datasets: {n['datasets_built']} built, {n['datasets_up_to_date']} up to date{skipped}, "
                    f"{n['datasets_failed']} failed")
        if self.io_errors:
            n["io_errors"] = len(self.io_errors)
            msg += f"; {len(self.io_errors)} of the run's own files could not be written"
        return msg, n

    def datasets_not_needed(self) -> int:
        """Datasets not built because the sessions lack their inputs (a build that skipped itself, saying why)."""
        return sum(o.status == "skipped" and o.reason.startswith("skipped:") for o in self.outcomes if is_dataset(o))

    @property
    def failed(self) -> list[UnitOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    @property
    def exit_code(self) -> int:
        return 1 if self.failed or self.io_errors else 0


def is_dataset(outcome: UnitOutcome) -> bool:
    """Whether an outcome is a dataset's build (``build:NAME``) rather than a take unit (a stage on a take)."""
    return outcome.stage.startswith("build:")


def is_session(outcome: UnitOutcome) -> bool:
    """Whether an outcome is a session stage's unit (run once for its session, before its takes)."""
    return outcome.take == SESSION_UNIT


@dataclass
class RunPlan:
    """Every unit of a run planned: the sessions' and takes' jobs (each with its units' plans), the outcomes of
    units that failed while planning, and every plan (session units first)."""

    session_jobs: list[SessionJob] = field(default_factory=list)
    take_jobs: list[TakeJob] = field(default_factory=list)
    failures: list[UnitOutcome] = field(default_factory=list)
    plans: list[UnitPlan] = field(default_factory=list)


def plan_run(sessions: Sequence[SessionLike], out: Path, *, until: str | None = None,
             params: dict[str, Any] | None = None, force: bool = False,
             hashes: HashCache | None = None) -> RunPlan:
    """Plan every session and take: jobs for those with work, outcomes for units that failed while planning."""
    layout = OutLayout(Path(out))
    stages = registry.upto(until) if until and until != BUILD else registry.stages()
    session_stages = registry.session_stages_for(stages)
    params = params or {}
    hashes = hashes or HashCache(layout.hashes)
    for ds in registry.datasets():   # the datasets' code identities, kept in the memo with the stages'
        code_of(ds.run, hashes.code)
    run = RunPlan()
    dag = registry.modules()
    for session in sessions:
        try:
            session_plans = plan_session(session, session_stages, params, layout, hashes, force)
        except GazepipeError as exc:
            run.failures.append(UnitOutcome(session.id, SESSION_UNIT, session_stages[0].name, "failed",
                                            error=f"session {session.id}: {exc.one_line()}"))
            continue
        run.plans.extend(session_plans)
        if session_plans:
            run.session_jobs.append(SessionJob(str(layout.root), session, session_plans, params, dag=dag))
        for take in session.takes:
            try:
                take_plans = plan_take(session, take, stages, params, layout, hashes, force, session_plans)
            except GazepipeError as exc:
                exc.take = f"{session.id}/{take.id}" if exc.take in (None, take.id) else exc.take
                run.failures.append(UnitOutcome(session.id, take.id, stages[0].name, "failed",
                                                error=exc.one_line()))
                continue
            run.plans.extend(take_plans)
            if take_plans:
                run.take_jobs.append(TakeJob(str(layout.root), session, take, take_plans, params, dag=dag))
    return run


def run_pipeline(sessions: Sequence[SessionLike], out: str | Path, *, until: str | None = None,
                 params: dict[str, Any] | None = None, executor: str = "process", jobs: int | None = None,
                 scheduler: str | None = None, force: bool = False, dry_run: bool = False,
                 log: EventLog | None = None, heartbeat_every: int = 10,
                 report: RunReport | None = None, preload: Sequence[str] = ()) -> RunSummary:
    """Run the stages (up to ``until``) on every take of ``sessions`` into ``out``.

    ``preload``: modules the workers import before their first job, besides those of the registered stages (say,
    what ``report``'s jobs run); with the process executor they are imported once and shared by every worker.

    ``report``: told when the takes are done, of each dataset built and when the datasets are done (only when
    units ran; :class:`RunReport`) and, at the end, still under the output folder's lock, ``finish`` (every run
    that is not a dry run).
    """
    check_executor(executor, scheduler)
    params = params or {}
    _check_params(params)
    layout = OutLayout(Path(out))
    log = log or EventLog()
    summary = RunSummary(run_id=log.run_id or new_run_id())
    if dry_run:
        _dry_run(sessions, layout, until, params, force, log, summary)
        return summary
    layout.state.mkdir(parents=True, exist_ok=True)
    with OutputLock(layout.lock):
        clear_stale_temporaries(layout.tmp)
        try:
            _remember_sessions(layout, sessions)
        except OSError as exc:   # nothing can be recorded: stop before anything runs
            raise GazepipeError(None, os_problem(exc, layout.sessions)) from None
        hashes = HashCache(layout.hashes)
        planned = plan_run(sessions, layout.root, until=until, params=params, force=force, hashes=hashes)
        todo, session_todo = _record_plan(planned, summary, log, report)
        n_before = sum(bool(u.error) for u in planned.plans if u.take != SESSION_UNIT)
        with _Workers(executor, jobs, scheduler, max(len(todo), len(session_todo)),
                      (*registry.modules(), *preload)) as workers:
            failed_session = _run_sessions(planned.session_jobs, session_todo, summary, log, workers)
            for j in todo:
                j.failed_session = frozenset(failed_session.get(j.session.id, ()))
            if todo:
                _log_start(planned, todo, n_before, until, log)
                if report is not None:
                    report.takes_started(workers.pool())
                _execute(todo, summary, log, workers, heartbeat_every, report)
                if report is not None:   # what the report's unit states are worked out with
                    _keep(summary, log, layout.hashes, lambda: hashes.save(layout.write_bytes))
            built = 0
            if until in (None, BUILD):
                built = _build_datasets(sessions, layout, planned.plans, params, force, summary, log, workers,
                                        report if todo else None)
            elif report is not None and todo:
                report.takes_done()
            if report is not None and todo:
                report.datasets_done()   # still on the workers: what the report put on them is finished
        if not todo and not built and not session_todo:
            _log_nothing_to_do(planned, n_before, summary, log)
        _keep(summary, log, layout.hashes, lambda: hashes.save(layout.write_bytes))
        run_record = layout.runs() / f"{summary.run_id}.json"
        _keep(summary, log, run_record, lambda: layout.write_json(run_record, {
            "run_id": summary.run_id, "outcomes": [asdict(o) for o in summary.outcomes]}))
        if report is not None:
            _keep(summary, log, layout.root / "qc", report.finish)
    return summary


def _dry_run(sessions: Sequence[SessionLike], layout: OutLayout, until: str | None, params: dict[str, Any],
             force: bool, log: EventLog, summary: RunSummary) -> None:
    """Plan every unit and dataset and say what would run, writing nothing."""
    planned = plan_run(sessions, layout.root, until=until, params=params, force=force,
                       hashes=HashCache(layout.hashes))
    summary.plans = planned.plans
    summary.outcomes = planned.failures
    for p in planned.plans:
        what = "would run" if p.run else "up to date"
        log.emit("info", "plan", f"{p.session}/{p.take} {p.stage}: {what}" + (f" ({p.reason})" if p.run else ""),
                 session=p.session, take=p.take, stage=p.stage, status="run" if p.run else "skip", reason=p.reason)
    for f in planned.failures:
        log.emit("error", "plan_failed", f.error, session=f.session, take=f.take, stage=f.stage, status="failed")
    if until in (None, BUILD):
        for d in plan_datasets(sessions, layout, planned.plans, params, force, optimistic=True):
            what = f"would build ({d.reason})" if d.run else "up to date"
            log.emit("info", "plan", f"dataset {d.name}: {what} from {len(d.takes)} takes", stage="build",
                     dataset=d.name, status="run" if d.run else "skip", reason=d.reason)


def _record_plan(planned: RunPlan, summary: RunSummary, log: EventLog,
                 report: RunReport | None) -> tuple[list[TakeJob], list[SessionJob]]:
    """Record what planning decided (failures, units not run, units that failed before on the same inputs);
    the take jobs and session jobs with work, the take jobs told what to run after their units."""
    summary.plans = planned.plans
    summary.outcomes.extend(planned.failures)
    for f in planned.failures:
        log.emit("error", "unit", f.error, session=f.session, take=f.take, stage=f.stage, status="failed")
    todo = [j for j in planned.take_jobs if any(u.run for u in j.units)]
    after = report.take_job() if report is not None else None
    for j in todo:
        j.after = after
    for j in planned.take_jobs:
        if j not in todo:
            summary.outcomes.extend(_not_run(u) for u in j.units)
    for u in planned.plans:
        if u.error:
            log.emit("error", "unit", f"{u.error} (failed earlier on these same inputs; --force retries)",
                     session=u.session, take=u.take, stage=u.stage, status="failed")
    return todo, [j for j in planned.session_jobs if any(u.run for u in j.units)]


def _log_start(planned: RunPlan, todo: list[TakeJob], n_before: int, until: str | None, log: EventLog) -> None:
    n_plans = sum(u.take != SESSION_UNIT for u in planned.plans)
    n_units = sum(u.run for j in todo for u in j.units)
    before = f", {n_before} failed before on the same inputs" if n_before else ""
    later = ", then the datasets" if until in (None, BUILD) else ""
    log.emit("info", "run_start", f"running {n_units} take units on {len(todo)} takes "
             f"({n_plans - n_units - n_before} up to date{before}){later}", takes=len(todo),
             units=n_units, up_to_date=n_plans - n_units - n_before, failed_before=n_before)


def _log_nothing_to_do(planned: RunPlan, n_before: int, summary: RunSummary, log: EventLog) -> None:
    n_plans = sum(u.take != SESSION_UNIT for u in planned.plans)
    n_ds = summary.count("skipped", datasets=True)
    also = f" and {n_ds} datasets" if n_ds else ""
    before = f" ({n_before} take units failed before on the same inputs)" if n_before else ""
    log.emit("info", "nothing_to_do", f"nothing to do: {n_plans - n_before} take units{also} up to "
             f"date{before}", status="up_to_date", units=n_plans - n_before, datasets=n_ds)


def _keep(summary: RunSummary, log: EventLog, path: Path, write: Callable[[], None]) -> None:
    """Run one of the run's own writes (its records, its report); an I/O error (a full or read-only disk) is
    one error line naming the file, and the run still ends with its summary (exit 1). A file whose write
    failed once in the run is not tried again (one line per file)."""
    if str(path) in summary.io_failed:
        return
    try:
        write()
    except OSError as exc:
        msg = os_problem(exc, path)
        summary.io_failed.add(str(path))
        summary.io_errors.append(msg)
        log.emit("error", "io_error", msg, status="failed", path=str(path))


def _check_params(params: dict[str, Any]) -> None:
    """Refuse unknown parameter names and values a parameter does not accept (ConfigError, exit 2), before
    anything runs: the command line checks them too, this is for callers of :func:`run_pipeline`."""
    defaults = registry.default_params()
    lines = [f"unknown parameter {k}; `gazepipe params` lists them" for k in params if k not in defaults]
    lines += [p for _, p in registry.param_problems({k: v for k, v in params.items() if k in defaults})]
    if lines:
        raise ConfigError(None, "; ".join(lines))


@dataclass(frozen=True)
class WorkerPool:
    """The run's workers as a report may use them: ``submit(fn, *args)`` returns a future; ``parent_pid`` is the
    run's process when the workers are local processes (a job checks it before writing), else ``None``;
    ``workers``: how many."""

    submit: Callable[..., Future]
    parent_pid: int | None
    workers: int


class RunReport(Protocol):
    """What a run tells the QC report (see :func:`run_pipeline`). When take units run, in this order:
    :meth:`take_job` (before the takes are planned onto the workers), :meth:`takes_started`,
    :meth:`take_finished` for each take, :meth:`dataset_built` for each dataset built, :meth:`takes_done` (the
    takes, and the dataset builds when the run makes them, are done), :meth:`datasets_done` (the workers are
    still there, for the last time). Then :meth:`finish`, always."""

    def take_job(self) -> Callable[[str, str, Any, int | None], None] | None:
        """A picklable function each take's job runs after its units, on its worker (see
        :attr:`gazepipe.pipeline.runner.TakeJob.after`), or ``None``."""
        ...

    def takes_started(self, pool: WorkerPool | None) -> None:
        """The takes are going to the workers (``pool`` is ``None`` when the run has no parallel workers)."""
        ...

    def take_finished(self, session: SessionLike, take: Any, waiting: int) -> None:
        """A take's units are done (ok or not); ``waiting``: takes not yet started on a worker."""
        ...

    def takes_done(self) -> None: ...

    def dataset_built(self, name: str) -> None: ...

    def datasets_done(self) -> None: ...

    def finish(self) -> None: ...


class _Workers:
    """The run's executor, started when first needed (a run with nothing to do starts no cluster)."""

    def __init__(self, executor: str, jobs: int | None, scheduler: str | None, n_takes: int,
                 preload: Sequence[str] = ()) -> None:
        self.n = min(n_takes, jobs or os.cpu_count() or 1)
        self.preload = tuple(preload)
        self.kind = "serial" if (executor == "process" and self.n <= 1) else executor
        self.scheduler = scheduler
        self._ex: Executor | None = None

    @property
    def local(self) -> bool:
        """Workers are processes of this machine (they watch this process and stop when it is gone)."""
        return self.kind == "process"

    def pool(self) -> WorkerPool | None:
        """The workers for other jobs of the run; ``None`` for a serial run (its jobs would run one after the
        other in this process anyway)."""
        if self.kind == "serial":
            return None
        return WorkerPool(self.executor.submit, os.getpid() if self.local else None, self.n)

    @property
    def executor(self):
        if self._ex is None:
            self._ex = make_executor(self.kind, self.n, self.scheduler, self.preload)
        return self._ex

    def __enter__(self) -> _Workers:
        return self

    def __exit__(self, *exc) -> None:
        if self._ex is not None:
            self._ex.shutdown(wait=True)


def _build_datasets(sessions: Sequence[SessionLike], layout: OutLayout, plans: list[UnitPlan], params: dict[str, Any],
                    force: bool, summary: RunSummary, log: EventLog, workers: _Workers,
                    report: RunReport | None = None) -> int:
    """Build the datasets that are not up to date, in this process; the number built.
    ``report`` is told of each dataset built, then that the builds are done (:meth:`RunReport.takes_done`)."""
    todo = []
    for d in plan_datasets(sessions, layout, plans, params, force):
        if d.run:
            todo.append(d)
            continue
        summary.outcomes.append(UnitOutcome("-", "-", f"build:{d.name}", "failed" if d.error else "skipped",
                                            reason=d.reason, error=d.error))
        if d.error:
            log.emit("error", "dataset", f"{d.error} (failed earlier on these same inputs; --force retries)",
                     stage="build", dataset=d.name, status="failed")
    # here, one after the other: a build only merges what the takes' units made and places their files (a
    # worker would first have to finish what the report gave it). The report's own work in this process waits
    # for the builds: both are Python, and sharing this process's interpreter would only hold up the builds,
    # which the report's dataset jobs on the workers wait for
    for d in todo:
        o = run_dataset(d, layout, params)
        summary.outcomes.append(o)
        if o.status == "ok":
            log.emit("info", "dataset", f"dataset {d.name}: built from {len(d.takes)} takes "
                     f"({o.duration_s:.2f} s)", stage="build", dataset=d.name, status="ok",
                     duration_s=round(o.duration_s, 4))
            for w in o.warnings:
                log.emit("warning", "qc_warning", w, stage="build", dataset=d.name)
            if report is not None:
                report.dataset_built(d.name)
        elif o.status == "skipped":
            log.emit("warning", "dataset", f"dataset {d.name}: {o.reason}", stage="build", dataset=d.name,
                     status="skipped", reason=o.reason)
            if report is not None:
                report.dataset_built(d.name)
        else:
            log.emit("error", "dataset", o.error, stage="build", dataset=d.name, status="failed",
                     traceback=o.traceback or None)
    if report is not None:
        report.takes_done()
    return len(todo)


def _run_sessions(jobs: list[SessionJob], todo: list[SessionJob], summary: RunSummary, log: EventLog,
                  workers: _Workers) -> dict[str, set[str]]:
    """Run the session stages' units that have work (the sessions in parallel on the workers), before any take;
    record every session unit's outcome. Returns, by session id, the session stages that failed (now or before
    on the same inputs): the take units that read them are not run."""
    outcomes: list[UnitOutcome] = []
    for job in jobs:
        if job not in todo:
            outcomes.extend(_not_run(u) for u in job.units)
    if todo:
        parent = os.getpid() if workers.local else None
        for job in todo:
            job.parent_pid = parent
        if workers.kind == "serial":
            done = [run_session_job(job) for job in todo]
        else:
            futures = {workers.executor.submit(run_session_job, job): job for job in todo}
            done = [_session_result(f, futures[f]) for f in as_completed(futures)]
        outcomes.extend(o for out in done for o in out)
    failed: dict[str, set[str]] = {}
    for o in outcomes:
        summary.outcomes.append(o)
        if o.status in ("failed", "blocked"):
            failed.setdefault(o.session, set()).add(o.stage)
        if o.status == "ok":
            log.emit("info", "unit", f"{o.session} (session) {o.stage}: ok ({o.duration_s:.2f} s)",
                     session=o.session, take=o.take, stage=o.stage, status="ok", duration_s=round(o.duration_s, 4))
            for w in o.warnings:
                log.emit("warning", "qc_warning", f"{o.session} (session) {o.stage}: {w}", session=o.session,
                         take=o.take, stage=o.stage)
        elif o.status == "failed":
            log.emit("error", "unit", o.error, session=o.session, take=o.take, stage=o.stage, status="failed",
                     duration_s=round(o.duration_s, 4), traceback=o.traceback or None)
    return failed


def _session_result(fut: Future, job: SessionJob) -> list[UnitOutcome]:
    try:
        return fut.result()
    except Exception as exc:  # the worker itself died
        return [UnitOutcome(u.session, u.take, u.stage, "failed",
                            error=f"session {u.session}: worker died while running ({type(exc).__name__}: {exc})")
                for u in job.units if u.run]


def _execute(todo: list[TakeJob], summary: RunSummary, log: EventLog, workers: _Workers,
             heartbeat_every: int, report: RunReport | None = None) -> None:
    done = 0
    if workers.local:  # local workers stop if this process dies (the lock dies with it)
        for job in todo:
            job.parent_pid = os.getpid()
    ex = workers.executor
    if workers.kind == "serial":  # one take at a time, so progress shows as it happens
        futures = {}
        pending = ((ex.submit(run_take_job, job), job) for job in todo)
    else:
        futures = {ex.submit(run_take_job, job): job for job in todo}
        pending = ((fut, futures[fut]) for fut in as_completed(futures))
    try:
        for fut, job in pending:
            try:
                outcomes = fut.result()
            except Exception as exc:  # the worker itself died (killed, out of memory): the take fails
                outcomes = [UnitOutcome(u.session, u.take, u.stage, "failed",
                                        error=f"take {u.session}/{u.take}: worker died while running ({type(exc).__name__}: {exc})")
                            for u in job.units if u.run]
            done += 1
            summary.outcomes.extend(outcomes)
            for o in outcomes:
                if o.status == "ok":
                    log.emit("info", "unit", f"[{done}/{len(todo)}] {o.session}/{o.take} {o.stage}: ok "
                             f"({o.duration_s:.2f} s)", session=o.session, take=o.take, stage=o.stage,
                             status="ok", duration_s=round(o.duration_s, 4))
                    for w in o.warnings:
                        log.emit("warning", "qc_warning", f"{o.session}/{o.take} {o.stage}: {w}", session=o.session,
                                 take=o.take, stage=o.stage)
                elif o.status == "failed":
                    log.emit("error", "unit", o.error, session=o.session, take=o.take, stage=o.stage,
                             status="failed", duration_s=round(o.duration_s, 4), traceback=o.traceback or None)
                elif o.status == "blocked":
                    log.emit("info", "unit", f"{o.session}/{o.take} {o.stage}: not run (an upstream stage failed)",
                             session=o.session, take=o.take, stage=o.stage, status="blocked")
            if report is not None:
                report.take_finished(job.session, job.take, max(0, len(todo) - done - workers.n))
            log.progress(done, len(todo))
            if heartbeat_every and done % heartbeat_every == 0 and done < len(todo) and not log.interactive:
                log.emit("info", "heartbeat", f"{done}/{len(todo)} takes done", done=done, total=len(todo))
    except KeyboardInterrupt:
        # workers may have finished more than reported here: their records and files are kept all the same
        log.emit("error", "interrupted", f"interrupted after {done} of {len(todo)} takes reported done; "
                 "units that finished are kept and the same command resumes", done=done, total=len(todo),
                 status="interrupted")
        raise


def _not_run(u: UnitPlan) -> UnitOutcome:
    """The outcome of a unit that is not run: up to date, or failed before on the same inputs."""
    status = "failed" if u.error else "skipped"
    return UnitOutcome(u.session, u.take, u.stage, status, reason=u.reason, error=u.error)


def _remember_sessions(layout: OutLayout, sessions: Sequence[SessionLike]) -> None:
    known = read_json(layout.sessions) or {}
    new = dict(known)
    new.update({s.id: s.path for s in sessions})
    if new != known:
        layout.write_json(layout.sessions, new)
