"""Tests of the dataset builders (gaze_rnn, gaze_rnn_lod, gaze_map, face_clean) and the dataset writer/reader.

gaze_rnn inputs are built from the sample session's truth (segment rotations, target and eye directions of the
gaze_follow takes, as a joints and an eyes table), since the sample session has no eye tracking; gaze_map is
checked against the generator's truth both on the truth's own rotations and on the pipeline's output
(read → clean → frames) for the noisy capture files.
"""

from __future__ import annotations

import dataclasses
import json
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest
from scipy.spatial.transform import Rotation

from gazepipe.errors import SchemaError, StageError
from gazepipe.io.dataset_files import (
    StagedDatasetWriter,
    open_dataset,
    read_dataset,
    read_info,
    take_path,
    write_dataset,
)
from gazepipe.io.session_toml import load_session
from gazepipe.model import Take
from gazepipe.schemas.base import with_identity
from gazepipe.schemas.joints import fixed_list, joints_arrays, joints_to_table, list_to_numpy
from gazepipe.schemas.tracks import EYES
from gazepipe.stages.build.splits import assign_split
from gazepipe.stages.build.stage import BuildParams, TakeTables, build_dataset
from gazepipe.stages.frames.stage import Joints
from gazepipe.stages.geometry import from_wxyz, matrix_from_six, six_from_rotation, to_wxyz
from gazepipe.synth import load_truth
from tests.helpers import SAMPLE
from tests.helpers.sample import near_threshold, peak_speeds, truth_joints

RATE = 30000 / 1001
FOLLOW = ("follow_standing_01", "follow_standing_02", "follow_sitting_01")
M = np.diag([-1.0, 1.0, 1.0])


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return SAMPLE


@pytest.fixture(scope="module")
def session(root):
    return load_session(root / "session.toml")


def eyes_table(tr: dict, frames: np.ndarray, invalid: np.ndarray) -> pa.Table:
    """An eyes table with the truth's eye direction, ``invalid`` rows marked invalid."""
    d = tr["eye_dir_char"][frames].astype(np.float64)
    vec = pa.FixedSizeListArray.from_arrays(pa.array(d.reshape(-1)), 3)
    n = len(frames)
    return pa.Table.from_pydict({
        "frame": pa.array(frames.astype(np.int32)), "source_frame": pa.array(frames + 1),
        "time_s": pa.array(frames / RATE), "valid": pa.array(~invalid), "filled": pa.array(np.zeros(n, bool)),
        "confidence": pa.array(np.where(invalid, 0.1, 0.95)), "eye_dir_char": vec, "eye_dir_head": vec,
    }, schema=EYES)


@pytest.fixture(scope="module")
def follow_takes(session):
    """TakeTables of the three gaze_follow takes from truth; 1 % of eye frames invalid (seeded)."""
    rng = np.random.default_rng(7)
    out, invalid_frames = [], {}
    for tid in FOLLOW:
        tr = load_truth(session.root, tid)
        c0, c1 = tr["scalars"]["crop"]
        frames = np.arange(c0, c1)
        bad = rng.random(len(frames)) < 0.01
        invalid_frames[tid] = frames[bad]
        take = session.take(tid)
        out.append(TakeTables(session=session.id, subject=session.subject, take=take,
                              joints=truth_joints(tr, frames), eyes=eyes_table(tr, frames, bad),
                              markerset=session.markerset, meta={"rests": tr["scalars"]["rest_periods"]}))
    return out, invalid_frames


def pinned_take(t: Take, split: str | None) -> Take:
    return Take(id=t.id, kind=t.kind, pose=t.pose, mocap=t.mocap, split=split,
                target_yaw_deg=t.target_yaw_deg, target_pitch_deg=t.target_pitch_deg)


def pinned(tt: TakeTables, split: str | None) -> TakeTables:
    t = tt.take
    take = Take(id=t.id, kind=t.kind, pose=t.pose, mocap=t.mocap, split=split,
                target_yaw_deg=t.target_yaw_deg, target_pitch_deg=t.target_pitch_deg)
    return TakeTables(session=tt.session, subject=tt.subject, take=take, joints=tt.joints, eyes=tt.eyes,
                      face=tt.face, markerset=tt.markerset, meta=tt.meta)


@pytest.fixture(scope="module")
def rnn(follow_takes):
    takes, _ = follow_takes
    splits = {"follow_standing_01": "train", "follow_standing_02": "val", "follow_sitting_01": "train"}
    takes = [pinned(t, splits[t.take.id]) for t in takes]
    return {name: build_dataset(name, takes) for name in ("gaze_rnn", "gaze_rnn_lod")}


