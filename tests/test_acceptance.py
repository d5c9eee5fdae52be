"""End-to-end acceptance: what ``gazepipe run`` writes for the sample session, against its ground truth.

The command runs once for the whole test run (process executor, the ``sample_process_run`` fixture); every test
reads that output. The serial run it is compared with is the suite's shared one (``sample_run``). Tolerances are the
acceptance criteria's; the figures each test measured are printed (``pytest -s``) and in assertion messages.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest
from click.testing import CliRunner

from gazepipe.cli.main import cli
from gazepipe.stages.build.mirror import mirror_quat
from gazepipe.stages.build.summary import feature_values
from tests.helpers import tree_digest
from tests.helpers.sample import (
    FILL_MEASURED,
    FILL_UNFILLED,
    Output,
    angle_deg,
    frame_rows,
    invalid_runs,
    json_events,
    markerset,
    mirror_rnn,
    near_threshold,
    overshoot_amplitude_deg,
    peak_speeds,
    session_takes,
    take_ids,
    truth,
    vec_angle_deg,
)

FOLLOW = take_ids("gaze_follow")
SHIFT = take_ids("gaze_shift")
VIDEO_FPS = 60.0


@pytest.fixture(scope="module")
def run(sample_process_run, sample_run):
    """The whole sample session run once with the process executor, then a second time with nothing changed
    (the shared ``sample_process_run``), and the serial run to compare it with (the shared ``sample_run``: the
    same command with ``--executor serial``); both ran with exit 0."""
    return {**sample_process_run, "out": Output(sample_process_run["out"]), "serial_out": sample_run}


@pytest.fixture(scope="module")
def out(run) -> Output:
    return run["out"]


def _pct(a, q) -> float:
    return float(np.percentile(a, q))


# ----------------------------------------------------------------------------------------------- issue 2 --

def test_second_run_does_nothing_and_says_so(run):
    second = run["second"]
    assert second.exit_code == 0, second.output[-3000:]
    events = json_events(second.output)
    names = [e.get("event") for e in events]
    assert "nothing_to_do" in names, names
    end = [e for e in events if e.get("event") == "run_end"]
    assert end and end[-1]["ran"] == 0 and end[-1]["failed"] == 0, end
    assert run["after"] == run["before"], "a run with nothing changed rewrote outputs"


def test_serial_and_process_runs_byte_identical(run):
    root, serial = run["out"].root, run["serial_out"]
    a, b = tree_digest(root, ("takes", "datasets")), tree_digest(serial, ("takes", "datasets"))
    assert len(a) > 50 and a.keys() == b.keys(), sorted(set(a) ^ set(b))
    assert [k for k in a if a[k] != b[k]] == []
    # Unit records: the same QC, outputs and fingerprints (only the measured wall and CPU times may differ).
    for rec in sorted((root / ".gazepipe").glob("units/*/*/*.json")) + sorted((root / ".gazepipe").glob(
            "datasets/*.json")):
        other = serial / rec.relative_to(root)
        x, y = json.loads(rec.read_text()), json.loads(other.read_text())
        for timed in ("duration_s", "cpu_s"):
            x.pop(timed, None)
            y.pop(timed, None)
        assert x == y, rec.relative_to(root)


# ----------------------------------------------------------------------------------------------- issue 4 --

def _expected_stages(kind: str, has_video: bool) -> list[str]:
    if kind == "face":
        return ["face"]
    stages = ["ingest", "clean"]
    if kind in ("gaze_follow", "gaze_shift"):
        stages.append("frames")
    if has_video:
        stages += ["sync", "eyes"]
    return stages


def test_every_take_went_through_every_stage(out):
    bad = []
    for t in session_takes():
        for stage in _expected_stages(t["kind"], "video" in t):
            rec = out.unit(t["id"], stage)
            if rec.get("status") != "ok":
                bad.append((t["id"], stage, rec.get("status")))
    assert not bad, bad
    for name in ("gaze_rnn", "gaze_rnn_lod", "gaze_map", "face_clean"):
        assert out.dataset_record(name)["status"] == "ok", name


def test_clap_times_offset_and_ratio(out):
    errs_frames, rows = [], []
    for take in FOLLOW:
        tr = truth(take)
        video = tr["scalars"]["video"]
        sync = out.table(take, "sync").to_pydict()
        qc = out.unit(take, "sync")["qc"]
        true_video = np.asarray(tr["video_clap_times_s"])
        assert len(sync["video_s"]) == len(true_video) == 2, (take, sync["video_s"])
        e = (np.asarray(sync["video_s"]) - true_video) * VIDEO_FPS
        errs_frames += list(np.abs(e))
        # t_mocap = offset + ratio * t_video: offset at video zero (sync table), at the first clap (QC).
        off0_ms = (sync["offset_s"][0] - video["offset_s"]) * 1e3
        off1_ms = (qc["offset_s"] - video["offset_at_first_clap_s"]) * 1e3
        ratio_err = sync["ratio"][0] / video["ratio"] - 1.0
        ratio_qc_err = qc["ratio"] / video["ratio"] - 1.0
        mocap_err = (np.asarray(sync["mocap_s"]) - np.asarray(tr["clap_times_s"])) * tr["scalars"]["rate_hz"]
        rows.append((take, e.round(3).tolist(), round(off0_ms, 3), round(off1_ms, 3), ratio_err, ratio_qc_err,
                     mocap_err.round(3).tolist()))
    print("\nclaps (take, video clap error [frames], offset@0 err ms, offset@clap1 err ms, ratio err, "
          "QC ratio err, mocap clap error [mocap frames]):")
    for r in rows:
        print("  ", r)
    errs_frames = np.asarray(errs_frames)
    print(f"  clap error: median {np.median(errs_frames):.3f} max {errs_frames.max():.3f} video frames")
    assert np.median(errs_frames) <= 0.25, errs_frames
    assert errs_frames.max() <= 1.0, errs_frames
    for take, _, off0, off1, r, rq, _ in rows:
        assert abs(off0) <= 5.0 and abs(off1) <= 5.0, (take, off0, off1)
        # the ratio follows from the two claps: its error over the span between them is the second clap's
        # error less the first's, so it stays within what the clap errors allow (0.5 video frame, 8.3 ms)
        span_s = float(np.diff(truth(take)["video_clap_times_s"])[0])
        assert abs(r) * span_s * 1e3 <= 500.0 / VIDEO_FPS and r == rq, (take, r, rq, span_s)
    # The mocap claps (a quarter of a mocap frame: the contact is refined below one frame).
    mocap = np.abs(np.concatenate([np.asarray(r[6]) for r in rows]))
    assert mocap.max() <= 0.25, mocap


def test_eye_directions_against_truth(out):
    pooled, per_take = [], {}
    for take in FOLLOW:
        eyes = out.eyes(take)
        tr = truth(take)
        v = eyes["valid"]
        assert v.sum() > 0.5 * len(v), (take, v.mean())
        err = vec_angle_deg(eyes["eye_dir_char"][v], tr["eye_dir_char"][eyes["frame"][v]])
        assert np.isfinite(err).all(), take
        per_take[take] = (round(float(np.median(err)), 3), round(_pct(err, 95), 3), int(v.sum()))
        pooled.append(err)
    pooled = np.concatenate(pooled)
    print(f"\neye direction error (median, p95, valid frames) per take: {per_take}; pooled median "
          f"{np.median(pooled):.3f} deg, p95 {_pct(pooled, 95):.3f} deg")
    assert np.median(pooled) <= 2.0
    for take, (med, _, _) in per_take.items():
        assert med <= 2.0, (take, med)


def test_camera_rotation_estimate(out):
    q_true = np.asarray(truth(FOLLOW[0])["session"]["camera_to_head_quat"])
    errs = {}
    for take in FOLLOW:
        q = np.asarray(out.unit(take, "eyes")["qc"]["camera_rotation"])
        errs[take] = float(angle_deg(q, q_true))
    print(f"\ncamera rotation error per take (deg): {errs}")
    assert all(e <= 1.0 for e in errs.values()), errs


def _gated_mocap_frames(take: str, max_gap_s: float = 0.1) -> np.ndarray:
    """Mocap frames that no correct pipeline may call valid: inside an injected invalid run on the video clock
    longer than ``max_gap_s`` (so not filled), at least one video frame in from either end of the run (so a clock
    error under one video frame cannot give them a valid neighbour). Mapped through the TRUE clock."""
    tr = truth(take)
    rate = tr["scalars"]["rate_hz"]
    vt = tr["video_mocap_time_s"]
    frames = []
    for a, b in invalid_runs(~tr["eyes_valid"]):
        if (b - a) / VIDEO_FPS <= max_gap_s or b - a < 3:
            continue
        lo, hi = vt[a + 1], vt[b - 2]
        f = np.arange(int(np.ceil(lo * rate)), int(np.floor(hi * rate)) + 1)
        frames.append(f[(f >= 0) & (f < len(tr["time_s"]))])
    return np.concatenate(frames) if frames else np.zeros(0, dtype=np.int64)


def test_no_gated_out_frame_reaches_a_dataset(out):
    table, _ = out.dataset("gaze_rnn")
    takes = np.asarray(table.column("take").to_pylist())
    frames = table.column("frame").to_numpy().astype(np.int64)
    report = {}
    for take in FOLLOW:
        eyes = out.eyes(take)
        rows = frames[takes == take]
        assert rows.size, take
        # Row t holds eyes at t (y) and t - 1 (x): both must be valid in the eyes table.
        for f in (rows, rows - 1):
            idx = frame_rows(eyes["frame"], f)
            assert eyes["valid"][idx].all(), (take, f[~eyes["valid"][idx]][:10])
        gated = _gated_mocap_frames(take)
        assert gated.size, take
        in_table = np.isin(gated, eyes["frame"])
        idx = frame_rows(eyes["frame"], gated[in_table])
        leaked_eyes = gated[in_table][eyes["valid"][idx]]
        leaked_rows = np.intersect1d(np.union1d(rows, rows - 1), gated)
        report[take] = (int(in_table.sum()), leaked_eyes.size, leaked_rows.size)
        assert leaked_eyes.size == 0, (take, "valid in the eyes table", leaked_eyes[:20])
        assert leaked_rows.size == 0, (take, "in gaze_rnn", leaked_rows[:20])
    print(f"\ngated-out frames in the crop / leaked to eyes / leaked to gaze_rnn: {report}")


# ----------------------------------------------------------------------------------------------- issue 3 --

def _fill_errors(out, markers: set[str] | None, exclude: set[str]) -> dict:
    """Errors (mm) of the markers table's filled samples against the noise-free truth, both relative to the root
    marker, over the gaze_follow and gaze_shift takes; per method; and the short gaps left unfilled."""
    root = markerset()["root"]
    errs, per_method, unfilled_short = [], {}, []
    for take in FOLLOW + SHIFT:
        m, frames, _, _ = out.markers(take)
        fill = out.fill_names(take)
        tr = truth(take)
        cols = [tr["labels"].index(lab) for lab in m.labels]
        true_xyz = tr["markers_true"].astype(np.float64)[frames][:, cols]
        true_rel = true_xyz - true_xyz[:, [m.labels.index(root)]]
        keep = np.array([(markers is None or lab in markers) and lab not in exclude for lab in m.labels])
        filled = (fill != FILL_MEASURED) & (fill != FILL_UNFILLED) & keep[None, :]
        assert np.isfinite(m.xyz[filled]).all(), take
        e = np.linalg.norm(m.xyz - true_rel, axis=-1)
        errs.append(e[filled])
        for meth in np.unique(fill[filled]):
            per_method.setdefault(str(meth), []).append(e[filled & (fill == meth)])
        # Gaps of at most max_gap_s (1 s) inside the take (not touching its first or last frame) are filled.
        rate = tr["scalars"]["rate_hz"]
        for col, a, b in tr["gaps"]:
            lab = tr["labels"][col]
            if (b - a) / rate > 1.0 or a == 0 or b == len(tr["time_s"]) or not keep[m.labels.index(lab)]:
                continue
            sel = (frames >= a) & (frames < b)
            if (fill[sel, m.labels.index(lab)] == FILL_UNFILLED).any():
                unfilled_short.append((take, lab, int(a), int(b)))
    per_method = {k: np.concatenate(v) for k, v in per_method.items()}
    return {"errors": np.concatenate(errs), "per_method": per_method, "unfilled_short": unfilled_short}


def _print_fill(what: str, r: dict) -> None:
    e = r["errors"]
    print(f"\ngap filling, {what}: {e.size} filled samples, mean {e.mean():.3f} mm, p95 {_pct(e, 95):.3f} mm, "
          f"max {e.max():.3f} mm")
    for meth, v in sorted(r["per_method"].items()):
        print(f"   {meth:7s} n={v.size:5d} mean {v.mean():.3f} mm p95 {_pct(v, 95):.3f} mm max {v.max():.3f} mm")


def test_gap_filling_against_truth(out):
    """Every marker but the gaze target: the subject's markers and the clapper."""
    r = _fill_errors(out, None, {markerset()["target"]})
    _print_fill("subject and clapper markers", r)
    e = r["errors"]
    assert e.size > 500
    # one short gap may stay open: a 19-frame head gap of follow_standing_02 whose marker travels six times
    # further than on any stretch its fill was tried on (its PCA fill was 4.3 mm off on average, estimated 1.8)
    assert len(r["unfilled_short"]) <= 1, r["unfilled_short"]
    assert e.mean() <= 3.0
    assert _pct(e, 95) <= 10.0


