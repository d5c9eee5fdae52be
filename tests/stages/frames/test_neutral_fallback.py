"""Neutral calibration's last resort (SPEC §3.3): a segment whose markers are never all there in the take's own
first rest, in a session without a neutral take, is calibrated on another take's first rest. The session's
neutral poses are cleaned once, by the session unit ``neutral_poses``; changing a capture it read re-runs it and
the frames units that read it."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from gazepipe.dag import run_pipeline
from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog
from gazepipe.schemas.joints import joints_arrays
from gazepipe.stages.geometry import from_wxyz
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.session import write_c3d

LOST = "CHB"        # a chest marker, hidden from the start of one take well past its first rest


def _run(folder, out):
    return run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                        log=EventLog(fmt="json", stream=io.StringIO()))


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("fallback")
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=12.0, head_camera=False, face_takes=(),
                      shift_targets=((36.0, 12.0),), neutral_s=0.0, gaps=False)
    folder = generate_session(root / "s", seed=3, config=cfg)
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    take = next(t for t, v in truth.items() if v["kind"] == "gaze_follow")
    path = folder / "mocap" / f"{take}.c3d"
    mk = read_markers(str(path))
    rest_end = truth[take]["rest_periods"][0][1]
    xyz = mk.xyz.copy()
    xyz[: rest_end + int(4 * mk.rate_hz), mk.labels.index(LOST)] = np.nan   # > max_gap_s: stays a gap
    write_c3d(path, list(mk.labels), xyz, mk.rate_hz)
    out = root / "out"
    summary = _run(folder, out)
    return folder, out, take, summary


def test_the_segment_is_calibrated_on_another_takes_rest(session):
    folder, out, take, summary = session
    assert [o.error for o in summary.failed if o.take != "-"] == []     # (no eyes: the datasets are not built)
    rec = json.loads((out / ".gazepipe" / "units" / "session01" / take / "frames.json").read_text())
    other = [t.id for t in load_session(folder / "session.toml").takes if t.id != take and t.mocap]
    assert rec["qc"]["neutral_sources"]["chest"] == f"first rest period of take {other[0]}"
    assert rec["qc"]["neutral_sources"]["head"].startswith("first rest period [")
    assert rec["read"] == {}     # the frames unit reads no other take's capture: the session unit did
    poses = json.loads((out / ".gazepipe" / "session_units" / "session01" / "neutral_poses.json").read_text())
    # no neutral take: first rests in session order until every segment has one (this take's lacks the chest)
    assert poses["qc"]["sources"] == [f"first rest period of take {take}", f"first rest period of take {other[0]}"]
    assert poses["qc"]["segments_without_neutral"] == []
    # the chest is right once its markers are back, calibrated on the other take's rest
    joints = joints_arrays(pq.read_table(out / "takes" / "session01" / take / "joints.parquet"))
    tr = np.load(folder / "truth" / f"{take}.npz")
    seg = list(joints["segments"]).index("chest")
    frames = joints["frame"]
    ok = np.isfinite(joints["quat"][:, seg]).all(axis=1)
    assert ok.sum() > 100
    want = from_wxyz(tr["seg_quat_char"][frames[ok], list(tr["segments"]).index("chest")].astype(np.float64))
    err = np.degrees((from_wxyz(joints["quat"][ok, seg]) * want.inv()).magnitude())
    assert np.median(err) < 1.0, np.median(err)


def test_changing_the_capture_it_read_reruns_the_unit(session):
    folder, out, take, _ = session
    other = [t for t in load_session(folder / "session.toml").takes if t.id != take and t.mocap][0]
    again = _run(folder, out)
    assert not [o for o in again.outcomes if o.status == "ok" and o.stage == "frames"]
    path = folder / other.mocap if not str(other.mocap).startswith("/") else other.mocap
    mk = read_markers(str(path))
    write_c3d(path, list(mk.labels), mk.xyz + 0.01, mk.rate_hz)
    third = _run(folder, out)
    reran = {(o.take, o.stage): o.reason for o in third.outcomes if o.status == "ok"}
    assert reran[("*", "neutral_poses")] == f"input changed: mocap/{other.id}.c3d"
    assert "session:neutral_poses" in reran[(take, "frames")]
