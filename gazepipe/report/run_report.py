"""The QC report of a run, made as the run goes: each take's checks on the worker that ran the take, as soon as
it ran (:func:`take_part`); the plots of the takes the page will show drawn on the run's workers as soon as
they can be told apart (:func:`draw_take_plots`); each dataset's checks and plots on a worker as soon as it is
built (:func:`dataset_part_job`). Everything goes into the caches of :mod:`gazepipe.report.cache`, so the end
of the run only reads them back and merges (:class:`ReportInBackground`). Whatever was not made ahead (a job
that failed, a serial run) is made at the end, with the same bytes.
"""

from __future__ import annotations

import heapq
import itertools
import threading
from pathlib import Path
from typing import Any

from gazepipe.pipeline.state import OutLayout
from gazepipe.report import checks as C
from gazepipe.report.cache import CheckCache, DatasetCache, FigureCache, ReplayCache
from gazepipe.report.collect import TakeEntry, has_plot_tables, open_output, take_entry
from gazepipe.report.validate import (
    DEFAULT_PLOT_TAKES,
    FAIL_ON,
    PlotRequest,
    TakePass,
    ValidateResult,
    dataset_part,
    finish_report,
    output_checks,
    plot_choice,
    plot_limit,
    take_figures_cached,
    take_pass,
    take_rank_key,
    take_replay_cached,
)

# ------------------------------------------------------------------------------------ jobs for the workers

def take_part(root: str, session: str, take: Any, parent_pid: int | None = None) -> None:
    """One take's output checks into the check cache, with the default thresholds (those of the report a run
    writes): run at the end of the take's units, on the worker that ran them. Writes nothing once the run
    ``parent_pid`` is gone."""
    layout = OutLayout(Path(root))
    output_checks(layout, take_entry(layout, session, take), C.Thresholds(), CheckCache(layout, parent_pid))


def draw_take_plots(root: str, entry: TakeEntry, markerset: Any, parent_pid: int | None = None) -> None:
    """One take's plots into the figure cache, and its 3D replay page into the replay cache."""
    layout = OutLayout(Path(root))
    take_figures_cached(layout, entry, markerset, FigureCache(layout, parent_pid))
    if entry.kind != "face":
        take_replay_cached(layout, entry, markerset, ReplayCache(layout, parent_pid))


def dataset_part_job(root: str, name: str, thresholds: C.Thresholds, parent_pid: int | None = None) -> None:
    """One built dataset's checks and plots into the caches."""
    from gazepipe.report.collect import dataset_records

    layout = OutLayout(Path(root))
    path = layout.root / "datasets" / name
    dataset_part(layout, name, path if path.is_dir() else None, dataset_records(layout).get(name), thresholds,
                 FigureCache(layout, parent_pid), DatasetCache(layout, parent_pid))


# ------------------------------------------------------------------------------------------ the merge