def test_gap_filling_target_marker_against_truth(out):
    """follow_sitting_01's POLE gap [160, 181) spans the pole's turn to a new goal (frame 176): the samples
    hidden beside it validate a straight fill at 1.1 mm, but the velocities at its edges show the turn, so it
    stays a gap instead of a fill 245 mm off."""
    r = _fill_errors(out, {markerset()["target"]}, set())
    _print_fill("target marker", r)
    e = r["errors"]
    assert e.size > 0
    assert e.mean() <= 3.0
    assert _pct(e, 95) <= 10.0


def test_measured_samples_are_the_raw_ones(out):
    root = markerset()["root"]
    for take in FOLLOW + SHIFT + take_ids("neutral"):
        m, frames, _, _ = out.markers(take)
        fill = out.fill_names(take)
        raw, raw_frames, _, _ = out.markers(take, "markers_raw")
        assert list(raw.labels) == list(m.labels), take
        rows = frame_rows(raw_frames, frames)
        r = m.labels.index(root)
        raw_xyz = raw.xyz[rows]
        raw_valid = raw.valid[rows]
        measured = fill == FILL_MEASURED
        # A measured sample was measured; a sample measured in the raw table stays measured unless removed as
        # a spike (counted in the clean QC).
        assert not (measured & ~raw_valid).any(), take
        spikes = sum(v["spikes_removed"] for v in out.unit(take, "clean")["qc"]["markers"].values())
        assert int((raw_valid & ~measured).sum()) == spikes, (take, int((raw_valid & ~measured).sum()), spikes)
        # Bit for bit, relative to the root, where the root itself is measured (positions are stored as float32:
        # the difference of the raw samples, rounded once)
        sel = measured & measured[:, [r]]
        expect = (raw_xyz - raw_xyz[:, [r]]).astype(np.float32)
        assert np.array_equal(m.xyz[sel], expect[sel]), (take, np.abs(m.xyz[sel] - expect[sel]).max())
        assert np.isnan(m.xyz[fill == FILL_UNFILLED]).all(), take


