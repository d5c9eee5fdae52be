"""Bad input an independent suite found (issue 46): each a one-line error naming the file with the README's exit
code, nothing written outside OUT, every page's embedded data escaped, and a capture whose file does not say its
units (QTM TSV, wide CSV, a CSV `gazepipe export` wrote) read as such by the report."""

from __future__ import annotations

import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.c3d import read_c3d
from gazepipe.io.export_text import write_qtm_tsv
from tests.helpers import SAMPLE, check_page_escapes, run_session, session_copy

#: the labels given to two extra markers of a take: a comment and script opener, a placeholder's name
ODD_LABELS = ["<!--<script>", "INFO"]


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args))


def one_line(res, code: int) -> str:
    """The single ``error:`` line of a command that exited ``code``."""
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == code and len(lines) == 1 and lines[0].startswith("error: "), (res.exit_code, res.output)
    assert "Traceback" not in res.output
    return lines[0]


@pytest.fixture(scope="module")
def odd_run(tmp_path_factory, sample_run: Path) -> tuple[Path, Path]:
    """Three takes of the sample, run: the neutral take as it is; shift_y036_p12 as a QTM TSV (no units in the
    file) with two more markers labelled :data:`ODD_LABELS`; shift_ym036_p00 as the wide CSV `gazepipe export`
    writes of its capture. Returns (session folder, output folder)."""
    root = tmp_path_factory.mktemp("odd")
    session = session_copy(root / "s", {"neutral": None, "shift_y036_p12": None, "shift_ym036_p00": None})
    m = read_c3d(SAMPLE / "mocap" / "shift_y036_p12.c3d")
    extra = m.xyz[:, [m.labels.index("SP2A"), m.labels.index("NK2B")]] + np.array([0.0, 150.0, 0.0])
    write_qtm_tsv(session / "mocap" / "shift_y036_p12.tsv", m.labels + ODD_LABELS,
                  np.concatenate([m.xyz, extra], axis=1), np.concatenate([m.valid, m.valid[:, :2]], axis=1),
                  rate_hz=m.rate_hz, first_frame=m.first_frame)
    res = invoke("export", str(sample_run), "session01/shift_ym036_p00", "--table", "markers_raw",
                 "--to", str(session / "mocap" / "shift_ym036_p00.csv"))
    assert res.exit_code == 0, res.output
    toml = session / "session.toml"
    text = toml.read_text()
    for take, ext in (("shift_y036_p12", "tsv"), ("shift_ym036_p00", "csv")):
        (session / "mocap" / f"{take}.c3d").unlink()
        text = text.replace(f'"mocap/{take}.c3d"', f'"mocap/{take}.{ext}"')
    toml.write_text(text)
    out = root / "out"
    run_session(session, out)
    return session, out


def test_captures_that_do_not_say_their_units_pass_the_report(odd_run) -> None:
    """A QTM TSV and a wide CSV (the one `gazepipe export` writes too) say no units: ingest records null, and the
    report reads that as "the file did not say": no check at error, the gate passes."""
    _, out = odd_run
    for take in ("shift_y036_p12", "shift_ym036_p00"):
        rec = json.loads((out / ".gazepipe" / "units" / "session01" / take / "ingest.json").read_text())
        assert rec["status"] == "ok" and rec["qc"]["units_found"] is None
    res = invoke("validate", str(out), "--json", "--no-plots")
    assert res.exit_code == 0, res.output
    report = json.loads((out / "qc" / "report.json").read_text())
    errors = [(t["take"], c["id"], c["message"]) for t in report["takes"] for c in t["checks"]
              if c["severity"] == "error"]
    assert errors == []


def test_a_marker_labelled_like_markup_leaves_every_page_whole(odd_run, tmp_path) -> None:
    """`<!--<script>` as a marker label: the report's replay page, the `view` page and a stand-alone page keep
    their script element whole and give the label back as it is; the report writes it as text."""
    _, out = odd_run
    res = invoke("validate", str(out), "--plot-takes", "all")
    assert res.exit_code == 0, res.output
    replay = out / "qc" / "replay" / "session01" / "shift_y036_p12.html"
    check_page_escapes(replay.read_text(), ODD_LABELS)
    res = invoke("view", str(out), "session01/shift_y036_p12")
    assert res.exit_code == 0, res.output
    check_page_escapes(Path(res.stdout.strip().splitlines()[-1]).read_text(), ODD_LABELS)
    res = invoke("view", str(out), "shift_y036_p12", "--to", str(tmp_path / "alone.html"))
    assert res.exit_code == 0, res.output
    check_page_escapes((tmp_path / "alone.html").read_text(), ODD_LABELS)
    html = (out / "qc" / "report.html").read_text()
    assert "<!--" not in html and "&lt;!--&lt;script&gt;" in html


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file()}


