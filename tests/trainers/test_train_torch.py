"""The torch trainers at work: devices, determinism, progress, early stopping, saved files, the inference API
and the README's inference examples, on datasets built from generated sessions
(tests/helpers/datasets.py). Tiny models and few epochs: the learning itself is measured by
bench/bench_train.py."""

from __future__ import annotations

import json
import math
import os
import runpy
import stat
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from gazepipe.cli.train import train as train_cmd
from gazepipe.errors import ConfigError
from tests.helpers import TESTS

torch = pytest.importorskip("torch")

EXAMPLES = TESTS / "readme_examples"
SMALL = ["--epochs", "2", "--hidden", "16", "--option", "threads=1", "--option", "max_windows=16"]
CUDA = torch.cuda.is_available()


@pytest.fixture(scope="module")
def datasets(generated_datasets) -> Path:
    return generated_datasets


def run_train(*args: str):
    return CliRunner().invoke(train_cmd, list(args))


@pytest.fixture
def no_gpu(monkeypatch):
    """A machine where torch sees no GPU."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


# ------------------------------------------------------------------------------------------------- devices

def test_cuda_without_a_gpu_is_one_line_exit_2(datasets, tmp_path, no_gpu):
    for spec in ("cuda", "cuda:1"):
        res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"),
                        "--device", spec, *SMALL)
        assert res.exit_code == 2, res.output
        assert res.output.count("\n") == 1 and f"--device {spec}:" in res.output and "GPU" in res.output
        assert not (tmp_path / "m" / "model.json").exists()
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"),
                    "--device", "gpu", *SMALL)
    assert res.exit_code == 2 and "expected auto, cpu, cuda or cuda:N" in res.output
    res = run_train("gaze_map", "--data", str(datasets / "gaze_map"), "--out", str(tmp_path / "m"),
                    "--device", "cpu")
    assert res.exit_code == 2 and "trainer 'gaze_map' does not use --device" in res.output


def test_auto_without_a_gpu_trains_on_the_cpu(datasets, tmp_path, no_gpu):
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"), *SMALL)
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "m" / "model.json").read_text())
    assert meta["metrics"]["device"] == "cpu (1 thread)"


def test_same_seed_same_bytes_on_the_cpu(datasets, tmp_path):
    """face_clean (dropout draws random numbers) and gaze_rnn, each trained twice: the same weights and
    model.json byte for byte; another seed gives other weights."""
    for name, data in (("face_clean", "face_clean"), ("gaze_rnn", "gaze_rnn")):
        outs = []
        for k, seed in enumerate(("5", "5", "6")):
            out = tmp_path / f"{name}{k}"
            res = run_train(name, "--data", str(datasets / data), "--out", str(out), "--seed", seed,
                            "--device", "cpu", *SMALL)
            assert res.exit_code == 0, res.output
            outs.append(out)
        weights = f"{name}.pt"
        assert (outs[0] / weights).read_bytes() == (outs[1] / weights).read_bytes(), name
        assert (outs[0] / weights).read_bytes() != (outs[2] / weights).read_bytes(), name
        assert (outs[0] / "model.json").read_bytes() == (outs[1] / "model.json").read_bytes(), name


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU (torch.cuda.is_available() is False here)")
def test_cuda_training_loads_on_the_cpu(datasets, tmp_path):
    """Both torch trainers on the GPU: finite losses and metrics, the same bytes for the same seed (deterministic
    algorithms), and the saved model loads and runs on the CPU."""
    from gazepipe.trainers.face_clean import FaceCleaner
    from gazepipe.trainers.gaze_rnn import GazeRNNPredictor

    for name, data in (("gaze_rnn", "gaze_rnn"), ("face_clean", "face_clean")):
        for out in ("a", "b"):
            res = run_train(name, "--data", str(datasets / data), "--out", str(tmp_path / name / out),
                            "--device", "cuda", *SMALL)
            assert res.exit_code == 0, res.output
        m = json.loads((tmp_path / name / "a" / "model.json").read_text())["metrics"]
        assert m["device"].startswith("cuda:0") and m["epochs_run"] == 2, m
        assert all(math.isfinite(v) for v in m["train_loss"] + m["val_loss"])
        assert all(math.isfinite(v) for v in m["validation"].values() if isinstance(v, float))
        same = (tmp_path / name / "a" / f"{name}.pt").read_bytes() == (tmp_path / name / "b" / f"{name}.pt").read_bytes()
        assert same or m["nondeterministic"], "GPU runs differ though no operation was reported nondeterministic"
    rnn = GazeRNNPredictor.load(tmp_path / "gaze_rnn" / "a", device="cpu")
    x = open_windows(datasets / "gaze_rnn")
    out = rnn.rollout(x[:2, 0, 3:], x[:2, :, :3])
    assert np.isfinite(out.y).all() and out.quat.shape == (2, 120, 10, 4)
    face = FaceCleaner.load(tmp_path / "face_clean" / "a", device="cpu")
    cleaned = face.clean(np.full((30, 52), 0.2, np.float32), np.arange(30) / 60.0)
    assert np.isfinite(cleaned).all()


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU (torch.cuda.is_available() is False here)")
def test_cuda_graph_steps_train_as_eager_steps_do(datasets, tmp_path):
    """On the GPU the training step is captured as a CUDA graph by default; the same seed with
    ``cuda_graph=false`` (eager steps) gives the same losses and validation figures, to float round-off."""
    ms = {}
    for graph in ("true", "false"):
        res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn"), "--out", str(tmp_path / graph),
                        "--device", "cuda", "--epochs", "3", "--hidden", "32", "--option", "max_windows=40",
                        "--option", "batch=8", "--option", f"cuda_graph={graph}")
        assert res.exit_code == 0, res.output
        ms[graph] = json.loads((tmp_path / graph / "model.json").read_text())["metrics"]
    assert ms["true"]["execution"]["training_step"] == "cuda_graph", ms["true"]["execution"]
    assert ms["false"]["execution"]["training_step"] == "eager"
    np.testing.assert_allclose(ms["true"]["train_loss"], ms["false"]["train_loss"], rtol=1e-4)
    np.testing.assert_allclose(ms["true"]["val_loss"], ms["false"]["val_loss"], rtol=1e-4)
    for key in ("closed_loop_deg", "one_step_deg"):
        assert ms["true"]["validation"][key] == pytest.approx(ms["false"]["validation"][key], rel=1e-3)


def test_graph_step_plumbing_trains_as_eager_steps_do(monkeypatch):
    """The captured step's plumbing, checked on the CPU with a stand-in for the capture that runs the captured
    body on every replay (as a graph replays its kernels, gradients written afresh): the warm-up steps are
    undone, minibatch indices reach the fixed index tensor, short minibatches run eagerly, and the weights
    after training are the eager loop's, bit for bit."""
    from gazepipe.trainers import loop
    from gazepipe.trainers.gaze_rnn import build_model
    from gazepipe.trainers.torch_utils import DeviceArrays

    rng = np.random.default_rng(3)
    x = rng.normal(size=(10, 12, 9)).astype(np.float32)
    y = rng.normal(size=(10, 12, 6)).astype(np.float32)
    cfg = loop.FitConfig(epochs=3, batch=4, lr=1e-2, clip=1.0, keep="last")
    results = []
    for graphed in (False, True):
        torch.manual_seed(0)
        model = build_model(9, 6, 8, residual=False)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        data = DeviceArrays({"x": x, "y": y}, torch.device("cpu"))

        def loss_fn(b, model=model):
            mse = torch.mean((model(b["x"]) - b["y"]) ** 2)
            return mse, mse

        if graphed:
            def runner(model_, optimizer, data_, loss_fn_, cfg_):
                def capture(body):
                    def replay():
                        optimizer.zero_grad(set_to_none=True)
                        body()
                    return replay
                return loop.GraphStep(model_, optimizer, data_, loss_fn_, cfg_.clip, cfg_.batch, capture=capture)
            monkeypatch.setattr(loop, "step_runner", runner)
        hist = loop.fit(model, opt, data, loss_fn, None, cfg, np.random.default_rng(0))
        results.append((hist, torch.cat([p.detach().flatten() for p in model.parameters()]).numpy()))
    (eager, w_eager), (graph, w_graph) = results
    assert eager["execution"]["training_step"] == "eager" and graph["execution"]["training_step"] == "cuda_graph"
    assert eager["train_loss"] == graph["train_loss"]
    assert w_eager.tobytes() == w_graph.tobytes()


