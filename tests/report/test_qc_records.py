"""The take stages' QC records as frozen dataclasses (``stages/*/qc.py``, ``stages/ingest_qc.py``): the sample's
real records parse; a record that lacks a key the report reads, or holds one with the wrong type, makes the checks
that read it ``error`` naming the record file and the key, never a pass on a default."""

from __future__ import annotations

import copy
import dataclasses
import json
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.pipeline.state import OutLayout
from gazepipe.report import checks as C
from gazepipe.report.collect import QC_TYPES, TakeEntry, load_take_tables, take_entries
from gazepipe.report.validate import take_output_checks
from gazepipe.stages.build.qc import RowsQC
from gazepipe.stages.clean.qc import CleanQC
from gazepipe.stages.qc import QCRecordError
from gazepipe.stages.sync.qc import SyncQC
from tests.helpers import REPO

SAMPLE = REPO / "sample_data" / "session01"
#: one take of each kind that runs every take stage: ingest, clean (neutral); + frames, sync, eyes; face
TAKES = ("neutral", "follow_sitting_01", "face_01")


@pytest.fixture
def out(sample_run: Path) -> Path:
    """The pipeline's output for the sample session (shared, read only: the tests read its records and change
    them only in memory or in a copy)."""
    return sample_run


def _entry(out: Path, take: str) -> TakeEntry:
    return next(e for e in take_entries(OutLayout(out), {}) if e.take == take)


def _checks(out: Path, e: TakeEntry) -> dict[str, C.Check]:
    return {c.id: c for c in take_output_checks(e, load_take_tables(OutLayout(out), e, arrays=False), C.Thresholds())}


def test_every_stage_record_of_the_sample_parses_and_round_trips(out: Path) -> None:
    seen = set()
    for path in sorted((out / ".gazepipe" / "units").glob("*/*/*.json")):
        rec = json.loads(path.read_text())
        cls = RowsQC if rec["stage"].startswith("rows_") else QC_TYPES[rec["stage"]]
        qc = cls.from_record(rec["qc"], path)
        assert dataclasses.is_dataclass(qc) and type(qc).__dataclass_params__.frozen
        # every key the stage wrote is a field, with the same value (a key left out stays out)
        assert qc.to_record() == rec["qc"], path
        assert set(rec["qc"]) <= {f.name for f in dataclasses.fields(cls)}, path
        seen.add(cls.stage)
    assert seen == set(QC_TYPES) | {"rows"}
    assert set(QC_TYPES) == {"ingest", "clean", "frames", "sync", "eyes", "face"}


def test_the_sample_takes_have_no_record_error(out: Path) -> None:
    for take in TAKES:
        e = _entry(out, take)
        assert not [c for c in _checks(out, e).values() if c.severity == "error"], take
        assert all(e.qc_error(cls) is None for cls in QC_TYPES.values())


#: the checks that read each stage's QC record (of a gaze_follow take with video and eyes; of a face take)
READERS = {
    "ingest": ["gap_share", "spikes", "crop", "clap_residual", "frames_without_video"],
    "clean": ["longest_gap", "fill_error", "spikes", "swaps", "crop", "invalid_frames", "clock_map"],
    "frames": ["invalid_frames"],
    "sync": list(C.SYNC_CHECKS),
    "eyes": list(C.EYES_CHECKS),
    "face": list(C.FACE_CHECKS),
}
# (stage, take, where in the QC record): a record that does not parse makes every check that reads it an error
MISSING = [
    ("ingest", "follow_sitting_01", ["gap_fraction"]),
    ("ingest", "follow_sitting_01", ["frames"]),
    ("clean", "follow_sitting_01", ["kept_frames"]),
    ("clean", "follow_sitting_01", ["markers", "CHA", "longest_gap_s"]),
    ("frames", "follow_sitting_01", ["invalid_frames"]),
    ("sync", "follow_sitting_01", ["n_claps"]),
    ("sync", "follow_sitting_01", ["claps", 0, "video_s"]),
    ("eyes", "follow_sitting_01", ["gated_share"]),
    ("face", "face_01", ["rows_tracked"]),
]


def _key(where: list) -> str:
    return "qc" + "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in where)


