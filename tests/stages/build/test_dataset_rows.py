"""Dataset rows built per take (SPEC §7): each take's part of a dataset (its table and the facts the statistics,
counts and checks need) is made alone, travels as JSON, and the dataset's merge of the parts gives the bytes one
process building the whole dataset gives; in a run, the ``rows_<dataset>`` units make the parts on the workers and
the dataset's build links their files in."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.io.dataset_files import info_bytes, read_info, table_bytes, take_files
from gazepipe.io.parquet import read_table
from gazepipe.io.session_toml import load_session
from gazepipe.model import Take
from gazepipe.schemas.tracks import EYES
from gazepipe.stages.build.stage import (
    BuildParams,
    DatasetMerge,
    TakePart,
    TakeTables,
    build_dataset,
    take_part,
    with_split,
)
from gazepipe.synth import load_truth
from tests.helpers import REPO
from tests.helpers.sample import truth_joints

SAMPLE = REPO / "sample_data" / "session01"
FOLLOW = ("follow_standing_01", "follow_standing_02", "follow_standing_03", "follow_sitting_01",
          "follow_sitting_02")


def _eyes(tr: dict, frames: np.ndarray, invalid: np.ndarray) -> pa.Table:
    d = tr["eye_dir_char"][frames].astype(np.float64)
    vec = pa.FixedSizeListArray.from_arrays(pa.array(d.reshape(-1)), 3)
    n = len(frames)
    return pa.Table.from_pydict({
        "frame": pa.array(frames.astype(np.int32)), "source_frame": pa.array(frames + 1),
        "time_s": pa.array(frames / 30.0), "valid": pa.array(~invalid), "filled": pa.array(np.zeros(n, bool)),
        "confidence": pa.array(np.where(invalid, 0.1, 0.95)), "eye_dir_char": vec, "eye_dir_head": vec,
    }, schema=EYES)


@pytest.fixture(scope="module")
def follow() -> list[TakeTables]:
    """The sample's five gaze_follow takes from truth (unpinned: the merge moves one to fill the test split),
    3 % of eye frames invalid; the last one without eyes (gaze_rnn leaves it out)."""
    session = load_session(SAMPLE / "session.toml")
    rng = np.random.default_rng(3)
    out = []
    for i, tid in enumerate(FOLLOW):
        tr = load_truth(session.root, tid)
        c0, c1 = tr["scalars"]["crop"]
        frames = np.arange(c0, c1)
        t = session.take(tid)
        take = Take(id=t.id, kind=t.kind, pose=t.pose, mocap=t.mocap)
        out.append(TakeTables(session=session.id, subject=session.subject, take=take,
                              joints=truth_joints(tr, frames),
                              eyes=_eyes(tr, frames, rng.random(len(frames)) < 0.03) if i < 4 else None,
                              markerset=session.markerset))
    return out


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_parts_through_json_merge_to_the_bytes_of_one_build(follow, name):
    params = BuildParams()
    whole = build_dataset(name, follow, params)
    merge = DatasetMerge(name, params)
    kept: dict[tuple[str, str], TakePart] = {}
    tables: dict[tuple[str, str], pa.Table] = {}
    for tt in sorted(follow, key=lambda t: t.key):
        part = take_part(name, tt, params)
        again = TakePart.from_json(json.loads(json.dumps(part.to_json())))   # what a unit record holds
        assert again.to_json() == part.to_json()
        if merge.add(again):
            kept[again.key] = again
            tables[again.key] = part.table
    moves = merge.rebalance()
    if name == "gaze_rnn_lod":
        assert moves, "five unpinned takes: the merge fills an empty split"
    assert info_bytes(merge.info()) == info_bytes(whole.info)     # statistics bit for bit, counts, skipped
    assert sorted(kept) == sorted(whole.tables)
    for key, part in kept.items():
        split = merge.split[key]
        table = tables[key]
        if split != part.split:   # moved: made again from its stored file, as the dataset's build does
            sink = pa.BufferOutputStream()
            pq.write_table(table, sink)
            table = with_split(pq.read_table(sink.getvalue()), split, merge.schema)
        assert table_bytes(table) == table_bytes(whole.tables[key]), key
    if name == "gaze_rnn":
        assert [s["take"] for s in whole.info["skipped"]] == ["follow_sitting_02"]


def test_a_part_that_cannot_fit_is_skipped_with_the_reason_one_build_gives(follow):
    """A take whose segments differ from the dataset's first take is left out by the merge, with the same
    reason the one-process build gives."""
    params = BuildParams()
    odd = follow[1]
    joints = odd.joints
    meta = json.loads(joints.schema.metadata[b"gazepipe.meta"])
    meta["segments"] = list(reversed(meta["segments"]))
    md = dict(joints.schema.metadata)
    md[b"gazepipe.meta"] = json.dumps(meta, sort_keys=True, separators=(",", ":")).encode()
    changed = TakeTables(session=odd.session, subject=odd.subject, take=odd.take, joints=joints.replace_schema_metadata(md),
                         eyes=odd.eyes, markerset=odd.markerset)
    takes = [t if t is not odd else changed for t in follow]
    whole = build_dataset("gaze_rnn", takes, params)
    merge = DatasetMerge("gaze_rnn", params)
    for tt in sorted(takes, key=lambda t: t.key):
        merge.add(TakePart.from_json(json.loads(json.dumps(take_part("gaze_rnn", tt, params).to_json()))))
    merge.rebalance()
    assert merge.skipped == whole.info["skipped"]
    assert any("differ from the dataset's" in s["reason"] for s in merge.skipped)


# ------------------------------------------------------------------------------------------------ in a run

def _faces(root: Path, takes: tuple[str, ...]) -> Path:
    """A session of the sample's face takes, unpinned."""
    s = root / "session"
    (s / "face").mkdir(parents=True)
    shutil.copy(SAMPLE / "markerset.toml", s / "markerset.toml")
    lines = ['schema = 1', '[session]', 'id = "faces"', 'subject = "s1"', 'markerset = "markerset.toml"', '']
    for take in takes:
        for part in ("tracked", "clean"):
            shutil.copy(SAMPLE / "face" / f"{take}_{part}.csv", s / "face" / f"{take}_{part}.csv")
        lines += ['[[takes]]', f'id = "{take}"', 'kind = "face"', f'tracked = "face/{take}_tracked.csv"',
                  f'clean = "face/{take}_clean.csv"', 'rate_hz = 60', 'timecode_fps = 60', '']
    (s / "session.toml").write_text("\n".join(lines))
    return s