def test_loop_defaults_keep_the_best_epoch_with_patience_unless_there_is_no_validation(tmp_path):
    """By default the best validation epoch is kept, with patience; ``--patience 0`` runs every epoch; without
    validation items the last epoch is kept, and asking for patience is a usage error naming the dataset."""
    from gazepipe.trainers.base import TrainOptions
    from gazepipe.trainers.loop import DEFAULT_PATIENCE, fit_config

    fc = fit_config(TrainOptions(), validation=True)
    assert fc.patience == DEFAULT_PATIENCE and fc.keep == "best"
    assert fit_config(TrainOptions(patience=0), validation=True).patience is None
    fc = fit_config(TrainOptions(), validation=False)
    assert fc.patience is None and fc.keep == "last"
    with pytest.raises(ConfigError, match="--patience needs validation items"):
        fit_config(TrainOptions(patience=3), validation=False, data_path=tmp_path)


def open_windows(path: Path) -> np.ndarray:
    from gazepipe.datasets import open_dataset

    return open_dataset(path).windows("val", normalise=False).x


# ------------------------------------------------------------------------------- progress, summary, patience

def test_progress_is_json_lines_off_a_terminal(datasets, tmp_path):
    res = run_train("face_clean", "--data", str(datasets / "face_clean"), "--out", str(tmp_path / "m"),
                    "--device", "cpu", *SMALL, "--log-format", "json")
    assert res.exit_code == 0, res.output
    events = [json.loads(line) for line in res.stderr.splitlines()]
    epochs = [e for e in events if e["event"] == "epoch"]
    assert [e["epoch"] for e in epochs] == [1, 2] and all(e["epochs"] == 2 for e in epochs)
    for e in epochs:
        assert e["train_loss"] > 0 and e["val_loss"] > 0 and e["seconds"] > 0 and "time" in e
    end = events[-1]
    assert end["event"] == "train_end" and end["epochs_run"] == 2 and "raw tracked signal" in end["summary"][0]
    assert "vs" in res.stdout and ("% better" in res.stdout or "% worse" in res.stdout or "the same" in res.stdout)