def test_segment_orientations_against_truth(out):
    segs = truth(FOLLOW[0])["segments"]
    pooled, per_seg, valid_share = [], {s: [] for s in segs}, {}
    for take in FOLLOW + SHIFT:
        j = out.joints(take)
        assert list(j["segments"]) == list(segs), take
        v = j["valid"]
        # Every frame whose subject markers are all measured or filled has a character frame and rotations.
        ms = markerset()
        m, frames, _, _ = out.markers(take)
        subject = [m.labels.index(x) for s in ms["segments"].values() for x in s["markers"]]
        complete = (out.fill_names(take)[:, subject + [m.labels.index(ms["root"])]] != FILL_UNFILLED).all(axis=1)
        assert np.array_equal(frames, j["frame"]), take
        assert not (complete & ~v).any(), (take, frames[complete & ~v][:10])
        valid_share[take] = round(float(v.mean()), 3)
        err = angle_deg(j["quat"][v], truth(take)["seg_quat_char"][j["frame"][v]])
        pooled.append(err.ravel())
        for k, s in enumerate(segs):
            per_seg[s].append(err[:, k])
    pooled = np.concatenate(pooled)
    print(f"\nvalid joints rows per take: {valid_share}")
    print(f"segment orientation error: median {np.median(pooled):.3f} deg, p99 {_pct(pooled, 99):.3f} deg")
    for s, v in per_seg.items():
        v = np.concatenate(v)
        print(f"   {s:7s} median {np.median(v):.3f} p99 {_pct(v, 99):.3f} max {v.max():.3f}")
    assert np.median(pooled) <= 1.0
    assert _pct(pooled, 99) <= 3.0


