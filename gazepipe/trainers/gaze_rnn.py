"""The ``gaze_rnn`` trainer (Klein 6, 7): one GRU layer and a linear output, trained closed-loop.

Model: x(t) → GRU(hidden) → linear → y(t), in normalised units (the dataset's training mean and standard
deviation, kept in the saved model). x = the target direction at t, then the pose at t − 1 (y's layout: every
segment's 6-number rotation, then the eye direction); y = the pose at t. By default the network predicts the
change of pose (Klein 8.2's residual variant): y(t) = the pose part of x(t) + the network's output, whose layer
starts at zero, so the untrained model holds the previous pose and training learns the motion.

Training (Klein 6.2): windows of 120 frames, minibatches of 64, MSE plus λ·Σw² (L², weights only), Adam (β 0.9,
0.999) with the learning rate decayed to 0 along a cosine over the epochs and gradients clipped to norm 1.
Closed loop: inside a window the network's own previous output replaces the pose part of the next input (only
the window's first frame is taken whole from the data; the target direction always is), as it runs in a game.

Defaults by dataset: ``gaze_rnn`` 512 units, λ 8e-5; ``gaze_rnn_lod`` (Klein 7) 96 units, λ 1e-4; lr 1e-3, 50
epochs. Validation reports, on the validation windows, the model's MSE fed its own outputs (closed loop: Klein 8)
and fed the captured previous pose (one step), against the "repeat the previous pose" baseline run the same two
ways: closed loop (the window's first pose held) and one step (the captured previous pose). The validation loss
of every epoch is the closed-loop MSE.

Inference: :class:`GazeRNNPredictor` (``GazeRNNPredictor.load(model_dir).rollout(start_pose, target_dirs)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from gazepipe.errors import ConfigError
from gazepipe.trainers.base import (
    Option,
    TrainOptions,
    check_options,
    loop_options,
    options_table,
    read_model_json,
)
from gazepipe.trainers.loop import fit, fit_config, history_metrics, make_adam, validation_lines, verdict
from gazepipe.trainers.torch_utils import (
    DeviceArrays,
    deterministic,
    device_name,
    l2_penalty,
    load_state,
    pick_split,
    require_torch,
    resolve_device,
    save_trained,
    subsample,
)

WEIGHTS = "gaze_rnn.pt"
DEFAULTS: dict[str, dict[str, float]] = {
    "gaze_rnn": {"hidden": 512, "l2": 8e-5},
    "gaze_rnn_lod": {"hidden": 96, "l2": 1e-4},
}
TARGET_DIMS = 3
#: windows per forward pass when evaluating
EVAL_CHUNK = 1024
STATS = ("x_mean", "x_std", "y_mean", "y_std")


def build_model(n_in: int, n_out: int, hidden: int, residual: bool = True,
                stats: dict[str, np.ndarray] | None = None):
    """The network: ``cell`` (GRUCell n_in → hidden) and ``out`` (Linear hidden → n_out), with the training
    statistics ``stats`` (``x_mean``, ``x_std``, ``y_mean``, ``y_std``; default 0 and 1) as buffers.

    ``model(x)`` maps normalised inputs (B, T, n_in) to normalised outputs (B, T, n_out), closed loop."""
    torch = require_torch()
    nn: Any = torch.nn   # torch is optional and untyped here; its classes are subclassed below
    if n_in - TARGET_DIMS != n_out:
        raise ConfigError(None, f"x has {n_in} values and y {n_out}: x must be the 3-value target direction then "
                                "y's layout")
    buffers = stats or {"x_mean": np.zeros(n_in), "x_std": np.ones(n_in), "y_mean": np.zeros(n_out),
                        "y_std": np.ones(n_out)}

    class GazeRnn(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.cell = nn.GRUCell(n_in, hidden)
            self.out = nn.Linear(hidden, n_out)
            self.residual = residual
            if residual:
                nn.init.zeros_(self.out.weight)
                nn.init.zeros_(self.out.bias)
            for k in STATS:
                self.register_buffer(k, torch.as_tensor(np.asarray(buffers[k], np.float32)))

        def forward(self, x, closed: bool = True):
            """x (B, T, n_in) normalised → y (B, T, n_out) normalised. Closed loop: from the second frame on,
            the pose part of the input is the previous output (only x's target directions are read there);
            ``closed=False`` feeds x as it is (one step)."""
            a = self.y_std / self.x_std[TARGET_DIMS:]       # normalised y → normalised pose part of x
            b = (self.y_mean - self.x_mean[TARGET_DIMS:]) / self.x_std[TARGET_DIMS:]
            batch, t, _ = x.shape
            h = x.new_zeros(batch, self.cell.hidden_size)
            inp = x[:, 0]
            ys = []
            for i in range(t):
                h = self.cell(inp, h)
                y = self.out(h)
                if self.residual:
                    y = y + (inp[:, TARGET_DIMS:] - b) / a
                ys.append(y)
                if i + 1 < t:
                    pose = y * a + b if closed else x[:, i + 1, TARGET_DIMS:]
                    inp = torch.cat([x[:, i + 1, :TARGET_DIMS], pose], dim=1)
            return torch.stack(ys, dim=1)

    return GazeRnn()


def _stats(data) -> dict[str, np.ndarray]:
    mx, sx = data.mean_std("x")
    my, sy = data.mean_std("y")
    if len(mx) - TARGET_DIMS != len(my):
        raise ConfigError(data.path, f"x has {len(mx)} values and y {len(my)}: x must be the 3-value target "
                                     "direction then y's layout")
    return {"x_mean": mx, "x_std": sx, "y_mean": my, "y_std": sy}


def predict(model, x: np.ndarray, closed: bool = True, device: Any = None) -> np.ndarray:
    """The model's normalised outputs (n, T, n_out) for normalised windows ``x`` (n, T, n_in), run on
    ``device`` (default: the model's) :data:`EVAL_CHUNK` windows at a time."""
    torch = require_torch()
    device = device or next(model.parameters()).device
    model.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(x), EVAL_CHUNK):
            xb = torch.from_numpy(np.ascontiguousarray(x[i:i + EVAL_CHUNK], np.float32)).to(device)
            out.append(model(xb, closed=closed).cpu().numpy())
    n_out = int(model.out.out_features)
    return np.concatenate(out) if out else np.zeros((0, x.shape[1], n_out), np.float32)


class GazeRnnTrainer:
    """Klein's gaze RNN on a ``gaze_rnn`` or ``gaze_rnn_lod`` dataset (defaults follow the dataset)."""

    name = "gaze_rnn"
    dataset = ("gaze_rnn", "gaze_rnn_lod")
    schema_version = 1
    required_columns = ("x", "y")
    knobs = ("epochs", "hidden", "lr", "device", "patience")
    options = options_table(
        Option("l2", float, None, "L2 weight-decay coefficient", min=0,
               default_text="8e-5; 1e-4 for gaze_rnn_lod"),
        *loop_options("windows", "_dataset.json's, 120", "_dataset.json's"),
        Option("residual", bool, True, "predict the change of pose (Klein 8.2's residual variant)"),
    )

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        check_options(self, options)
        d = DEFAULTS[data.name]
        device = resolve_device(options.device)
        hidden = int(options.get("hidden", d["hidden"]))
        l2 = float(options.get("l2", d["l2"]))
        window, stride = options.get("window", None), options.get("stride", None)
        max_windows = options.get("max_windows", None)
        residual = bool(options.get("residual", True))
        rng = np.random.default_rng(options.seed)
        train_w = data.windows("train", window=window, stride=stride)
        if len(train_w) == 0:
            raise ConfigError(data.path, f"no training window of {train_w.window} frames (runs: {train_w.runs}, "
                                         f"shorter ones: {train_w.short_runs})")
        pick = subsample(len(train_w), None if max_windows is None else int(max_windows), rng)
        xs, ys = train_w.x[pick], train_w.y[pick]
        stride = int(stride or data.stride or train_w.window)
        split = pick_split(data)
        val_w = data.windows(split, window=train_w.window, stride=stride) if split else None
        val_x, val_y = (val_w.x, val_w.y) if val_w is not None else (np.zeros((0,)), np.zeros((0,)))
        fc = fit_config(options, validation=len(val_x) > 0, data_path=data.path)
        config = {"dataset": data.name, "n_in": int(xs.shape[2]), "n_out": int(ys.shape[2]), "hidden": hidden,
                  "lr": fc.lr, "l2": l2, "epochs": fc.epochs, "batch": fc.batch, "window": train_w.window,
                  "stride": stride, "seed": options.seed, "train_windows": int(len(pick)), "closed_loop": True,
                  "target_dims": TARGET_DIMS, "residual": residual, "schedule": fc.schedule, "clip": fc.clip,
                  "patience": fc.patience, "keep": fc.keep}
        with deterministic(options.seed, options.get("threads", None), device) as (torch, det):
            model = build_model(config["n_in"], config["n_out"], hidden, residual, _stats(data)).to(device)
            opt = make_adam(model, fc, device)
            train = DeviceArrays({"x": xs, "y": ys}, device)
            val = DeviceArrays({"x": val_x, "y": val_y}, device) if len(val_x) else None

            def loss_fn(b):
                mse = torch.mean((model(b["x"]) - b["y"]) ** 2)
                return mse + l2 * l2_penalty(model), mse

            def val_fn() -> float:
                assert val is not None   # fit calls val_fn only when there are validation rows
                total = 0.0
                for i in range(0, val.n, EVAL_CHUNK):
                    b = val.batch(np.arange(i, min(i + EVAL_CHUNK, val.n)))
                    total += float(torch.sum((model(b["x"]) - b["y"]) ** 2))
                return total / val_y.size

            hist = fit(model, opt, train, loss_fn, val_fn if val is not None else None, fc, rng, options.progress)
            metrics: dict[str, Any] = {"device": device_name(device), **history_metrics(hist),
                                       "train_windows": int(len(xs)), "dropped_rows": train_w.dropped_rows}
            metrics["validation"] = evaluate(model, data, split, train_w.window, stride) if split else None
            metrics["summary"] = summary(metrics["validation"]) + validation_lines(hist, fc)
        # what torch warned about is known on leaving the block
        save_trained(out_dir, self.name, config, model, metrics, data, WEIGHTS, det.nondeterministic)
        return metrics


def evaluate(model, data, split: str, window: int, stride: int) -> dict[str, Any]:
    """Errors on ``split``'s windows of the model and of the repeat-the-previous-pose baseline, each closed loop
    and one step (see the module notes).

    The figures the verdicts use are angles in degrees (``*_deg``): per frame, each segment's rotation error
    (the angle of the rotation between the predicted and the captured one, both made orthonormal from their 6
    numbers) and the eye direction's, averaged over the segments and the eyes, then over frames and windows;
    ``*_deg_segments`` and ``*_deg_eyes`` are the two parts. ``mse`` holds the training loss's figures (MSE,
    normalised and in the stored units), which weigh the numbers otherwise and may rank the model and a
    baseline differently; the verdicts do not use them.
    """
    w = data.windows(split, window=window, stride=stride)
    if len(w) == 0:
        return {"split": split, "windows": 0}
    st = _stats(data)
    mx, sx, my, sy = (st[k] for k in STATS)
    x, y = w.x, w.y
    closed = predict(model, x, closed=True)
    one = predict(model, x, closed=False)
    y_raw = y * sy + my
    pose_raw = x[:, :, TARGET_DIMS:] * sx[TARGET_DIMS:] + mx[TARGET_DIMS:]   # the previous pose, as captured
    held = np.repeat(pose_raw[:, :1], pose_raw.shape[1], axis=1)
    n_seg, has_eyes = len(my) // 6, len(my) % 6 == 3
    out: dict[str, Any] = {"split": split, "windows": len(w), "frames": int(y.shape[0] * y.shape[1]),
                           "mse": {}}
    for key, pred in (("closed_loop", closed * sy + my), ("one_step", one * sy + my),
                      ("baseline_closed_loop", held), ("baseline_one_step", pose_raw)):
        seg, eyes = angle_errors_deg(pred, y_raw, n_seg, has_eyes)
        both = np.concatenate([seg, eyes[..., None]], axis=-1) if eyes is not None else seg
        out[f"{key}_deg"] = float(np.mean(both))
        out[f"{key}_deg_segments"] = float(np.mean(seg))
        out[f"{key}_deg_eyes"] = None if eyes is None else float(np.mean(eyes))
        out["mse"][key] = float(np.mean(((pred - my) / sy - y) ** 2))
        out["mse"][f"{key}_raw"] = float(np.mean((pred - y_raw) ** 2))
    return out


def angle_errors_deg(pred: np.ndarray, truth: np.ndarray, n_seg: int,
                     has_eyes: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Angles in degrees between predicted and captured poses in y's layout (..., 6·S [+ 3]): each segment's
    rotation error (..., S) and the eye direction's (...) (``None`` without eyes).

    A segment's error is the angle of R_pred⁻¹ R_true, from the matrices' Frobenius distance
    (‖R₁ − R₂‖ = 2√2 sin(θ/2), exact to round-off at small angles, where arccos of the trace is not)."""
    shape = pred.shape[:-1]
    r_pred = six_to_matrix(pred[..., :6 * n_seg].reshape(*shape, n_seg, 6).astype(np.float64))
    r_true = six_to_matrix(truth[..., :6 * n_seg].reshape(*shape, n_seg, 6).astype(np.float64))
    dist = np.linalg.norm(r_pred - r_true, axis=(-2, -1))
    seg = np.rad2deg(2.0 * np.arcsin(np.clip(dist / (2.0 * np.sqrt(2.0)), 0.0, 1.0)))
    if not has_eyes:
        return seg, None
    a = pred[..., 6 * n_seg:].astype(np.float64)
    b = truth[..., 6 * n_seg:].astype(np.float64)
    eyes = np.rad2deg(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
    return seg, eyes


def summary(v: dict[str, Any] | None) -> list[str]:
    """The validation metrics in words: the model against each baseline, in degrees."""
    if not v or not v.get("windows"):
        return ["no validation windows: nothing to compare with a baseline"]
    n = f"{v['windows']} {v['split']} windows"
    parts = "the segments' rotations and the eye direction" if v.get("closed_loop_deg_eyes") is not None \
        else "the segments' rotations"
    return [verdict(f"closed loop (fed its own output, {n}): mean angle error over {parts}, degrees",
                    v["closed_loop_deg"], v["baseline_closed_loop_deg"], "holding each window's first pose"),
            verdict("one step (fed the captured previous pose): mean angle error, degrees", v["one_step_deg"],
                    v["baseline_one_step_deg"], "repeating the previous pose")]


# ------------------------------------------------------------------------------------------------ inference

def six_to_matrix(six: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from 6-number rotations (..., 6) = forward R·z then up R·y: Gram-Schmidt
    (forward normalised, up made orthogonal to it), x = up × forward."""
    f = six[..., :3] / np.linalg.norm(six[..., :3], axis=-1, keepdims=True)
    u = six[..., 3:] - np.sum(six[..., 3:] * f, axis=-1, keepdims=True) * f
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    return np.stack([np.cross(u, f), u, f], axis=-1)


@dataclass
class Rollout:
    """A closed-loop rollout, every array with the leading shape of the request (B, T) or (T,).

    Attributes
    ----------
    y : (..., n_out) the network's outputs in the dataset's ``y`` layout and units (what validation scores).
    rot6d : (..., S, 6) each segment's rotation as forward R·z then up R·y, made orthonormal; character frame
        (+X left, +Y up, +Z forward).
    quat : (..., S, 4) the same rotations as unit quaternions w, x, y, z.
    eye_dir : (..., 3) unit eye direction, character frame; ``None`` for a model without eyes (LOD).
    segments : the S segment names.
    """

    y: np.ndarray
    rot6d: np.ndarray
    quat: np.ndarray
    eye_dir: np.ndarray | None
    segments: list[str]


class GazeRNNPredictor:
    """A trained ``gaze_rnn`` model (or its LOD variant) for closed-loop inference in the dataset's units.

    ``GazeRNNPredictor.load("models/gaze_rnn").rollout(start_pose, target_dirs)``; the normalisation with the
    training statistics happens inside.

    Attributes
    ----------
    model : the torch module (eval mode); ``meta`` : model.json; ``segments`` : segment names, in y's order;
    has_eyes : whether y ends with the eye direction; ``y_std`` : (n_out,) the training standard deviation of y
    (the unit of the normalised validation MSE).
    """

    def __init__(self, model, meta: dict[str, Any], device: Any = "cpu") -> None:
        self.model, self.meta, self.device = model, meta, device
        names = list((meta.get("dataset") or {}).get("features", {}).get("y") or [])
        n_out = int(meta["config"]["n_out"])
        self.has_eyes = n_out % 6 == 3
        seg = [n.split(".")[0] for n in names if ".fwd." in n][::3]
        self.segments = seg if len(seg) == n_out // 6 else [f"segment{i}" for i in range(n_out // 6)]
        self.x_mean, self.x_std, self.y_mean, self.y_std = (getattr(model, k).cpu().numpy() for k in STATS)

    @classmethod
    def load(cls, model_dir: str | Path, device: str = "cpu") -> GazeRNNPredictor:
        """The model saved in ``model_dir`` by ``gazepipe train gaze_rnn``, on ``device`` (``cpu``, ``cuda``,
        ``cuda:N`` or ``auto``)."""
        dev = resolve_device(device)
        model, meta = load_model(model_dir)
        return cls(model.to(dev), meta, dev)

    def rollout(self, start_pose: np.ndarray, target_dirs: np.ndarray) -> Rollout:
        """Run the model closed loop from ``start_pose`` for a sequence of target directions.

        Parameters
        ----------
        start_pose : (n_out,) or (B, n_out): the pose just before the first frame, in y's layout (each segment's
            forward and up unit vectors, then the eye direction), character frame.
        target_dirs : (T, 3) or (B, T, 3): unit direction to the gaze target at each frame, character frame.

        Returns
        -------
        :class:`Rollout` of T frames (frame t answers target_dirs[t]).
        """
        start = np.asarray(start_pose, np.float32)
        targets = np.asarray(target_dirs, np.float32)
        single = targets.ndim == 2
        start, targets = np.atleast_2d(start), targets[None] if single else targets
        if start.shape[-1] != len(self.y_mean) or targets.shape[-1] != TARGET_DIMS or len(start) != len(targets):
            raise ValueError(f"start_pose (B, {len(self.y_mean)}) and target_dirs (B, T, 3) expected, got "
                             f"{start.shape} and {targets.shape}")
        x = np.zeros((*targets.shape[:2], len(self.x_mean)), np.float32)
        x[:, :, :TARGET_DIMS] = (targets - self.x_mean[:TARGET_DIMS]) / self.x_std[:TARGET_DIMS]
        x[:, 0, TARGET_DIMS:] = (start - self.x_mean[TARGET_DIMS:]) / self.x_std[TARGET_DIMS:]
        y = predict(self.model, x, closed=True, device=self.device) * self.y_std + self.y_mean
        if single:
            y = y[0]
        s = len(self.segments)
        rot = six_to_matrix(y[..., :6 * s].reshape(*y.shape[:-1], s, 6).astype(np.float64))
        quat = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]].reshape(*rot.shape[:-2], 4)
        rot6d = np.concatenate([rot[..., :, 2], rot[..., :, 1]], axis=-1)
        eye = None
        if self.has_eyes:
            e = y[..., 6 * s:].astype(np.float64)
            eye = e / np.linalg.norm(e, axis=-1, keepdims=True)
        return Rollout(y=y, rot6d=rot6d, quat=quat, eye_dir=eye, segments=list(self.segments))


def load_model(model_dir: str | Path):
    """(module in eval mode on the CPU, model.json) of a saved gaze_rnn model. The module carries the training
    statistics: ``module(x)`` maps normalised windows (B, T, n_in) to normalised outputs, closed loop; see
    :class:`GazeRNNPredictor` for inference in the dataset's units."""
    meta = read_model_json(model_dir)
    c = meta["config"]
    model = build_model(int(c["n_in"]), int(c["n_out"]), int(c["hidden"]), bool(c.get("residual", False)))
    load_state(model, Path(model_dir) / meta.get("weights", WEIGHTS))
    model.eval()
    return model, meta
