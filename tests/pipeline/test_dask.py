"""The Dask executor gives byte-identical outputs to the serial one (in-process cluster and worker processes)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import SAMPLE, make_tiny_session, output_digests

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


def _worker_settings() -> dict[str, object]:
    import os

    import dask

    got: dict[str, object] = {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")}
    got.update({k: dask.config.get(k) for k in ("distributed.admin.tick.interval", "distributed.worker.profile.enabled")})
    return got


def test_local_cluster_worker_settings():
    # Dask's default MALLOC_TRIM_THRESHOLD_ makes the stages 1.5x slower; the thread limits stay; the cluster's own
    # periodic work (event-loop ticks, stack sampling) is quieted
    import dask

    from gazepipe.pipeline.executors import QUIET_LOCAL_CLUSTER, DaskExecutor

    keys = ["distributed.nanny.pre-spawn-environ", *QUIET_LOCAL_CLUSTER]
    before = {k: dask.config.get(k, None) for k in keys}
    ex = DaskExecutor(workers=1)
    try:
        got = ex.submit(_worker_settings).result(timeout=60)
    finally:
        ex.shutdown()
    assert got == {"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1",
                   "distributed.admin.tick.interval": "1s", "distributed.worker.profile.enabled": False}
    assert before["distributed.admin.tick.interval"] != "1s"  # so the worker did not merely see the default
    # the process's Dask configuration is as it was
    assert {k: dask.config.get(k, None) for k in keys} == before
