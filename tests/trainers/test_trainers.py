"""Trainer plugins and ``gazepipe train``: discovery, refusing the wrong dataset, and the three reference
trainers against their baselines on datasets built from generated sessions
(tests/helpers/datasets.py)."""

from __future__ import annotations

import json
import shutil
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from gazepipe.cli.train import train as train_cmd
from gazepipe.datasets import open_dataset
from gazepipe.errors import ConfigError
from gazepipe.trainers import base
from gazepipe.trainers.base import TrainOptions, check_compatible, load_trainer
from gazepipe.trainers.gaze_map import GazeMap, GazeMotion, knn_weights
from tests.helpers.datasets import GAZE_MAP_VAL


@pytest.fixture(scope="module")
def datasets(generated_datasets) -> Path:
    return generated_datasets


def run_train(*args: str):
    return CliRunner().invoke(train_cmd, list(args))


# ------------------------------------------------------------------------------------ discovery and checks

def test_unknown_trainer_lists_the_available_ones(datasets, tmp_path):
    res = run_train("nope", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2
    line = res.output.strip()
    assert "\n" not in line and "unknown trainer 'nope'" in line
    assert "face_clean, gaze_map, gaze_rnn" in line


def test_entry_points_are_discovered(monkeypatch):
    ep = EntryPoint(name="my_map", value="gazepipe.trainers.gaze_map:GazeMapTrainer", group=base.GROUP)
    monkeypatch.setattr(base, "entry_points", lambda group: [ep] if group == base.GROUP else [])
    assert base.available()["my_map"] == "gazepipe.trainers.gaze_map:GazeMapTrainer"
    t = load_trainer("my_map")
    assert t.dataset == "gaze_map" and isinstance(t, base.Trainer)


@pytest.mark.parametrize("trainer, dataset, message", [
    ("gaze_map", "gaze_rnn", "trainer 'gaze_map' needs a gaze_map dataset, this is 'gaze_rnn'"),
    ("gaze_rnn", "face_clean", "needs a gaze_rnn or gaze_rnn_lod dataset, this is 'face_clean'"),
    ("face_clean", "gaze_map", "needs a face_clean dataset"),
])
def test_wrong_dataset_is_refused(datasets, tmp_path, trainer, dataset, message):
    res = run_train(trainer, "--data", str(datasets / dataset), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2
    assert res.output.count("\n") == 1 and message in res.output and str(datasets / dataset) in res.output
    assert not (tmp_path / "m").exists()


def test_schema_version_and_columns_are_checked(datasets, tmp_path):
    copy = tmp_path / "gaze_map"
    shutil.copytree(datasets / "gaze_map", copy)
    info = json.loads((copy / "_dataset.json").read_text())
    info["schema_version"] = 99
    (copy / "_dataset.json").write_text(json.dumps(info))
    res = run_train("gaze_map", "--data", str(copy), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2 and "reads schema version 3, the dataset has 99" in res.output

    class Needy:
        name, dataset, schema_version, required_columns = "needy", "gaze_map", 1, ("p_plus", "gaze_target")

    with pytest.raises(ConfigError, match="needs columns gaze_target, missing"):
        check_compatible(Needy(), {"name": "gaze_map", "schema_version": 1}, ["p_plus"], "d")


def test_usage_errors(datasets, tmp_path):
    res = run_train("gaze_map", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2 and "no such dataset folder" in res.output
    (tmp_path / "empty").mkdir()
    res = run_train("gaze_map", "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2 and "_dataset.json" in res.output
    res = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"), "--option", "q=1")
    assert res.exit_code == 2 and "has no option q (options: k, train_split)" in res.output
    res = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"), "--option", "k")
    assert res.exit_code == 2 and "expected KEY=VALUE" in res.output
    res = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"), "--epochs", "3")
    assert res.exit_code == 2 and "trainer 'gaze_map' does not use --epochs" in res.output


def test_torch_trainer_without_torch(datasets, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn"), "--out", str(tmp_path / "m"))
    assert res.exit_code == 2 and "gazepipe[torch]" in res.output


# -------------------------------------------------------------------------------------------- gaze_map

def test_knn_weights():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [10.0, 0.0]])
    idx, w = knn_weights(pts, np.array([0.5, 0.0]), k=2)   # d = 0.5, 0.5, 2.5: w ∝ 2 − 0.4 each
    assert sorted(idx.tolist()) == [0, 1] and np.allclose(w, 0.5)
    idx, w = knn_weights(pts, np.array([0.2, 0.0]), k=2)   # 1/0.2 − 1/2.8 vs 1/0.8 − 1/2.8
    a, b = 1 / 0.2 - 1 / 2.8, 1 / 0.8 - 1 / 2.8
    assert idx.tolist() == [0, 1] and np.allclose(w, [a / (a + b), b / (a + b)])
    idx, w = knn_weights(pts, np.array([3.0, 0.0]), k=2)
    assert idx.tolist() == [2] and w.tolist() == [1.0]


def test_overshoot_curve():
    """Pejsa 5.2.3 with ease-in/ease-out: identity before t_j, (1 + β)·P+ at t_β, P+ at the end, C¹."""
    q = Rotation.from_rotvec([[0, 0.4, 0], [0, 0.2, 0.1], [0.1, 0.5, 0]]).as_quat()[:, [3, 0, 1, 2]]
    m = GazeMotion(yaw_deg=40, pitch_deg=5, names=["a", "b", "eyes"], p_plus=q, duration_s=0.8,
                   start_times=np.array([0.2, 0.7]), overshoot_time=0.6, overshoot=0.1)
    u = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.6, 0.8, 1.0])
    s = m.scale(u)
    # joint a: eases from 0 at 0.2 to 1.1 at 0.6 ((1 − cos πs)/2 at s = 0.25, 0.5), back to 1 at 1
    e = lambda x: 0.5 * (1 - np.cos(np.pi * x))   # noqa: E731
    np.testing.assert_allclose(s[:, 0], [0, 0, 0, 1.1 * e(0.25), 1.1 * e(0.5), 1.1, 1 + 0.1 * (1 - e(0.5)), 1])
    # joint b starts after the peak: eases from 0 at 0.7 to 1 at 1 with no overshoot
    np.testing.assert_allclose(s[:, 1], [0, 0, 0, 0, 0, 0, e(0.1 / 0.3), 1])
    # eyes start at 0
    np.testing.assert_allclose(s[:, 2], [0, 1.1 * e(1 / 6), 1.1 * e(2 / 6), 1.1 * e(0.5), 1.1 * e(4 / 6), 1.1,
                                         1 + 0.1 * (1 - e(0.5)), 1])
    t, quats = m.curve(fps=200)
    assert t[0] == 0 and t[-1] == pytest.approx(0.8)
    np.testing.assert_allclose(np.abs(np.sum(quats[-1] * q, axis=1)), 1, atol=1e-12)
    ang = Rotation.from_quat(quats[:, 0][:, [1, 2, 3, 0]]).magnitude()
    assert ang.max() == pytest.approx(1.1 * 0.4, abs=1e-3)
    # C¹: the largest second difference is the ease's own curvature, (π²/2)·A/T²·h² for the rise of
    # A = 0.44 rad over T = 0.32 s (a linear ramp's corner would give A/T·h = 6.9e-3, thirteen times more)
    second = np.abs(np.diff(ang, 2))
    assert second.max() < 1.05 * (np.pi ** 2 / 2) * 0.44 / 0.32 ** 2 / 200 ** 2


def _toy_map(known=None, poison=False, start_known=None):
    """Five examples of a two-segment map on a yaw line; with ``poison`` the nearest one to yaw 10° has NaN for
    segment 1 (P+ and start) and the overshoot."""
    rng = np.random.default_rng(0)
    yaw = np.array([0.0, 9.0, 20.0, 40.0, -30.0])
    q = Rotation.from_rotvec(rng.normal(0, 0.2, (15, 3))).as_quat()[:, [3, 0, 1, 2]].reshape(5, 3, 4)
    start = rng.uniform(0, 0.5, (5, 2))
    t_b, beta = rng.uniform(0.5, 0.9, 5), rng.uniform(0, 0.1, 5)
    if poison:
        q[1, 1], start[1, 1], t_b[1], beta[1] = np.nan, np.nan, np.nan, np.nan
    return GazeMap(["a", "b"], yaw, np.zeros(5), q.reshape(5, -1), np.full(5, 0.8), start, t_b, beta, k=2,
                   known=known, start_known=start_known)


def test_gaze_map_never_blends_a_null_parameter(monkeypatch):
    """An example's null segment and overshoot (NaN, False in its ``known`` mask) never reach a blend: every
    quaternion blended and every weight is finite, that segment and the overshoot come from the nearest examples
    that know them (the same as a map without that example gives), and the other joints still use it."""
    import gazepipe.trainers.gaze_map as gm

    seen = []
    real = gm.blend_quaternions

    def spy(q, w):
        assert np.isfinite(q).all() and np.isfinite(w).all()
        seen.append(q.shape)
        return real(q, w)

    monkeypatch.setattr(gm, "blend_quaternions", spy)
    mask = np.ones((5, 4), bool)
    mask[1, [1, 3]] = False
    poisoned = _toy_map(mask, poison=True)
    assert (poisoned.known == mask).all() and (_toy_map(poison=True).known == mask).all()   # NaN alone says it too
    m = poisoned.motion(10.0, 0.0)
    assert seen and np.isfinite(m.p_plus).all() and np.isfinite(m.start_times).all()
    assert np.isfinite([m.overshoot_time, m.overshoot, m.duration_s]).all()
    full = _toy_map().motion(10.0, 0.0)                      # the example known everywhere
    keep = np.array([True, False, True, True, True])
    without = GazeMap(["a", "b"], *(np.asarray(v)[keep] for v in (
        _toy_map().yaw, _toy_map().pitch, _toy_map().p_plus, _toy_map().duration, _toy_map().start_times,
        _toy_map().overshoot_time, _toy_map().overshoot)), k=2).motion(10.0, 0.0)
    np.testing.assert_allclose(m.p_plus[1], without.p_plus[1], atol=1e-12)
    assert m.start_times[1] == pytest.approx(without.start_times[1])
    assert (m.overshoot_time, m.overshoot) == pytest.approx((without.overshoot_time, without.overshoot))
    for j in (0, 2):                                          # segment a and the eyes still blend example 1
        np.testing.assert_allclose(m.p_plus[j], full.p_plus[j], atol=1e-12)
    assert m.start_times[0] == pytest.approx(full.start_times[0])
    assert not np.allclose(full.p_plus[1], without.p_plus[1], atol=1e-3)    # example 1 does weigh in when known
    # leave-one-out and held-out errors skip what the reference does not know; every figure is finite
    ev = gm.evaluate(poisoned)
    assert ev["compared"] == 14 and ev["not_compared"] == 1 and np.isfinite(ev["final_pose_error_deg_max"])
    assert all(np.isfinite(v) for v in ev["final_pose_error_deg_per_joint_mean"].values())
    # a joint whose P+ no example knows is NaN in the motion and stays still in its curve; its start time is
    # the dataset's start_known's business: blended where examples know it, 0 (Pejsa) where none does
    mask[:, 1] = False
    lone = _toy_map(mask).motion(10.0, 0.0)
    assert np.isnan(lone.p_plus[1]).all() and lone.start_times[1] == pytest.approx(full.start_times[1])
    _, curve = lone.curve(fps=30)
    assert np.isfinite(curve).all() and np.allclose(curve[:, 1], [1, 0, 0, 0])
    no_start = np.ones((5, 2), bool)
    no_start[:, 1] = False
    unstarted = _toy_map(start_known=no_start)
    assert (unstarted.start_known == no_start).all() and (unstarted.known == np.ones((5, 4), bool)).all()
    got = unstarted.motion(10.0, 0.0)
    assert got.start_times[1] == 0.0 and got.start_times[0] == pytest.approx(full.start_times[0])
    np.testing.assert_allclose(got.p_plus, full.p_plus, atol=1e-12)


def test_gaze_map_reproduces_held_out_examples(datasets, tmp_path):
    """Acceptance: the map trained without the val takes synthesises each val example's final pose (every
    segment's and the eyes' P+) within 5°; saving is deterministic."""
    res = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"), "--json")
    assert res.exit_code == 0, res.output
    metrics = json.loads(res.output)
    gmap = GazeMap.load(tmp_path / "m")
    ds = open_dataset(datasets / "gaze_map")
    val = ds.table(split="val").to_pylist()
    assert len(gmap) == ds.table(split="train").num_rows and len(val) == 2 * len(GAZE_MAP_VAL)
    worst = 0.0
    for row in val:
        assert (abs(row["yaw_deg"]), row["pitch_deg"]) in {(abs(y), p) for y, p in GAZE_MAP_VAL}
        m = gmap.motion(row["yaw_deg"], row["pitch_deg"])
        want = np.array(row["p_plus"], np.float64).reshape(-1, 4)
        err = (Rotation.from_quat(m.p_plus[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(want[:, [1, 2, 3, 0]]))
        worst = max(worst, float(np.rad2deg(err.magnitude()).max()))
        head = Rotation.from_quat(want[-2, [1, 2, 3, 0]]).magnitude()
        assert np.rad2deg(head) > 5       # the held-out examples do move: 5° is not met by standing still
    assert worst < 5.0
    assert metrics["val"]["final_pose_error_deg_max"] == pytest.approx(worst, abs=1e-6)
    res2 = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m2"))
    assert res2.exit_code == 0
    for f in ("gaze_map.npz", "model.json"):
        a, b = (tmp_path / "m" / f).read_bytes(), (tmp_path / "m2" / f).read_bytes()
        assert a == b, f


def _linear_map(rng, shares: np.ndarray, yaws: np.ndarray, pitches: np.ndarray) -> GazeMap:
    """A map of 3 segments whose every joint's rotation vector is ``shares[j] @ (yaw, pitch)`` (radians)."""
    yp = np.deg2rad(np.stack([yaws, pitches], axis=1))
    rv = np.einsum("jab,eb->eja", shares, yp)
    quats = Rotation.from_rotvec(rv.reshape(-1, 3)).as_quat()[:, [3, 0, 1, 2]].reshape(len(yaws), -1)
    n = len(yaws)
    return GazeMap(["a", "b", "c"], yaws, pitches, quats, np.full(n, 0.5), rng.uniform(0, 0.3, (n, 3)),
                   np.full(n, 0.6), np.full(n, 0.05))


def test_gaze_map_verdict_against_its_baselines():
    """A map whose joints turn by fixed shares of the request: the fixed-shares baseline is exact (0°), the mean
    shift's error is the one recomputed here from scipy's rotations, and the verdict lines print those
    figures with better and worse the right way round."""
    from gazepipe.trainers.gaze_map import evaluate, summary

    rng = np.random.default_rng(4)
    shares = rng.uniform(-0.4, 0.4, (4, 3, 2))
    yaws, pitches = np.repeat([-40.0, -20.0, 0.0, 20.0, 40.0], 3), np.tile([-15.0, 0.0, 15.0], 5)
    gmap = _linear_map(rng, shares, yaws, pitches)
    held = _linear_map(rng, shares, np.array([-30.0, 10.0, 30.0]), np.array([5.0, -10.0, 10.0]))
    ev = evaluate(gmap, held)
    assert ev["fixed_shares_final_pose_error_deg_mean"] == pytest.approx(0.0, abs=1e-6)
    mean_rot = [Rotation.from_quat(gmap.p_plus[:, j][:, [1, 2, 3, 0]]) for j in range(4)]
    worst = []
    for i in range(len(held)):
        errs = [np.rad2deg((mean_rot[j].mean().inv() * Rotation.from_quat(held.p_plus[i, j, [1, 2, 3, 0]]))
                           .magnitude()) for j in range(4)]
        worst.append(max(errs))
    # scipy's mean is the chordal L2 mean; the baseline's normalised sum differs from it by far under 0.5°
    assert ev["mean_shift_final_pose_error_deg_mean"] == pytest.approx(np.mean(worst), abs=0.5)
    assert ev["final_pose_error_deg_mean"] > 1e-3   # the map blends neighbours, so it is not exact here
    line = summary({"val": ev})[0]
    assert line.startswith(f"val split (3 examples): final-pose error (worst joint per example, mean), degrees: "
                           f"{ev['final_pose_error_deg_mean']:.3g} for the map;")
    mine, mean = ev["final_pose_error_deg_mean"], ev["mean_shift_final_pose_error_deg_mean"]
    assert f"{mean:.3g} for the mean shift (" in line.split(";")[1]
    assert ("% better" if mine < mean else "% worse") in line.split(";")[1]
    assert "worse: the baseline is exact" in line.split(";")[2]
    loo = evaluate(gmap)
    assert loo["fixed_shares_final_pose_error_deg_mean"] == pytest.approx(0.0, abs=1e-6)
    assert loo["examples"] == len(gmap) and loo["compared"] == len(gmap) * 4


# ------------------------------------------------------------------------------------------ torch trainers

def test_gaze_rnn_beats_repeating_the_previous_pose(datasets, tmp_path):
    """A small GRU trained closed loop for 3 epochs on CPU predicts the validation windows better than
    repeating the previous pose would, both run on their own outputs (the baseline's own output is the window's
    first pose, held); the baseline is recomputed here from the raw windows."""
    torch = pytest.importorskip("torch")
    from gazepipe.trainers.gaze_rnn import load_model

    ds = open_dataset(datasets / "gaze_rnn")
    opts = TrainOptions(epochs=3, hidden=48, seed=1, device="cpu", extra={"threads": 1})
    m = load_trainer("gaze_rnn").train(ds, tmp_path / "m", opts)
    v = m["validation"]
    w = ds.windows("val", normalise=False)
    x, y = w.x.astype(np.float64), w.y.astype(np.float64)
    my, sy = (np.array(ds.stats["overall"]["y"][k]) for k in ("mean", "std"))
    held = np.repeat(x[:, :1, 3:], x.shape[1], axis=1)
    baseline = np.mean(((held - y) / sy) ** 2)
    assert v["mse"]["baseline_closed_loop"] == pytest.approx(baseline, rel=1e-4)
    assert v["mse"]["closed_loop"] < 0.75 * baseline, v
    # the verdicts' degrees: the held baseline's angle errors recomputed with scipy's rotations
    n_seg = (y.shape[2] - 3) // 6

    def rotations(six):
        f, u = six[..., :3], six[..., 3:]
        f = f / np.linalg.norm(f, axis=-1, keepdims=True)
        u = u - np.sum(u * f, axis=-1, keepdims=True) * f
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        return Rotation.from_matrix(np.stack([np.cross(u, f), u, f], axis=-1).reshape(-1, 3, 3))

    held_r = rotations(held[..., :6 * n_seg].reshape(*held.shape[:2], n_seg, 6))
    true_r = rotations(y[..., :6 * n_seg].reshape(*y.shape[:2], n_seg, 6))
    seg_deg = np.rad2deg((held_r.inv() * true_r).magnitude()).reshape(*y.shape[:2], n_seg)
    eh, ey = held[..., -3:], y[..., -3:]
    eye_deg = np.rad2deg(np.arccos(np.clip(np.sum(eh * ey, -1) / np.linalg.norm(eh, axis=-1)
                                           / np.linalg.norm(ey, axis=-1), -1, 1)))
    assert v["baseline_closed_loop_deg_segments"] == pytest.approx(seg_deg.mean(), rel=1e-4)
    assert v["baseline_closed_loop_deg_eyes"] == pytest.approx(eye_deg.mean(), rel=1e-3)
    deg = np.concatenate([seg_deg, eye_deg[..., None]], axis=-1).mean()
    assert v["baseline_closed_loop_deg"] == pytest.approx(deg, rel=1e-4)
    # the verdict line says what the printed figures say
    better = v["closed_loop_deg"] < v["baseline_closed_loop_deg"]
    assert m["summary"][0].startswith("closed loop") and ("% better" if better else "% worse") in m["summary"][0]
    assert f"{v['closed_loop_deg']:.3g} vs {v['baseline_closed_loop_deg']:.3g}" in m["summary"][0]
    assert m["val_loss"][-1] == pytest.approx(v["mse"]["closed_loop"], rel=1e-5)   # the epoch's validation loss
    # the obvious call works: the saved module carries its statistics and runs on normalised windows
    model, meta = load_model(tmp_path / "m")
    assert meta["config"]["hidden"] == 48 and meta["config"]["closed_loop"] is True
    with torch.no_grad():
        pred = model(torch.from_numpy(ds.windows("val").x)).numpy()
    assert np.mean((pred - ds.windows("val").y) ** 2) == pytest.approx(v["mse"]["closed_loop"], rel=1e-5)
    assert v["windows"] == len(w) > 20


def test_gaze_rnn_lod_defaults_cli_and_determinism(datasets, tmp_path):
    """gaze_rnn on the LOD dataset takes Klein 7's defaults (96 units, λ 1e-4; lr 1e-3); same seed, same bytes."""
    pytest.importorskip("torch")
    import torch

    args = ["gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--epochs", "1", "--seed", "3",
            "--option", "max_windows=16", "--option", "threads=1"]
    r1 = run_train(*args, "--out", str(tmp_path / "a"))
    r2 = run_train(*args, "--out", str(tmp_path / "b"))
    assert r1.exit_code == 0 and r2.exit_code == 0, r1.output
    cfg = json.loads((tmp_path / "a" / "model.json").read_text())["config"]
    assert (cfg["hidden"], cfg["lr"], cfg["l2"], cfg["n_in"], cfg["n_out"]) == (96, 1e-3, 1e-4, 21, 18)
    state = torch.load(tmp_path / "a" / "gaze_rnn.pt", weights_only=True)
    assert tuple(state["cell.weight_hh"].shape) == (3 * 96, 96) and tuple(state["out.weight"].shape) == (18, 96)
    assert (tmp_path / "a" / "gaze_rnn.pt").read_bytes() == (tmp_path / "b" / "gaze_rnn.pt").read_bytes()
    assert (tmp_path / "a" / "model.json").read_text() == (tmp_path / "b" / "model.json").read_text()


def test_face_clean_untrained_reproduces_the_tracked_input(datasets):
    """Derivative parametrisation with the residual connection: before training, x̂[n+1] = x̂[n] + Δt·x_c[n]
    is exactly the next tracked value."""
    torch = pytest.importorskip("torch")
    from gazepipe.trainers.face_clean import _scales, build_model

    ds = open_dataset(datasets / "face_clean")
    w = ds.windows("val", normalise=False, columns=["tracked", "tracked_d1", "dt_s"])
    arr = [torch.from_numpy(w.stack(c)[:4].astype(np.float32)) for c in ("tracked", "tracked_d1", "dt_s")]
    model = build_model(52, 16, 0.3, _scales(ds)).eval()
    with torch.no_grad():
        x, _ = model(*arr)
    np.testing.assert_allclose(x.numpy()[:, :-1], w.stack("tracked")[:4, 1:], atol=2e-5)


def test_face_clean_beats_the_tracked_input(datasets, tmp_path):
    """A small cleaner trained for 3 epochs is closer to the clean track than the raw tracked input is, on the
    validation take's chunks (RMS error recomputed here for the tracked input)."""
    pytest.importorskip("torch")
    ds = open_dataset(datasets / "face_clean")
    opts = TrainOptions(epochs=3, hidden=48, lr=3e-3, seed=0, device="cpu", extra={"threads": 1, "batch": 16})
    m = load_trainer("face_clean").train(ds, tmp_path / "m", opts)
    v = m["validation"]
    assert "% better" in m["summary"][0] and "raw tracked signal" in m["summary"][0]
    w = ds.windows("val", normalise=False)
    rmse_tracked = float(np.sqrt(np.mean((w.x[:, 1:] - w.y[:, 1:]) ** 2)))
    assert v["tracked_rmse"] == pytest.approx(rmse_tracked, rel=1e-5)
    assert v["cleaned_rmse"] < 0.95 * rmse_tracked, v
    meta = json.loads((tmp_path / "m" / "model.json").read_text())
    assert meta["config"]["dropout"] == 0.3 and meta["config"]["window"] == 200 and meta["config"]["stride"] == 50


# ------------------------------------------------------------------------------------- on a pipeline run

@pytest.mark.slow
def test_trainers_on_the_sample_session_run(sample_run, tmp_path):
    """`gazepipe run` on sample_data/session01 (the shared run, exit 0), then every trainer through `gazepipe
    train` on what it wrote; the reader's runs agree with the builder's own segment counts in dataset.json."""
    out, root = sample_run, tmp_path
    for name in ("gaze_rnn", "gaze_rnn_lod"):
        ds = open_dataset(out / "datasets" / name)
        counts = ds.info["counts"]
        w = ds.windows(None, mirrored=False)
        assert w.runs == counts["segments"]
        assert w.runs - w.short_runs == counts["segments_with_a_window"]
    have_torch = True
    try:
        import torch  # noqa: F401
    except ImportError:
        have_torch = False
    jobs = [("gaze_map", "gaze_map", [])]
    if have_torch:
        small = ["--epochs", "1", "--hidden", "16", "--option", "threads=1", "--option", "max_windows=16"]
        jobs += [("gaze_rnn", "gaze_rnn", small), ("gaze_rnn", "gaze_rnn_lod", small),
                 ("face_clean", "face_clean", small)]
    for trainer, name, extra in jobs:
        model = root / "models" / name
        r = run_train(trainer, "--data", str(out / "datasets" / name), "--out", str(model), *extra)
        assert r.exit_code == 0, (name, r.output)
        meta = json.loads((model / "model.json").read_text())
        assert meta["trainer"] == trainer and meta["dataset"]["name"] == name
        assert (model / meta["weights"]).is_file()
