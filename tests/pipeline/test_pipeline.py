"""The engine: incremental runs, dry runs, failures kept to their take, lock, executors, kill safety."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.schemas.markers import table_to_markers
from tests.helpers import REPO, make_tiny_session, output_digests, tiny_motion, write_wide_csv


def run_cli(*args: str) -> tuple[int, str, str]:
    res = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    return res.exit_code, res.stdout, res.stderr


def events(stderr: str) -> list[dict]:
    return [json.loads(line) for line in stderr.splitlines() if line.startswith("{")]


def test_ingest_writes_canonical_tables_that_match_the_input(tiny_session, tmp_path):
    out = tmp_path / "out"
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    assert code == 0, err
    table = pq.read_table(out / "takes" / "tiny" / "t1" / "markers_raw.parquet")
    markers, frames, fill, meta = table_to_markers(table)
    labels, xyz = tiny_motion(1)
    assert markers.labels == labels
    assert np.allclose(markers.xyz, xyz, atol=1e-4)          # the CSV keeps 4 decimals
    assert frames.tolist() == list(range(90))
    assert meta["rate_hz"] == pytest.approx(30.0)
    assert table.column("source_frame").to_pylist()[:2] == [1, 2]


def test_second_run_does_nothing_and_says_so(tiny_session, tmp_path):
    out = tmp_path / "out"
    assert run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")[0] == 0
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*.parquet")}
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    assert code == 0
    ev = events(err)
    assert any(e["event"] == "nothing_to_do" for e in ev)
    assert not any(e["event"] == "unit" and e.get("status") == "ok" for e in ev)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.parquet")} == before


def test_planning_a_run_does_not_import_the_heavy_libraries():
    """A run with nothing to do plans and stops: the CLI, the engine and every stage's parameters load without
    scipy, matplotlib, Dask or pyarrow.compute (scipy.spatial alone costs about 0.3 s, a third of the no-op re-run;
    pyarrow.compute 60 ms)."""
    code = ("import sys, gazepipe.cli.main, gazepipe.pipeline.engine, gazepipe.dag, "
            "gazepipe.pipeline.registry as r; gazepipe.dag.declare(); r.default_params(); "
            "print(sorted(({m.split('.')[0] for m in sys.modules} & {'scipy', 'matplotlib', 'dask', 'distributed', "
            "'cv2', 'torch', 'pandas'}) | ({'pyarrow.compute'} & set(sys.modules))))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]", res.stdout


def test_changing_one_take_reruns_only_that_take(tiny_session, tmp_path):
    out = tmp_path / "out"
    run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    labels, xyz = tiny_motion(1)
    write_wide_csv(tiny_session / "mocap" / "t1.csv", labels, xyz + 1.0, 30.0)
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--dry-run")
    plan = {e["take"]: e for e in events(err) if e["event"] == "plan"}
    assert plan["t1"]["status"] == "run" and "input changed: mocap/t1.csv" in plan["t1"]["reason"]
    assert plan["t0"]["status"] == "skip" and plan["t2"]["status"] == "skip"
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    ran = [e["take"] for e in events(err) if e["event"] == "unit" and e.get("status") == "ok"]
    assert ran == ["t1"]


def test_bad_take_fails_alone_with_one_line(tiny_session, tmp_path):
    out = tmp_path / "out"
    (tiny_session / "mocap" / "t2.csv").write_bytes(b"\x00\xff garbage, not a capture\n" * 3)
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial",
                           "--log-format", "text")
    assert code == 1
    assert "Traceback" not in err
    bad = [line for line in err.splitlines() if line.startswith("error:") and "t2" in line]
    assert len(bad) == 1 and "t2.csv" in bad[0]
    assert (out / "takes" / "tiny" / "t0" / "markers_raw.parquet").is_file()
    assert (out / "takes" / "tiny" / "t1" / "markers_raw.parquet").is_file()
    assert not (out / "takes" / "tiny" / "t2" / "markers_raw.parquet").exists()
    code, stdout, _ = run_cli("status", str(out))
    assert "failed" in stdout and "t2" in stdout


def test_config_error_exits_2_naming_file_and_key(tiny_session, tmp_path):
    text = (tiny_session / "session.toml").read_text().replace('kind = "gaze_follow"', 'kind = "gaze_folow"', 1)
    (tiny_session / "session.toml").write_text(text)
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(tmp_path / "o"))
    assert code == 2
    line = err.strip().splitlines()[-1]
    assert "session.toml" in line and "takes[0].kind" in line and "Traceback" not in err


def test_lock_makes_a_second_run_exit_75(tiny_session, tmp_path):
    from gazepipe.pipeline.lock import OutputLock
    from gazepipe.pipeline.state import OutLayout

    out = tmp_path / "out"
    layout = OutLayout(out)
    with OutputLock(layout.lock):
        code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out))
    assert code == 75 and "another gazepipe run" in err


def test_process_and_serial_executors_give_identical_bytes(tmp_path):
    session = make_tiny_session(tmp_path / "s", n_takes=4)
    a, b = tmp_path / "a", tmp_path / "b"
    assert run_cli("ingest", str(session), "--out", str(a), "--executor", "serial")[0] == 0
    assert run_cli("ingest", str(session), "--out", str(b), "--executor", "process", "-j", "2")[0] == 0
    da, db = output_digests(a), output_digests(b)
    assert da and da == db


def test_sigkill_midway_then_rerun_gives_identical_outputs(tmp_path):
    session = make_tiny_session(tmp_path / "s", n_takes=12)
    ref = tmp_path / "ref"
    assert run_cli("ingest", str(session), "--out", str(ref), "--executor", "serial")[0] == 0
    expected = output_digests(ref)
    rng = np.random.default_rng(7)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for trial in range(3):
        out = tmp_path / f"k{trial}"
        proc = subprocess.Popen([sys.executable, "-m", "gazepipe", "ingest", str(session), "--out", str(out),
                                 "--executor", "serial"], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(float(rng.uniform(0.3, 1.5)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        for p in out.rglob("*.parquet"):   # whatever is visible is whole
            pq.read_table(p)
        res = subprocess.run([sys.executable, "-m", "gazepipe", "ingest", str(session), "--out", str(out),
                              "--executor", "serial"], env=env, capture_output=True, text=True)
        assert res.returncode == 0, res.stderr
        assert output_digests(out) == expected


def test_unchanged_bad_take_is_not_retried_but_still_fails_the_run(tiny_session, tmp_path):
    out = tmp_path / "out"
    (tiny_session / "mocap" / "t2.csv").write_text("frame,time,SACR_x\n1,0.0,not-a-number\n")
    assert run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")[0] == 1
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    ev = events(err)
    assert code == 1                                   # the take is still failed
    assert any(e["event"] == "nothing_to_do" for e in ev)
    again = [e for e in ev if e["event"] == "unit" and e.get("status") == "failed"]
    assert len(again) == 1 and again[0]["take"] == "t2" and "t2.csv" in again[0]["message"]
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial", "--force")
    assert any(e["event"] == "unit" and e.get("take") == "t0" and e.get("status") == "ok" for e in events(err))


def test_serial_executor_reports_each_take_as_it_finishes(tmp_path):
    session = make_tiny_session(tmp_path / "s", n_takes=3)
    code, _, err = run_cli("ingest", str(session), "--out", str(tmp_path / "o"), "--executor", "serial",
                           "--heartbeat", "1")
    ev = events(err)
    order = [e["event"] for e in ev if e["event"] in ("unit", "heartbeat")]
    # a heartbeat after the first and second takes, each after that take's unit line
    assert order[:4] == ["unit", "heartbeat", "unit", "heartbeat"]


def test_stale_temporaries_and_staging_folders_are_cleared(tmp_path):
    from gazepipe.pipeline.atomic import clear_stale_temporaries

    tmp = tmp_path / "tmp"
    (tmp / "gaze_rnn.123.abc.part" / "subject=p" / "pose=s").mkdir(parents=True)
    (tmp / "gaze_rnn.123.abc.part" / "subject=p" / "pose=s" / "take=t.parquet").write_bytes(b"x")
    (tmp / ".joints.parquet.9.def.part").write_bytes(b"y")
    (tmp / "keep.txt").write_bytes(b"z")
    assert clear_stale_temporaries(tmp) == 2
    assert [p.name for p in tmp.iterdir()] == ["keep.txt"]


def test_an_interrupted_run_logs_how_far_it_got_and_keeps_finished_takes(tiny_session, tmp_path, monkeypatch):
    """Ctrl-C while the second take runs: an `interrupted` event says one of three takes was reported done, the
    interrupt propagates, the first take's outputs stay, and the same command then resumes from there."""
    import io

    import gazepipe.pipeline.engine as engine
    from gazepipe.cli.common import load_sessions
    from gazepipe.pipeline.events import EventLog

    real, calls = engine.run_take_job, []

    def interrupt_second(job):
        calls.append(job.take.id)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(job)

    monkeypatch.setattr(engine, "run_take_job", interrupt_second)
    out, stream = tmp_path / "out", io.StringIO()
    sessions = load_sessions((str(tiny_session),))
    with pytest.raises(KeyboardInterrupt):
        engine.run_pipeline(sessions, out, until="ingest", executor="serial", log=EventLog("json", stream))
    ev = [e for e in events(stream.getvalue()) if e["event"] == "interrupted"]
    assert len(ev) == 1 and ev[0]["done"] == 1 and ev[0]["total"] == 3 and "resumes" in ev[0]["message"]
    assert (out / "takes" / "tiny" / calls[0] / "markers_raw.parquet").is_file()
    monkeypatch.setattr(engine, "run_take_job", real)
    code, _, err = run_cli("ingest", str(tiny_session), "--out", str(out), "--executor", "serial")
    ran = {e["take"] for e in events(err) if e["event"] == "unit" and e.get("status") == "ok"}
    assert code == 0 and ran == {"t0", "t1", "t2"} - {calls[0]}