@pytest.mark.parametrize(("stage", "take", "where"), MISSING, ids=lambda v: str(v))
def test_a_missing_key_makes_the_checks_that_read_it_error(out: Path, stage: str, take: str, where: list) -> None:
    ids = READERS[stage]
    before = _checks(out, _entry(out, take))
    assert all(before[i].severity != "error" for i in ids)
    e = _entry(out, take)                                # (an entry converts each record's QC once)
    e.records[stage] = rec = copy.deepcopy(e.records[stage])
    node = rec["qc"]
    for k in where[:-1]:
        node = node[k]
    del node[where[-1]]
    got = _checks(out, e)
    record = f".gazepipe/units/session01/{take}/{stage}.json"
    for i in ids:
        assert got[i].severity == "error", (i, got[i])
        assert record in got[i].message and _key(where) in got[i].message, got[i].message
        assert "missing" in got[i].message
    # the take's other checks are as they were
    assert {i: c.severity for i, c in got.items() if i not in ids} == \
        {i: c.severity for i, c in before.items() if i not in ids}


def test_a_key_of_the_wrong_type_is_an_error_too(out: Path) -> None:
    e = _entry(out, "follow_sitting_01")
    e.records["sync"] = rec = copy.deepcopy(e.records["sync"])
    rec["qc"]["n_claps"] = "2"
    got = _checks(out, e)
    assert got["clock_drift"].severity == "error"
    assert "qc.n_claps: is str, not an integer" in got["clock_drift"].message
    e = _entry(out, "follow_sitting_01")
    e.records["clean"] = rec = copy.deepcopy(e.records["clean"])
    del rec["qc"]                                        # a record with no QC at all
    assert "clean.json: qc: missing from the unit record" in _checks(out, e)["crop"].message


def test_validate_fails_the_gate_on_a_record_that_lacks_a_key(out: Path, tmp_path: Path) -> None:
    copied = tmp_path / "out"
    shutil.copytree(out, copied)
    path = copied / ".gazepipe" / "units" / "session01" / "face_01" / "face.json"
    rec = json.loads(path.read_text())
    del rec["qc"]["unmatched_tracked"]
    path.write_text(json.dumps(rec))
    res = CliRunner().invoke(cli, ["validate", str(copied), "--plot-takes", "0"])
    assert res.exit_code == 3, res.output
    report = json.loads((copied / "qc" / "report.json").read_text())
    take = next(t for t in report["takes"] if t["take"] == "face_01")
    check = next(c for c in take["checks"] if c["id"] == "face_unmatched")
    assert check["severity"] == "error"
    assert ".gazepipe/units/session01/face_01/face.json: qc.unmatched_tracked: missing" in check["message"]
    assert str(tmp_path) not in check["message"]         # the report names no absolute path


def test_optional_keys_are_none_only_where_the_stage_may_leave_them_out(out: Path) -> None:
    rec = json.loads((out / ".gazepipe/units/session01/follow_sitting_01/clean.json").read_text())["qc"]
    assert "lowpass" not in rec and "swaps_not_checked" not in rec
    qc = CleanQC.from_record(rec)
    assert qc.lowpass is None and qc.swaps_not_checked is None
    assert "lowpass" not in qc.to_record()               # written back as the stage wrote it
    lp = CleanQC.from_record({**rec, "lowpass": {"cutoff_hz": 6.0, "order_per_pass": 2, "runs_unfiltered": 0}})
    assert lp.lowpass is not None and lp.lowpass.cutoff_hz == 6.0
    for key in ("gaps", "crop", "swap_pairs"):
        with pytest.raises(QCRecordError, match=f"r.json: qc.{key}: missing from the CleanQC record"):
            CleanQC.from_record({k: v for k, v in rec.items() if k != key}, "r.json")
    with pytest.raises(QCRecordError, match=r"qc.crop: has 3 item\(s\), not 2"):
        CleanQC.from_record({**rec, "crop": [0, 1, 2]})
    gaps = copy.deepcopy(rec["gaps"])
    gaps[0]["method"] = "spline"
    with pytest.raises(QCRecordError, match=r"qc.gaps\[0\].method: 'spline' is not a fill code"):
        CleanQC.from_record({**rec, "gaps": gaps})
    sync = json.loads((out / ".gazepipe/units/session01/follow_sitting_01/sync.json").read_text())["qc"]
    with pytest.raises(QCRecordError, match="qc.clock_bound_ms: is null"):
        SyncQC.from_record({**sync, "clock_bound_ms": None})
    claps = copy.deepcopy(sync["claps"])
    claps[0]["video_s"] = None                           # a mocap clap without a video clap: null is allowed
    assert SyncQC.from_record({**sync, "claps": claps}).claps[0].video_s is None
