"""Small but real datasets for the reading-API, trainer and README-example tests.

Generated sessions (:mod:`gazepipe.synth`) go through the dataset builder's pure API
(:func:`gazepipe.stages.build.stage.build_dataset`) and the dataset writer, as ``gazepipe run`` does:

- gaze_rnn / gaze_rnn_lod: five 40 s gaze_follow takes from the generator's truth (segment rotations, target and
  eye directions); four train, one val;
- gaze_map: a 9 x 5 grid of gaze_shift takes (yaw -72..72 by 18 deg, pitch -24..24 by 12 deg) from truth, three
  interior ones held out as val;
- face_clean: four 30 s Live Link Face takes at 60 Hz through the face stage (reader, alignment); three train,
  one val.

Built once per test run by the ``generated_datasets`` fixture (tests/conftest.py) and shared read-only.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pyarrow as pa

from tests.helpers.sample import truth_joints

GAZE_MAP_VAL = ((18.0, 12.0), (-36.0, 0.0), (54.0, -12.0))
FOLLOW_POSES = ("standing", "standing", "sitting", "standing", "sitting")
FOLLOW_VAL = "follow_standing_03"
FACE_VAL = "face_04"


def _eyes_table(tr: dict, frames: np.ndarray) -> pa.Table:
    from gazepipe.schemas.tracks import EYES

    d = tr["eye_dir_char"][frames].astype(np.float64)
    vec = pa.FixedSizeListArray.from_arrays(pa.array(d.reshape(-1)), 3)
    n = len(frames)
    rate = float(tr["scalars"]["rate_hz"])
    return pa.Table.from_pydict({
        "frame": pa.array(frames.astype(np.int32)), "source_frame": pa.array(frames + 1),
        "time_s": pa.array(frames / rate), "valid": pa.array(np.ones(n, bool)),
        "filled": pa.array(np.zeros(n, bool)), "confidence": pa.array(np.full(n, 0.95)),
        "eye_dir_char": vec, "eye_dir_head": vec,
    }, schema=EYES)


def _pin(take, split: str):
    return dataclasses.replace(take, split=split)


def make_datasets(out: Path) -> Path:
    """Generate the sessions under ``out/sessions`` and write the four datasets under ``out/datasets``."""
    from gazepipe.io.dataset_files import write_dataset
    from gazepipe.io.livelinkface import read_livelinkface
    from gazepipe.io.session_toml import load_session
    from gazepipe.schemas.face_table import face_to_table
    from gazepipe.stages.build.stage import BuildParams, TakeTables, build_dataset
    from gazepipe.stages.face.stage import align_face
    from gazepipe.synth import load_truth
    from gazepipe.synth.session import SynthConfig, generate_session

    datasets = out / "datasets"
    base = dict(neutral_s=0.0, head_camera=False, gaps=False)
    shifts = tuple((float(y), float(p)) for y in range(-72, 73, 18) for p in (-24, -12, 0, 12, 24))
    cfgs = {
        "follow": SynthConfig(follow_poses=FOLLOW_POSES, follow_duration_s=40.0, shift_targets=(), face_takes=(),
                              **base),
        "shift": SynthConfig(follow_poses=(), shift_targets=shifts, face_takes=(), **base),
        "face": SynthConfig(follow_poses=(), shift_targets=(), face_takes=((60.0, 30.0),) * 4, **base),
    }
    sessions = {k: load_session(generate_session(out / "sessions" / k, seed=3, config=c) / "session.toml")
                for k, c in cfgs.items()}
    params = BuildParams()

    s = sessions["follow"]
    follow = []
    for t in s.takes:
        tr = load_truth(s.root, t.id)
        frames = np.arange(*tr["scalars"]["crop"])
        follow.append(TakeTables(session=s.id, subject=s.subject, take=_pin(t, "val" if t.id == FOLLOW_VAL else
                                                                            "train"),
                                 joints=truth_joints(tr, frames), eyes=_eyes_table(tr, frames), markerset=s.markerset))
    for name in ("gaze_rnn", "gaze_rnn_lod"):
        write_dataset(build_dataset(name, follow, params), datasets)

    s = sessions["shift"]
    shift = []
    for t in s.takes:
        tr = load_truth(s.root, t.id)
        if tr["scalars"]["crop"] is None:     # (0, 0): no shift to crop
            continue
        frames = np.arange(*tr["scalars"]["crop"])
        split = "val" if (t.target_yaw_deg, t.target_pitch_deg) in GAZE_MAP_VAL else "train"
        shift.append(TakeTables(session=s.id, subject=s.subject, take=_pin(t, split),
                                joints=truth_joints(tr, frames), markerset=s.markerset,
                                meta={"rests": tr["scalars"]["rest_periods"]}))
    write_dataset(build_dataset("gaze_map", shift, params), datasets)

    s = sessions["face"]
    face = []
    for t in s.takes:
        trk, cln = (read_livelinkface(p, rate_hz=t.rate_hz, timecode_fps=t.timecode_fps) for p in (t.tracked, t.clean))
        table = face_to_table(align_face(trk, cln), meta={"rate_hz": trk.rate_hz})
        face.append(TakeTables(session=s.id, subject=s.subject, take=_pin(t, "val" if t.id == FACE_VAL else "train"),
                               face=table))
    write_dataset(build_dataset("face_clean", face, params), datasets)
    return datasets