def test_a_file_rewritten_in_the_same_process_is_identified_afresh(tmp_path):
    """No cache keyed by path alone: a capture rewritten while the process runs (a broken capture mended between
    two runs of one process) has a new identity, so whether it is usable is looked at again."""
    from gazepipe.dag.nodes.common import file_id as _file_id
    from gazepipe.dag.nodes.common import usable_capture as _usable_capture

    path = tmp_path / "t.c3d"
    path.write_bytes(b"not a capture")
    first = _file_id(str(path))
    assert not _usable_capture(str(path), first)
    path.write_bytes(b"still not a capture, but longer")
    second = _file_id(str(path))
    assert second[0] == len(b"still not a capture, but longer")
    assert second != first


# ------------------------------------------------------------------------------- outputs that cannot go stale

def _neutral_and_face_session(dest: Path) -> Path:
    """The sample session's neutral take and its first face take, in a folder of their own."""
    from tests.helpers import SAMPLE

    files = ["markerset.toml", "mocap/neutral.c3d", "face/face_01_tracked.csv", "face/face_01_clean.csv"]
    for rel in files:
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLE / rel, dest / rel)
    (dest / "session.toml").write_text(
        'schema = 1\n[session]\nid = "s"\nsubject = "p01"\nmarkerset = "markerset.toml"\n\n'
        '[[takes]]\nid = "neutral"\nkind = "neutral"\npose = "standing"\nmocap = "mocap/neutral.c3d"\n\n'
        '[[takes]]\nid = "face_01"\nkind = "face"\ntracked = "face/face_01_tracked.csv"\n'
        'clean = "face/face_01_clean.csv"\nrate_hz = 60\ntimecode_fps = 60\n')
    return dest


