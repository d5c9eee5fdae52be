"""Executors behind one ``concurrent.futures`` interface: serial, local processes, Dask distributed.

Each submits the same picklable job function; results are identical whatever runs them.
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import os
from collections.abc import Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor

from gazepipe.errors import ConfigError
from gazepipe.pipeline.lifeline import worker_initializer

EXECUTORS = ("serial", "process", "dask")
#: the preload module that makes a helper process die with its parent (:mod:`gazepipe.pipeline.lifeline`)
LIFELINE = "gazepipe.pipeline.lifeline_preload"

#: how to get the Dask executor, said when it is asked for and missing
DASK_INSTALL = "pip install 'gazepipe[dask]' (in a source checkout: pip install -e \".[dask]\")"


class SerialExecutor(Executor):
    """Runs each job in the calling process when it is submitted."""

    def submit(self, fn, /, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered through the future, as other executors do
            fut.set_exception(exc)
        return fut


#: Dask settings of the local cluster that keep its own threads out of the workers' way. By default every server
#: wakes every 20 ms to time its event loop, a worker samples its task's stack every 10 ms for a dashboard this
#: cluster does not start, and memory and system monitors poll every 0.1-0.5 s: 3-6 % of each busy worker's CPU
#: (measured on a pure-Python task), taken from the task thread and the other worker. Quieter, under 1 %.
QUIET_LOCAL_CLUSTER = {
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


class DaskExecutor(Executor):
    """A ``dask.distributed`` client as an executor: a local cluster, or an existing scheduler's address."""

    def __init__(self, scheduler: str | None = None, workers: int | None = None,
                 preload: Sequence[str] = ()) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError(None, f"--executor dask needs the dask extra: {DASK_INSTALL}") from None
        if scheduler:
            self._cluster = None
            try:
                self._client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(None, f"cannot reach Dask scheduler {scheduler} ({exc})") from None
        else:
            import dask

            # Dask's nannies start workers with MALLOC_TRIM_THRESHOLD_=65536. Setting it also fixes glibc's mmap
            # threshold, so every numpy temporary over 128 KiB is mapped and unmapped afresh (page faults each
            # time): takes ran 1.5x slower in such workers. They keep the thread limits. (Set for the cluster's
            # life: a nanny that restarts a worker reads it again.)
            environ = {k: v for k, v in (dask.config.get("distributed.nanny.pre-spawn-environ", None) or {}).items()
                       if k != "MALLOC_TRIM_THRESHOLD_"}
            self._config = dask.config.set({"distributed.nanny.pre-spawn-environ": environ, **QUIET_LOCAL_CLUSTER})
            try:
                # each worker process dies with this one (gazepipe.pipeline.lifeline)
                self._cluster = LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1,
                                             processes=True, dashboard_address=None,
                                             preload=[LIFELINE, *preload])
                self._client = Client(self._cluster)
            except BaseException:
                self._config.__exit__(None, None, None)
                raise

    def submit(self, fn, /, *args, **kwargs) -> Future:
        # pure=False: a job writes files; never let Dask dedupe or cache it
        dfut = self._client.submit(fn, *args, pure=False, **kwargs)
        fut: Future = Future()

        def _done(df) -> None:
            try:
                fut.set_result(df.result())
            except BaseException as exc:
                fut.set_exception(exc)

        dfut.add_done_callback(_done)
        return fut

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()
            self._config.__exit__(None, None, None)


def check_executor(kind: str, scheduler: str | None = None) -> None:
    """Refuse at once (:class:`ConfigError`, exit 2) an executor that cannot start here: ``dask`` (or any
    ``scheduler``) without dask and distributed installed. Looks the modules up without importing them."""
    if kind != "dask" and not scheduler:
        return
    missing = [m for m in ("dask", "distributed") if not _importable(m)]
    if missing:
        raise ConfigError(None, f"--executor dask needs the dask extra ({' and '.join(missing)} not installed): "
                                f"{DASK_INSTALL}")


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):   # a broken install, or a module set to None in sys.modules
        return False


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def make_executor(kind: str, jobs: int | None = None, scheduler: str | None = None,
                  preload: Sequence[str] = ()) -> Executor:
    """Build the executor named ``kind`` (``serial``, ``process`` or ``dask``). ``preload``: modules each worker
    imports before its first job (a local cluster's workers; with ``process``, the forkserver imports them once
    and every worker it forks shares them, which spares each worker seconds of imports)."""
    if scheduler and kind != "dask":
        kind = "dask"
    if kind == "serial" or (kind == "process" and (jobs or default_workers()) == 1):
        return SerialExecutor()
    if kind == "process":
        # forkserver: workers do not inherit the parent's threads or locks. The forkserver dies with this
        # process and the workers with the forkserver (gazepipe.pipeline.lifeline)
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload([LIFELINE, *preload])
        return ProcessPoolExecutor(max_workers=jobs or default_workers(), mp_context=ctx,
                                   initializer=worker_initializer)
    if kind == "dask":
        return DaskExecutor(scheduler, jobs, preload)
    raise ConfigError(None, f"unknown executor '{kind}' (choose from {', '.join(EXECUTORS)})")
