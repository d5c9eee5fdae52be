"""Session-scoped units (SPEC §7): work every take reads (the subject's marker geometry, the neutral poses) runs once
per session as its own unit, with its own table and fingerprint, before the session's take units."""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path

import numpy as np
import pytest

import gazepipe.dag
from gazepipe.dag import run_pipeline
from gazepipe.errors import StageError
from gazepipe.io.session_toml import load_session
from gazepipe.model import Markers
from gazepipe.pipeline import registry
from gazepipe.pipeline.events import EventLog
from gazepipe.schemas.poses import PoseSource, stack_to_table, table_to_stack

gazepipe.dag.declare()   # the stages, read from the registry below


def _run(folder: Path, out: Path, **kw):
    return run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                        log=EventLog(fmt="json", stream=io.StringIO()), **kw)


def _with_neutral_take(folder: Path) -> Path:
    """The tiny session with its first take made the neutral take."""
    toml = folder / "session.toml"
    text = toml.read_text()
    toml.write_text(text.replace('kind = "gaze_follow"', 'kind = "neutral"', 1))
    return folder


def test_session_units_run_once_before_the_takes_and_are_then_up_to_date(tiny_session, tmp_path, monkeypatch):
    import gazepipe.stages.clean.stage as clean_stage
    import gazepipe.stages.frames.neutral as neutral

    folder = _with_neutral_take(tiny_session)
    cleaned: list[str] = []
    real = clean_stage.clean_markers

    def counting(raw, ms, kind, *args, **kw):
        cleaned.append(kw.get("take"))
        return real(raw, ms, kind, *args, **kw)

    monkeypatch.setattr(clean_stage, "clean_markers", counting)
    monkeypatch.setattr(neutral, "clean_markers", counting)   # the session's neutral poses clean through it
    out = tmp_path / "out"
    summary = _run(folder, out, until="frames")
    assert summary.exit_code == 0, [o.error for o in summary.failed]
    order = [(o.take, o.stage) for o in summary.outcomes]
    assert order[:2] == [("*", "subject_geometry"), ("*", "neutral_poses")]
    # the neutral take is cleaned by its own clean unit and once more for the session, however many takes
    # need its pose (t1 and t2 each used to clean it again in their frames unit)
    assert cleaned.count("t0") == 2
    assert sorted(cleaned) == ["t0", "t0", "t1", "t2"]
    for name in ("subject_geometry", "neutral_poses"):
        assert (out / "sessions" / "tiny" / f"{name}.parquet").is_file()
        rec = json.loads((out / ".gazepipe" / "session_units" / "tiny" / f"{name}.json").read_text())
        assert rec["status"] == "ok"
    poses = json.loads((out / ".gazepipe" / "session_units" / "tiny" / "neutral_poses.json").read_text())
    assert poses["qc"]["sources"] == ["neutral take t0"]
    frames = json.loads((out / ".gazepipe" / "units" / "tiny" / "t1" / "frames.json").read_text())
    assert frames["qc"]["neutral_sources"]["head"] == "neutral take t0"
    assert set(frames["components"]["upstream"]) == {"clean", "session:neutral_poses"}

    again = _run(folder, out, until="frames")
    assert {o.status for o in again.outcomes} == {"skipped"}
    assert ("*", "neutral_poses") in [(o.take, o.stage) for o in again.outcomes]


def test_a_changed_parameter_of_the_session_unit_reruns_it_and_the_takes_that_read_it(tiny_session, tmp_path):
    folder = _with_neutral_take(tiny_session)
    out = tmp_path / "out"
    assert _run(folder, out, until="frames").exit_code == 0
    again = _run(folder, out, until="frames", params={"frames.min_neutral_frames": 4})
    reasons = {(o.take, o.stage): o.reason for o in again.outcomes if o.status == "ok"}
    assert reasons[("*", "neutral_poses")] == "parameters changed: frames.min_neutral_frames"
    assert ("*", "subject_geometry") not in reasons
    assert set(reasons) == {("*", "neutral_poses"), ("t1", "frames"), ("t2", "frames")}


def test_a_failed_session_unit_blocks_only_the_take_units_that_read_it(tiny_session, tmp_path, monkeypatch):
    st = registry.get_session_stage("neutral_poses")

    def broken(ctx):
        raise StageError("mocap/t0.csv", "no usable frame")

    monkeypatch.setitem(registry._SESSION_STAGES, "neutral_poses", dataclasses.replace(st, run=broken))
    out = tmp_path / "out"
    summary = _run(tiny_session, out, until="frames")
    assert summary.exit_code == 1
    failed = [o for o in summary.outcomes if o.status == "failed"]
    assert [(o.take, o.stage) for o in failed] == [("*", "neutral_poses")]
    assert failed[0].error == "session tiny: stage neutral_poses: mocap/t0.csv: no usable frame"
    by_unit = {(o.take, o.stage): o.status for o in summary.outcomes}
    assert all(by_unit[(t, "clean")] == "ok" and by_unit[(t, "frames")] == "blocked" for t in ("t0", "t1", "t2"))
    assert "1 session unit failed" in summary.end_message()[0]
    # it is not retried on the same inputs, and still fails the run
    again = _run(tiny_session, out, until="frames")
    assert again.exit_code == 1
    assert {(o.take, o.stage): o.status for o in again.outcomes}[("t1", "frames")] == "blocked"


