"""Outputs never outlive their inputs: a take that can no longer feed a dataset is counted as left out, and a
dataset whose rebuild fails (or that no take can feed any more) is removed, its record and the report saying
why; mending the input builds it again."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
from click.testing import CliRunner

from gazepipe.cli.main import cli
from tests.helpers import SAMPLE


def _session(root: Path) -> Path:
    s = root / "session"
    (s / "face").mkdir(parents=True)
    shutil.copy(SAMPLE / "markerset.toml", s / "markerset.toml")
    lines = ['schema = 1', '[session]', 'id = "faces"', 'subject = "s1"', 'markerset = "markerset.toml"', '']
    for take, split in (("face_01", "train"), ("face_02", "train")):
        for part in ("tracked", "clean"):
            shutil.copy(SAMPLE / "face" / f"{take}_{part}.csv", s / "face" / f"{take}_{part}.csv")
        lines += ['[[takes]]', f'id = "{take}"', 'kind = "face"', f'tracked = "face/{take}_tracked.csv"',
                  f'clean = "face/{take}_clean.csv"', 'rate_hz = 60', 'timecode_fps = 60', f'split = "{split}"', '']
    (s / "session.toml").write_text("\n".join(lines))
    return s


def _run(session: Path, out: Path) -> int:
    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--executor", "serial",
                                   "--log-format", "json"])
    return res.exit_code


def _break(session: Path, take: str) -> bytes:
    """Drop the Timecode column of the take's tracked CSV; the old bytes."""
    path = session / "face" / f"{take}_tracked.csv"
    old = path.read_bytes()
    pd.read_csv(path).drop(columns=["Timecode"]).to_csv(path, index=False)
    return old


def _dataset_report(out: Path) -> dict:
    report = json.loads((out / "qc" / "report.json").read_text())
    return next(d for d in report["datasets"] if d["name"] == "face_clean")


def test_a_dataset_that_no_take_can_feed_is_removed_and_comes_back(tmp_path: Path) -> None:
    session, out = _session(tmp_path), tmp_path / "out"
    assert _run(session, out) == 0
    assert (out / "datasets" / "face_clean" / "_dataset.json").is_file()

    old2 = _break(session, "face_02")     # one take left: the dataset is built from it, the other counted
    assert _run(session, out) == 1
    skipped = next(c for c in _dataset_report(out)["checks"] if c["id"] == "skipped_takes")
    assert skipped["severity"] == "warning" and skipped["value"] == 1
    assert "faces/face_02" in skipped["message"] and "face stage failed" in skipped["message"]
    assert sorted(p.stem for p in (out / "datasets" / "face_clean").rglob("*.parquet")) == ["face_01"]

    old1 = _break(session, "face_01")     # no take left: what was built from the old inputs goes
    assert _run(session, out) == 1
    assert not (out / "datasets" / "face_clean").exists()
    record = json.loads((out / ".gazepipe" / "datasets" / "face_clean.json").read_text())
    assert record["status"] == "failed" and "no take can feed it" in record["error"]
    build = next(c for c in _dataset_report(out)["checks"] if c["id"] == "build")
    assert build["severity"] == "fail" and "removed" in build["message"]
    status = CliRunner().invoke(cli, ["status", str(out), "--json"])
    row = next(d for d in json.loads(status.stdout)["datasets"] if d["dataset"] == "face_clean")
    assert row["state"] == "failed" and "no take can feed it" in row["detail"]

    (session / "face" / "face_01_tracked.csv").write_bytes(old1)
    (session / "face" / "face_02_tracked.csv").write_bytes(old2)
    assert _run(session, out) == 0
    assert sorted(p.stem for p in (out / "datasets" / "face_clean").rglob("*.parquet")) == ["face_01", "face_02"]
