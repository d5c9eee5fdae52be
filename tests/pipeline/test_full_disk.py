"""A full disk: every failure is one line naming the file (and the take or dataset), no internal error, and the
run still ends with its summary (exit 1). Needs a small tmpfs: run as root where mount works, else skipped."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import session_copy


@pytest.fixture
def small_disk(tmp_path: Path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=512k", "tmpfs", str(mnt)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode(errors='replace').strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.parametrize("executor", ["serial", "process"])
def test_a_full_disk_gives_one_line_per_failure_and_the_summary(small_disk: Path, tmp_path: Path,
                                                                executor: str) -> None:
    session = session_copy(tmp_path / "session", {"neutral": None, "shift_y036_p12": None,
                                                    "shift_ym036_p00": "train"})
    res = subprocess.run([sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(small_disk / "out"),
                          "--executor", executor, "-j", "2", "--log-format", "json"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 1, res.stderr[-3000:]
    events = [json.loads(line) for line in res.stderr.splitlines()]   # every line is an event: no traceback
    errors = [e for e in events if e["level"] == "error" and e["event"] != "run_end"]
    assert errors and all("No space left on device" in e["message"] for e in errors)
    assert not any("internal error" in e["message"] or "worker died" in e["message"] for e in events)
    assert all(str(small_disk) in e["message"] for e in errors), "each names the file it could not write"
    assert events[-1]["event"] == "run_end" and events[-1]["message"].startswith("done:")
    io_paths = [e["path"] for e in errors if e["event"] == "io_error"]
    assert len(io_paths) == len(set(io_paths)), "a file the run could not write is reported once"


def test_a_file_the_run_cannot_write_is_reported_once(tmp_path: Path) -> None:
    """The hash cache is written after the takes and again at the end: when the first write hits a full disk,
    the second is not tried, and the file is one error line, not two."""
    import errno
    import io

    from gazepipe.pipeline.engine import RunSummary, _keep
    from gazepipe.pipeline.events import EventLog

    stream = io.StringIO()
    log, summary, tries = EventLog("json", stream), RunSummary("r"), []

    def full() -> None:
        tries.append(1)
        raise OSError(errno.ENOSPC, "No space left on device")

    hashes = tmp_path / ".gazepipe" / "hashes.json"
    _keep(summary, log, hashes, full)
    _keep(summary, log, hashes, full)
    _keep(summary, log, tmp_path / "qc", lambda: None)
    lines = [json.loads(s) for s in stream.getvalue().splitlines()]
    assert len(tries) == 1 and len(summary.io_errors) == 1 and len(lines) == 1
    assert str(hashes) in lines[0]["message"] and "No space left" in lines[0]["message"]
    assert summary.exit_code == 1