class ReportInBackground:
    """The report of a run that is going on, on its workers ``pool`` (a
    :class:`gazepipe.pipeline.engine.WorkerPool`; ``None``: everything is done by :meth:`finish`).

    The run calls, in order: :meth:`take_finished` for each take whose units are done; :meth:`dataset_built` for
    each dataset built (its checks and plots go to a worker); :meth:`start` when every take and build is done
    (the checks of every take are then gathered in a thread, mostly from the cache the workers filled; then the
    plots the page will show and are not drawn yet go to the workers); :meth:`wait_for_workers` before its
    workers stop; :meth:`finish`, which writes ``qc/`` as
    :func:`gazepipe.report.validate.validate_output` would have.

    The plots are drawn ahead, before every take is done, once no take waits for a worker (the workers would
    otherwise idle while the last takes finish): those of the takes that are the worst so far. A take that
    turns out worse later has its plots drawn after the others; one pushed out has been drawn for nothing.
    At most one job of the report per worker is given to the pool at a time, a dataset's before any plot, so
    the dataset builds, which the end of the run waits for, are never queued behind many plots.

    The caller keeps every take's outputs as they are until :meth:`finish` (a run holds the folder's lock; only
    the datasets may change meanwhile).
    """

    _order = itertools.count()   # ties between jobs of one priority go first come, first served

    def __init__(self, out: str | Path, thresholds: C.Thresholds | None = None,
                 plot_takes: int | str | None = DEFAULT_PLOT_TAKES, pool: Any = None) -> None:
        self.layout = open_output(out)
        self.th = thresholds or C.Thresholds()
        self.plots = PlotRequest(limit=plot_limit(plot_takes))
        self.pool = pool
        self._seen: dict[str, tuple[tuple, TakeEntry, Any]] = {}   # take → (rank key, entry, markerset)
        self._done: TakePass | None = None
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        # jobs waiting for the pool: (priority, order, function, arguments); 0 = a dataset, 1 = a take's plots
        self._cond = threading.Condition()
        self._queue: list[tuple[int, int, Any, tuple]] = []
        self._queued_takes: set[str] = set()
        self._in_flight = 0
        self._closing = False
        self._dispatcher: threading.Thread | None = None
        # nothing is imported in a thread beside the takes: a thread loading an extension module (holding the
        # interpreter lock, waiting for the loader's) while a unit scans the loaded libraries for thread pools
        # (holding the loader's lock, its callback waiting for the interpreter's) hangs the run
        if pool is not None:
            self._dispatcher = threading.Thread(target=self._dispatch, name="gazepipe-report-jobs", daemon=True)
            self._dispatcher.start()

    # ---- the pool

    def _put(self, priority: int, fn: Any, *args: Any) -> None:
        with self._cond:
            heapq.heappush(self._queue, (priority, next(self._order), fn, args))
            self._cond.notify_all()

    def _dispatch(self) -> None:
        while True:
            with self._cond:
                while not (self._queue and self._in_flight < self.pool.workers) and not \
                        (self._closing and not self._queue):
                    self._cond.wait()
                if not self._queue:
                    return
                _, _, fn, args = heapq.heappop(self._queue)
                self._in_flight += 1
            try:
                fut = self.pool.submit(fn, *args)
            except Exception:  # the pool is gone: finish() makes what is missing itself
                self._job_done(None)
                continue
            fut.add_done_callback(self._job_done)

    def _job_done(self, _fut: Any) -> None:
        with self._cond:   # whatever a job did, finish() reads the caches and makes what is missing
            self._in_flight -= 1
            self._cond.notify_all()

    def _draw(self, e: TakeEntry, markerset: Any) -> None:
        with self._cond:
            if e.key in self._queued_takes:
                return
            self._queued_takes.add(e.key)
        self._put(1, draw_take_plots, str(self.layout.root), e, markerset, self.pool.parent_pid)

    # ---- while the takes run

    def take_finished(self, session: Any, take: Any, waiting: int) -> None:
        """A take's units are done; ``waiting`` takes have not started on a worker yet. Ranks the take from the
        checks its worker cached; once no take waits, draws the plots of the worst so far on the workers."""
        if self.pool is None or self.plots.limit == 0:
            return
        e = take_entry(self.layout, session.id, take)
        cache = CheckCache(self.layout)
        found = cache.get(cache.key(e, self.th))
        if found is not None and has_plot_tables(self.layout, e):
            checks = [C.check_stages(e.records)] + found
            rank = take_rank_key({"session": e.session, "take": e.take, "checks": [c.to_dict() for c in checks],
                                  "severity": C.worst([c.severity for c in checks])})
            self._seen[e.key] = (rank, e, getattr(session, "markerset", None))
        if waiting == 0:
            worst = sorted(self._seen, key=lambda k: self._seen[k][0])
            for key in worst if self.plots.limit is None else worst[:self.plots.limit]:
                _, entry, markerset = self._seen[key]
                self._draw(entry, markerset)

    # ---- after the takes

    def start(self) -> None:
        """Every take is done: gather their checks in a thread, then draw the plots still missing."""
        self._thread = threading.Thread(target=self._run, name="gazepipe-report-takes", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._done = take_pass(self.layout, self.th)
            if self.pool is not None:
                _, _, chosen, _ = plot_choice(self.layout, self._done, self.plots)
                by_key = {e.key: e for e in self._done.entries}
                for key in chosen:
                    e = by_key[key]
                    s = self._done.sessions.get(e.session)
                    self._draw(e, s.markerset if s is not None else None)
        except BaseException as exc:  # handed to the caller by finish()
            self._error = exc

    def dataset_built(self, name: str) -> None:
        """Check and draw dataset ``name`` on the workers (nothing without a pool)."""
        if self.pool is not None:
            self._put(0, dataset_part_job, str(self.layout.root), name, self.th, self.pool.parent_pid)

    def wait_for_workers(self) -> None:
        """Wait for the take checks and for what was given to the workers."""
        if self._thread is None:
            self.start()
        assert self._thread is not None
        self._thread.join()
        if self._dispatcher is not None:
            with self._cond:
                self._closing = True
                self._cond.notify_all()
            self._dispatcher.join()
            with self._cond:
                while self._in_flight:
                    self._cond.wait()

    def finish_quietly(self) -> None:
        """Wait for the workers and drop the report (it turned out not to be needed)."""
        self.wait_for_workers()

    def finish(self, fail_on: str = "fail") -> ValidateResult:
        """Wait for the take checks (raising their error, if any) and the workers, then make what is missing and
        write ``qc/``."""
        if fail_on not in FAIL_ON:
            raise ValueError(f"fail_on must be one of {FAIL_ON}")
        self.wait_for_workers()
        if self._error is not None:
            raise self._error
        assert self._done is not None
        return finish_report(self.layout, self.th, fail_on, self.plots, self._done)


__all__ = ["ReportInBackground", "dataset_part_job", "draw_take_plots", "take_part"]