def test_target_direction_against_truth(out):
    res = {}
    for take in FOLLOW:
        j = out.joints(take)
        v = j["valid"]
        err = vec_angle_deg(j["target_dir"][v], truth(take)["target_dir_char"][j["frame"][v]])
        assert np.isfinite(err).mean() > 0.9, take
        err = err[np.isfinite(err)]
        res[take] = (round(float(np.median(err)), 3), round(_pct(err, 99), 3))
    print(f"\ntarget direction error (median, p99) deg: {res}")
    assert all(med <= 1.0 for med, _ in res.values()), res


def test_crop_bounds(out):
    res = {}
    for take in SHIFT + FOLLOW:
        crop = out.unit(take, "clean")["qc"]["crop"]
        true = [int(c) for c in truth(take)["crop"]]
        res[take] = (crop, true)
        # The tables' rows are the crop, for every take (wiring).
        for name in ("joints", "markers"):
            frames = out.table(take, name).column("frame").to_numpy()
            assert np.array_equal(np.unique(frames), np.arange(*crop)), (take, name)
    print(f"\ncrops (pipeline, truth): {res}")
    for take in SHIFT:
        crop, true = res[take]
        assert abs(crop[0] - true[0]) <= 2 and abs(crop[1] - true[1]) <= 2, (take, crop, true)


# ----------------------------------------------------------------------------------------------- issue 5 --

@pytest.mark.parametrize("name,n_in,n_out", [("gaze_rnn", 66, 63), ("gaze_rnn_lod", 21, 18)])
def test_rnn_widths(out, name, n_in, n_out):
    table, info = out.dataset(name)
    assert table.num_rows > 0
    assert feature_values(table, "x").shape[1] == n_in
    assert feature_values(table, "y").shape[1] == n_out
    assert len(info["features"]["x"]) == n_in and len(info["features"]["y"]) == n_out
    assert info["sizes"] == {"n_in": n_in, "n_out": n_out}


def _rnn_arrays(out, name):
    table, info = out.dataset(name)
    ident = {c: np.asarray(table.column(c).to_pylist()) for c in ("take", "mirrored", "segment", "frame", "split")}
    return ident, feature_values(table, "x"), feature_values(table, "y"), info


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_rnn_y_is_next_x(out, name):
    ident, x, y, _ = _rnn_arrays(out, name)
    n_rot = y.shape[1]
    key = np.stack([np.unique(ident["take"], return_inverse=True)[1], ident["mirrored"].astype(int),
                    ident["segment"]], axis=1)
    same = (key[1:] == key[:-1]).all(axis=1)
    consecutive = same & (np.diff(ident["frame"]) == 1)
    # Rows of one segment are consecutive frames, in order.
    assert np.array_equal(same, consecutive)
    assert consecutive.sum() > 0.8 * len(x)
    i = np.flatnonzero(consecutive)
    assert np.array_equal(y[i], x[i + 1, 3:3 + n_rot])