def test_a_unit_record_whose_take_is_a_path_writes_nothing_outside_out(odd_run, tmp_path) -> None:
    """A unit record saying its take is `x/../../../escaped` (or its session `../..`): `view` refuses it in one
    line, and `validate --plot-takes all` and `view` write nothing outside OUT (the record is not the engine's:
    its take is not where it lies)."""
    _, src = odd_run
    out = tmp_path / "a" / "b" / "out"
    shutil.copytree(src, out, ignore=shutil.ignore_patterns("datasets"))
    real = json.loads((out / ".gazepipe" / "units" / "session01" / "neutral" / "ingest.json").read_text())
    for session, take, folder in (("session01", "x/../../../escaped", "evil"), ("../..", "neutral", "evil2")):
        forged = out / ".gazepipe" / "units" / "session01" / folder / "ingest.json"
        forged.parent.mkdir(parents=True)
        forged.write_text(json.dumps({**real, "session": session, "take": take}))
    before = _files(tmp_path)
    line = one_line(invoke("view", str(out), "session01/x/../../../escaped"), 2)
    assert "no take" in line
    res = invoke("validate", str(out), "--plot-takes", "all")
    assert res.exit_code in (0, 3), res.output
    res = invoke("view", str(out), "neutral")
    assert res.exit_code == 0, res.output
    new = _files(tmp_path) - before
    assert new and all(out in p.parents for p in new)
    assert not [p for p in _files(tmp_path) if "escaped" in p.name]
    report = json.loads((out / "qc" / "report.json").read_text())
    assert {t["take"] for t in report["takes"]} == {"neutral", "shift_y036_p12", "shift_ym036_p00"}


# ------------------------------------------------------------------------------------------------ train

def test_train_refuses_a_number_no_trainer_can_take(sample_run: Path, tmp_path: Path) -> None:
    """`--option k=<30 digits>` passed the check, trained, then ended in "internal error" with an empty --out: it
    is a usage error naming the option, before anything is made; so are a seed beyond 64 bits and a negative one."""
    data = str(sample_run / "datasets" / "gaze_map")
    big = "1" * 30
    line = one_line(invoke("train", "gaze_map", "--data", data, "--out", str(tmp_path / "m"), "--option",
                           f"k={big}"), 2)
    assert f"k={big}" in line and "at most 2147483647" in line
    for seed in (big, "-1"):
        res = invoke("train", "gaze_map", "--data", data, "--out", str(tmp_path / "m"), "--seed", seed)
        assert res.exit_code == 2 and "--seed" in res.output, res.output
    assert not (tmp_path / "m").exists()
    res = invoke("train", "gaze_map", "--data", data, "--out", str(tmp_path / "m"), "--option", "k=2147483647")
    assert res.exit_code == 0, res.output          # the largest accepted: blends every example there is


def test_a_training_that_fails_leaves_no_out_folder(sample_run: Path, tmp_path: Path, monkeypatch) -> None:
    from gazepipe.trainers.gaze_map import GazeMapTrainer

    def broken(self, data, out_dir, options):
        (out_dir / "half.npz").write_bytes(b"")
        raise RuntimeError("the trainer broke")

    monkeypatch.setattr(GazeMapTrainer, "train", broken)
    res = invoke("train", "gaze_map", "--data", str(sample_run / "datasets" / "gaze_map"), "--out",
                 str(tmp_path / "m"))
    assert res.exit_code == 1 and "the trainer broke" in res.stderr
    assert not (tmp_path / "m").exists()


# ------------------------------------------------------------------------------------------- the generator