def _records(out: Path) -> dict[str, tuple[int, int]]:
    """Every unit and dataset record of ``out`` by its path under the run state, with its inode and mtime: a
    unit that runs writes its record anew (atomically: a new file)."""
    state = out / ".gazepipe"
    return {str(p.relative_to(state)): (p.stat().st_ino, p.stat().st_mtime_ns)
            for part in ("units", "session_units", "datasets") for p in sorted((state / part).rglob("*.json"))}


def _run_with(package_root: Path, session: Path, out: Path) -> set[str]:
    """``gazepipe run`` in a fresh process importing gazepipe from ``package_root`` (its working folder: ``-m``
    puts that first on the path): the records it wrote."""
    before = _records(out) if out.exists() else {}
    env = {**os.environ, "PYTHONPATH": str(package_root)}
    res = subprocess.run([sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(out),
                          "--executor", "serial"], env=env, cwd=package_root, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    return {k for k, v in _records(out).items() if before.get(k) != v}


@pytest.mark.slow
def test_an_edit_of_a_stages_code_reruns_it_and_its_readers_and_nothing_else(tmp_path):
    """A stage's units are up to date only with the code they ran: an edit of a function the face stage runs
    re-runs the face unit, the face_clean rows it feeds and the dataset, and nothing of the neutral take; an edit
    of its comments and docstrings re-runs nothing."""
    import gazepipe

    copy = tmp_path / "code"
    shutil.copytree(Path(gazepipe.__file__).parent, copy / "gazepipe",
                    ignore=shutil.ignore_patterns("__pycache__"))
    session, out = _neutral_and_face_session(tmp_path / "session"), tmp_path / "out"
    first = _run_with(copy, session, out)
    assert "units/s/face_01/face.json" in first and "units/s/neutral/clean.json" in first

    stage = copy / "gazepipe" / "stages" / "face" / "stage.py"
    source = stage.read_text()
    head = 'def align_face('
    assert head in source
    commented = source.replace(head, "# a comment that changes nothing\n" + head, 1).replace(
        '"""Tracked and clean blendshapes', '"""Tracked and clean (docstring edited) blendshapes', 1)
    assert commented != source
    stage.write_text(commented)
    assert _run_with(copy, session, out) == set()

    # a line of align_face written otherwise (computing the same): its code changed
    assert commented.count("rows_out=int(m),") == 1
    edited = commented.replace("rows_out=int(m),", "rows_out=int(m) + 0,")
    stage.write_text(edited)
    assert _run_with(copy, session, out) == {"units/s/face_01/face.json", "units/s/face_01/rows_face_clean.json",
                                             "datasets/face_clean.json"}


def test_the_samples_outputs_never_change_under_an_unchanged_identity(sample_run):
    """Against a record of an earlier run of the sample (``tests/data/sample_identities.json``, written by
    ``python -m tests.helpers.identities``): a unit whose fingerprint and code identity are what they were then
    wrote the same bytes. A change of outputs that neither saw (code the digest does not reach, a library it does
    not name) would leave every output folder made before it up to date with stale tables.

    Units whose identity changed since (an edit of their code, another library) are not judged: the record is
    refreshed after a deliberate change of the sample's outputs."""
    from tests.helpers.identities import RECORD, unit_identities

    recorded = json.loads(RECORD.read_text())
    now = unit_identities(sample_run)
    assert set(now) == set(recorded), "the sample's units changed: refresh the record"
    judged = [k for k in sorted(now) if now[k]["identity"] == recorded[k]["identity"]]
    stale = [k for k in judged if now[k]["outputs"] != recorded[k]["outputs"]]
    assert not stale, f"outputs changed under an unchanged fingerprint and code identity ({len(judged)} judged)"


# ------------------------------------------------------------------------------------ stages as declarations

def test_the_engine_derives_each_stages_upstream_from_the_tables_it_declares():
    """A stage declares the tables it reads; the engine derives the stages it follows from their writers, and
    refuses a table nobody writes before it, or stages named instead of tables."""
    import gazepipe.dag
    from gazepipe.pipeline import registry

    gazepipe.dag.declare()   # the stages and their parameters

    derived = {st.name: (st.requires, st.session_requires) for st in registry.stages()}
    assert derived["clean"] == (("ingest",), ("subject_geometry",))
    assert derived["frames"] == (("clean",), ("neutral_poses",))
    assert derived["sync"] == (("ingest",), ())
    assert derived["eyes"] == (("frames", "sync"), ())
    assert derived["rows_gaze_map"] == (("frames", "clean"), ())
    assert registry.get_session_stage("neutral_poses").requires == ("subject_geometry",)
    with pytest.raises(ValueError, match="no stage registered before it writes"):
        registry.register(dataclasses.replace(registry.get("eyes"), name="late", inputs=("nowhere",),
                                              outputs=("late",), requires=(), session_requires=()))
    with pytest.raises(ValueError, match="declare the tables it reads"):
        registry.register(dataclasses.replace(registry.get("eyes"), name="late", outputs=("late",)))


def test_a_stage_that_loads_a_table_it_does_not_declare_fails_loudly(tiny_session, tmp_path, monkeypatch):
    """frames declares the cleaned markers and the neutral rest, not the raw markers: asking for them fails its
    unit, naming the table, before anything is read."""
    import io

    import gazepipe.dag
    from gazepipe.io.session_toml import load_session
    from gazepipe.pipeline import registry
    from gazepipe.pipeline.engine import run_pipeline
    from gazepipe.pipeline.events import EventLog

    gazepipe.dag.declare()   # the stages and their parameters

    frames = registry.get("frames")
    read: list[str] = []

    def sneaky(ctx):
        read.append("asked")
        ctx.load("markers_raw")
        read.append("read")
        return frames.run(ctx)

    monkeypatch.setitem(registry._STAGES, "frames", dataclasses.replace(frames, run=sneaky))
    out = tmp_path / "out"
    run_pipeline([load_session(tiny_session / "session.toml")], out, executor="serial", until="frames",
                 log=EventLog(fmt="json", stream=io.StringIO()))
    rec = json.loads((out / ".gazepipe" / "units" / "tiny" / "t1" / "frames.json").read_text())
    assert rec["status"] == "failed"
    assert "'markers_raw', which it does not declare among its inputs (markers, neutral)" in rec["error"]
    assert read and set(read) == {"asked"}   # every take asked; none was given the table
    clean = json.loads((out / ".gazepipe" / "units" / "tiny" / "t1" / "clean.json").read_text())
    assert clean["status"] == "ok"


@pytest.mark.slow
def test_a_stages_code_identity_depends_on_neither_the_folder_nor_the_hash_seed(tmp_path):
    """The same code gives the same digests from another folder, under another hash seed, imported in another
    order (the DAG's modules before the engine's)."""
    import gazepipe
    import gazepipe.dag
    from gazepipe.pipeline import registry
    from gazepipe.pipeline.codehash import code_of

    gazepipe.dag.declare()   # the stages and their parameters

    here = {st.name: code_of(st.run).digest for st in registry.stages()}
    copy = tmp_path / "elsewhere"
    shutil.copytree(Path(gazepipe.__file__).parent, copy / "gazepipe", ignore=shutil.ignore_patterns("__pycache__"))
    script = ("import json, gazepipe.dag.takes, gazepipe.dag\ngazepipe.dag.declare()\n"
              "from gazepipe.pipeline import registry\nfrom gazepipe.pipeline.codehash import code_of\n"
              "print(json.dumps({st.name: code_of(st.run).digest for st in registry.stages()}))")
    env = {**os.environ, "PYTHONPATH": str(copy), "PYTHONHASHSEED": "12345"}
    res = subprocess.run([sys.executable, "-c", script], env=env, cwd=copy, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert json.loads(res.stdout) == here
    assert len(set(here.values())) >= 5   # the stages' code differs


def test_a_stages_parameters_are_its_dataclass_not_a_dict():
    """A stage declares its parameters dataclass; the engine derives the defaults and rules from it and refuses
    parameters given as a dict."""
    import gazepipe.dag
    from gazepipe.pipeline import registry
    from gazepipe.stages.sync.stage import SyncParams

    gazepipe.dag.declare()   # the stages and their parameters

    sync = registry.get("sync")
    assert sync.params_class is SyncParams
    assert sync.params == registry.defaults_of(SyncParams) and sync.rules == registry.rules_of(SyncParams)
    assert "help" not in {k for rule in sync.rules.values() for k in rule}
    with pytest.raises(ValueError, match="declare its parameters dataclass"):
        registry.register(dataclasses.replace(sync, name="late", outputs=("late",), params_class=None,
                                              requires=(), session_requires=()))


def test_importing_the_dag_registers_nothing_until_it_is_declared():
    """The registry fills on an explicit call (gazepipe.dag.declare(), once: a second call changes nothing), and a
    worker started afresh fills it from the modules the planning process names (registry.ensure)."""
    script = ("import gazepipe.dag\nfrom gazepipe.pipeline import registry\n"
              "before = len(registry._STAGES)\n"
              "gazepipe.dag.declare(); gazepipe.dag.declare()\n"
              "print(before, len(registry.stages()), len(registry.datasets()), registry.modules()[0])")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["0", "10", "4", "gazepipe.dag"]
    worker = ("from gazepipe.pipeline import registry\nregistry.ensure(['gazepipe.dag'])\n"
              "print(len(registry.stages()), len(registry.session_stages_for(registry.stages())))")
    res = subprocess.run([sys.executable, "-c", worker], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["10", "2"]
