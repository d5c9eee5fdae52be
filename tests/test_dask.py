"""The Dask executor gives byte-identical outputs to the serial one (in-process cluster and worker processes)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.conftest import SAMPLE, make_tiny_session
from tests.test_pipeline import output_digests

distributed = pytest.importorskip("distributed", reason="the dask extra is not installed")


def _run(*args: str) -> None:
    res = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    assert res.exit_code == 0, res.stderr


def test_in_process_cluster_matches_serial(tmp_path):
    session = make_tiny_session(tmp_path / "s", n_takes=4)
    serial, dask_out = tmp_path / "serial", tmp_path / "dask"
    _run("ingest", str(session), "--out", str(serial), "--executor", "serial")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        _run("ingest", str(session), "--out", str(dask_out), "--scheduler", cluster.scheduler_address)
    assert output_digests(serial) and output_digests(serial) == output_digests(dask_out)


def test_local_multiprocess_cluster_matches_serial(tmp_path):
    serial, dask_out = tmp_path / "serial", tmp_path / "dask"
    _run("clean", str(SAMPLE), "--out", str(serial), "--executor", "serial")
    _run("clean", str(SAMPLE), "--out", str(dask_out), "--executor", "dask", "-j", "2")
    digests = output_digests(serial)
    assert any(k.endswith("joints.parquet") for k in digests)
    assert digests == output_digests(dask_out)


def _worker_environ() -> dict[str, str | None]:
    import os

    return {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")}


def test_local_cluster_workers_keep_glibc_malloc_defaults():
    # Dask's default MALLOC_TRIM_THRESHOLD_ makes the stages 1.5x slower; the thread limits stay
    import dask

    from gazepipe.pipeline.executors import DaskExecutor

    before = dask.config.get("distributed.nanny.pre-spawn-environ", None)
    ex = DaskExecutor(workers=1)
    try:
        env = ex.submit(_worker_environ).result(timeout=60)
    finally:
        ex.shutdown()
    assert env == {"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1"}
    # the process's Dask configuration is as it was
    assert dask.config.get("distributed.nanny.pre-spawn-environ", None) == before
