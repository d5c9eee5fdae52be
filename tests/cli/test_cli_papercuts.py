"""Command-line papercuts: `status` (header, datasets by name, the lock's holder), unit counts that agree from a
run's start to its end, a missing Dask extra refused at once, `fill` not overwriting, model file modes,
`params` meanings, `inspect` on OpenFace and Live Link Face CSVs, and JSON floats rounded to what they mean."""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import CORPUS, SAMPLE

ISO_UTC = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ"


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args), catch_exceptions=False)


def events(stderr: str) -> list[dict]:
    return [json.loads(line) for line in stderr.splitlines() if line.startswith("{")]


def make_face_session(root: Path) -> Path:
    """A session of one face take (the sample's face_01): one take unit and one dataset, built in about 2 s."""
    (root / "face").mkdir(parents=True)
    for name in ("face_01_tracked.csv", "face_01_clean.csv"):
        shutil.copy(SAMPLE / "face" / name, root / "face" / name)
    (root / "session.toml").write_text(textwrap.dedent("""\
        schema = 1
        [session]
        id = "faces"
        subject = "p01"

        [[takes]]
        id = "face_01"
        kind = "face"
        tracked = "face/face_01_tracked.csv"
        clean = "face/face_01_clean.csv"
        rate_hz = 60
        timecode_fps = 60
        """))
    return root


@pytest.fixture(scope="module")
def face_session(tmp_path_factory) -> Path:
    return make_face_session(tmp_path_factory.mktemp("faces") / "session")


@pytest.fixture(scope="module")
def built(face_session, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("built") / "out"
    res = invoke("build", str(face_session), "--out", str(out), "--executor", "serial", "--log-format", "json")
    assert res.exit_code == 0, res.stderr[-2000:]
    return out


def dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


# ------------------------------------------------------------------------------------------ 1. status

def test_status_prints_a_header_and_names_datasets_plainly(built):
    res = invoke("status", str(built))
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].split() == ["take", "or", "dataset", "stage", "state", "detail"]
    assert any(re.fullmatch(r"faces/face_01\s+face\s+ok", ln) for ln in lines), lines
    assert any(re.fullmatch(r"dataset face_clean\s+build\s+ok", ln) for ln in lines), lines
    assert "-/dataset" not in res.stdout and "a run is in progress" not in res.stdout
    assert lines[-1] == "take units: 2 ok; datasets: 1 ok"   # face, rows_face_clean
    doc = json.loads(invoke("status", str(built), "--json").stdout)
    assert doc["lock"] is None
    assert [(d["dataset"], d["state"]) for d in doc["datasets"]] == [("face_clean", "ok")]
    assert "session" not in doc["datasets"][0] and "take" not in doc["datasets"][0]
    assert [(u["session"], u["take"], u["stage"]) for u in doc["units"]] == [("faces", "face_01", "face"),
                                                                            ("faces", "face_01", "rows_face_clean")]
    assert doc["counts"] == {"units": {"ok": 2, "failed": 0, "stale": 0, "pending": 0},
                             "datasets": {"ok": 1, "failed": 0, "stale": 0, "pending": 0}}


def test_status_names_the_run_that_holds_the_lock(built, face_session):
    from gazepipe.pipeline.lock import OutputLock, lock_state
    from gazepipe.pipeline.state import OutLayout

    lock = OutLayout(built).lock
    with OutputLock(lock):
        holder = lock_state(lock)
        res = invoke("status", str(built))
        doc = json.loads(invoke("status", str(built), "--json").stdout)
        second = invoke("build", str(face_session), "--out", str(built), "--executor", "serial")
    assert holder is not None and holder.state == "held" and holder.pid == os.getpid()
    assert re.fullmatch(ISO_UTC, holder.started)
    first = res.stdout.splitlines()[0]
    assert first.startswith(f"a run is in progress (pid {os.getpid()}, started {holder.started})"), first
    assert doc["lock"]["state"] == "held" and doc["lock"]["pid"] == os.getpid()
    assert doc["lock"]["started"] == holder.started
    assert second.exit_code == 75 and f"pid {os.getpid()}, started {holder.started}" in second.stderr
    # let go: the file says nobody holds it
    assert lock_state(lock) is None and lock.read_bytes() == b""
    assert "a run is in progress" not in invoke("status", str(built)).stdout


