"""Inputs are looked at before they are hashed: a C3D whose header declares more frames than the file holds
fails its take at once, without the file being read whole, and the other takes run."""

from __future__ import annotations

import json
from pathlib import Path

from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.pipeline import hashing
from tests.helpers import session_copy


def test_a_c3d_that_cannot_hold_its_frames_fails_its_take_before_it_is_hashed(tmp_path: Path, monkeypatch) -> None:
    session = session_copy(tmp_path / "session", {"neutral": None, "shift_y036_p12": None})
    bad = session / "mocap" / "shift_y036_p12.c3d"
    bad.write_bytes(bad.read_bytes()[: bad.stat().st_size // 3])
    hashed: list[str] = []
    real = hashing.sha256_file
    monkeypatch.setattr(hashing, "sha256_file", lambda p, *a, **k: (hashed.append(Path(p).name), real(p, *a, **k))[1])
    res = CliRunner().invoke(cli, ["ingest", str(session), "--out", str(tmp_path / "out"), "--executor", "serial",
                                   "--log-format", "json"])
    assert res.exit_code == 1, res.output
    events = [json.loads(line) for line in res.stderr.splitlines()]
    failed = [e for e in events if e.get("status") == "failed" and e["event"] == "unit"]
    assert len(failed) == 1 and failed[0]["take"] == "shift_y036_p12"
    assert str(bad) in failed[0]["message"] and "\n" not in failed[0]["message"]
    assert "shift_y036_p12.c3d" not in hashed and "neutral.c3d" in hashed
    assert (tmp_path / "out" / "takes" / "session01" / "neutral" / "markers_raw.parquet").is_file()
