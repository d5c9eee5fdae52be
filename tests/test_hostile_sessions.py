"""The whole pipeline on hostile generated sessions (ghost spikes on any marker, 1–3 s occlusions of trunk and
neck markers inside the first rest and across the crop's edges, dense gaps), in both marker layouts and both
lab up axes, row by row against the ground truth (SPEC §3.2, §3.3, §3.6)."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog
from gazepipe.schemas.base import read_meta
from gazepipe.stages.geometry import from_wxyz, matrix_from_six
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENTS


@pytest.fixture(scope="module", params=[(SEGMENTS, "z"), (FOUR_SEGMENTS, "y")], ids=["10seg-zup", "4seg-yup"])
def hostile_run(request, tmp_path_factory):
    segments, up = request.param
    root = tmp_path_factory.mktemp("hostile")
    cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=15.0, head_camera=False,
                      face_takes=(), shift_targets=((36.0, 12.0), (-72.0, 0.0)), spikes_per_marker_min=2.0,
                      long_gaps=4, gaps_per_marker_min=3.0, segments=segments, up_axis=up)
    folder = generate_session(root / "s", seed=4, config=cfg)
    out = root / "out"
    summary = run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                           log=EventLog(fmt="json", stream=io.StringIO()))
    return folder, out, summary


def test_no_take_fails_a_stage_over_a_missing_marker(hostile_run):
    _, _, summary = hostile_run
    assert [o.error for o in summary.failed if o.take != "-"] == []


def test_every_lod_row_is_within_five_degrees_of_the_truth(hostile_run):
    """Every segment rotation of every unmirrored gaze_rnn_lod row: none more than 5° from the truth, median at
    most 1°, 99th percentile at most 3°; the target direction within 3°; and the dataset holds most of the
    crop's frames."""
    folder, out, _ = hostile_run
    root = out / "datasets" / "gaze_rnn_lod"
    info = json.loads((root / "_dataset.json").read_text())
    names = [n.split(".")[0] for n in info["features"]["y"][0::6]]
    errors, target_errors, rows, crop_frames = [], [], 0, 0
    truth_meta = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    for f in sorted(root.rglob("*.parquet")):
        t = pq.read_table(f, columns=["take", "mirrored", "frame", "x", "y"])
        keep = ~t.column("mirrored").to_numpy(zero_copy_only=False)
        take = t.column("take")[0].as_py()
        truth = np.load(folder / "truth" / f"{take}.npz")
        frames = t.column("frame").to_numpy()[keep]
        y = t.column("y").combine_chunks().flatten().to_numpy().reshape(t.num_rows, -1)[keep]
        x = t.column("x").combine_chunks().flatten().to_numpy().reshape(t.num_rows, -1)[keep, :3]
        cos = (x * truth["target_dir_char"][frames]).sum(axis=1) / np.linalg.norm(x, axis=1)
        target_errors.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        idx = [list(truth["segments"]).index(n) for n in names]
        got = Rotation.from_matrix(matrix_from_six(y.reshape(-1, 6).astype(np.float64)))
        want = from_wxyz(truth["seg_quat_char"][frames][:, idx].reshape(-1, 4).astype(np.float64))
        errors.append(np.degrees((got * want.inv()).magnitude()))
        rows += len(frames)
        a, b = truth_meta[take]["crop"]
        crop_frames += b - a
    err = np.concatenate(errors)
    assert err.max() <= 5.0 and np.median(err) <= 1.0 and np.percentile(err, 99) <= 3.0, \
        (err.max(), np.median(err), np.percentile(err, 99))
    assert rows >= 0.8 * crop_frames, (rows, crop_frames)
    # the target direction too: a fill across a turn of the target that the samples beside it hide is refused
    assert np.concatenate(target_errors).max() <= 3.0, np.concatenate(target_errors).max()
    dropped = info["counts"]["dropped_frames"]
    assert set(dropped) == {"no_character_frame", "segment_missing", "no_target", "first_of_run"}


def test_spikes_are_marked_in_the_cleaned_markers(hostile_run):
    """Most ghost spikes inside the crop are marked ``spike`` in the cleaned markers, and few other samples."""
    folder, out, _ = hostile_run
    caught = total = false = measured = 0
    for take_dir in sorted((out / "takes").glob("*/*")):
        path = take_dir / "markers.parquet"
        if not path.is_file():
            continue
        t = pq.read_table(path, columns=["frame", "spike"])
        labels = read_meta(pq.read_schema(path))["labels"]
        n = len(labels)
        frames = t.column("frame").to_numpy()[: t.num_rows // n]
        spike = t.column("spike").to_numpy(zero_copy_only=False).reshape(n, -1).T
        truth = np.load(folder / "truth" / f"{take_dir.name}.npz")
        want = truth["spike_mask"][frames][:, [list(truth["labels"]).index(lab) for lab in labels]]
        caught += int((spike & want).sum())
        total += int(want.sum())
        false += int((spike & ~want).sum())
        measured += int(want.size)
    assert total > 20 and caught >= 0.9 * total and false <= 0.001 * measured, (caught, total, false, measured)


def test_filled_segment_rotations_are_close_to_the_truth(hostile_run, request):
    """Rotations filled across their markers' gaps (by slerp or by the neighbour model): within 5° of the truth
    everywhere, and the neighbour model used where it was the better guess. (The four-segment session has one
    gap its estimate could fill, a 101-frame neck gap in a gaze_follow take whose hold-out stretches that move
    like it give 2.3°: it stays open, so only the ten-segment session must have fills.)"""
    from gazepipe.schemas.joints import joints_arrays

    folder, out, _ = hostile_run
    errors, methods = [], set()
    for path in sorted((out / "takes").glob("*/*/joints.parquet")):
        j = joints_arrays(pq.read_table(path))
        truth = np.load(folder / "truth" / f"{path.parent.name}.npz")
        idx = [list(truth["segments"]).index(s) for s in j["segments"]]
        rows, segs = np.nonzero(j["rot_filled"])
        if len(rows):
            got = from_wxyz(j["quat"][rows, segs])
            want = from_wxyz(truth["seg_quat_char"][j["frame"][rows]][np.arange(len(rows)),
                                                                       np.asarray(idx)[segs]].astype(np.float64))
            errors.append(np.degrees((got * want.inv()).magnitude()))
        rec = json.loads((out / ".gazepipe" / "units" / path.parts[-3] / path.parent.name / "frames.json").read_text())
        methods |= {g["method"] for g in rec["qc"]["rotation_gaps"] if g["filled"]}
    err = np.concatenate(errors) if errors else np.zeros(0)
    assert err.size == 0 or err.max() <= 5.0, err.max()
    # slerp or the neighbours' model, either one turned to meet the markers still measured in the gap
    assert methods <= {"slerp", "model", "slerp+markers", "model+markers"}
    if "10seg" in request.node.callspec.id:
        assert len(err) > 50 and methods