@pytest.mark.parametrize("pid", ["dead", "reused"])
def test_a_stale_lock_is_reported_as_stale_then_taken_over(pid, face_session, tmp_path):
    """A run killed outright leaves its name in the lock file: its pid is dead (or, later, another process's
    that does not hold the lock). Status says stale, not in progress; the next run takes the lock over."""
    from gazepipe.pipeline.lock import lock_state
    from gazepipe.pipeline.state import OutLayout

    out = tmp_path / "out"
    assert invoke("build", str(face_session), "--out", str(out), "--executor", "serial").exit_code == 0
    lock = OutLayout(out).lock
    who = dead_pid() if pid == "dead" else os.getpid()
    lock.write_text(json.dumps({"pid": who, "started": "2024-01-02T03:04:05Z", "host": os.uname().nodename}))
    assert lock_state(lock).state == "stale"
    res = invoke("status", str(out))
    first = res.stdout.splitlines()[0]
    assert first.startswith(f"stale lock: the run that held this output folder (pid {who}, started "
                            "2024-01-02T03:04:05Z) is gone"), first
    assert "in progress" not in res.stdout
    assert json.loads(invoke("status", str(out), "--json").stdout)["lock"]["state"] == "stale"
    res = invoke("build", str(face_session), "--out", str(out), "--executor", "serial")
    assert res.exit_code == 0, res.stderr
    assert lock_state(lock) is None and "stale" not in invoke("status", str(out)).stdout


# --------------------------------------------------------------------------------------- 2. unit counts

def test_a_run_counts_the_same_units_at_its_start_and_its_end(face_session, tmp_path):
    """`run_start` counts the take units it runs, `run_end` the take units that ran, apart from the datasets."""
    out = tmp_path / "out"
    res = invoke("build", str(face_session), "--out", str(out), "--executor", "serial", "--log-format", "json")
    assert res.exit_code == 0, res.stderr
    ev = events(res.stderr)
    start = next(e for e in ev if e["event"] == "run_start")
    end = next(e for e in ev if e["event"] == "run_end")
    units_ok = [e for e in ev if e["event"] == "unit" and e.get("status") == "ok"]
    built_ds = [e for e in ev if e["event"] == "dataset" and e.get("status") == "ok"]
    assert start["units"] == end["ran"] == len(units_ok) == 2   # face, rows_face_clean
    assert end["datasets_built"] == len(built_ds) == 1
    assert start["message"].startswith("running 2 take units on 1 takes")
    assert end["message"] == ("done: 2 take units ran, 0 up to date, 0 failed; "
                              "datasets: 1 built, 0 up to date, 0 failed")
    again = events(invoke("build", str(face_session), "--out", str(out), "--executor", "serial",
                          "--log-format", "json").stderr)
    idle = next(e for e in again if e["event"] == "nothing_to_do")
    end = next(e for e in again if e["event"] == "run_end")
    assert idle["units"] == end["up_to_date"] == 2 and idle["datasets"] == end["datasets_up_to_date"] == 1
    assert end["ran"] == 0 and end["datasets_built"] == 0


# ----------------------------------------------------------------------------------- 3. dask extra missing

@pytest.mark.parametrize("extra", [["--executor", "dask"], ["--executor", "dask", "--dry-run"],
                                   ["--scheduler", "tcp://127.0.0.1:1"]])
@pytest.mark.parametrize("missing", ["distributed", "dask"])
def test_executor_dask_without_the_extra_is_refused_at_once(extra, missing, tiny_session, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, missing, None)   # as if not installed: importing it fails
    out = tmp_path / "out"
    res = invoke("ingest", str(tiny_session), "--out", str(out), *extra)
    assert res.exit_code == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --executor dask needs the dask extra"), lines
    assert "pip install 'gazepipe[dask]'" in lines[0] and 'pip install -e ".[dask]"' in lines[0]
    assert not out.exists()   # nothing ran, not even the lock