def test_progress_is_readable_lines_as_text(datasets, tmp_path):
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"),
                    "--device", "cpu", *SMALL, "--log-format", "text")
    assert res.exit_code == 0, res.output
    lines = res.stderr.splitlines()
    assert lines[0].startswith("epoch 1/2  train ") and " val " in lines[0] and lines[0].endswith("validation)")
    assert lines[-1].startswith("trained 2 epoch(s) in ") and "on cpu" in lines[-1]
    out = res.stdout.splitlines()
    assert out[1].strip().startswith("closed loop (fed its own output") and "holding each window's first pose" in out[1]
    assert out[2].strip().startswith("one step") and "repeating the previous pose" in out[2]


def test_verdict_says_better_or_worse():
    from gazepipe.trainers.loop import verdict

    assert verdict("MSE", 0.41, 0.94, "holding") == "MSE: 0.41 vs 0.94 holding: 56 % better"
    assert verdict("MSE", 1.13, 0.942, "holding") == "MSE: 1.13 vs 0.942 holding: 20 % worse"
    assert verdict("MSE", 0.5, 0.501, "x").endswith("the same (within 0.5 %)")


class _Scalar(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(()))


def test_patience_stops_and_keeps_the_best_weights():
    """The validation losses 3, 2, 2.5, 2.6, 1: with patience 2 training stops after epoch 4 and the weights
    are those after epoch 2 (the parameter counts the minibatches: 2 per epoch)."""
    from gazepipe.trainers.loop import FitConfig, fit, validation_lines
    from gazepipe.trainers.torch_utils import DeviceArrays

    model = _Scalar()
    opt = torch.optim.SGD(model.parameters(), lr=1.0)
    data = DeviceArrays({"x": np.zeros((4, 1), np.float32)}, torch.device("cpu"))
    vals = iter([3.0, 2.0, 2.5, 2.6, 1.0])
    seen = []

    def loss_fn(b):
        loss = -model.w       # SGD with lr 1 adds 1 to w per step
        return loss, loss

    cfg = FitConfig(epochs=5, batch=2, lr=1.0, schedule="constant", clip=None, patience=2)
    hist = fit(model, opt, data, loss_fn, lambda: next(vals), cfg, np.random.default_rng(0), seen.append)
    assert hist["epochs_run"] == 4 and hist["stopped"] == "patience" and hist["best_epoch"] == 2
    assert hist["kept"] == "best" and float(model.w) == 4.0
    epochs = [e for e in seen if e["event"] == "epoch"]
    assert [e["best"] for e in epochs] == [True, True, False, False]
    assert [e["batch"] for e in seen if e["event"] == "batch"] == [1, 2] * 4
    model2 = _Scalar()
    cfg2 = FitConfig(epochs=5, batch=2, lr=1.0, schedule="constant", clip=None, keep="last")
    vals = iter([3.0, 2.0, 2.5, 2.6, 1.0])
    hist = fit(model2, torch.optim.SGD(model2.parameters(), lr=1.0), data, lambda b: (-model2.w, -model2.w),
               lambda: next(vals), cfg2, np.random.default_rng(0))
    assert hist["epochs_run"] == 5 and hist["kept"] == "last" and float(model2.w) == 10.0
    # without patience every epoch runs, and by default the best one is kept: the losses 3, 2, 2.5, 1.5, 1.8
    model3 = _Scalar()
    vals = iter([3.0, 2.0, 2.5, 1.5, 1.8])
    hist = fit(model3, torch.optim.SGD(model3.parameters(), lr=1.0), data, lambda b: (-model3.w, -model3.w),
               lambda: next(vals), FitConfig(epochs=5, batch=2, lr=1.0, schedule="constant", clip=None),
               np.random.default_rng(0))
    assert hist["epochs_run"] == 5 and hist["kept"] == "best" and hist["best_epoch"] == 4 and float(model3.w) == 8.0
    line = validation_lines(hist, FitConfig(epochs=5, batch=2, lr=1.0))[0]
    assert line == "validation loss: best 1.5 at epoch 4 of 5, rose 20 % to 1.8 by epoch 5; kept epoch 4"