def _synth(capsys, *argv: str) -> tuple[int, str]:
    """``python -m gazepipe.synth ARGV`` in this process: (exit code, stderr)."""
    from gazepipe.synth.__main__ import main

    try:
        code = main(list(argv))
    except SystemExit as e:
        code = int(e.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, err
    return code, err.strip()


@pytest.mark.parametrize("argv, words", [
    (["{tmp}/s", "--seed", "-1"], "is not a seed"),
    (["{tmp}/s", "--seed", "x"], "is not a seed"),
    (["{tmp}/s", "--label-swaps", str(10**18)], "is not a count (0 to 1000)"),
    (["{tmp}/s", "--occlusion-bursts", "-2"], "is not a count"),
    (["{tmp}/s", "--clap-hazards", "nan"], "is not a share"),
    ([""], "no folder named"),
    (["{tmp}/afile"], "afile: is a file"),
    (["{tmp}/afile/s"], "afile is a file"),
])
def test_the_generator_refuses_bad_options_and_folders_in_one_line(argv, words, tmp_path, capsys) -> None:
    (tmp_path / "afile").write_text("not a folder")
    code, err = _synth(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code == 2 and words in err and err.startswith("python -m gazepipe.synth: error: "), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_the_generator_leaves_no_partial_session_where_it_cannot_write(tmp_path, capsys, monkeypatch) -> None:
    """A folder it may not create (read-only /sys), and a disk that fills after the first take: one line, exit 1,
    and nothing of the session left (the files of a folder that was there are kept as they were)."""
    code, err = _synth(capsys, "/sys/gazepipe-synth-test/s")
    assert code == 1 and "/sys/gazepipe-synth-test/s: cannot write the session" in err, err
    import gazepipe.synth.session as session_module

    calls = []
    real = session_module.write_npz

    def fills_up(path, arrays):
        calls.append(path)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, arrays)

    monkeypatch.setattr(session_module, "write_npz", fills_up)
    code, err = _synth(capsys, str(tmp_path / "new"), "--no-eyes")
    assert code == 1 and "No space left on device" in err and ".partial" not in err, err
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "notes.txt").write_text("mine")
    calls.clear()
    code, err = _synth(capsys, str(tmp_path / "old"))
    assert code == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["notes.txt"]


# ------------------------------------------------------------------------------------------------ a video's tag

def _retag(src: Path, dest: Path, fps: float) -> None:
    """``src`` re-encoded frame for frame with another frame rate tag."""
    import cv2

    cap = cv2.VideoCapture(str(src))
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    writer = cv2.VideoWriter(str(dest), cv2.VideoWriter.fourcc(*"mp4v"), fps, size)
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        writer.write(frame)
    writer.release()
    cap.release()


def test_a_video_tagged_at_another_rate_than_its_eye_tracking_is_named(tmp_path) -> None:
    """The sample's 60 fps head camera re-tagged 30 fps (its OpenFace CSV timed at 60): the eyes stage names the
    video and both rates (a warning when the camera rotation is still found), and when the rotation cannot be
    estimated the error names the video, not the eyes CSV."""
    from gazepipe.errors import StageError
    from gazepipe.io.openface import read_openface
    from gazepipe.stages.eyes.stage import _video_at_fault, tag_mismatch

    session = session_copy(tmp_path / "s", {"neutral": None, "follow_standing_03": None})
    video = session / "video" / "follow_standing_03.mp4"
    _retag(SAMPLE / "video" / "follow_standing_03.mp4", video, 30.0)
    out = tmp_path / "out"
    run_session(session, out)
    rec = json.loads((out / ".gazepipe" / "units" / "session01" / "follow_standing_03" / "eyes.json").read_text())
    if rec["status"] == "ok":       # the rotation was still found: one warning names the video and both rates
        named = [w for w in rec.get("warnings", []) if w.startswith("video/follow_standing_03.mp4:")]
        assert len(named) == 1 and "tagged 30 fps" in named[0] and "60 fps" in named[0], rec
    else:                           # it was not (which, depends on the codec's re-encode): the error names the video
        assert rec["status"] == "failed", rec
        assert f"{video}: eyes: cannot estimate" in rec["error"], rec
        assert "tagged 30 fps" in rec["error"] and "60 fps" in rec["error"], rec
    eye = read_openface(session / "eyes" / "follow_standing_03.csv")
    with pytest.raises(StageError) as ei:
        _video_at_fault((str(video), 58.8, 1764, 30.0), 29.4, eye, "follow_standing_03")
    assert ei.value.path == str(video) and "tagged 30 fps" in str(ei.value)
    assert tag_mismatch((str(video), 29.4, 1764, 60.0), eye) is None      # the tag it was timed at: no fault
    _video_at_fault((str(video), 29.4, 1764, 60.0), 29.4, eye, "follow_standing_03")