def xy(table: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    return (list_to_numpy(table.column("x"), table.schema.field("x").type.list_size),
            list_to_numpy(table.column("y"), table.schema.field("y").type.list_size))


# ------------------------------------------------------------------------------------------------ gaze_rnn

def test_rnn_sizes_and_feature_names(rnn):
    full, lod = rnn["gaze_rnn"], rnn["gaze_rnn_lod"]
    assert (full.info["sizes"]["n_in"], full.info["sizes"]["n_out"]) == (66, 63)
    assert (lod.info["sizes"]["n_in"], lod.info["sizes"]["n_out"]) == (21, 18)
    assert full.schema.field("x").type == pa.list_(pa.float32(), 66)
    f = full.info["features"]
    assert len(f["x"]) == 66 and len(f["y"]) == 63 and len(set(f["x"])) == 66
    assert f["x"][:4] == ["target_dir.x", "target_dir.y", "target_dir.z", "pelvis.fwd.x"]
    assert f["x"][-3:] == ["eye_dir.x", "eye_dir.y", "eye_dir.z"] and f["y"] == f["x"][3:]
    assert lod.info["features"]["y"][::6] == ["pelvis.fwd.x", "chest.fwd.x", "head.fwd.x"]
    assert full.info["fps"] == pytest.approx(RATE) and full.info["window"] == 120
    counts = full.info["counts"]
    assert counts["segments"] == sum(v["segments"] for v in counts["per_take"].values())
    assert counts["rows"] == sum(v["rows"] for v in counts["per_take"].values())
    assert all(v["rows"] == 2 * (v["usable_frames"] - v["segments"]) for v in counts["per_take"].values())


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_y_is_next_x_within_segments(rnn, name):
    for table in rnn[name].tables.values():
        x, y = xy(table)
        seg = table.column("segment").to_numpy()
        frame = table.column("frame").to_numpy()
        mir = table.column("mirrored").to_numpy()
        nxt = (seg[1:] == seg[:-1]) & (mir[1:] == mir[:-1])
        assert nxt.sum() > 0.9 * len(seg)
        assert np.all(np.diff(frame)[nxt] == 1)           # rows of a segment are consecutive frames
        np.testing.assert_array_equal(x[1:][nxt][:, 3:], y[:-1][nxt])


def test_rnn_matches_truth_and_directions_are_unit(rnn, session):
    table = rnn["gaze_rnn"].tables[("session01", "follow_standing_01")]
    x, y = xy(table)
    orig = ~table.column("mirrored").to_numpy()
    frames = table.column("frame").to_numpy()[orig]
    tr = load_truth(session.root, "follow_standing_01")
    np.testing.assert_allclose(x[orig, :3], tr["target_dir_char"][frames], atol=1e-6)
    np.testing.assert_allclose(y[orig, -3:], tr["eye_dir_char"][frames], atol=1e-6)
    np.testing.assert_allclose(x[orig, -3:], tr["eye_dir_char"][frames - 1], atol=1e-6)
    head = from_wxyz(tr["seg_quat_char"][frames, 9].astype(np.float64)).as_matrix()
    np.testing.assert_allclose(y[orig, 54:57], head[:, :, 2], atol=1e-6)     # head forward = R·ẑ
    np.testing.assert_allclose(y[orig, 57:60], head[:, :, 1], atol=1e-6)     # head up = R·ŷ
    for name in ("gaze_rnn", "gaze_rnn_lod"):
        for t in rnn[name].tables.values():
            x, y = xy(t)
            vecs = np.concatenate([x.reshape(len(x), -1, 3), y.reshape(len(y), -1, 3)], axis=1)
            np.testing.assert_allclose(np.linalg.norm(vecs.astype(np.float64), axis=2), 1.0, atol=2e-6)


def test_invalid_eyes_end_segments(rnn, follow_takes):
    _, invalid = follow_takes
    for (_, tid), table in rnn["gaze_rnn"].tables.items():
        orig = ~table.column("mirrored").to_numpy()
        frame = table.column("frame").to_numpy()[orig]
        seg = table.column("segment").to_numpy()[orig]
        bad = invalid[tid]
        assert len(bad) > 3
        # a row needs its frame and the previous one: no row at an invalid frame or right after it
        assert not np.isin(frame, bad).any() and not np.isin(frame, bad + 1).any()
        # rows on both sides of an invalid frame belong to different segments
        for f in bad:
            before, after = seg[frame < f], seg[frame > f + 1]
            if len(before) and len(after):
                assert before.max() < after.min()
        assert seg.max() + 1 == rnn["gaze_rnn"].info["counts"]["per_take"][f"session01/{tid}"]["segments"]
    # the LOD dataset has no eyes, so invalid eyes do not cut it
    lod = rnn["gaze_rnn_lod"].tables[("session01", "follow_standing_01")]
    assert lod.column("segment").to_numpy().max() == 0


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_mirrored_rows_are_exact_mirrors(rnn, name):
    built = rnn[name]
    for table in built.tables.values():
        mir = table.column("mirrored").to_numpy()
        assert mir.sum() * 2 == len(mir) and not mir[: len(mir) // 2].any()
        half = len(mir) // 2
        for c in ("segment", "frame", "time_s", "take", "split"):
            col = table.column(c).to_numpy(zero_copy_only=False)
            np.testing.assert_array_equal(col[:half], col[half:])
        x, y = xy(table)
        xo, xm, yo, ym = x[:half], x[half:], y[:half], y[half:]
        # directions: X negated; rotations: M·R·M in the 6-number form, computed from the matrices
        np.testing.assert_array_equal(xm[:, :3], xo[:, :3] * np.float32([-1, 1, 1]))
        n_seg = (y.shape[1] - (3 if name == "gaze_rnn" else 0)) // 6
        r = matrix_from_six(yo[:, : 6 * n_seg].reshape(-1, n_seg, 6).astype(np.float64))
        mr = M @ r @ M
        six_m = np.concatenate([mr[..., :, 2], mr[..., :, 1]], axis=-1).reshape(len(yo), -1)
        np.testing.assert_allclose(ym[:, : 6 * n_seg], six_m, atol=2e-6)
        # every X component negated, every other value unchanged, bit for bit (so mirroring twice is exact)
        sign = np.where([n.endswith(".x") for n in built.info["features"]["x"]], -1, 1).astype(np.float32)
        np.testing.assert_array_equal(xm, xo * sign)


def test_mirror_swaps_left_right_segments():
    """Segments named as a left/right pair swap blocks in the mirrored rows (SPEC §2), central ones do not."""
    rng = np.random.default_rng(3)
    n, segs = 40, ["pelvis", "arm_l", "arm_r"]
    q = Rotation.random(n * 3, random_state=rng).as_quat(canonical=True, scalar_first=True).reshape(n, 3, 4)
    six = six_from_rotation(from_wxyz(q.reshape(-1, 4))).reshape(n, 3, 6)
    tgt = rng.normal(size=(n, 3))
    j = Joints(segments=segs, parents=np.array([-1, 0, 0]), quat=q, quat_local=q, six=six,
               head_centre=np.zeros((n, 3)), target_dir=tgt / np.linalg.norm(tgt, axis=1, keepdims=True),
               char_origin=np.zeros((n, 3)), char_rot=np.tile([1.0, 0, 0, 0], (n, 1)), valid=np.ones(n, bool),
               rate_hz=30.0)
    frames = np.arange(n)
    eyes = eyes_table({"eye_dir_char": tgt}, frames, np.zeros(n, bool))
    tt = TakeTables(session="s", subject="p", take=Take(id="t", kind="gaze_follow", pose="standing", split="train"),
                    joints=joints_to_table(j, frames), eyes=eyes)
    table = build_dataset("gaze_rnn", [tt]).tables[("s", "t")]
    _, y = xy(table)
    half = len(y) // 2
    blocks, mblocks = y[:half, :18].reshape(-1, 3, 6), y[half:, :18].reshape(-1, 3, 6)
    flip = np.float32([-1, 1, 1, -1, 1, 1])
    np.testing.assert_array_equal(mblocks[:, 0], blocks[:, 0] * flip)
    np.testing.assert_array_equal(mblocks[:, 1], blocks[:, 2] * flip)     # mirrored left arm = right arm
    np.testing.assert_array_equal(mblocks[:, 2], blocks[:, 1] * flip)


def test_take_without_eyes_is_skipped_for_gaze_rnn_only(follow_takes):
    takes, _ = follow_takes
    takes = [pinned(t, "train") for t in takes]
    no_eyes = TakeTables(session=takes[0].session, subject=takes[0].subject, take=takes[0].take,
                         joints=takes[0].joints, markerset=takes[0].markerset)
    takes = [no_eyes, *takes[1:]]
    full = build_dataset("gaze_rnn", takes)
    assert [s["take"] for s in full.info["skipped"]] == ["follow_standing_01"]
    assert "eyes" in full.info["skipped"][0]["reason"]
    assert ("session01", "follow_standing_01") not in full.tables
    lod = build_dataset("gaze_rnn_lod", takes)
    assert ("session01", "follow_standing_01") in lod.tables and not lod.info["skipped"]


# ------------------------------------------------------------------------------------------------ splits

def test_splits_pinned_hashed_and_disjoint(follow_takes, rnn):
    assert assign_split("any", "test") == "test"
    ids = [f"take_{i:04d}" for i in range(2000)]
    got = [assign_split(t, None) for t in ids]
    assert got == [assign_split(t, None) for t in ids]                 # deterministic
    share = {s: got.count(s) / len(got) for s in ("train", "val", "test")}
    assert abs(share["train"] - 0.8) < 0.03 and abs(share["val"] - 0.1) < 0.02
    assert [assign_split(t, None, 0.5, 0.25) for t in ids] != got
    # the same take id in many sessions is drawn independently per session
    per_session = {assign_split(f"s{i:03d}/follow_standing_01", None) for i in range(100)}
    assert per_session == {"train", "val", "test"}
    # every take's rows, mirrored included, are in one split; pins win
    built = rnn["gaze_rnn"]
    where: dict[str, set] = {}
    for table in built.tables.values():
        for take, split in zip(table.column("take").to_pylist(), table.column("split").to_pylist(), strict=True):
            where.setdefault(take, set()).add(split)
    assert where == {"follow_standing_01": {"train"}, "follow_standing_02": {"val"},
                     "follow_sitting_01": {"train"}}
    assert built.info["splits"]["takes"]["val"] == ["session01/follow_standing_02"]
    assert "split 'test' is empty: every take is pinned to another split" in built.info["warnings"]


def test_splits_never_empty_when_a_take_can_fill_them(follow_takes):
    """SPEC §3.6: the train split is never empty while an unpinned take exists, and a take changes split only to
    fill a split that would otherwise be empty; a moved take's rows carry its new split, the statistics follow,
    and a warning says why it moved."""
    from gazepipe.stages.build.splits import rebalance

    takes, _ = follow_takes
    # every take hashed out of train: the one nearest train's share moves there
    salted = next(salt for salt in (f"s{i}" for i in range(500))
                  if all(assign_split(f"{t.session}/{t.take.id}", None, salt=salt) != "train" for t in takes))
    built = build_dataset("gaze_rnn_lod", takes, BuildParams(split_salt=salted))
    info = built.info
    assert info["counts"]["by_split"]["train"]["takes"] == 1
    moved = [w for w in info["warnings"] if " moved from " in w]
    assert len(moved) == 1 and "to train: the train split would be empty" in moved[0]
    for table in built.tables.values():
        take = f"session01/{table.column('take')[0].as_py()}"
        want = next(s for s, v in info["splits"]["takes"].items() if take in v)
        assert set(table.column("split").to_pylist()) == {want}
    assert info["stats"]["overall"]["rows"] == info["counts"]["by_split"]["train"]["rows"] > 0
    # with five or more takes every split gets one, moved from a split that keeps one; few takes are left be
    keys = [f"s/take_{i}" for i in range(6)]
    moves = rebalance([(k, "train", False) for k in keys])
    assert sorted(m[2] for m in moves) == ["test", "val"] and all(m[1] == "train" for m in moves)
    # three or four: train and val a take each (a trainer needs something to validate on), test may stay empty
    for n in (3, 4):
        assert [m[1:3] for m in rebalance([(k, "train", False) for k in keys[:n]])] == [("train", "val")]
    assert rebalance([(k, "train", False) for k in keys[:2]]) == []
    three = rebalance([("a", "train", True), ("b", "train", False), ("c", "test", False)])
    assert [m[:3] for m in three] == [("b", "train", "val")]          # one pinned to train: the other moves
    assert rebalance([("a", "val", True), ("b", "test", True)]) == []          # pinned takes stay
    assert rebalance([("a", "val", True), ("b", "test", False)])[0][:3] == ("b", "test", "train")
    assert rebalance([(k, "train", False) for k in keys]) == moves            # deterministic


def test_no_training_take_is_an_error(follow_takes):
    takes, _ = follow_takes
    with pytest.raises(StageError, match="no training take"):
        build_dataset("gaze_rnn_lod", [pinned(t, "val") for t in takes])


def test_stats_equal_recomputation_over_training_rows(rnn, tmp_path):
    built = rnn["gaze_rnn"]
    write_dataset(built, tmp_path)
    table = open_dataset(tmp_path / "gaze_rnn").to_table()
    train = table.filter(pa.compute.equal(table.column("split"), "train"))
    assert 0 < train.num_rows < table.num_rows
    stats = read_info(tmp_path / "gaze_rnn")["stats"]
    for pose in (None, "standing", "sitting"):
        sub = train if pose is None else train.filter(pa.compute.equal(train.column("pose"), pose))
        got = stats["overall"] if pose is None else stats["per_pose"][pose]
        assert got["rows"] == sub.num_rows
        for c in ("x", "y"):
            v = xy(sub)[0 if c == "x" else 1].astype(np.float64)
            np.testing.assert_allclose(got[c]["mean"], v.mean(axis=0), rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(got[c]["std"], v.std(axis=0), rtol=1e-12, atol=1e-15)
    # mirrored training rows count: the mean X of every direction is zero
    np.testing.assert_allclose(stats["overall"]["x"]["mean"][0], 0.0, atol=1e-7)


# ------------------------------------------------------------------------------------------------ writing

def test_rebuild_is_byte_identical(follow_takes, tmp_path):
    takes, _ = follow_takes
    takes = [pinned(t, "train") for t in takes]
    for run in ("a", "b"):
        fresh = [TakeTables(session=t.session, subject=t.subject, take=t.take,
                            joints=pa.Table.from_batches(t.joints.to_batches()), eyes=t.eyes,
                            markerset=t.markerset) for t in takes]
        write_dataset(build_dataset("gaze_rnn", fresh), tmp_path / run)
    files_a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*") if p.is_file())
    assert files_a == files_b and len(files_a) == 3 + 4
    for rel in files_a:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


def _lazy(tt: TakeTables, events: list[str]) -> TakeTables:
    """The take with its tables behind a loader that logs when it is called."""
    def load() -> dict:
        events.append(f"load {tt.take.id}")
        return {"joints": tt.joints, "eyes": tt.eyes, "meta": dict(tt.meta)}
    return TakeTables(session=tt.session, subject=tt.subject, take=tt.take, markerset=tt.markerset, loader=load)


def test_streaming_build_loads_one_take_at_a_time_and_writes_the_same_bytes(follow_takes, tmp_path):
    takes, _ = follow_takes
    takes = [pinned(t, s) for t, s in zip(takes, ("train", "val", "train"), strict=True)]
    write_dataset(build_dataset("gaze_rnn", takes), tmp_path / "memory")
    events: list[str] = []
    writer = StagedDatasetWriter(tmp_path / "stream", "gaze_rnn", tmp_path / "staging.part")

    def sink(key, table):
        events.append(f"emit {key[1]}")
        writer(key, table)

    built = build_dataset("gaze_rnn", [_lazy(t, events) for t in takes], sink=sink)
    assert built.tables == {}
    # in (session, take) order, each take is loaded only after the previous one was handed on
    order = ["follow_sitting_01", "follow_standing_01", "follow_standing_02"]
    assert events == [f"{what} {tid}" for tid in order for what in ("load", "emit")]
    assert not (tmp_path / "stream" / "gaze_rnn" / "_dataset.json").exists()   # nothing published before commit
    writer.commit(built)
    assert not (tmp_path / "staging.part").exists()
    a = sorted(p.relative_to(tmp_path / "memory") for p in (tmp_path / "memory").rglob("*") if p.is_file())
    b = sorted(p.relative_to(tmp_path / "stream") for p in (tmp_path / "stream").rglob("*") if p.is_file())
    assert a == b and len(a) == 3 + 4   # the take files, then the side files
    for rel in a:
        assert (tmp_path / "memory" / rel).read_bytes() == (tmp_path / "stream" / rel).read_bytes(), rel


def test_failed_streaming_build_leaves_the_published_dataset_as_it_was(follow_takes, tmp_path):
    takes, _ = follow_takes
    write_dataset(build_dataset("gaze_rnn", [pinned(t, "train") for t in takes]), tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    writer = StagedDatasetWriter(tmp_path, "gaze_rnn", tmp_path / "staging.part")
    with pytest.raises(StageError, match="no training take"):   # found only after every take was built
        build_dataset("gaze_rnn", [pinned(t, "val") for t in takes], sink=writer)
    assert len(writer.staged) == 3
    writer.abort()
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before


def test_layout_and_loaders(rnn, tmp_path):
    """<split>/<session>/<take>.parquet with the side files named so that pandas and pyarrow skip them: both
    open the folder with no arguments, and the identifier columns come from the files alone."""
    built = rnn["gaze_rnn"]
    written = write_dataset(built, tmp_path)
    root = tmp_path / "gaze_rnn"
    assert [p.name for p in written[-4:]] == ["_common_metadata", ".huggingface.yaml", "_README.md", "_dataset.json"]
    split = built.tables[("session01", "follow_sitting_01")].column("split")[0].as_py()
    assert (root / split / "session01" / "follow_sitting_01.parquet").is_file()
    table, info = read_dataset(root)
    assert table.num_rows == info["counts"]["rows"] == sum(t.num_rows for t in built.tables.values())
    d = ds.dataset(root)
    sitting = d.to_table(filter=ds.field("pose") == "sitting")
    assert set(sitting.column("take").to_pylist()) == {"follow_sitting_01"}
    assert d.schema.field("subject").type == pa.string()          # no partition column clashing with it
    x = list_to_numpy(d.to_table(columns=["x"]).column("x"), 66)
    assert x.shape == (table.num_rows, 66) and x.dtype == np.float32
    df = pd.read_parquet(root)
    assert len(df) == table.num_rows and set(df["pose"]) == {"standing", "sitting"}
    assert list(df.columns) == table.column_names
    assert df["mirrored"].sum() * 2 == len(df)
    # a stale take file from an earlier build, and an earlier layout's files, are removed by the next write
    stale = root / take_path("test", "session01", "old_take")
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_bytes((root / take_path(split, "session01", "follow_sitting_01")).read_bytes())
    (root / "dataset.json").write_text("{}")
    (root / "subject=p01" / "pose=sitting").mkdir(parents=True)
    write_dataset(built, tmp_path)
    assert not stale.exists() and not (root / "test").exists()
    assert not (root / "dataset.json").exists() and not (root / "subject=p01").exists()


def test_take_file_names_keep_readers_reading():
    """Ids are URI-encoded, and a leading "_" too: pyarrow skips files and folders named "_…" or ".…"."""
    assert take_path("val", "s 1", "_warmup") == Path("val") / "s%201" / "%5Fwarmup.parquet"
    assert take_path("train", "_s", "t-1") == Path("train") / "%5Fs" / "t-1.parquet"
    with pytest.raises(SchemaError, match="not one of"):
        take_path("validation", "s", "t")


def test_read_rejects_tampered_files(rnn, tmp_path):
    built = rnn["gaze_rnn_lod"]
    write_dataset(built, tmp_path)
    root = tmp_path / "gaze_rnn_lod"
    path = next(root.glob("*/session01/follow_standing_02.parquet"))
    good = pq.read_table(path)
    # x stored as float64: schema mismatch
    i = good.schema.get_field_index("x")
    x64 = good.column("x").cast(pa.list_(pa.float64(), 21))
    bad = good.set_column(i, pa.field("x", x64.type, nullable=False), x64)
    pq.write_table(bad.replace_schema_metadata(good.schema.metadata), path)
    with pytest.raises(SchemaError, match="x is fixed_size_list"):
        read_dataset(root)
    # right schema, wrong take name inside the file
    j = good.schema.get_field_index("take")
    wrong = good.set_column(j, good.schema.field("take"), pa.array(["other"] * good.num_rows))
    pq.write_table(wrong, path)
    with pytest.raises(SchemaError, match="path says"):
        read_dataset(root)
    # a file without the dataset's identity
    pq.write_table(good.replace_schema_metadata(None), path)
    with pytest.raises(SchemaError):
        read_dataset(root)


# ------------------------------------------------------------------------------------------------ gaze_map

def _shift_takes(session):
    return [t for t in session.takes if t.kind == "gaze_shift"]


def _check_map_row(row: dict, tr: dict, crop0: int, skip_starts: tuple[str, ...] = (), tb_tol: float = 2.0,
                   beta_tol: float = 0.05) -> None:
    """Compare a gaze_map row with the truth. Times are compared as absolute frames of the take, since the
    pipeline's crop start and duration may differ from the truth's by a frame or two. A segment the truth never
    starts (its peak speed under the 18°/s threshold; the truth writes 0, Pejsa's rule) has a null start time,
    masked in ``start_known``; every other one has its start."""
    sc = tr["scalars"]
    l_row = row["duration_s"]
    assert row["yaw_deg"] == sc["target"]["yaw_deg"] and row["pitch_deg"] == sc["target"]["pitch_deg"]
    t0 = sc["crop"][0]
    got_tb = crop0 + row["overshoot_time"] * l_row * RATE
    want_tb = t0 + sc["t_beta_frac"] * sc["l_s"] * RATE
    assert abs(got_tb - want_tb) <= tb_tol + 1e-4, (got_tb, want_tb)   # 1e-4: float32 storage
    assert abs(row["overshoot"] - sc["beta"]) <= beta_tol, (row["overshoot"], sc["beta"])
    peak = peak_speeds(tr, RATE)
    st, known = np.array(row["start_times"], dtype=np.float64), np.array(row["start_known"], dtype=bool)
    assert (np.isnan(st) == ~known).all()
    for k, s in enumerate(tr["segments"]):
        if s in skip_starts:
            continue
        if peak[s] <= 18.0:
            assert not known[k], (s, st[k], peak[s])        # no start: null, never 0
            continue
        got = crop0 + st[k] * l_row * RATE
        want = t0 + sc["start_frac"][s] * sc["l_s"] * RATE
        assert known[k] and abs(got - want) <= 2.0 + 1e-4, (s, got, want)


def test_gaze_map_on_truth_rotations(session):
    """On the generator's own rotations the builder reproduces its truth: start times, t_β (±2 frames), β
    (±0.05), duration and P+. The rotations are noise-free, so the start rule runs as the truth's (Pejsa's: raw
    central differences, no low-pass, no minimum duration)."""
    takes = []
    for t in _shift_takes(session):
        tr = load_truth(session.root, t.id)
        c0, c1 = tr["scalars"]["crop"]
        takes.append(TakeTables(session=session.id, subject=session.subject, take=t,
                                joints=truth_joints(tr, np.arange(c0, c1)), markerset=session.markerset,
                                meta={"rests": tr["scalars"]["rest_periods"]}))
    built = build_dataset("gaze_map", takes, BuildParams(train_frac=1.0, val_frac=0.0, start_filter_hz=None,
                                                         start_min_s=0.0))
    assert len(built.tables) == 9 and not built.info["skipped"]
    assert built.schema.field("p_plus").type == pa.list_(pa.float32(), 44)
    segs = list(load_truth(session.root, takes[0].take.id)["segments"])
    nonzero = 0
    for (_, tid), table in built.tables.items():
        rows = table.to_pylist()
        assert len(rows) == 2 and [r["mirrored"] for r in rows] == [False, True]
        row = rows[0]
        tr = load_truth(session.root, tid)
        sc = tr["scalars"]
        assert row["frame"] == sc["crop"][0]
        assert row["duration_s"] == pytest.approx(sc["l_s"], rel=1e-6)
        _check_map_row(row, tr, sc["crop"][0], beta_tol=0.005)
        nonzero += sum(v > 0 for v in sc["start_frac"].values())
        pp = np.array(row["p_plus"], dtype=np.float64).reshape(-1, 4)
        want = np.array([sc["p_plus"][s] for s in (*segs, "eyes")])
        ang = (from_wxyz(pp).inv() * from_wxyz(want)).magnitude()
        assert np.rad2deg(ang).max() < 0.05
        # the eyes' global displacement is the requested change: D_head · eyes = Ry(yaw)·Rx(−pitch)
        fixed = _fixed_head(tr)
        d_head = fixed[-1] * fixed[0].inv()
        gaze = Rotation.from_rotvec([0, np.deg2rad(row["yaw_deg"]), 0]) * \
            Rotation.from_rotvec([-np.deg2rad(row["pitch_deg"]), 0, 0])
        # (the row's last pose is the mean over the crop's last 0.5 s, where the noise-free head has all but settled)
        assert np.rad2deg(((d_head * from_wxyz(pp[-1])).inv() * gaze).magnitude()) < 0.05
        # mirror: yaw negated, quaternions (w, x, −y, −z)
        mrow = rows[1]
        assert mrow["yaw_deg"] == -row["yaw_deg"] and mrow["pitch_deg"] == row["pitch_deg"]
        np.testing.assert_array_equal(np.array(mrow["p_plus"]).reshape(-1, 4), pp * [1, 1, -1, -1])
        np.testing.assert_array_equal(mrow["start_times"], row["start_times"])
        assert mrow["start_known"] == row["start_known"] and mrow["overshoot"] == row["overshoot"]
    assert nonzero >= 9    # the truth has real start times to match, not only zeros


def _fixed_head(tr: dict) -> Rotation:
    c0, c1 = tr["scalars"]["crop"]
    c = from_wxyz(tr["char_quat_lab"][c0:c1])
    return c[0].inv() * c * from_wxyz(tr["seg_quat_char"][c0:c1, 9].astype(np.float64))


@pytest.fixture(scope="module")
def pipeline_shift_takes(session):
    """The gaze_shift takes through the real stages: read → clean → frames (neutral take calibration)."""
    from gazepipe.io.capture import read_markers
    from gazepipe.stages.clean.stage import clean_markers
    from gazepipe.stages.frames.stage import compute_frames

    ms = session.markerset
    neutral_take = next(t for t in session.takes if t.kind == "neutral")
    neutral = clean_markers(read_markers(neutral_take.mocap), ms, "neutral").markers
    out = []
    for t in _shift_takes(session):
        res = clean_markers(read_markers(t.mocap), ms, t.kind, take=t.id)
        joints = compute_frames(res.markers, ms, neutral, take=t.id)
        out.append(TakeTables(session=session.id, subject=session.subject, take=t,
                              joints=joints_to_table(joints, res.frames), markerset=ms,
                              meta={"rests": [list(r) for r in res.rests], "rate_hz": res.markers.rate_hz}))
    return out


def _near_threshold(tr: dict) -> tuple[str, ...]:
    return near_threshold(tr, RATE)


def test_gaze_map_on_pipeline_output(pipeline_shift_takes, session):
    """On the noisy capture files through clean and frames: t_β within ±2 frames and β within ±0.05 of the
    truth; start times within ±2 frames (in take frames) for every segment whose noise-free peak speed is not
    within 2.5°/s of the 18°/s threshold.

    Parent-relative orientations carry ~1° of noise with 0.5 mm marker noise; after the start rule's 2 Hz
    low-pass a few °/s of speed noise remain, so a segment peaking at 16–20°/s (the chest and necks of the 72°
    shifts) may or may not cross 18°/s: those are left out (measured: 3 of 90 starts miss, all of them such).
    shift_y000_p12 (pitch only) overshoots by β = 0.023 of a ~12° head turn, about 0.3°, the size of the
    orientation noise: its t_β is only located within ±3 frames, and its head's start is not checked. A segment
    the truth never starts has a null start time (never 0)."""
    built = build_dataset("gaze_map", pipeline_shift_takes, BuildParams(train_frac=1.0, val_frac=0.0))
    assert len(built.tables) == 9 and not built.info["skipped"]
    checked = 0
    for (_, tid), table in built.tables.items():
        row = table.to_pylist()[0]
        tr = load_truth(session.root, tid)
        tiny = tr["scalars"]["beta"] < 0.03
        tol = 3.0 if tiny else 2.0
        # the same take's ~5° head pitch peaks at 28°/s noise-free but at 17°/s after the start rule's 2 Hz
        # low-pass: no start is found there (null; Pejsa's 0 used to match its start at frame 1 by chance)
        skip = _near_threshold(tr) + (("head",) if tiny else ())
        assert len(skip) <= 4, skip
        checked += len(tr["segments"]) - len(skip)
        _check_map_row(row, tr, row["frame"], skip_starts=skip, tb_tol=tol)
    assert checked >= 75


# ------------------------------------------------------------------------------------------------ face_clean

def face_take(tid: str, n: int, seed: int, k: int = 1) -> TakeTables:
    from gazepipe.arkit import ARKIT_NAMES
    from gazepipe.schemas.face_table import face_to_table
    from gazepipe.stages.face.stage import FaceAligned, forward_derivatives

    rng = np.random.default_rng(seed)
    t = np.cumsum(np.where(rng.random(n + k) < 0.05, 2, 1)) / 60.0      # a few dropped frames
    trk = rng.random((n + k, 52)).astype(np.float32)
    cln = np.clip(trk + rng.normal(0, 0.05, trk.shape), 0, 1).astype(np.float32)
    dt = np.diff(t)
    face = FaceAligned(names=ARKIT_NAMES, timecode=np.array([f"00:00:{i:05d}" for i in range(n)]),
                       time_s=t[:n], frame_index=np.round(t[:n] * 60).astype(np.int64), dt_s=dt[:n],
                       tracked=trk[:n], clean=cln[:n], d_tracked=forward_derivatives(trk, dt, k),
                       d_clean=forward_derivatives(cln, dt, k), k=k)
    table = face_to_table(face, meta={"rate_hz": 60.0})
    return TakeTables(session="s01", subject="p01", take=Take(id=tid, kind="face", pose="sitting", split="train"),
                      face=table)


def test_face_clean():
    from gazepipe.arkit import ARKIT_NAMES, mirror_face

    takes = [face_take("face_01", 300, 1), face_take("face_02", 250, 2)]
    built = build_dataset("face_clean", takes)
    info = built.info
    assert (info["window"], info["stride"]) == (200, 50) and info["fps"] == 60.0
    assert list(info["features"]) == ["tracked", "clean", "tracked_d1", "clean_d1"]
    assert info["features"]["tracked"][0] == "tracked.eyeBlinkLeft"
    table = built.tables[("s01", "face_01")]
    src = takes[0].face
    assert table.num_rows == 2 * src.num_rows
    half = src.num_rows
    np.testing.assert_array_equal(table.column("dt_s").to_numpy()[:half], src.column("dt_s").to_numpy())
    np.testing.assert_array_equal(table.column("frame").to_numpy()[:half], src.column("frame").to_numpy())
    for c in ("tracked", "clean", "tracked_d1", "clean_d1"):
        orig = list_to_numpy(table.column(c), 52)
        np.testing.assert_array_equal(orig[:half], list_to_numpy(src.column(c), 52))
        np.testing.assert_array_equal(orig[half:], mirror_face(orig[:half], ARKIT_NAMES))
    left, right = ARKIT_NAMES.index("eyeBlinkLeft"), ARKIT_NAMES.index("eyeBlinkRight")
    trk = list_to_numpy(table.column("tracked"), 52)
    np.testing.assert_array_equal(trk[half:, left], trk[:half, right])


def test_face_clean_from_the_face_stage(session):
    """The sample session's face takes (60 Hz and 30 Hz) through the face stage: every face-table row becomes
    one row plus its mirror; takes at different rates give no single fps."""
    from gazepipe.io.livelinkface import read_livelinkface
    from gazepipe.schemas.face_table import face_to_table
    from gazepipe.stages.face.stage import align_face

    takes = []
    for t in (t for t in session.takes if t.kind == "face"):
        trk, cln = (read_livelinkface(p, rate_hz=t.rate_hz, timecode_fps=t.timecode_fps) for p in (t.tracked, t.clean))
        table = face_to_table(align_face(trk, cln), meta={"rate_hz": trk.rate_hz})
        takes.append(TakeTables(session=session.id, subject=session.subject, take=t, face=table))
    assert len(takes) >= 2, "the sample session has two face takes"
    built = build_dataset("face_clean", [pinned(t, "train") for t in takes])
    assert built.info["fps"] is None and built.info["rates_hz"] == [30.0, 60.0]
    for tt in takes:
        out = built.tables[tt.key]
        assert out.num_rows == 2 * tt.face.num_rows
        np.testing.assert_array_equal(list_to_numpy(out.column("clean"), 52)[: tt.face.num_rows],
                                      list_to_numpy(tt.face.column("clean"), 52))
        np.testing.assert_array_equal(out.column("time_s").to_numpy()[: tt.face.num_rows],
                                      tt.face.column("time_s").to_numpy())


def test_unknown_dataset_and_no_takes():
    with pytest.raises(StageError, match="unknown dataset"):
        build_dataset("gaze_nope", [])
    with pytest.raises(StageError, match="no face takes"):
        build_dataset("face_clean", [])


def test_schema_identity_is_checked():
    from gazepipe.schemas.base import check_table
    from gazepipe.schemas.dataset_tables import gaze_rnn_schema

    s = gaze_rnn_schema(21, 18, "gaze_rnn_lod")
    t = s.empty_table()
    check_table(t, s)
    with pytest.raises(SchemaError, match="expected a 'gaze_rnn' table"):
        check_table(t, gaze_rnn_schema(21, 18))
    with pytest.raises(SchemaError):
        check_table(with_identity(gaze_rnn_schema(21, 17, "gaze_rnn_lod"), "gaze_rnn_lod", 1).empty_table(), s)


# ------------------------------------------------------------------------------------------------ start times

def _shift_rotations(amp_deg: float, n: int = 90, onset: int = 30, dur_s: float = 0.5, rate: float = 30000 / 1001,
                     noise_deg: float = 0.0, seed: int = 0) -> Rotation:
    """A quintic (minimum-jerk) turn of ``amp_deg`` about a tilted axis starting at frame ``onset``, with
    Gaussian rotation-vector noise of ``noise_deg`` per axis."""
    u = np.clip((np.arange(n) - onset) / (dur_s * rate), 0.0, 1.0)
    theta = np.deg2rad(amp_deg) * (10 * u**3 - 15 * u**4 + 6 * u**5)
    axis = np.array([0.2, 1.0, 0.1]) / np.linalg.norm([0.2, 1.0, 0.1])
    rv = theta[:, None] * axis + np.random.default_rng(seed).normal(0.0, np.deg2rad(noise_deg), (n, 3))
    return Rotation.from_rotvec(rv)


def test_start_times_robust_to_orientation_noise():
    """With ~1° of orientation noise (0.6° per axis, the sample session's parent-relative level) the default
    low-pass start rule finds a fast turn's start within 2 frames of the noise-free crossing of 18°/s, and no
    start for a slow turn (peak ~11°/s); raw central differences fire on the noise alone."""
    from gazepipe.stages.build.gaze import angular_speed, start_frame

    rate = 30000 / 1001
    p = BuildParams()
    thr = np.deg2rad(p.start_speed_deg_s)
    min_frames = max(1, round(p.start_min_s * rate))
    want = int(np.flatnonzero(angular_speed(_shift_rotations(30.0), rate) > thr)[0])
    assert np.degrees(angular_speed(_shift_rotations(3.0), rate).max()) < 12.0
    got, slow, raw_slow = [], [], []
    for seed in range(20):
        fast = _shift_rotations(30.0, noise_deg=0.6, seed=seed)
        slow_r = _shift_rotations(3.0, noise_deg=0.6, seed=100 + seed)
        got.append(start_frame(fast, rate, thr, p.start_filter_hz, min_frames))
        slow.append(start_frame(slow_r, rate, thr, p.start_filter_hz, min_frames))
        raw_slow.append(start_frame(slow_r, rate, thr, None, 1))
    assert np.abs(np.array(got) - want).max() <= 2, (got, want)
    assert slow == [-1] * 20, slow
    assert sum(r >= 0 for r in raw_slow) >= 15, raw_slow     # the old rule: noise "starts" the slow turn


def test_start_time_needs_min_duration():
    """A one-frame excursion above the threshold is not a start; two frames are (the default minimum at 30 Hz)."""
    from gazepipe.stages.build.gaze import start_frame

    rate = 30.0
    rv = np.zeros((40, 3))
    rv[10, 1] = np.deg2rad(2.0)                          # a one-sample spike: 30°/s at frames 9 and 11 alone
    rv[25:, 1] = np.deg2rad(1.0) * np.arange(1, 16)     # a 30°/s turn: above 18°/s from frame 25 on
    r = Rotation.from_rotvec(rv)
    thr = np.deg2rad(18.0)
    assert start_frame(r, rate, thr, None, 1) == 9
    assert start_frame(r, rate, thr, None, 2) == 25


def test_gaze_rows_gate_on_the_segments_they_keep_and_count_every_dropped_frame():
    """A segment outside the LOD set missing for 20 frames costs gaze_rnn_lod nothing and gaze_rnn those frames;
    every frame either gives a row or is counted under the first reason it gives none."""
    from gazepipe.stages.build.gaze import rnn_rows

    n, segs = 100, 4
    rot = Rotation.from_rotvec(np.random.default_rng(0).normal(0, 0.2, (n * segs, 3)))
    six = six_from_rotation(rot).reshape(n, segs, 6)
    six[40:60, 1] = np.nan                                   # segment 1 unsolvable for 20 frames
    target = np.tile([0.0, 0.0, 1.0], (n, 1))
    target[70:75] = np.nan                                   # the target occluded
    char_rot = np.tile([1.0, 0, 0, 0], (n, 1))
    char_rot[90] = np.nan                                    # no character frame once
    joints = {"frame": np.arange(n), "six": six, "target_dir": target, "char_rot": char_rot,
              "time_s": np.arange(n) / 30.0, "valid": np.isfinite(six).all(axis=(1, 2)) & (np.arange(n) != 90)}
    lod = rnn_rows(joints, [0, 2, 3], None)
    full = rnn_rows(joints, [0, 1, 2, 3], None)
    assert lod.qc["dropped"] == {"no_character_frame": 1, "segment_missing": 0, "no_target": 5, "first_of_run": 3}
    assert full.qc["dropped"] == {"no_character_frame": 1, "segment_missing": 20, "no_target": 5, "first_of_run": 4}
    for rows in (lod, full):
        assert len(rows.frame) + sum(rows.qc["dropped"].values()) == n
    assert set(range(41, 60)) <= set(lod.frame.tolist()) and not set(range(40, 61)) & set(full.frame.tolist())
    eyes_ok = np.ones(n, bool)
    eyes_ok[10:13] = False
    gr = rnn_rows(joints, [0, 1, 2, 3], (eyes_ok, target))
    assert gr.qc["dropped"]["eyes_invalid"] == 3 and len(gr.frame) + sum(gr.qc["dropped"].values()) == n


def _truth_map_take(session):
    """The first gaze_shift take's truth: (joints arrays over its crop, rests, yaw, pitch, crop start)."""
    t = _shift_takes(session)[0]
    tr = load_truth(session.root, t.id)
    c0, c1 = tr["scalars"]["crop"]
    tab = joints_arrays(truth_joints(tr, np.arange(c0, c1)))
    return tab, tr["scalars"]["rest_periods"], tr["scalars"]["target"]["yaw_deg"], \
        tr["scalars"]["target"]["pitch_deg"], c0


def _map_row(tab, rests, yaw, pitch, quat_holes=(), char_holes=(), filled=(), how="rotation", **kw):
    """gaze_map_row on a copy of ``tab`` with NaN holes (segment, start, stop) / (start, stop) and filled
    rotations (segment, start, stop, degrees added about X: a fill that far off), filled as ``how`` says:
    ``rotation`` (across a marker gap: ``rot_filled``, not ``rot_measured``), ``markers`` (from gap-filled
    markers: not ``rot_measured``) or ``none`` (marked measured)."""
    from gazepipe.stages.build.gaze import gaze_map_row

    j = {k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in tab.items()}
    for seg, a, b in quat_holes:
        j["quat"][a:b, seg] = np.nan
    for a, b in char_holes:
        j["char_rot"][a:b] = np.nan
    for seg, a, b, deg in filled:
        j["rot_filled"][a:b, seg] = how == "rotation"
        j["rot_measured"][a:b, seg] = how == "none"
        j["quat"][a:b, seg] = to_wxyz(Rotation.from_rotvec([np.radians(deg), 0, 0]) * from_wxyz(j["quat"][a:b, seg]))
    return gaze_map_row(j, rests, RATE, yaw, pitch, head=9, start_filter_hz=None, start_min_s=0.0, **kw)


def _same_except(got, want, null: list[int], starts: tuple[int, ...] = (), found: tuple[int, ...] = (),
                 n_seg: int = 10) -> None:
    """``got``'s row equals ``want``'s everywhere but the ``known`` entries ``null`` (segments' P+, then eyes =
    n_seg, overshoot = n_seg + 1), NaN and False in ``got``, the start times of the segments ``starts``, NaN
    and False in ``got``'s ``start_known`` where ``want`` has them, and those of ``found``, which ``got`` has
    where ``want`` found none (``want``'s own may be null: no start found)."""
    known = got.features["known"][0]
    assert known.dtype == bool and list(np.flatnonzero(~known)) == sorted(null)
    assert want.features["known"].all()
    sk_got, sk_want = got.features["start_known"][0], want.features["start_known"][0]
    assert list(np.flatnonzero(sk_want & ~sk_got)) == sorted(starts)
    assert list(np.flatnonzero(sk_got & ~sk_want)) == sorted(found)
    segs = [k for k in null if k < n_seg]
    keep = [k for k in range(n_seg) if k not in segs]
    st, pp = got.features["start_times"][0], got.features["p_plus"][0].reshape(-1, 4)
    assert (np.isnan(st) == ~sk_got).all() and np.isnan(pp[segs]).all()
    same = sk_got & sk_want
    np.testing.assert_array_equal(st[same], want.features["start_times"][0][same])
    rows = keep + ([] if n_seg in null else [n_seg])
    np.testing.assert_array_equal(pp[rows], want.features["p_plus"][0].reshape(-1, 4)[rows])
    if n_seg in null:
        assert np.isnan(pp[n_seg]).all()
    for k in ("overshoot_time", "overshoot"):
        if n_seg + 1 in null:
            assert np.isnan(got.features[k]).all()
        else:
            np.testing.assert_array_equal(got.features[k], want.features[k])
    for k in ("yaw_deg", "pitch_deg", "duration_s"):
        np.testing.assert_array_equal(got.features[k], want.features[k])


def test_gaze_map_bridges_short_holes_and_nulls_what_it_cannot_compute(session):
    """Frames inside the crop without a rotation are bridged in rotation space up to build.max_bridge_s
    (0.5 s): the row stays within the truth's tolerances and QC counts them. After a longer hole nothing is
    known: a start or overshoot found before it stands; one that may lie inside it is null in the row (with the
    segment's P+, masked in ``known``) and the rest of the row is what it is without the hole. A missing
    character frame at the crop's first or last frame still leaves the take out: nothing can be computed."""
    tab, rests, yaw, pitch, c0 = _truth_map_take(session)

    def row(**kw):
        return _map_row(tab, rests, yaw, pitch, **kw)

    whole = row()
    assert whole.features["known"].all() and whole.qc["null_segments"] == [] and whole.qc["null_reasons"] == {}
    n = len(tab["frame"])
    mid = n // 2
    holed = row(quat_holes=[(9, mid - 6, mid + 6), (3, 10, 20)], char_holes=[(mid + 10, mid + 14)])
    assert holed.qc["bridged_frames"] == 12 + 10 + 4 and whole.qc["bridged_frames"] == 0
    for k in ("duration_s", "p_plus"):
        np.testing.assert_allclose(holed.features[k], whole.features[k], atol=1e-6)
    assert abs(holed.features["overshoot"][0] - whole.features["overshoot"][0]) < 0.02
    pp = from_wxyz(holed.features["p_plus"].reshape(-1, 4).astype(np.float64))
    assert np.degrees(pp.magnitude()).max() < 180
    # a longer hole: events found before it stand
    found = np.nan_to_num(whole.features["start_times"][0], nan=0.0)       # (no start found: null)
    starts = np.rint(found * whole.features["duration_s"][0] * RATE).astype(int)
    late = max(int(starts.max()), whole.qc["overshoot_frame"] - c0 + 4) + 2
    assert late + 20 < n - 2
    after = row(quat_holes=[(9, late, late + 20)])
    assert after.qc["unbridged_frames"] == 20 and after.qc["bridged_frames"] == 0
    for k in whole.features:
        np.testing.assert_allclose(after.features[k], whole.features[k], atol=1e-6)
    # ... one that may lie inside it is null: a hole before the head's start nulls the head and the overshoot
    # (it comes after the start); the eyes need only the head's end poses, which stand
    head_start = max(1, int(starts[9]))
    before_start = row(quat_holes=[(9, head_start, head_start + 20)])
    _same_except(before_start, whole, [11], starts=(9,))
    assert before_start.qc["null_segments"] == ["overshoot", "head start"]
    assert re.search(rf"start time cannot be computed: crop frames {head_start}–{head_start + 19} .*more than "
                     r"build.max_bridge_s \(0.5 s\)", before_start.qc["null_reasons"]["head start"])
    ov = whole.qc["overshoot_frame"] - c0
    no_overshoot = row(quat_holes=[(9, ov - 5, ov + 20)])
    _same_except(no_overshoot, whole, [11])
    assert "overshoot cannot be computed" in no_overshoot.qc["null_reasons"]["overshoot"]
    # no rotation at the crop's first frame: the pelvis's P+ is null, and so is its child's (relative to it);
    # the start times of both need the pelvis from frame 0 on
    no_first = row(quat_holes=[(0, 0, 3)])
    _same_except(no_first, whole, [0, 1])
    names = list(tab["segments"])
    assert no_first.qc["null_segments"] == [*names[:2], f"{names[0]} start", f"{names[1]} start"]
    assert "no measured rotation at the crop's first frame" in no_first.qc["null_reasons"]["pelvis"]
    with pytest.raises(StageError, match="crop's last frame has no character frame rotation"):
        row(char_holes=[(int(rests[1][0]) - c0, n)])   # the last pose is a mean over the second rest's frames
    with pytest.raises(StageError, match="crop's first frame has no character frame rotation"):
        row(char_holes=[(0, 1)])
    assert row(char_holes=[(n - 2, n)]).qc["bridged_frames"] == 1   # the last from the mean, n − 2 bridged


def test_gaze_map_row_with_a_segment_missing_at_the_crop_end(session):
    """A segment without rotation over the crop's final rest (its markers hidden to the end): the take still
    gives a row; that segment's P+ is null and so is its child's (parent-relative), each masked; every other
    value is the one computed without the hole. The head missing there nulls the head, the eyes (they need the
    head's displacement) and the overshoot, and nothing else."""
    tab, rests, yaw, pitch, c0 = _truth_map_take(session)
    whole = _map_row(tab, rests, yaw, pitch)
    n = len(tab["frame"])
    second = int(rests[1][0]) - c0
    got = _map_row(tab, rests, yaw, pitch, quat_holes=[(4, second - 5, n)])
    _same_except(got, whole, [4, 5])
    names = list(tab["segments"])
    # (neither starts: with their rotations gone to the end, a start may lie unseen there)
    assert got.qc["null_segments"] == [names[4], names[5], f"{names[4]} start", f"{names[5]} start"]
    assert "no measured rotation in the crop's final rest" in got.qc["null_reasons"][names[4]]
    assert f"relative to {names[4]!r}" in got.qc["null_reasons"][names[5]]
    head = _map_row(tab, rests, yaw, pitch, quat_holes=[(9, second, n)])
    _same_except(head, whole, [9, 10, 11])
    assert head.qc["null_segments"] == ["head", "eyes", "overshoot"]


def test_gaze_map_end_poses_come_from_measured_rotations_only(session):
    """A segment's end pose is the mean of its measured rotations in the rest: rotations filled across a marker
    gap (``rot_filled``) or computed from gap-filled markers (not ``rot_measured``) never enter it, even 6° off;
    when the final rest holds no measured rotation of the segment its P+ is null (not taken from the fill), and
    so is its child's. The fills still carry the angular speeds (the start times stand)."""
    tab, rests, yaw, pitch, c0 = _truth_map_take(session)
    whole = _map_row(tab, rests, yaw, pitch)
    n = len(tab["frame"])
    second = int(rests[1][0]) - c0
    # filled over the last 5 frames, 6° off: the mean over the measured frames of the rest is the truth's
    partly = _map_row(tab, rests, yaw, pitch, filled=[(6, n - 5, n, 6.0)])
    assert partly.features["known"].all()
    np.testing.assert_allclose(partly.features["p_plus"], whole.features["p_plus"], atol=2e-3)
    off = _map_row(tab, rests, yaw, pitch, filled=[(6, n - 5, n, 6.0)], how="none")   # the fill taken as measured
    off_pp = off.features["p_plus"][0].reshape(-1, 4).astype(np.float64)
    pp = whole.features["p_plus"][0].reshape(-1, 4).astype(np.float64)
    assert np.degrees((from_wxyz(off_pp[6]) * from_wxyz(pp[6]).inv()).magnitude()) > 0.5
    # filled over the whole final rest, across a gap of its markers or from gap-filled markers: null, with its
    # child
    # (the 6° step where the fill begins moves the segment, and its child, fast enough to read as a start)
    for how in ("rotation", "markers"):
        _same_except(_map_row(tab, rests, yaw, pitch, filled=[(6, second - 3, n, 6.0)], how=how), whole, [6, 7],
                     found=(6, 7))
    # at the crop's first frame (no rest before it in this table): a filled first frame is not a first pose
    first = _map_row(tab, rests, yaw, pitch, filled=[(2, 0, 1, 0.0)])
    _same_except(first, whole, [2, 3])
    # with the frames stage's rest_before (measured means), the first pose is that, whatever frame 0 holds
    meta = dict(tab["meta"], rest_before={"quat": [list(q) for q in tab["quat"][0]], "char_rot": list(tab["char_rot"][0])})
    with_rest = _map_row(dict(tab, meta=meta), rests, yaw, pitch, filled=[(2, 0, 1, 6.0)])
    np.testing.assert_allclose(with_rest.features["p_plus"], whole.features["p_plus"], atol=1e-6)
    meta["rest_before"]["quat"][2] = None          # no measured rotation in that rest: frame 0 is filled → null
    none = _map_row(dict(tab, meta=meta), rests, yaw, pitch, filled=[(2, 0, 1, 6.0)])
    assert list(np.flatnonzero(~none.features["known"][0])) == [2, 3]
    assert "no measured rotation in the rest before the crop" in none.qc["null_reasons"][tab["segments"][2]]


def _null_map_takes(session) -> list[TakeTables]:
    """Four gaze_shift takes from truth, pinned to train; the second's segment 4 is hidden from 5 frames before
    its second rest to the end (null P+ for it and its child)."""
    takes = []
    for i, t in enumerate(_shift_takes(session)[:4]):
        tr = load_truth(session.root, t.id)
        c0, c1 = tr["scalars"]["crop"]
        joints = truth_joints(tr, np.arange(c0, c1))
        if i == 1:           # segment 4 hidden from 5 frames before the second rest to the end
            q = list_to_numpy(joints.column("quat"), 40).reshape(-1, 10, 4).copy()
            q[int(tr["scalars"]["rest_periods"][1][0]) - 5 - c0:, 4] = np.nan
            f = joints.schema.get_field_index("quat")
            joints = joints.set_column(f, joints.schema.field("quat"), fixed_list(q, 40, np.float32))
        takes.append(TakeTables(session=session.id, subject=session.subject, take=pinned_take(t, "train"),
                                joints=joints, markerset=session.markerset,
                                meta={"rests": tr["scalars"]["rest_periods"]}))
    return takes


def test_gaze_map_with_null_segments_builds_writes_reads_and_counts_them(session, tmp_path):
    """A take whose segment has no rotation over its final rest keeps its row: the build counts the nulls per
    take and overall, the statistics are taken per element over the values that are not null (mean, std and
    count equal NumPy's nan-aware ones over the training rows, mirrored copies included), and the folder reads
    back through gazepipe, pyarrow, pandas and Hugging Face ``datasets`` with the ``known`` mask intact."""
    takes = _null_map_takes(session)
    built = build_dataset("gaze_map", takes, BuildParams(start_filter_hz=None, start_min_s=0.0))
    segs = list(load_truth(session.root, takes[0].take.id)["segments"])
    holed = f"{session.id}/{takes[1].take.id}"
    info = built.info
    assert not info["skipped"] and len(built.tables) == 4
    lost = [segs[4], segs[5], f"{segs[4]} start", f"{segs[5]} start"]
    assert info["counts"]["null_segments"] == dict.fromkeys(lost, 1) and info["counts"]["takes_with_nulls"] == 1
    assert info["counts"]["per_take"][holed]["null_segments"] == lost
    assert info["masks"] == {"known": [*segs, "eyes", "overshoot"], "start_known": segs}
    assert "known" not in info["features"] and "start_known" not in info["features"]
    assert info["schema_version"] == 3 and built.schema.field("known").type == pa.list_(pa.bool_(), 12)
    assert built.schema.field("start_known").type == pa.list_(pa.bool_(), 10)
    write_dataset(built, tmp_path)
    root = tmp_path / "gaze_map"
    table, _ = read_dataset(root)
    known = list_to_numpy(table.column("known"), 12)
    start_known = list_to_numpy(table.column("start_known"), 10)
    st = list_to_numpy(table.column("start_times"), 10).astype(np.float64)
    pp = list_to_numpy(table.column("p_plus"), 44).astype(np.float64).reshape(-1, 11, 4)
    assert known.dtype == bool and (~known).sum() == 4            # two segments, original and mirrored rows
    assert (np.isnan(st) == ~start_known).all() and (np.isnan(pp).all(axis=2) == ~known[:, :11]).all()
    assert start_known.any() and not start_known.all()
    assert not np.isnan(pp).any(axis=2)[known[:, :11]].any()
    stats = info["stats"]["overall"]
    assert stats["rows"] == 8
    for c, v in (("start_times", st), ("p_plus", pp.reshape(-1, 44))):
        seen = (~np.isnan(v)).any(axis=0)       # (an element null in every row: mean 0, std 0, count 0)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, std = np.where(seen, np.nanmean(v, axis=0), 0.0), np.where(seen, np.nanstd(v, axis=0), 0.0)
        np.testing.assert_allclose(stats[c]["mean"], mean, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(stats[c]["std"], std, rtol=1e-12, atol=1e-15)
        assert stats[c]["count"] == (~np.isnan(v)).sum(axis=0).tolist()
    assert stats["start_times"]["count"] == start_known.sum(axis=0).tolist() and stats["yaw_deg"]["count"] == [8]
    from gazepipe.datasets import open_dataset as open_gd

    gd = open_gd(root)
    assert gd.array("known").dtype == bool and gd.array("known").shape == (8, 12)
    mean, std = gd.mean_std("p_plus")
    assert np.isfinite(mean).all() and np.isfinite(std).all()
    df = pd.read_parquet(root)
    assert [list(k) for k in df["known"]] == known.tolist()
    assert open_dataset(root).to_table(columns=["known"]).column("known").type == pa.list_(pa.bool_(), 12)
    hf = __import__("datasets").load_dataset(str(root))
    assert hf["train"].num_rows == 8 and hf["train"][2]["known"] == known[2].tolist()
    assert np.isnan(np.array(hf["train"][2]["start_times"], dtype=float)).tolist() == (~start_known[2]).tolist()
    # the gaze map trains on it: its nulls are masked, its figures finite
    from click.testing import CliRunner

    from gazepipe.cli.train import train
    from gazepipe.trainers.gaze_map import GazeMap

    res = CliRunner().invoke(train, ["gaze_map", "--data", str(root), "--out", str(tmp_path / "m"), "--json"])
    assert res.exit_code == 0, res.output
    loo = json.loads(res.output)["leave_one_out"]
    assert loo["not_compared"] == 4 and np.isfinite(loo["final_pose_error_deg_max"])
    gmap = GazeMap.load(tmp_path / "m")
    assert (gmap.known == known).all() and (gmap.start_known == start_known).all()
    motion = gmap.motion(10.0, 5.0)
    assert np.isfinite(motion.p_plus).all() and np.isfinite(motion.start_times).all()


def test_gaze_map_with_null_segments_loads_in_torch_and_masks_a_loss(session, tmp_path):
    """PyTorch takes the columns as tensors (``known`` as bool); a loss masked by ``known`` is finite and its
    gradient too: the null values never reach it."""
    torch = pytest.importorskip("torch")
    from gazepipe.datasets import open_dataset as open_gd

    write_dataset(build_dataset("gaze_map", _null_map_takes(session)), tmp_path)
    gd = open_gd(tmp_path / "gaze_map")
    pp = torch.from_numpy(np.array(gd.array("p_plus")))
    known = torch.from_numpy(np.array(gd.array("known")))
    assert known.dtype == torch.bool and pp.dtype == torch.float32 and torch.isnan(pp).any()
    mask = known[:, :-1].repeat_interleave(4, dim=1)              # segments and eyes, 4 values each
    pred = torch.zeros_like(pp, requires_grad=True)
    loss = ((pred - torch.where(mask, pp, 0.0)) ** 2)[mask].mean()
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    assert (pred.grad[~mask] == 0).all()


def test_mirroring_a_gaze_map_row_moves_its_mask_with_its_values():
    """mirror_gaze_map permutes ``known`` and ``start_known`` with the left/right segments (eyes and overshoot
    stay last), so each entry still marks the NaN values it marked; mirroring twice gives the row back, NaN
    included."""
    from gazepipe.stages.build.gaze import mirror_gaze_map, segment_permutation

    segs = ["pelvis", "LeftArm", "RightArm", "head"]
    rng = np.random.default_rng(4)
    known = np.array([[True, False, True, True, True, False]])
    start_known = np.array([[True, False, True, False]])
    start = rng.random((1, 4)).astype(np.float32)
    pp = rng.normal(size=(1, 5, 4)).astype(np.float32)
    start[0, [1, 3]], pp[0, 1] = np.nan, np.nan
    feats = {"yaw_deg": np.float32([30.0]), "pitch_deg": np.float32([5.0]), "duration_s": np.float32([0.8]),
             "start_times": start, "overshoot_time": np.float32([np.nan]), "overshoot": np.float32([np.nan]),
             "p_plus": pp.reshape(1, -1), "known": known, "start_known": start_known}
    perm = segment_permutation(segs)
    m = mirror_gaze_map(feats, perm)
    assert m["known"].tolist() == [[True, True, False, True, True, False]]
    assert m["start_known"].tolist() == [[True, True, False, False]]
    mpp = m["p_plus"].reshape(1, 5, 4)
    for f in (m, feats):           # NaN exactly where the masks are False, before and after mirroring
        p = f["p_plus"].reshape(1, 5, 4)
        assert (np.isnan(f["start_times"][0]) == ~f["start_known"][0]).all()
        assert (np.isnan(p[0]).all(axis=1) == ~f["known"][0, :5]).all()
    np.testing.assert_array_equal(mpp[0, 1], pp[0, 2] * [1, 1, -1, -1])
    back = mirror_gaze_map(m, perm)
    for k in feats:
        np.testing.assert_array_equal(back[k], feats[k])


def test_a_gaze_map_row_with_nothing_known_is_not_written(session):
    """No P+, start time, eyes' P+ nor overshoot can be computed (every segment's rotation gone over the final
    rest, the head's start unreadable): the row is not written; the build lists the take as skipped, with the
    reasons (SPEC §3.6)."""
    tab, rests, yaw, pitch, c0 = _truth_map_take(session)
    n = len(tab["frame"])
    second = int(rests[1][0]) - c0
    with pytest.raises(StageError, match="no parameter of the row could be computed .*no measured rotation"):
        _map_row(tab, rests, yaw, pitch, quat_holes=[(k, 1, n) for k in range(10)])
    # one start time is enough to keep the row: every P+ null, the head's start read before its hole
    head_start = int(np.rint(_map_row(tab, rests, yaw, pitch).features["start_times"][0, 9]
                             * (rests[1][0] - rests[0][1])))
    row = _map_row(tab, rests, yaw, pitch, quat_holes=[(k, max(second - 5, head_start + 3), n) for k in range(10)])
    assert not row.features["known"].any() and row.features["start_known"][0].tolist() == [False] * 9 + [True]
    # in a build: left out and counted with the reason
    t = _shift_takes(session)[0]
    tr = load_truth(session.root, t.id)
    joints = truth_joints(tr, np.arange(*tr["scalars"]["crop"]))
    q = list_to_numpy(joints.column("quat"), 40).reshape(-1, 10, 4).copy()
    q[1:] = np.nan
    joints = joints.set_column(joints.schema.get_field_index("quat"), joints.schema.field("quat"),
                               fixed_list(q, 40, np.float32))
    takes = [TakeTables(session=session.id, subject=session.subject, take=pinned_take(t, "train"), joints=joints,
                        markerset=session.markerset, meta={"rests": tr["scalars"]["rest_periods"]})]
    takes += _null_map_takes(session)[1:3]
    built = build_dataset("gaze_map", takes, BuildParams(start_filter_hz=None, start_min_s=0.0))
    assert [s["take"] for s in built.info["skipped"]] == [t.id]
    assert "no parameter of the row could be computed" in built.info["skipped"][0]["reason"]
    assert len(built.tables) == 2


def test_a_rebuild_rewrites_only_the_take_files_that_changed(rnn, tmp_path):
    """Publishing a rebuilt dataset leaves take files whose bytes did not change as they are (same inode and
    modification time), replaces the changed one, and moves a take whose split changed."""
    built = rnn["gaze_rnn"]

    def publish(tables):
        writer = StagedDatasetWriter(tmp_path, "gaze_rnn", tmp_path / f"staging{len(list(tmp_path.iterdir()))}")
        for key, table in sorted(tables.items()):
            writer(key, table)
        return writer.commit(built)

    publish(built.tables)
    root = tmp_path / "gaze_rnn"
    stamp = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in root.rglob("*.parquet")}
    keys = sorted(built.tables)
    changed = dict(built.tables)
    t = changed[keys[0]]
    i = t.schema.get_field_index("time_s")
    changed[keys[0]] = t.set_column(i, t.schema.field("time_s"), pa.array(np.asarray(t.column("time_s")) + 1.0))
    publish(changed)
    after = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in root.rglob("*.parquet")}
    first = next(p for p in after if p.stem == keys[0][1])
    assert after.keys() == stamp.keys() and after[first] != stamp[first]
    assert all(after[p] == stamp[p] for p in after if p != first)
    # a take moved to another split: its old file goes, the new one appears under the new split's folder
    moved = dict(built.tables)
    t = moved[keys[1]]
    new = "test" if t.column("split")[0].as_py() != "test" else "val"
    j = t.schema.get_field_index("split")
    moved[keys[1]] = t.set_column(j, t.schema.field("split"), pa.array([new] * t.num_rows))
    publish(moved)
    files = {p.relative_to(root) for p in root.rglob("*.parquet")}
    assert Path(new) / keys[1][0] / f"{keys[1][1]}.parquet" in files and len(files) == len(keys)


def test_one_subject_over_two_sessions_with_the_same_take_ids(follow_takes, tmp_path):
    """Two capture days of one subject reuse their take ids: a take is (session, take), so every take gets its
    own file, its own split by the hash of both, and the dataset checks see two takes, not one in two splits."""
    from gazepipe.report.checks import Thresholds
    from gazepipe.report.checks_datasets import check_counts, check_splits
    from gazepipe.report.collect import load_dataset

    takes, _ = follow_takes
    again = [dataclasses.replace(t, session="s02") for t in takes]
    built = build_dataset("gaze_rnn", [*takes, *again])
    assert set(built.tables) == {(t.session, t.take.id) for t in [*takes, *again]} and len(built.tables) == 6
    write_dataset(built, tmp_path)
    root = tmp_path / "gaze_rnn"
    assert len(list(root.glob("*/s02/*.parquet"))) == 3 and len(list(root.glob("*/session01/*.parquet"))) == 3
    listed = {t for ts in built.info["splits"]["takes"].values() for t in ts}
    assert {f"s02/{t.take.id}" for t in takes} <= listed
    d = load_dataset(root, Thresholds())
    assert check_splits(d.info, d.files).severity == "pass"
    assert check_counts(d.info, d.files).severity in ("pass", "warning")
    table, info = read_dataset(root)
    assert set(zip(table.column("session").to_pylist(), table.column("take").to_pylist(), strict=True)) == \
        set(built.tables)