def test_patience_on_the_cli_keeps_the_best_epoch(datasets, tmp_path):
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"),
                    "--device", "cpu", "--patience", "2", *SMALL[2:], "--epochs", "4", "--lr", "0.05")
    assert res.exit_code == 0, res.output
    meta = json.loads((tmp_path / "m" / "model.json").read_text())
    m = meta["metrics"]
    assert meta["config"]["patience"] == 2 and m["kept"] == "best"
    assert m["val_loss"][m["best_epoch"] - 1] == min(m["val_loss"])
    # the saved model is the best epoch's: its closed-loop validation MSE is that epoch's validation loss
    assert m["validation"]["mse"]["closed_loop"] == pytest.approx(min(m["val_loss"]), rel=1e-5)


def test_time_budget_cuts_the_epochs(datasets, tmp_path):
    res = run_train("gaze_rnn", "--data", str(datasets / "gaze_rnn_lod"), "--out", str(tmp_path / "m"),
                    "--device", "cpu", *SMALL[2:], "--epochs", "500", "--option", "max_seconds=0.001")
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "m" / "model.json").read_text())["metrics"]
    assert m["epochs_run"] == 1 and m["stopped"] == "time"


# ------------------------------------------------------------------------------------------- saved files

def test_models_are_written_0644_atomically(datasets, tmp_path):
    old = os.umask(0o022)
    try:
        for name, data in (("gaze_rnn", "gaze_rnn_lod"), ("face_clean", "face_clean"), ("gaze_map", "gaze_map")):
            extra = [] if name == "gaze_map" else SMALL
            out = tmp_path / name
            res = run_train(name, "--data", str(datasets / data), "--out", str(out), *extra)
            assert res.exit_code == 0, res.output
            files = sorted(p.name for p in out.iterdir())
            assert files == sorted(["model.json", f"{name}.{'npz' if name == 'gaze_map' else 'pt'}"]), files
            for f in out.iterdir():
                assert stat.S_IMODE(f.stat().st_mode) == 0o644, (f, oct(f.stat().st_mode))
    finally:
        os.umask(old)


# ------------------------------------------------------------------------------------------- inference API