def test_run_pipeline_refuses_a_missing_dask_before_taking_the_lock(tiny_session, tmp_path, monkeypatch):
    from gazepipe.dag import run_pipeline
    from gazepipe.errors import ConfigError
    from gazepipe.io.session_toml import load_session

    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ConfigError, match=r"gazepipe\[dask\]"):
        run_pipeline([load_session(str(tiny_session))], tmp_path / "out", executor="dask", dry_run=True)
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------------------------- 4. fill --force

def test_fill_refuses_to_overwrite_an_existing_out_unless_forced(tmp_path):
    src, dest = tmp_path / "in.c3d", tmp_path / "out.c3d"
    shutil.copy(CORPUS / "c3d" / "gait-raw.c3d", src)
    dest.write_bytes(b"an earlier result")
    res = invoke("fill", str(src), str(dest))
    assert res.exit_code == 2
    assert res.stderr.strip() == f"error: {dest}: OUT exists: give --force to overwrite it, or another file name"
    assert dest.read_bytes() == b"an earlier result"
    res = invoke("fill", str(src), str(dest), "--force")
    assert res.exit_code == 0, res.stderr
    from gazepipe.io.capture import read_markers

    assert read_markers(dest).n_frames == read_markers(src).n_frames
    # no temporary left behind; the sidecar lists the filled samples (24 of gait-raw's measured ones have a
    # residual byte of 0, as a filled one has)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.c3d", "out.c3d", "out.c3d.gazepipe.json"]


# ------------------------------------------------------------------------------------- 5. model modes

@pytest.fixture
def umask():
    """Set the process's umask for a test, restored after."""
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o027, 0o640)])
def test_model_files_get_the_usual_mode_less_the_umask(mask, mode, umask, tmp_path):
    from gazepipe.trainers.base import save_model_json, write_atomic

    umask(mask)
    write_atomic(tmp_path / "m" / "weights.npz", b"weights")
    data = SimpleNamespace(info={"name": "gaze_map"}, path=tmp_path / "data")
    path = save_model_json(tmp_path / "m", "gaze_map", {}, {}, data, "weights.npz")
    for p in (tmp_path / "m" / "weights.npz", path):
        assert stat.S_IMODE(p.stat().st_mode) == mode, (p, oct(p.stat().st_mode))
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["model.json", "weights.npz"]
    write_atomic(tmp_path / "m" / "weights.npz", b"new")           # replaced whole, mode kept
    assert (tmp_path / "m" / "weights.npz").read_bytes() == b"new"
    assert stat.S_IMODE((tmp_path / "m" / "weights.npz").stat().st_mode) == mode


def test_a_trained_torch_model_is_saved_with_mode_0644(built, umask, tmp_path):
    pytest.importorskip("torch")
    from gazepipe.cli.train import train

    umask(0o022)
    res = CliRunner().invoke(train, ["face_clean", "--data", str(built / "datasets" / "face_clean"), "--out",
                                     str(tmp_path / "m"), "--epochs", "1", "--option", "max_windows=2",
                                     "--option", "threads=1"])
    assert res.exit_code == 0, res.output[-2000:]
    files = sorted((tmp_path / "m").iterdir())
    assert [p.name for p in files] == ["face_clean.pt", "model.json"]
    assert [oct(stat.S_IMODE(p.stat().st_mode)) for p in files] == [oct(0o644)] * 2


# ---------------------------------------------------------------------------------- 6. params meanings

def test_every_parameter_of_every_stage_has_a_meaning():
    """From the docstring of the class (or function) declaring it: a new undocumented parameter fails here."""
    import gazepipe.dag
    from gazepipe.cli.param_help import param_meanings
    from gazepipe.pipeline.registry import default_params

    gazepipe.dag.declare()   # the stages and their parameters

    meanings = param_meanings()
    missing = [k for k in default_params() if not meanings.get(k, "").strip()]
    assert missing == []
    assert meanings["clean.max_gap_s"] == "longest gap (s) that gets filled; longer gaps stay unfilled."
    assert meanings["build.train_frac"] == meanings["build.val_frac"]    # documented together
    assert "``" not in "".join(meanings.values()) and ":func:" not in "".join(meanings.values())


