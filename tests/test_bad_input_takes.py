"""A take's unreadable path (a link loop) fails that take only, and the errors of face and eye takes name the
file at fault: a Live Link Face file of one row, a head-camera video far shorter than its take."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.errors import StageError
from gazepipe.io.livelinkface import read_livelinkface
from gazepipe.io.session_toml import load_session
from gazepipe.stages.eyes.stage import SHORT_VIDEO_SHARE, _short_video
from gazepipe.stages.face.stage import align_face
from tests.helpers import SAMPLE

SHIFT = "shift_y036_p12"


def _session(root: Path, takes: str, copy: list[str]) -> Path:
    for rel in copy:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(SAMPLE / rel, root / rel)
    (root / "session.toml").write_text(f'schema = 1\n[session]\nid = "bad"\nsubject = "p01"\n{takes}')
    return root


def _mocap_session(root: Path) -> Path:
    shutil.copytree(SAMPLE / "mocap", root / "mocap", ignore=lambda d, names: [
        n for n in names if n not in ("neutral.c3d", f"{SHIFT}.c3d")])
    shutil.copyfile(SAMPLE / "markerset.toml", root / "markerset.toml")
    takes = ('markerset = "markerset.toml"\n\n[[takes]]\nid = "neutral"\nkind = "neutral"\npose = "standing"\n'
             'mocap = "mocap/neutral.c3d"\n\n'
             f'[[takes]]\nid = "{SHIFT}"\nkind = "gaze_shift"\npose = "standing"\nmocap = "mocap/{SHIFT}.c3d"\n'
             'target = { yaw_deg = 36.0, pitch_deg = 12.0 }\n')
    return _session(root, takes, [])


def _events(res) -> list[dict]:
    return [json.loads(line) for line in res.stderr.splitlines() if line.startswith("{")]


# ------------------------------------------------------------------------------------------------ link loops

def test_a_link_loop_loads_as_the_listed_path(tmp_path):
    root = _mocap_session(tmp_path / "s")
    loop = root / "mocap" / f"{SHIFT}.c3d"
    loop.unlink()
    loop.symlink_to(loop.name)
    session = load_session(root)
    take = next(t for t in session.takes if t.id == SHIFT)
    assert take.mocap == str(loop)


def test_a_link_loop_as_a_takes_mocap_fails_that_take_only(tmp_path):
    root = _mocap_session(tmp_path / "s")
    loop = root / "mocap" / f"{SHIFT}.c3d"
    loop.unlink()
    loop.symlink_to(loop.name)
    res = CliRunner().invoke(cli, ["run", str(root), "--out", str(tmp_path / "out"), "--executor", "serial",
                                   "--log-format", "json", "--param", "clean.max_gap_s=0.5"])
    assert res.exit_code == 1, res.output
    events = _events(res)
    failed = [e for e in events if e.get("event") == "unit" and e.get("status") == "failed"]
    assert [e["take"] for e in failed] == [SHIFT]
    assert str(loop) in failed[0]["message"] and "\n" not in failed[0]["message"]
    done = {(e["take"], e["stage"]) for e in events if e.get("event") == "unit" and e.get("status") == "ok"}
    assert ("neutral", "clean") in done


# ------------------------------------------------------------------------------------------------ face takes

def _face_files(root: Path, rows: int | None) -> tuple[Path, Path]:
    tracked, clean = root / "t.csv", root / "c.csv"
    shutil.copyfile(SAMPLE / "face" / "face_04_clean.csv", clean)
    lines = (SAMPLE / "face" / "face_04_tracked.csv").read_text().splitlines(keepends=True)
    tracked.write_text("".join(lines if rows is None else lines[: 1 + rows]))
    return tracked, clean


def test_a_face_file_of_one_row_is_named(tmp_path):
    tracked, clean = _face_files(tmp_path, rows=1)
    trk = read_livelinkface(tracked, rate_hz=30, timecode_fps=60)
    cln = read_livelinkface(clean, rate_hz=30, timecode_fps=60)
    with pytest.raises(StageError) as ei:
        align_face(trk, cln, paths=(tracked, clean))
    assert str(tracked) in str(ei.value) and "1 data row" in str(ei.value)
    with pytest.raises(StageError) as ei:
        align_face(cln, trk, paths=(clean, tracked))
    assert str(tracked) in str(ei.value)


def test_face_files_that_do_not_pair_name_both(tmp_path):
    tracked, clean = _face_files(tmp_path, rows=None)
    head, *rows = clean.read_text().splitlines(keepends=True)
    clean.write_text(head + "".join(f"{(int(r[:2]) + 5) % 24:02d}{r[2:]}" for r in rows))   # 5 h later
    trk = read_livelinkface(tracked, rate_hz=30, timecode_fps=60)
    cln = read_livelinkface(clean, rate_hz=30, timecode_fps=60)
    with pytest.raises(StageError) as ei:
        align_face(trk, cln, paths=(tracked, clean))
    assert str(tracked) in str(ei.value) and str(clean) in str(ei.value)


def test_a_face_take_of_one_row_fails_naming_the_file(tmp_path):
    root = tmp_path / "s"
    takes = ('\n[[takes]]\nid = "face_04"\nkind = "face"\ntracked = "face/face_04_tracked.csv"\n'
             'clean = "face/face_04_clean.csv"\nrate_hz = 30\ntimecode_fps = 60\n')
    _session(root, takes, ["face/face_04_tracked.csv", "face/face_04_clean.csv"])
    tracked = root / "face" / "face_04_tracked.csv"
    tracked.write_text("".join(tracked.read_text().splitlines(keepends=True)[:2]))
    res = CliRunner().invoke(cli, ["run", str(root), "--out", str(tmp_path / "out"), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 1, res.output
    failed = [e["message"] for e in _events(res) if e.get("event") == "unit" and e.get("status") == "failed"]
    assert len(failed) == 1 and str(tracked) in failed[0], failed


# ------------------------------------------------------------------------------------------------ short videos

def test_a_video_far_shorter_than_its_take_is_named():
    with pytest.raises(StageError) as ei:
        _short_video(("video/v.mp4", 2.5), 17.7, "t")
    msg = str(ei.value)
    assert "video/v.mp4" in msg and "2.5 s" in msg and "17.7 s" in msg
    _short_video(("video/v.mp4", SHORT_VIDEO_SHARE * 17.7 + 0.1), 17.7, "t")     # long enough: no error
    _short_video(("video/v.mp4", float("nan")), 17.7, "t")                       # unknown: no error
    _short_video(None, 17.7, "t")


def test_the_sync_stage_notes_a_short_video():
    from gazepipe.stages.sync.coverage import short_video_note

    note = short_video_note(np.arange(150) / 60.0, 23.6)
    assert len(note) == 1 and "2.5 s" in note[0] and "23.6 s" in note[0]
    assert short_video_note(np.arange(1400) / 60.0, 23.6) == []