def test_rnn_rows_are_the_take_tables_at_their_frame(out):
    """Unmirrored gaze_rnn rows hold the joints and eyes tables' values of their own frame (t) and the one
    before (t - 1), as float32: target direction, every segment's 6-number rotation, eye direction."""
    ident, x, y, info = _rnn_arrays(out, "gaze_rnn")
    n_seg = len(truth(FOLLOW[0])["segments"])
    for take in FOLLOW:
        sel = (ident["take"] == take) & ~ident["mirrored"]
        assert sel.sum() > 100, take
        f = ident["frame"][sel].astype(np.int64)
        j, eyes = out.joints(take), out.eyes(take)
        cur, prev = frame_rows(j["frame"], f), frame_rows(j["frame"], f - 1)
        six = j["six"].reshape(len(j["frame"]), -1)
        assert six.shape[1] == 6 * n_seg
        np.testing.assert_array_equal(y[sel][:, :6 * n_seg], six[cur].astype(np.float32))
        np.testing.assert_array_equal(x[sel][:, 3:3 + 6 * n_seg], six[prev].astype(np.float32))
        np.testing.assert_allclose(x[sel][:, :3], j["target_dir"][cur], atol=1e-6)
        ecur, eprev = frame_rows(eyes["frame"], f), frame_rows(eyes["frame"], f - 1)
        np.testing.assert_allclose(y[sel][:, 6 * n_seg:], eyes["eye_dir_char"][ecur], atol=1e-6)
        np.testing.assert_allclose(x[sel][:, 3 + 6 * n_seg:], eyes["eye_dir_char"][eprev], atol=1e-6)


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_rnn_directions_unit_length(out, name):
    _, x, y, _ = _rnn_arrays(out, name)
    for v in (x, y):
        norms = np.linalg.norm(v.reshape(len(v), -1, 3).astype(np.float64), axis=-1)
        assert np.abs(norms - 1).max() < 1e-5, np.abs(norms - 1).max()
    six = y[:, : (y.shape[1] // 6) * 6].reshape(len(y), -1, 2, 3).astype(np.float64)
    assert np.abs(np.einsum("nki,nki->nk", six[:, :, 0], six[:, :, 1])).max() < 1e-5


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod"])
def test_rnn_mirrored_rows(out, name):
    ident, x, y, _ = _rnn_arrays(out, name)
    assert not any(s.startswith(("left", "right")) for s in markerset()["segments"]), "pairs would swap blocks"
    orig = ~ident["mirrored"]
    assert orig.sum() == (~orig).sum()
    keys = np.char.add(ident["take"].astype(str), np.char.add(":", ident["frame"].astype(str)))
    o = np.argsort(keys[orig], kind="stable")
    mi = np.argsort(keys[~orig], kind="stable")
    assert np.array_equal(keys[orig][o], keys[~orig][mi])
    assert np.array_equal(mirror_rnn(x[orig][o]), x[~orig][mi])
    assert np.array_equal(mirror_rnn(y[orig][o]), y[~orig][mi])


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod", "gaze_map", "face_clean"])
def test_splits_take_disjoint(out, name):
    table, info = out.dataset(name)
    take = np.asarray(table.column("take").to_pylist())
    split = np.asarray(table.column("split").to_pylist())
    for t in np.unique(take):
        assert len(np.unique(split[take == t])) == 1, (name, t)
    listed = [t for ts in info["splits"]["takes"].values() for t in ts]
    assert len(listed) == len(set(listed)) == len(np.unique(take))


@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod", "gaze_map", "face_clean"])
def test_statistics_from_training_rows(out, name):
    table, info = out.dataset(name)
    split = np.asarray(table.column("split").to_pylist())
    pose = np.asarray(table.column("pose").to_pylist())
    stats = info["stats"]
    groups = {"overall": split == "train"}
    groups.update({p: (split == "train") & (pose == p) for p in stats["per_pose"]})
    assert (split == "train").any()
    for g, sel in groups.items():
        s = stats["overall"] if g == "overall" else stats["per_pose"][g]
        assert s["rows"] == int(sel.sum()), (g, s["rows"], int(sel.sum()))
        for col in (c for c in s if c != "rows"):
            v = feature_values(table.filter(sel), col).astype(np.float64)
            ok = ~np.isnan(v)                        # null values (gaze_map) are left out per element
            n = ok.sum(axis=0)
            mean = np.where(ok, v, 0.0).sum(axis=0) / np.maximum(n, 1)
            std = np.sqrt((np.where(ok, v - mean, 0.0) ** 2).sum(axis=0) / np.maximum(n, 1))
            assert s[col]["count"] == n.tolist(), (g, col)
            np.testing.assert_allclose(s[col]["mean"], mean, rtol=1e-9, atol=1e-9, err_msg=f"{g} {col}")
            np.testing.assert_allclose(s[col]["std"], std, rtol=1e-9, atol=1e-9, err_msg=f"{g} {col}")


def _gaze_map(out):
    table, info = out.dataset("gaze_map")
    d = {c: np.asarray(table.column(c).to_pylist()) for c in ("take", "mirrored")}
    for c in ("yaw_deg", "pitch_deg", "duration_s", "overshoot_time", "overshoot"):
        d[c] = feature_values(table, c)[:, 0].astype(np.float64)
    d["start_times"] = feature_values(table, "start_times").astype(np.float64)
    d["p_plus"] = feature_values(table, "p_plus").astype(np.float64)
    d["start_known"] = np.array(table.column("start_known").to_pylist(), dtype=bool)
    return d, info


# Event times are stored as float32 fractions of l: allow their rounding on top of the 2 frames.
FRAME_TOL = 2.0 + 1e-3


def _gaze_map_errors(out) -> list[dict]:
    """Per gaze_shift take, the unmirrored gaze_map row against truth.json. Event times in frames from the
    crop's first frame, as the row stores them (fraction of l times l times the rate); ``abs_*`` the same
    events in take frames (the clean QC's crop start added), which takes the crop's own error out."""
    d, info = _gaze_map(out)
    segs = info["features"]["start_times"]
    rate = info["fps"]
    rows = []
    for take in SHIFT:
        i = np.flatnonzero((d["take"] == take) & ~d["mirrored"])
        assert i.size == 1, take
        i = int(i[0])
        sc = truth(take)["scalars"]
        c0_p, c0_t = out.unit(take, "clean")["qc"]["crop"][0], sc["crop"][0]
        l_p, l_t = float(d["duration_s"][i]), float(sc["l_s"])
        start_p = {s: float(d["start_times"][i, k]) * l_p * rate for k, s in enumerate(segs)}
        assert (np.isnan(d["start_times"][i]) == ~d["start_known"][i]).all(), take     # null with the mask
        start_t = {s: sc["start_frac"][s] * l_t * rate for s in segs}
        tb_p, tb_t = float(d["overshoot_time"][i]) * l_p * rate, sc["t_beta_frac"] * l_t * rate
        rows.append({
            "take": take, "yaw": sc["target"]["yaw_deg"], "pitch": sc["target"]["pitch_deg"],
            "row_yaw": float(d["yaw_deg"][i]), "row_pitch": float(d["pitch_deg"][i]),
            "l_err": (l_p - l_t) * rate, "start_t": start_t,
            "start_err": {s: start_p[s] - start_t[s] for s in segs},
            "abs_start_err": {s: c0_p + start_p[s] - c0_t - start_t[s] for s in segs},
            "tb_err": tb_p - tb_t, "abs_tb_err": c0_p + tb_p - c0_t - tb_t,
            "beta_err": float(d["overshoot"][i]) - sc["beta"], "beta": (float(d["overshoot"][i]), sc["beta"]),
            "near_threshold": near_threshold(truth(take), rate), "peak": peak_speeds(truth(take), rate),
            "rate": rate,
            "start_known": dict(zip(segs, d["start_known"][i].tolist(), strict=True)),
        })
    return rows


def _undecidable(r: dict, s: str) -> bool:
    """A segment whose noise-free peak speed is within 2.5 deg/s of the 18 deg/s start threshold: with the speed
    noise left after the start low-pass (a few deg/s), whether it starts cannot be decided."""
    return s in r["near_threshold"]


def _print_gaze_map(rows: list[dict]) -> None:
    print("\ngaze_map vs truth, frames (take: duration err; overshoot time err as stored / in take frames; "
          "overshoot err; start time errs beyond 1 frame as stored [in take frames]):")
    for r in rows:
        st = {s: f"{e:+.1f} [{r['abs_start_err'][s]:+.1f}]" for s, e in r["start_err"].items() if abs(e) > 1}
        print(f"   {r['take']}: l {r['l_err']:+.1f}; t_beta {r['tb_err']:+.2f} / {r['abs_tb_err']:+.2f}; "
              f"beta {r['beta_err']:+.4f} {r['beta']}; starts {st}")


def test_gaze_map_requested_angles(out):
    for r in _gaze_map_errors(out):
        assert r["row_yaw"] == pytest.approx(r["yaw"], abs=1e-4), r["take"]
        assert r["row_pitch"] == pytest.approx(r["pitch"], abs=1e-4), r["take"]


def test_gaze_map_start_times(out):
    """Segments that do start (truth start > 0): the row has the start, within 2 frames, or (one of them at
    most) none where the rule can barely see it: its noise-free speed, low-passed as the rule does (2 Hz),
    peaks under 22 deg/s, within the few deg/s of speed noise of the threshold (the ~5 deg head pitch of
    shift_y000_p12: 28 deg/s raw, 20.6 low-passed, 17 in the capture; Pejsa's rule wrote 0 there, which
    matched its start at frame 1 by chance)."""
    rows = _gaze_map_errors(out)
    _print_gaze_map(rows)
    starts = [(r, s) for r in rows for s in r["start_t"] if r["start_t"][s] > 0 and not _undecidable(r, s)]
    off = [(r["take"], s, round(r["start_err"][s], 2)) for r, s in starts
           if r["start_known"][s] and not abs(r["start_err"][s]) <= FRAME_TOL]
    assert not off, off
    null = [(r["take"], s) for r, s in starts if not r["start_known"][s]]
    assert len(null) <= 1, null
    assert all(peak_speeds(truth(t), rows[0]["rate"], 2.0)[s] < 22.0 for t, s in null), null


def test_gaze_map_no_spurious_starts(out):
    """Segments whose truth never reaches 18 deg/s: the row's start is null (masked in start_known), never a
    0 that reads as a start at the crop's first frame."""
    rows = _gaze_map_errors(out)
    spurious = [(r["take"], s) for r in rows for s in r["start_err"]
                if r["peak"][s] < 18.0 and not _undecidable(r, s) and r["start_known"][s]]
    assert not spurious, spurious
    assert sum(not k for r in rows for k in r["start_known"].values()) >= 40      # most of the spine: no start


def test_gaze_map_undecidable_starts_are_few(out):
    """The segments left out of the start-time checks (peak within 2.5 deg/s of the threshold; 14 of 90 on the
    sample session) stay a minority, so the checks above still cover most segments."""
    rows = _gaze_map_errors(out)
    left_out = sum(len(r["near_threshold"]) for r in rows)
    total = sum(len(r["start_t"]) for r in rows)
    print(f"\ngaze_map start times: {left_out} of {total} segment starts undecidable (peak near 18 deg/s)")
    assert left_out <= 0.25 * total, left_out


def test_gaze_map_overshoot(out):
    """β within 0.05 everywhere; t_β within 2 frames wherever the overshoot is resolvable: the head passing its
    final orientation by at least 0.5° (shift_y000_p12's passes it by 0.19°, under the orientation noise)."""
    rows = _gaze_map_errors(out)
    _print_gaze_map(rows)
    tiny = {r["take"] for r in rows if overshoot_amplitude_deg(truth(r["take"])) < 0.5}
    assert len(tiny) <= 1, tiny
    bad_t = [(r["take"], round(r["tb_err"], 2)) for r in rows
             if abs(r["tb_err"]) > FRAME_TOL and r["take"] not in tiny]
    bad_b = [(r["take"], round(r["beta_err"], 4)) for r in rows if abs(r["beta_err"]) > 0.05]
    assert not bad_b, bad_b
    assert not bad_t, bad_t


def test_gaze_map_mirrored_rows(out):
    d, info = _gaze_map(out)
    for take in SHIFT:
        i = np.flatnonzero((d["take"] == take) & ~d["mirrored"])
        j = np.flatnonzero((d["take"] == take) & d["mirrored"])
        assert i.size == j.size == 1, take
        i, j = int(i[0]), int(j[0])
        assert d["yaw_deg"][j] == -d["yaw_deg"][i] and d["pitch_deg"][j] == d["pitch_deg"][i]
        for c in ("duration_s", "overshoot_time", "overshoot"):
            assert d[c][j] == d[c][i], (take, c)
        assert np.array_equal(d["start_times"][j], d["start_times"][i], equal_nan=True), take
        assert np.array_equal(d["start_known"][j], d["start_known"][i]), take
        pp = d["p_plus"][i].reshape(-1, 4)
        np.testing.assert_array_equal(d["p_plus"][j].reshape(-1, 4), mirror_quat(pp))


# ------------------------------------------------------------------------------------ every reader opens it

@pytest.mark.parametrize("name", ["gaze_rnn", "gaze_rnn_lod", "gaze_map", "face_clean"])
def test_every_reader_opens_each_dataset_with_no_arguments(out, name, tmp_path, monkeypatch):
    """pandas, pyarrow (read_table and dataset), polars and DuckDB on the glob, and Hugging Face datasets open
    each dataset of the sample as it is; they read the same rows, and Hugging Face's splits hold exactly the
    rows whose ``split`` column says so."""
    import duckdb
    import pandas as pd
    import polars as pl
    import pyarrow.dataset as pads
    import pyarrow.parquet as pq

    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))   # a fresh cache: no earlier build's rows
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    datasets = pytest.importorskip("datasets")
    root = out.root / "datasets" / name
    files = sorted(root.glob("*/*/*.parquet"))
    want = sum(pq.ParquetFile(f).metadata.num_rows for f in files)
    assert files and want > 0
    df = pd.read_parquet(root)
    by_split = df["split"].value_counts().to_dict()
    assert len(df) == want and df["session"].dtype != "category"
    assert pq.read_table(root).num_rows == want
    assert pads.dataset(root).to_table().num_rows == want
    assert pl.read_parquet(f"{root}/**/*.parquet").height == want
    assert pl.scan_parquet(f"{root}/**/*.parquet").select(pl.len()).collect().item() == want
    assert duckdb.sql(f"SELECT count(*) FROM read_parquet('{root}/**/*.parquet')").fetchall()[0][0] == want
    hf = datasets.load_dataset(str(root))
    hf_names = {"train": "train", "val": "validation", "test": "test"}
    assert {hf_names[s]: n for s, n in by_split.items()} == {k: v.num_rows for k, v in hf.items()}
    for split, data in hf.items():
        assert set(data.unique("split")) == {next(s for s, h in hf_names.items() if h == split)}


