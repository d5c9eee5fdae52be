"""A missing or unreadable file costs its take only (the session.toml's structure still refuses a run before
anything runs): the take fails with one line naming the file, exit 1, and every other take and every dataset
is built."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import SAMPLE


@pytest.fixture(scope="module")
def broken(tmp_path_factory) -> tuple[Path, dict[str, Path]]:
    """The sample session with one take's video missing, another's C3D a folder and a face take's tracked CSV a
    FIFO (reading it would wait for ever)."""
    root = tmp_path_factory.mktemp("missing") / "session"
    shutil.copytree(SAMPLE, root)
    video = root / "video" / "follow_sitting_01.mp4"
    video.unlink()
    c3d = root / "mocap" / "shift_y036_p12.c3d"
    c3d.unlink()
    c3d.mkdir()
    fifo = root / "face" / "face_02_tracked.csv"
    fifo.unlink()
    os.mkfifo(fifo)
    # dangling links: the listed name is what the messages give, whatever the target's name or suffix
    link = root / "mocap" / "shift_y072_p12.c3d"
    link.unlink()
    link.symlink_to("gone_to_another_format.bin")
    eyes = root / "eyes" / "follow_standing_02.csv"
    eyes.unlink()
    eyes.symlink_to(root / "eyes" / "no_such_eyes.csv")
    return root, {"follow_sitting_01": video, "shift_y036_p12": c3d, "face_02": fifo, "shift_y072_p12": link,
                  "follow_standing_02": eyes}


def test_each_bad_file_fails_its_take_only(broken, tmp_path: Path) -> None:
    root, bad = broken
    out = tmp_path / "out"
    res = CliRunner().invoke(cli, ["run", str(root), "--out", str(out), "-j", "2", "--log-format", "json"])
    assert res.exit_code == 1, res.output
    events = [json.loads(line) for line in res.stderr.splitlines()]
    failed = {e["take"]: e["message"] for e in events if e.get("status") == "failed" and e["event"] == "unit"}
    assert set(failed) == set(bad)
    for take, path in bad.items():
        assert str(path) in failed[take] and "\n" not in failed[take]
        assert f"session01/{take}" in failed[take]
    assert "not a file" in failed["shift_y036_p12"] and "not a file" in failed["face_02"]
    assert "file not found" in failed["follow_sitting_01"]
    for take in ("shift_y072_p12", "follow_standing_02"):
        assert "file not found" in failed[take] and "gone_to" not in failed[take] and "no_such" not in failed[take]
    end = events[-1]
    assert end["event"] == "run_end" and end["datasets_failed"] == 0 and end["datasets_built"] == 4
    for take in ("neutral", "follow_standing_03", "face_01", "shift_ym036_p00"):
        assert any((out / "takes" / "session01" / take).glob("*.parquet")), take
