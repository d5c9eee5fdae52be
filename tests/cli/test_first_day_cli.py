"""The command line as the README teaches it: ``--debug`` before or after any command, the QC gate on
``run``'s last lines, ``params`` once per parameter, the stage commands' own help, ``inspect`` on C3D
storage and on files that are not captures."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import TESTS


def invoke(*args: str, **kw):
    return CliRunner().invoke(cli, list(args), **kw)


# ------------------------------------------------------------------------------------------------ --debug

def test_every_command_shows_and_accepts_debug():
    for name, command in cli.commands.items():
        text = invoke(name, "--help", terminal_width=200).output
        assert "--debug" in text and "Show tracebacks" in text, name
        assert sum(p.name == "debug" for p in command.params) == 1, name


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_before_or_after_the_command_shows_the_traceback(tmp_path, monkeypatch, where):
    import gazepipe.io.inspect_tracks as it

    def broken(*a, **k):
        raise RuntimeError("a bug")

    monkeypatch.setattr(it, "inspect_file", broken)
    f = tmp_path / "a.c3d"
    f.write_bytes(b"x")
    res = invoke("inspect", str(f))
    assert res.exit_code == 1
    assert res.stderr.strip() == "error: internal error: RuntimeError: a bug (run with --debug for the traceback)"
    args = ["--debug", "inspect", str(f)] if where == "before" else ["inspect", str(f), "--debug"]
    res = invoke(*args)
    assert res.exit_code == 1 and "Traceback (most recent call last)" in res.stderr
    assert "raise RuntimeError" in res.stderr and "run with --debug" not in res.stderr


def test_debug_after_a_stage_command_is_accepted(tmp_path):
    res = invoke("run", str(tmp_path / "none"), "--out", str(tmp_path / "o"), "--debug")
    assert "No such option" not in res.output
    res = invoke("run", "--debug", "--help")
    assert res.exit_code == 0


# ---------------------------------------------------------------------------------------- QC gate at the end

def _fake_run(monkeypatch, gate: dict | None, exit_code: int = 0):
    """``run_pipeline`` replaced by one that writes ``qc/report.json`` with ``gate`` and ends as given."""
    import json
    import types

    import gazepipe.cli.main as main
    import gazepipe.dag

    gazepipe.dag.declare()   # the stages and their parameters

    def run_pipeline(sessions, out, **kw):
        if gate is not None:
            (Path(out) / "qc").mkdir(parents=True, exist_ok=True)
            (Path(out) / "qc" / "report.json").write_text(json.dumps({"gate": gate}))
        return types.SimpleNamespace(failed=[], exit_code=exit_code,
                                     end_message=lambda: ("done: 3 take units ran, 0 up to date, 0 failed",
                                                                  {"up_to_date": 0}))

    monkeypatch.setattr(gazepipe.dag, "run_pipeline", run_pipeline)
    monkeypatch.setattr(main, "load_sessions", lambda paths: [])


def test_run_says_on_its_last_lines_that_the_qc_gate_would_fail(tmp_path, monkeypatch):
    hit = [{"scope": "take", "target": f"s01/t{i}", "id": "sync_residual", "severity": "fail", "message": "m"}
           for i in range(5)]
    _fake_run(monkeypatch, {"fail_on": "fail", "passed": False, "hit": hit})
    out = tmp_path / "o"
    res = invoke("run", str(tmp_path), "--out", str(out), "--log-format", "text")
    assert res.exit_code == 0, res.output
    lines = res.stderr.splitlines()
    assert lines[-1].startswith("done: ")
    assert lines[-2] == (f"warning: QC gate: would fail (5 checks at fail: sync_residual (s01/t0), sync_residual "
                         f"(s01/t1), sync_residual (s01/t2), 2 more); see {out / 'qc' / 'report.html'}")


def test_run_says_nothing_of_a_gate_that_passes(tmp_path, monkeypatch):
    _fake_run(monkeypatch, {"fail_on": "fail", "passed": True, "hit": []})
    res = invoke("run", str(tmp_path), "--out", str(tmp_path / "o"), "--log-format", "text")
    assert res.exit_code == 0 and "QC gate" not in res.output
    _fake_run(monkeypatch, None, exit_code=1)   # no report: nothing to say
    res = invoke("run", str(tmp_path), "--out", str(tmp_path / "o2"), "--log-format", "text")
    assert res.exit_code == 1 and "QC gate" not in res.output


# ------------------------------------------------------------------------------------------------- params

def test_params_says_each_thing_once_in_words_for_users():
    import gazepipe.dag
    from gazepipe.pipeline.registry import default_params

    gazepipe.dag.declare()   # the stages and their parameters

    lines = invoke("params").stdout.splitlines()
    comments = [ln for ln, nxt in zip(lines, lines[1:] + [""], strict=True)
                if ln.startswith("# ") and re.match(r"(# )?\w+\.\w+ = ", nxt)]
    assert len(comments) == len(default_params())
    assert len(set(comments)) == len(comments)          # no explanation repeated
    assert not [c for c in comments if "()" in c or len(c) > 110]   # no function names, short
    assert "# longest gap, in s, that gets filled; longer gaps stay gaps" in lines


# ------------------------------------------------------------------------------------ README torch example

def test_readme_torch_comment_is_what_the_example_prints_on_the_sample(sample_run, tmp_path, monkeypatch):
    import contextlib
    import io
    import runpy

    pytest.importorskip("torch")
    example = TESTS / "readme_examples" / "torch_example.py"
    said = re.search(r"# on the sample: (.*)$", example.read_text(), re.M)
    assert said is not None
    (tmp_path / "out").symlink_to(sample_run)
    monkeypatch.chdir(tmp_path)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        runpy.run_path(str(example), run_name="__main__")
    assert printed.getvalue().strip() == said.group(1).strip()


# ------------------------------------------------------------------------------------------------ inspect

CORPUS = TESTS / "data" / "corpus" / "c3d"
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + bytes(range(256)) * 8


@pytest.mark.parametrize("name, data, what", [
    ("shot.png", PNG, "a PNG image"),
    ("shot.c3d", PNG, "a PNG image"),
    ("notes.pdf", b"%PDF-1.7\n" + bytes(600), "a PDF document"),
    ("blob.dat", b"\x02\x50" + bytes(range(256)) * 4, "binary data, neither a C3D file nor a text export"),
])
def test_inspect_says_a_file_is_not_a_capture_in_one_line(tmp_path, name, data, what):
    f = tmp_path / name
    f.write_bytes(data)
    res = invoke("inspect", str(f))
    assert res.exit_code == 1
    assert res.stderr.count("\n") == 1 and res.stdout == ""
    assert res.stderr.startswith(f"error: {f}: not a capture file ({what}; inspect reads C3D")
    assert "processor" not in res.stderr


def test_inspect_shows_a_c3ds_processor_storage_scale_and_analog_channels():
    import json

    res = invoke("inspect", str(CORPUS / "gait-raw.c3d"))
    assert res.exit_code == 0, res.output
    assert ("  processor dec, storage integer (POINT:SCALE 0.166829 mm per unit), 30 analog channels at 800 Hz"
            in res.stdout.splitlines())
    res = invoke("inspect", str(CORPUS / "Eb015pr.c3d"), "--json")
    info = json.loads(res.stdout)
    assert {k: info[k] for k in ("processor", "storage", "analog_channels", "analog_rate_hz")} == {
        "processor": "intel", "storage": "float", "analog_channels": 16, "analog_rate_hz": 200.0}
    assert info["point_scale"] == pytest.approx(-0.0833333)
    res = invoke("inspect", "sample_data/session01/mocap/neutral.c3d")
    assert "storage float (POINT:SCALE -1, applied to residuals only), 0 analog channels" in res.stdout


# ------------------------------------------------------------------------------------------ stage helps

@pytest.mark.parametrize("name, writes, not_written", [
    ("ingest", "markers_raw.parquet", "no dataset or QC report"),
    ("clean", "joints", "no sync, eyes, face, dataset or QC report"),
    ("build", "OUT/datasets/<name>/", "no QC report"),
    ("run", "OUT/qc/", None),
])
def test_each_stage_command_says_what_it_does_and_writes(name, writes, not_written):
    def summary(cmd: str) -> str:
        text = invoke(cmd, "--help", terminal_width=400).output
        return " ".join(text.split("Examples:")[0].split("\n", 1)[1].split())

    own = summary(name)
    assert "Writes OUT/" in own and writes in own
    if not_written:
        assert not_written in own and own != summary("run")


def test_fill_says_a_png_is_not_a_capture_in_one_line(tmp_path):
    """A PNG begins with bytes a loose C3D test takes for one; ``fill`` names what it is instead."""
    src = tmp_path / "shot.png"
    src.write_bytes(PNG)
    res = invoke("fill", str(src), str(tmp_path / "filled.png"))
    assert res.exit_code != 0 and not (tmp_path / "filled.png").exists()
    assert res.stderr.count("\n") == 1
    assert res.stderr.startswith(f"error: {src}: not a capture file (a PNG image;")
