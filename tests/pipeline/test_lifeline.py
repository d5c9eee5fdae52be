"""Workers die with their run: when the run's process alone is killed with SIGKILL (what the out-of-memory killer
does), its forkserver, its workers (process or Dask) and multiprocessing's resource tracker are gone within 2 s
(gazepipe.pipeline.lifeline; Linux)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.bench_faults import session_processes
from tests.helpers import session_copy

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signals are Linux's")


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    return session_copy(tmp_path_factory.mktemp("lifeline") / "session",
                         {"neutral": None, "shift_y036_p12": None, "shift_ym036_p00": None, "shift_y000_p12": None})


@pytest.mark.parametrize("executor", ["process", "dask"])
def test_killing_the_run_alone_ends_every_worker(session: Path, tmp_path: Path, executor: str) -> None:
    if executor == "dask":
        pytest.importorskip("distributed")
    cmd = [sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(tmp_path / "out"),
           "--executor", executor, "-j", "2", "--log-format", "json"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, start_new_session=True)
    try:
        for line in proc.stderr:   # the first take unit done (after the session's units): the workers are up
            event = json.loads(line)
            if event.get("event") == "unit" and event.get("take") != "*":
                break
        helpers = [p for p in session_processes(proc.pid) if p != proc.pid]
        assert len(helpers) >= 2, "the run has its workers"
        os.kill(proc.pid, signal.SIGKILL)   # the leader only, not its group
        proc.wait(timeout=10)
        deadline = time.monotonic() + 2.0
        while session_processes(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert session_processes(proc.pid) == [], "no process of the killed run is left 2 s after it died"
    finally:
        left = session_processes(proc.pid)
        if left:
            os.killpg(proc.pid, signal.SIGKILL)