def test_rollout_shapes_units_and_batching(datasets, tmp_path):
    from gazepipe.trainers.gaze_rnn import GazeRNNPredictor

    for data, segs, eyes in (("gaze_rnn", 10, True), ("gaze_rnn_lod", 3, False)):
        res = run_train("gaze_rnn", "--data", str(datasets / data), "--out", str(tmp_path / data), *SMALL)
        assert res.exit_code == 0, res.output
        rnn = GazeRNNPredictor.load(tmp_path / data)
        x = open_windows(datasets / data)[:3]
        many = rnn.rollout(x[:, 0, 3:], x[:, :, :3])
        one = rnn.rollout(x[1, 0, 3:], x[1, :, :3])
        np.testing.assert_allclose(one.y, many.y[1], atol=1e-6)
        assert many.rot6d.shape == (3, 120, segs, 6) and len(many.segments) == segs
        assert many.segments[0] == "pelvis" and (many.eye_dir is not None) == eyes
        np.testing.assert_allclose(np.linalg.norm(many.quat, axis=-1), 1, atol=1e-9)
        f, u = many.rot6d[..., :3], many.rot6d[..., 3:]
        np.testing.assert_allclose(np.sum(f * u, axis=-1), 0, atol=1e-9)
        # the quaternion turns z into the forward vector: q z q* = f
        from scipy.spatial.transform import Rotation
        r = Rotation.from_quat(many.quat.reshape(-1, 4)[:, [1, 2, 3, 0]])
        np.testing.assert_allclose(r.apply([0, 0, 1]), f.reshape(-1, 3), atol=1e-9)
        if eyes:
            np.testing.assert_allclose(np.linalg.norm(many.eye_dir, axis=-1), 1, atol=1e-9)
        with pytest.raises(ValueError, match="start_pose"):
            rnn.rollout(x[:, 0, 4:], x[:, :, :3])


def test_face_cleaner_single_and_batched(datasets, tmp_path):
    from gazepipe.datasets import open_dataset
    from gazepipe.trainers.face_clean import FaceCleaner

    res = run_train("face_clean", "--data", str(datasets / "face_clean"), "--out", str(tmp_path / "m"), *SMALL)
    assert res.exit_code == 0, res.output
    cleaner = FaceCleaner.load(tmp_path / "m")
    w = open_dataset(datasets / "face_clean").windows("val", normalise=False, columns=["tracked", "time_s"])
    tr, t = w.stack("tracked")[:2], w.stack("time_s")[:2, :, 0]
    both = cleaner.clean(tr, t)
    np.testing.assert_allclose(cleaner.clean(tr[1], t[1]), both[1], atol=1e-6)
    np.testing.assert_array_equal(both[:, 0], tr[:, 0])
    assert len(cleaner.channels) == 52 and not np.allclose(both[:, 1:], tr[:, 1:], atol=1e-4)
    with pytest.raises(ValueError, match="increasing"):
        cleaner.clean(tr[0], t[0][::-1])


def test_readme_gaze_rnn_inference_reproduces_the_validation_metric(workdir):
    res = run_train("gaze_rnn", "--data", "out/datasets/gaze_rnn", "--out", "models/gaze_rnn", *SMALL)
    assert res.exit_code == 0, res.output
    g = runpy.run_path(str(EXAMPLES / "gaze_rnn_example.py"), run_name="__main__")
    v = json.loads(Path("models/gaze_rnn/model.json").read_text())["metrics"]["validation"]
    assert g["out"].quat.shape == (v["windows"], 120, 10, 4) and g["out"].segments[-1] == "head"
    assert g["mse"] == pytest.approx(v["mse"]["closed_loop"], rel=1e-5)
    assert g["degrees"] == pytest.approx(v["closed_loop_deg"], rel=1e-4)
    assert abs(v["closed_loop_deg"] - v["baseline_closed_loop_deg"]) > 1e-3   # not the untrained model's score


def test_readme_face_clean_inference_reproduces_the_validation_metric(workdir):
    res = run_train("face_clean", "--data", "out/datasets/face_clean", "--out", "models/face", *SMALL)
    assert res.exit_code == 0, res.output
    g = runpy.run_path(str(EXAMPLES / "face_clean_example.py"), run_name="__main__")
    v = json.loads(Path("models/face/model.json").read_text())["metrics"]["validation"]
    assert g["cleaned"].shape == (v["chunks"], 200, 52)
    assert g["rmse"] == pytest.approx(v["cleaned_rmse"], rel=1e-5)
    assert abs(v["cleaned_rmse"] - v["tracked_rmse"]) > 1e-6
