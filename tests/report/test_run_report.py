"""The QC report of a run is made on the run's workers as it goes (gazepipe.report.run_report): each take's
checks as soon as the take ran, the plots of the takes the page shows, each dataset's checks and plots as soon
as it is built, all into the output folder's caches; the end of the run reads them back. What must hold: the
report is the same bytes whoever made its parts (a parallel run, a serial run, a validation after either), and
a cached part is used only while everything it was made from is unchanged.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.cli.validate import validate
from gazepipe.report.cache import CheckCache, DatasetCache, FigureCache
from tests.helpers import session_copy
from tests.helpers.shared import shared_folder

TAKES = {"neutral": None, "shift_y000_p12": "train", "shift_y036_p12": "train", "shift_ym036_p00": "val",
         "shift_ym072_p12": None}
FILES = ("report.json", "takes.parquet", "report.html")


def _run(session: Path, out: Path, *args: str) -> None:
    res = CliRunner().invoke(cli, ["run", str(session), "--out", str(out), "--log-format", "json", *args])
    assert res.exit_code in (0, 1), res.output


def _qc(out: Path) -> dict[str, bytes]:
    return {n: (out / "qc" / n).read_bytes() for n in FILES}


def _entries(out: Path, cache) -> list[Path]:
    return sorted((out / ".gazepipe" / cache.DIRNAME).glob("*.json"))


def _run_both(root: Path) -> None:
    session = session_copy(root / "session", TAKES)
    _run(session, root / "serial", "--executor", "serial")
    _run(session, root / "process", "--executor", "process", "-j", "2")


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """A serial and a parallel run of the slice, once per test run (shared by pytest-xdist's workers), read
    only: a test that validates or changes an output copies it."""
    root = shared_folder(tmp_path_factory, "run_report_runs", _run_both, fixture="runs")
    return {"serial": root / "serial", "process": root / "process"}


@pytest.fixture
def out(runs: dict[str, Path], tmp_path: Path) -> Path:
    dest = tmp_path / "out"
    shutil.copytree(runs["process"], dest)
    return dest


def test_a_parallel_runs_report_is_the_serial_runs_and_a_validations(runs, tmp_path) -> None:
    serial, parallel = _qc(runs["serial"]), _qc(runs["process"])
    assert serial == parallel
    copy = tmp_path / "copy"
    shutil.copytree(runs["process"], copy)
    for cache in (CheckCache, DatasetCache, FigureCache):
        shutil.rmtree(copy / ".gazepipe" / cache.DIRNAME)
    assert CliRunner().invoke(validate, [str(copy)]).exit_code in (0, 1)
    assert _qc(copy) == parallel, "made from nothing by validate: the same bytes as read back from the workers"


def test_the_workers_filled_the_caches(runs) -> None:
    out = runs["process"]
    report = json.loads((out / "qc" / "report.json").read_text())
    assert len(_entries(out, CheckCache)) == len(report["takes"]) == len(TAKES)
    assert len(_entries(out, DatasetCache)) == len(report["datasets"])
    assert _entries(out, FigureCache)


def test_a_cached_check_is_used_only_while_its_take_is_unchanged(out: Path) -> None:
    """A cache entry changed by hand shows in the report (the report reads it back instead of checking again);
    once the take's table changes, its checks are made again and the hand-made one is gone."""
    before = _qc(out)
    entry = _entries(out, CheckCache)[0]
    data = json.loads(entry.read_text())
    data["checks"][0]["message"] = "MARKED BY THE TEST"
    entry.write_text(json.dumps(data))
    assert CliRunner().invoke(validate, [str(out)]).exit_code in (0, 1)
    assert "MARKED BY THE TEST" in (out / "qc" / "report.json").read_text()
    take = next(t for t in json.loads((out / "qc" / "report.json").read_text())["takes"]
                if any(c["message"] == "MARKED BY THE TEST" for c in t["checks"]))
    table = out / "takes" / take["session"] / take["take"] / "markers.parquet"
    st = table.stat()
    os.utime(table, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert CliRunner().invoke(validate, [str(out)]).exit_code in (0, 1)
    assert "MARKED BY THE TEST" not in (out / "qc" / "report.json").read_text()
    assert not entry.exists(), "the entry the report no longer uses is deleted"
    assert _qc(out) == before


def test_a_cached_dataset_part_is_used_only_while_its_files_are_unchanged(out: Path) -> None:
    before = _qc(out)
    for entry in _entries(out, DatasetCache):
        data = json.loads(entry.read_text())
        data["entry"]["checks"][0]["message"] = "MARKED BY THE TEST"
        entry.write_text(json.dumps(data))
    assert CliRunner().invoke(validate, [str(out)]).exit_code in (0, 1)
    assert "MARKED BY THE TEST" in (out / "qc" / "report.json").read_text()
    for f in sorted((out / "datasets").rglob("*.parquet")):
        st = f.stat()
        os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert CliRunner().invoke(validate, [str(out)]).exit_code in (0, 1)
    assert "MARKED BY THE TEST" not in (out / "qc" / "report.json").read_text()
    assert _qc(out) == before
