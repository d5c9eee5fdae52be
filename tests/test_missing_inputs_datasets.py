"""A dataset whose inputs the session does not have (gaze_rnn on a mocap-only corpus: no eye tracking) is skipped
with one line saying why, not failed: the run exits 0, the report lists it as skipped, the gate does not fail
for it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli


@pytest.fixture(scope="module")
def mocap_only(tmp_path_factory) -> tuple[Path, Path, list[dict]]:
    from gazepipe.synth.session import SynthConfig, generate_session

    root = tmp_path_factory.mktemp("mocap_only")
    cfg = SynthConfig(follow_poses=("standing", "sitting", "standing"), follow_duration_s=15.0, shift_targets=(),
                      face_takes=(), head_camera=False)
    session = generate_session(root / "session", 0, cfg)
    out = root / "out"
    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output[-3000:]
    events = [json.loads(line) for line in res.output.splitlines() if line.startswith("{")]
    return session, out, events


def test_run_skips_the_dataset_with_one_line(mocap_only):
    _, out, events = mocap_only
    lines = [e for e in events if e.get("dataset") == "gaze_rnn"]
    assert len(lines) == 1, lines
    assert lines[0]["level"] in ("info", "warning") and lines[0]["status"] == "skipped"
    assert lines[0]["message"] == "dataset gaze_rnn: skipped: no take has eye tracking"
    assert not (out / "datasets" / "gaze_rnn").exists()
    assert (out / "datasets" / "gaze_rnn_lod").is_dir()           # the mocap-only dataset is built
    end = next(e for e in events if e["event"] == "run_end")
    assert end["failed"] == 0 and end["datasets_failed"] == 0
    assert end["datasets_skipped"] == 1 and "1 skipped (inputs missing)" in end["message"]


def test_report_lists_it_as_skipped_and_the_gate_ignores_it(mocap_only):
    _, out, _ = mocap_only
    report = json.loads((out / "qc" / "report.json").read_text())
    ds = next(d for d in report["datasets"] if d["name"] == "gaze_rnn")
    assert ds["severity"] == "skipped"
    assert "no take has eye tracking" in ds["checks"][0]["message"]
    assert not [h for h in report["gate"]["hit"] if h["target"] == "gaze_rnn"]
    html = (out / "qc" / "report.html").read_text()
    assert "dataset skipped: no take has eye tracking" in html


def test_second_run_is_up_to_date_and_exits_0(mocap_only):
    session, out, _ = mocap_only
    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 0, res.output[-3000:]
    events = [json.loads(line) for line in res.output.splitlines() if line.startswith("{")]
    assert not [e for e in events if e.get("dataset") == "gaze_rnn" and e.get("status") == "failed"]