def _run(*args: str) -> list[dict]:
    res = CliRunner().invoke(cli, [*args, "--executor", "serial", "--log-format", "json"])
    assert res.exit_code == 0, res.output
    return [json.loads(line) for line in res.output.splitlines() if line.startswith("{")]


def test_a_run_makes_each_takes_rows_in_its_unit_and_links_them_into_the_dataset(tmp_path):
    takes = ("face_01", "face_02", "face_03", "face_04", "face_05")
    session, out = _faces(tmp_path, takes), tmp_path / "out"
    _run("run", str(session), "--out", str(out))
    root = out / "datasets" / "face_clean"
    info = read_info(root)
    moved = {w.split()[1] for w in info["warnings"] if " moved from " in w}
    assert moved, "five unpinned takes: one moves to fill an empty split"
    files = take_files(root)
    assert len(files) == len(takes)
    for f in files:
        rows = out / "takes" / "faces" / f.stem / "rows_face_clean.parquet"
        rec = json.loads((out / ".gazepipe" / "units" / "faces" / f.stem / "rows_face_clean.json").read_text())
        assert rec["status"] == "ok" and rec["qc"]["rows"] == pq.read_metadata(f).num_rows
        # the take's own file, linked in; a take moved to another split is made again with that split
        assert os.path.samefile(f, rows) == (f"faces/{f.stem}" not in moved)

    # the same dataset as one process building it from the same face tables
    loaded = load_session(session / "session.toml")
    tts = []
    for t in loaded.takes:
        fp = json.loads((out / ".gazepipe" / "units" / "faces" / t.id / "face.json").read_text())["fingerprint"]
        tts.append(TakeTables(session="faces", subject="s1", take=t, hashes={"face": fp},
                              face=read_table(out / "takes" / "faces" / t.id / "face.parquet")))
    whole = build_dataset("face_clean", tts)
    assert (root / "_dataset.json").read_bytes() == info_bytes(whole.info)
    for (_, t), table in whole.tables.items():
        path = next(f for f in files if f.stem == t)
        assert path.read_bytes() == table_bytes(table)

    # a build parameter re-runs the takes' rows units, and only those, then the dataset
    events = _run("run", str(session), "--out", str(out), "--param", "build.mirror=false")
    ran = {(e["take"], e["stage"]) for e in events if e.get("event") == "unit" and e.get("status") == "ok"}
    assert ran == {(t, "rows_face_clean") for t in takes}
    dry = _run("run", str(session), "--out", str(out), "--param", "build.mirror=true", "--dry-run")
    why = {e["stage"]: e.get("reason") for e in dry if e.get("event") == "plan" and e.get("status") == "run"}
    assert why.get("rows_face_clean") == "parameters changed: build.mirror"
    assert read_info(root)["counts"]["mirrored"] is False