def test_the_dry_run_lists_the_session_units(tiny_session, tmp_path):
    summary = _run(tiny_session, tmp_path / "out", dry_run=True)
    planned = [(p.take, p.stage, p.run) for p in summary.plans]
    assert planned[:2] == [("*", "subject_geometry", True), ("*", "neutral_poses", True)]
    assert not (tmp_path / "out" / "sessions").exists()


def test_a_pose_stack_keeps_every_bit_of_its_positions():
    rng = np.random.default_rng(0)
    xyz = rng.normal(0, 500, (7, 3, 3))
    xyz[2, 1] = np.nan
    valid = np.isfinite(xyz).all(axis=2)
    a = Markers(labels=["A", "B", "C"], xyz=xyz, valid=valid, rate_hz=120.0, first_frame=5, units="mm")
    b = Markers(labels=["C", "D"], xyz=xyz[:4, :2], valid=valid[:4, :2], rate_hz=100.0)
    back = table_to_stack(stack_to_table([PoseSource("a", "t0", "neutral", a), PoseSource("b", "t1", "rest", b)]))
    assert [(p.label, p.take, p.role) for p in back] == [("a", "t0", "neutral"), ("b", "t1", "rest")]
    for got, want in zip(back, (a, b), strict=True):
        assert got.markers.labels == want.labels
        assert got.markers.rate_hz == want.rate_hz and got.markers.first_frame == want.first_frame
        np.testing.assert_array_equal(got.markers.valid, want.valid)
        assert np.array_equal(got.markers.xyz, want.xyz, equal_nan=True)
        assert got.markers.xyz.tobytes() == np.where(np.isnan(want.xyz), got.markers.xyz, want.xyz).tobytes()


@pytest.mark.parametrize("name", ["subject_geometry", "neutral_poses"])
def test_session_stages_are_registered_with_their_readers(name):
    readers = [st.name for st in registry.stages() if name in st.session_requires]
    assert readers == {"subject_geometry": ["clean"], "neutral_poses": ["frames"]}[name]


def test_a_take_without_a_rest_has_an_empty_neutral_table_that_reads_back(tmp_path):
    """A take without a rest period writes a ``neutral`` table of no frames; read back from Parquet (its marker
    dictionary comes back empty) it must still pass the check that later units' loads make."""
    from gazepipe.dag.store import check_stored_table
    from gazepipe.io.parquet import read_table, write_table
    from gazepipe.schemas.markers import MARKERS_CLEAN, markers_to_table

    empty = Markers(labels=["A", "B"], xyz=np.zeros((0, 2, 3)), valid=np.zeros((0, 2), bool), rate_hz=100.0)
    path = tmp_path / "neutral.parquet"
    write_table(markers_to_table(empty, fill_code=np.zeros((0, 2), np.int8), meta={"rest": None}), path,
                MARKERS_CLEAN)
    check_stored_table(read_table(path), path, "neutral")


def test_the_subject_geometry_reads_back_with_every_bit():
    """The swap references a session unit computes are what each take's clean reads, bit for bit."""
    import dataclasses as dc

    from gazepipe.schemas.poses import arrays_to_table, table_to_arrays
    from gazepipe.stages.clean.swaps import References, pooled_references

    rng = np.random.default_rng(1)
    base = rng.normal(0, 100, (6, 3))
    takes = []
    for _ in range(2):
        xyz = base[None] + rng.normal(0, 0.5, (300, 6, 3))
        valid = rng.random((300, 6)) > 0.05
        xyz[~valid] = np.nan
        takes.append(([f"M{i}" for i in range(6)], xyz, valid))
    refs = pooled_references(takes).references
    arrays = {f.name: getattr(refs, f.name) for f in dc.fields(refs) if getattr(refs, f.name) is not None}
    back = References(**table_to_arrays(arrays_to_table(arrays)))
    for f in dc.fields(refs):
        want, got = getattr(refs, f.name), getattr(back, f.name)
        if want is None:
            assert got is None
            continue
        assert got.dtype == want.dtype and got.shape == want.shape, f.name
        assert got.tobytes() == want.tobytes(), f.name


def test_a_broken_neutral_capture_fails_its_own_take_and_the_others_go_on_without_it(tiny_session, tmp_path):
    folder = _with_neutral_take(tiny_session)
    (folder / "mocap" / "t0.csv").write_bytes(b"\x00\xff garbage, not a capture\n" * 3)
    summary = _run(folder, tmp_path / "out", until="frames")
    assert summary.exit_code == 1
    by_unit = {(o.take, o.stage): o for o in summary.outcomes}
    assert by_unit[("t0", "ingest")].status == "failed" and "t0.csv" in by_unit[("t0", "ingest")].error
    # the session's poses are made without it, saying so, instead of failing every take's frames with it
    assert by_unit[("*", "neutral_poses")].status == "ok"
    assert any("neutral take t0 left out" in w and "t0.csv" in w for w in by_unit[("*", "neutral_poses")].warnings)
    # the tiny takes sway without a rest: with no neutral take their frames have no pose, each its own verdict
    for take in ("t1", "t2"):
        frames = by_unit[(take, "frames")]
        assert frames.status == "failed" and "no neutral take and no rest period" in frames.error
        assert f"{take}.csv" in frames.error