def test_the_readme_gate_passes_on_the_sample_and_its_warnings_are_findings(out, tmp_path):
    """The README's gate (``validate out --fail-on fail``) exits 0 after its first command, and no warning on
    the sample is about an empty split, rows without a full training window or a constant feature: the sample
    is fair to every dataset, and what is left are the capture's own findings. (Validation rewrites ``qc/``:
    it runs on a copy of the shared output.)"""
    import json
    import shutil

    root = tmp_path / "out"
    shutil.copytree(out.root, root, symlinks=True)
    res = CliRunner().invoke(cli, ["validate", str(root), "--fail-on", "fail"])
    assert res.exit_code == 0, res.output[-2000:]
    report = json.loads((root / "qc" / "report.json").read_text())
    warned = [(c.get("id") or c.get("check"), c.get("message", "")) for scope in ("datasets",)
              for d in report.get(scope, []) for c in d.get("checks", []) if c.get("severity") == "warning"]
    assert not warned, warned
    text = res.output.lower()
    for phrase in ("empty split", "feed no training window", "constant features"):
        assert phrase not in text, phrase


# ------------------------------------------------------------------------------------------------ lean Parquet

def test_every_table_is_lean_and_every_reader_reads_it(out, tmp_path, monkeypatch):
    """Per-take tables and dataset files: no dictionary on a float column, BYTE_STREAM_SPLIT on every float
    column and float list, no float64 list; and pandas, pyarrow, polars, DuckDB and Hugging Face read each
    table kind with its row count."""
    import duckdb
    import polars as pl
    import pyarrow.parquet as pq

    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    datasets = pytest.importorskip("datasets")
    files = sorted((out.root / "takes").rglob("*.parquet")) + sorted((out.root / "datasets").rglob("*.parquet"))
    kinds: dict[str, Path] = {}
    for f in files:
        pf = pq.ParquetFile(f)
        schema = pf.schema_arrow
        for g in range(pf.metadata.num_row_groups):
            rg = pf.metadata.row_group(g)
            for i in range(rg.num_columns):
                col = rg.column(i)
                top = schema.field(col.path_in_schema.split(".")[0]).type
                leaf = top.value_type if hasattr(top, "value_type") else top
                if pa.types.is_floating(leaf):
                    assert "BYTE_STREAM_SPLIT" in col.encodings, (f, col.path_in_schema, col.encodings)
                    assert "RLE_DICTIONARY" not in col.encodings, (f, col.path_in_schema)
                    assert not (pa.types.is_fixed_size_list(top) and leaf == pa.float64()), (f, col.path_in_schema)
        kinds.setdefault(f.stem if f.parent.parent.name != "datasets" else "dataset", f)
    assert {"markers_raw", "markers", "joints", "eyes", "sync", "face"} <= set(kinds), sorted(kinds)
    for kind, f in sorted(kinds.items()):
        n = pq.ParquetFile(f).metadata.num_rows
        assert len(pd.read_parquet(f)) == n, kind
        assert pl.read_parquet(f).height == n, kind
        assert duckdb.sql(f"SELECT count(*) FROM read_parquet('{f}')").fetchall()[0][0] == n, kind
        hf = datasets.load_dataset("parquet", data_files=str(f), split="train")
        assert hf.num_rows == n, kind