def test_params_prints_each_meaning_above_its_parameter():
    import gazepipe.dag
    from gazepipe.cli.param_help import user_help
    from gazepipe.pipeline.registry import default_params

    gazepipe.dag.declare()   # the stages and their parameters

    lines = invoke("params").stdout.splitlines()
    meanings = user_help()
    for key in default_params():
        i = next(i for i, ln in enumerate(lines) if re.match(rf"(# )?{re.escape(key)} = ", ln))
        assert lines[i - 1] == f"# {meanings[key]}", key
    assert "(not documented)" not in "\n".join(lines)


def test_docstring_entries_and_first_sentence():
    from gazepipe.cli.param_help import docstring_entries, first_sentence

    doc = """Summary line.

    Attributes
    ----------
    a, b : shared text (with ``code``, e.g. this). Second sentence.
    c : spans
        two lines.
    """
    got = docstring_entries(doc)
    assert got == {"a": "shared text (with ``code``, e.g. this). Second sentence.", "b": got["a"],
                   "c": "spans two lines."}
    assert first_sentence(got["a"]) == "shared text (with code, e.g. this)."
    assert first_sentence("see :func:`gazepipe.x.fill` (Pejsa. Later). End") == "see fill() (Pejsa. Later)."


# --------------------------------------------------------------------------------------- 7. inspect tracks

def _inspect_json(path: Path, *extra: str) -> dict:
    res = invoke("inspect", str(path), "--json", *extra)
    assert res.exit_code == 0, res.stderr
    return json.loads(res.stdout)


@pytest.mark.parametrize("path", [SAMPLE / "eyes" / "follow_sitting_01.csv",
                                  CORPUS / "openface" / "pyfeat_OpenFace_Test.csv"])
def test_inspect_summarises_an_openface_csv(path):
    df = pd.read_csv(path, skipinitialspace=True)
    df.columns = [c.strip() for c in df.columns]
    info = _inspect_json(path)
    assert info["format"] == "openface" and info["rows"] == len(df)
    valid = (df["success"] == 1) & (df["confidence"] >= 0.8)
    assert info["valid_share"] == pytest.approx(valid.mean(), abs=1e-6)
    assert info["blink_share"] == pytest.approx((df["AU45_c"] == 1).mean(), abs=1e-6)
    assert info["blink_rule"] == "AU45_c == 1" and "confidence >= 0.8" in info["valid_rule"]
    frames = df["frame"].to_numpy()
    rate = (frames[-1] - frames[0]) / (df["timestamp"].iloc[-1] - df["timestamp"].iloc[0])
    assert info["rate_hz"] == pytest.approx(rate, rel=1e-3)
    assert info["duration_s"] == pytest.approx((frames[-1] - frames[0] + 1) / info["rate_hz"], abs=1e-5)
    text = invoke("inspect", str(path)).stdout
    assert f"{info['rows']} rows at {info['rate_hz']:g} Hz" in text
    assert f"valid {100 * info['valid_share']:.1f} % (success == 1 and confidence >= 0.8)" in text
    assert f"blinks {100 * info['blink_share']:.1f} % (AU45_c == 1" in text


def test_inspect_sample_openface_rate_and_period():
    info = _inspect_json(SAMPLE / "eyes" / "follow_sitting_01.csv")
    assert info["rate_hz"] == 60.0 and info["frame_period_s"] == 0.016667 and info["missing_frames"] == 0


@pytest.mark.parametrize("name, head", [("face_01_tracked.csv", True), ("face_02_tracked.csv", False)])
def test_inspect_summarises_a_live_link_face_csv(name, head):
    path = SAMPLE / "face" / name
    df = pd.read_csv(path)
    info = _inspect_json(path)
    assert info["format"] == "livelinkface" and info["rows"] == len(df)
    left, right = df["EyeBlinkLeft"] > 0.5, df["EyeBlinkRight"] > 0.5
    assert info["blink_share"] == pytest.approx((left | right).mean(), abs=1e-6)
    assert info["blink_left_share"] == pytest.approx(left.mean(), abs=1e-6)
    assert info["blink_rule"] == "eyeBlinkLeft or eyeBlinkRight > 0.5"
    assert info["head_columns"] is True
    varies = bool(np.ptp(df[["HeadYaw", "HeadPitch", "HeadRoll"]].to_numpy(), axis=0).max() > 0)
    assert info["head_tracking"] is head is varies
    assert (info["head_range_deg"] is not None) is head
    assert info["duration_s"] == pytest.approx((info["rows"] + info["dropped_frames"]) / info["rate_hz"])
    text = invoke("inspect", str(path)).stdout
    assert ("head tracking on" if head else "head tracking off") in text
    assert f"{info['rows']} rows at {info['rate_hz']:g} Hz" in text


