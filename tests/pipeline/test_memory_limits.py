"""A take the machine cannot clean is refused in one line before it is tried, and running out of memory inside
a stage is one line naming the take and its files: never a process killed or swapping for an hour, never an
"internal error". Neither is the inputs' fault, so the next run tries again."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest

from gazepipe.cli.common import load_sessions
from gazepipe.dag import run_pipeline
from gazepipe.pipeline.events import EventLog
from gazepipe.pipeline.resources import available_memory_bytes
from tests.helpers import session_copy

TAKES = {"neutral": None, "shift_y036_p12": None}


def _run(session: Path, out: Path):
    return run_pipeline(load_sessions((str(session),)), out, until="clean", executor="serial",
                        log=EventLog("json", quiet=True))


def _clean_errors(summary) -> dict[str, str]:
    return {o.take: o.error for o in summary.outcomes if o.stage == "clean" and o.status == "failed"}


def test_the_memory_a_process_may_use_is_known_and_follows_its_limit():
    free = available_memory_bytes()
    assert free is not None and free > 0
    if resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY:
        pytest.skip("this process already runs under an address-space limit")
    code = ("import resource; from gazepipe.pipeline.resources import available_memory_bytes as a, "
            "_address_space_bytes as used\n"
            "resource.setrlimit(resource.RLIMIT_AS, (used() + (64 << 20), resource.RLIM_INFINITY))\n"
            "print(a())")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert 0 <= int(res.stdout) <= 64 << 20     # ulimit -v: what is left under it, whatever the machine has


def test_a_take_too_large_to_clean_is_refused_then_tried_again(tmp_path, monkeypatch):
    session = session_copy(tmp_path / "s", TAKES)
    out = tmp_path / "out"
    monkeypatch.setattr("gazepipe.pipeline.resources.available_memory_bytes", lambda: 1 << 20)
    summary = _run(session, out)
    errors = _clean_errors(summary)
    assert set(errors) == set(TAKES), errors
    msg = errors["shift_y036_p12"]
    assert "shift_y036_p12.c3d" in msg and "marker samples need about" in msg and "more than the 1 MiB free" in msg, msg
    assert "\n" not in msg and "internal error" not in msg
    assert summary.exit_code == 1
    monkeypatch.undo()     # the machine has the memory now: the same inputs are cleaned, not skipped
    again = _run(session, out)
    assert _clean_errors(again) == {}
    assert {o.take for o in again.outcomes if o.stage == "clean" and o.status == "ok"} == set(TAKES)


def test_running_out_of_memory_in_a_stage_is_one_line_naming_the_take_and_its_files(tmp_path, monkeypatch):
    session = session_copy(tmp_path / "s", TAKES)

    def no_memory(*args, **kwargs):
        raise MemoryError()

    monkeypatch.setattr("gazepipe.stages.clean.stage.clean_markers", no_memory)
    errors = _clean_errors(_run(session, tmp_path / "out"))
    assert set(errors) == set(TAKES)
    msg = errors["shift_y036_p12"]
    assert msg.startswith("take ") and "shift_y036_p12: stage clean: out of memory" in msg, msg
    assert "mocap/shift_y036_p12.c3d" in msg and "internal error" not in msg and "\n" not in msg


def test_a_take_too_long_to_plot_is_left_out_of_the_plots_with_a_note(tmp_path, monkeypatch):
    """A take's plots read its whole raw markers; past PLOT_MAX_SAMPLES the report says so instead of
    spending gigabytes on a 20-hour capture."""
    from gazepipe.report.validate import validate_output

    session = session_copy(tmp_path / "s", TAKES)
    out = tmp_path / "out"
    _run(session, out)
    monkeypatch.setattr("gazepipe.report.validate.PLOT_MAX_SAMPLES", 1000)   # neutral: 120 x 35 samples
    validate_output(out)
    html = (out / "qc" / "report.html").read_text()
    assert "not drawn: 4,200 marker samples, more than the 1,000 a take&#x27;s plots read" in html or \
        "not drawn: 4,200 marker samples, more than the 1,000 a take's plots read" in html