def test_derived_joint_columns_match_the_frames_stage(out):
    """``quat_local`` and ``six`` are derived on reading from the stored float32 ``quat``: they agree with the
    frames stage's own (from the rotation matrices) to float32 rounding, NaN where a rotation is missing."""
    from gazepipe.schemas.joints import joints_arrays
    from gazepipe.stages.geometry import from_wxyz

    take = FOLLOW[0]
    j = joints_arrays(out.table(take, "joints"))
    q, loc, six = j["quat"], j["quat_local"], j["six"]
    ok = np.isfinite(q).all(axis=-1)
    assert ok.mean() > 0.5
    parents = j["meta"]["parents"]
    for k, p in enumerate(parents):
        both = ok[:, k] & (ok[:, p] if p >= 0 else True)
        want = from_wxyz(q[both, k]) if p < 0 else from_wxyz(q[both, p]).inv() * from_wxyz(q[both, k])
        got = from_wxyz(loc[both, k])
        assert np.degrees((got.inv() * want).magnitude()).max() < 1e-4, k
        assert np.isnan(loc[~both, k]).all()
        m = from_wxyz(q[ok[:, k], k]).as_matrix()
        np.testing.assert_allclose(six[ok[:, k], k], np.concatenate([m[:, :, 2], m[:, :, 1]], axis=1), atol=1e-6)