def test_inspect_live_link_face_rate_given_and_corpus_file():
    info = _inspect_json(CORPUS / "livelinkface" / "alex_rom_3_first300.csv", "--rate-hz", "30")
    assert info["rate_hz"] == 30.0 and info["rows"] == 300 and info["head_tracking"] is False
    assert not any("capture rate not given" in w for w in info["warnings"])


@pytest.mark.parametrize("kind", ["openface", "livelinkface"])
def test_inspect_of_a_bad_track_is_one_line(kind, tmp_path):
    src = SAMPLE / ("eyes/follow_sitting_01.csv" if kind == "openface" else "face/face_01_tracked.csv")
    lines = src.read_text().splitlines()
    cells = lines[5].split(",")
    cells[3] = "garbage"
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([*lines[:5], ",".join(cells), *lines[6:]]) + "\n")
    for args in (["inspect", str(bad)], ["inspect", str(bad), "--json"]):
        res = invoke(*args)
        assert res.exit_code == 1 and res.stdout == ""
        err = res.stderr.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in res.stderr, err
        if "--json" in args:                  # under --json the one line is a JSON object
            line = json.loads(err[0])["error"]["message"]
        else:
            assert err[0].startswith("error: ")
            line = err[0].removeprefix("error: ")
        assert line.startswith(str(bad))
        assert "non-numeric value 'garbage' in data row 5" in line   # the reader's own complaint


# ---------------------------------------------------------------------------------- 8. JSON floats

def test_json_floats_are_rounded_to_what_they_mean():
    from gazepipe.cli.jsonout import rounded

    got = rounded({"rate_hz": 29.97002997002997, "duration_s": 4.0040000000000004, "frame_period_s":
                   0.06666666666666665, "markers": [{"gap_fraction": 0.04166666666666663}], "offset_mm": 1.23456,
                   "head_range_deg": {"yaw": 12.3456789}, "frames": 120, "flag": True, "other": 1.0 / 3.0,
                   "nan_s": float("nan")})
    assert got["rate_hz"] == 29.97 and got["duration_s"] == 4.004 and got["frame_period_s"] == 0.066667
    assert got["markers"] == [{"gap_fraction": 0.041667}] and got["offset_mm"] == 1.235
    assert got["head_range_deg"] == {"yaw": 12.346} and got["frames"] == 120 and got["flag"] is True
    assert got["other"] == 0.333333 and np.isnan(got["nan_s"])


def test_inspect_and_status_json_print_rounded_floats(built):
    text = invoke("inspect", str(SAMPLE / "mocap" / "neutral.c3d"), "--json").stdout
    info = json.loads(text)
    assert info["rate_hz"] == 29.97 and info["duration_s"] == 4.004
    assert "0.04166666" not in text and "0.041667" in text
    doc = json.loads(invoke("status", str(built), "--json").stdout)
    for row in doc["units"] + doc["datasets"]:
        assert row["duration_s"] == round(row["duration_s"], 6)


def test_two_sessions_with_one_id_are_refused_naming_both_files(tmp_path):
    """A take is (session, take): two session folders with the same [session] id are refused before anything
    runs (exit 2), naming both session.toml files."""
    from click.testing import CliRunner

    from gazepipe.cli.main import cli
    from tests.helpers import make_tiny_session

    a = make_tiny_session(tmp_path / "day1", n_takes=1)
    b = make_tiny_session(tmp_path / "day2", n_takes=1)
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", str(a), str(b), "--out", str(out), "--executor", "serial"])
    assert res.exit_code == 2, res.output
    msg = res.output.strip().splitlines()[-1]
    assert str(a / "session.toml") in msg and str(b / "session.toml") in msg and "'tiny'" in msg
    assert not (out / "takes").exists()
