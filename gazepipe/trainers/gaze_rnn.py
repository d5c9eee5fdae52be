"""The ``gaze_rnn`` trainer (Klein 6, 7): one GRU layer and a linear output, trained closed-loop.

Model: x(t) → GRU(hidden) → linear → y(t), in normalised units (the dataset's training mean and standard
deviation). Training (Klein 6.2): windows of 120 frames, minibatches of 64, MSE plus λ·Σw² (L², weights only),
Adam (β 0.9, 0.999). Closed loop: inside a window the network's own previous output replaces the pose part of
the next input (x = target direction, then the previous pose, which has y's layout); only the window's first
frame is taken whole from the data, and the target direction always is.

Defaults by dataset: ``gaze_rnn`` 512 units, lr 1e-4, λ 8e-5; ``gaze_rnn_lod`` (Klein 7) 96 units, lr 1e-3,
λ 1e-4; 50 epochs. Validation reports, on the validation windows, the model's MSE fed its own outputs
(closed loop, as it runs in a game: Klein 8) and fed the captured previous pose (one step), against the
"repeat the previous pose" baseline y(t) = the pose part of x(t) run the same two ways: closed loop (its own
previous output, i.e. the window's first pose held) and one step (the captured previous pose).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import ConfigError
from gazepipe.trainers.base import TrainOptions, read_model_json, save_model_json, write_atomic
from gazepipe.trainers.torch_utils import (
    batches,
    deterministic,
    l2_penalty,
    load_state,
    pick_split,
    require_torch,
    state_bytes,
    subsample,
)

WEIGHTS = "gaze_rnn.pt"
DEFAULTS: dict[str, dict[str, float]] = {
    "gaze_rnn": {"hidden": 512, "lr": 1e-4, "l2": 8e-5},
    "gaze_rnn_lod": {"hidden": 96, "lr": 1e-3, "l2": 1e-4},
}
TARGET_DIMS = 3


def build_model(n_in: int, n_out: int, hidden: int, residual: bool = False):
    """The network: ``cell`` (GRUCell n_in → hidden) and ``out`` (Linear hidden → n_out). With ``residual``
    (Klein 8.2's residual variant) the output is the input's previous pose plus ``out``, which starts at zero."""
    torch = require_torch()
    nn = torch.nn

    class GazeRnn(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.cell = nn.GRUCell(n_in, hidden)
            self.out = nn.Linear(hidden, n_out)
            self.residual = residual
            if residual:
                nn.init.zeros_(self.out.weight)
                nn.init.zeros_(self.out.bias)

        def forward(self, x, pose_map: tuple[Any, Any] | None = None, closed: bool = True):
            """x (B, T, n_in) normalised → y (B, T, n_out) normalised. ``pose_map`` (a, b) turns a normalised
            output into the normalised pose part of the next input (y·a + b); closed=False feeds x as is."""
            b, t, _ = x.shape
            h = x.new_zeros(b, self.cell.hidden_size)
            inp = x[:, 0]
            ys = []
            for i in range(t):
                h = self.cell(inp, h)
                y = self.out(h)
                if self.residual:
                    y = y + (inp[:, TARGET_DIMS:] - pose_map[1]) / pose_map[0]
                ys.append(y)
                if i + 1 < t:
                    pose = y * pose_map[0] + pose_map[1] if closed else x[:, i + 1, TARGET_DIMS:]
                    inp = torch.cat([x[:, i + 1, :TARGET_DIMS], pose], dim=1)
            return torch.stack(ys, dim=1)

    return GazeRnn()


def _pose_map(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    mx, sx = data.mean_std("x")
    my, sy = data.mean_std("y")
    if len(mx) - TARGET_DIMS != len(my):
        raise ConfigError(data.path, f"x has {len(mx)} values and y {len(my)}: x must be the 3-value target "
                                     "direction then y's layout")
    a = sy / sx[TARGET_DIMS:]
    b = (my - mx[TARGET_DIMS:]) / sx[TARGET_DIMS:]
    return a, b, mx, sx, my, sy


class GazeRnnTrainer:
    """Klein's gaze RNN on a ``gaze_rnn`` or ``gaze_rnn_lod`` dataset (defaults follow the dataset)."""

    name = "gaze_rnn"
    dataset = ("gaze_rnn", "gaze_rnn_lod")
    schema_version = 1
    required_columns = ("x", "y")
    options = {
        "l2": "L2 weight-decay coefficient (default 8e-5; 1e-4 for gaze_rnn_lod)",
        "batch": "windows per minibatch (default 64)",
        "window": "frames per window (default _dataset.json's, 120)",
        "stride": "step between windows (default _dataset.json's)",
        "max_windows": "use at most this many training windows (seeded subset; default all)",
        "threads": "torch CPU threads (default torch's)",
        "residual": "output = previous pose + network output (Klein 8.2's residual variant; default false)",
    }

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        d = DEFAULTS[data.name]
        hidden = int(options.get("hidden", d["hidden"]))
        lr = float(options.get("lr", d["lr"]))
        l2 = float(options.get("l2", d["l2"]))
        epochs = int(options.get("epochs", 50))
        batch = int(options.get("batch", 64))
        window = options.get("window", None)
        stride = options.get("stride", None)
        max_windows = options.get("max_windows", None)
        residual = bool(options.get("residual", False))
        rng = np.random.default_rng(options.seed)
        train_w = data.windows("train", window=window, stride=stride)
        if len(train_w) == 0:
            raise ConfigError(data.path, f"no training window of {train_w.window} frames (runs: {train_w.runs}, "
                                         f"shorter ones: {train_w.short_runs})")
        pick = subsample(len(train_w), None if max_windows is None else int(max_windows), rng)
        xs, ys = train_w.x[pick], train_w.y[pick]
        a, b, mx, sx, my, sy = _pose_map(data)
        config = {"dataset": data.name, "n_in": int(xs.shape[2]), "n_out": int(ys.shape[2]), "hidden": hidden,
                  "lr": lr, "l2": l2, "epochs": epochs, "batch": batch, "window": train_w.window,
                  "stride": int(stride or data.stride or train_w.window), "seed": options.seed,
                  "train_windows": int(len(pick)), "closed_loop": True, "target_dims": TARGET_DIMS,
                  "residual": residual}
        with deterministic(options.seed, options.get("threads", None)) as torch:
            model = build_model(config["n_in"], config["n_out"], hidden, residual)
            pm = (torch.from_numpy(a), torch.from_numpy(b))
            opt = torch.optim.Adam(model.parameters(), lr=lr, betas=(0.9, 0.999))
            tx, ty = torch.from_numpy(xs), torch.from_numpy(ys)
            losses = []
            for _ in range(epochs):
                model.train()
                total, count = 0.0, 0
                for idx in batches(len(xs), batch, rng):
                    opt.zero_grad()
                    pred = model(tx[idx], pm)
                    mse = torch.mean((pred - ty[idx]) ** 2)
                    loss = mse + l2 * l2_penalty(model)
                    loss.backward()
                    opt.step()
                    total += float(mse.detach()) * len(idx)
                    count += len(idx)
                losses.append(total / max(count, 1))
            metrics: dict[str, Any] = {"train_mse": losses, "train_windows": int(len(xs)),
                                       "dropped_rows": train_w.dropped_rows}
            split = pick_split(data)
            if split is not None:
                metrics["validation"] = evaluate(model, data, split, train_w.window, config["stride"])
            else:
                metrics["validation"] = None
            out = Path(out_dir)
            write_atomic(out / WEIGHTS, state_bytes(model))
        save_model_json(out, self.name, config, metrics, data, WEIGHTS)
        return metrics


def evaluate(model, data, split: str, window: int, stride: int) -> dict[str, Any]:
    """MSE on ``split``'s windows of the model and of the repeat-the-previous-pose baseline, each closed loop
    and one step (see the module notes), in normalised units and in the stored units (``_raw``: unit-vector
    components)."""
    torch = require_torch()
    w = data.windows(split, window=window, stride=stride)
    if len(w) == 0:
        return {"split": split, "windows": 0}
    a, b, mx, sx, my, sy = _pose_map(data)
    x, y = w.x, w.y
    model.eval()
    with torch.no_grad():
        tx = torch.from_numpy(x)
        pm = (torch.from_numpy(a), torch.from_numpy(b))
        closed = model(tx, pm, closed=True).numpy()
        one = model(tx, pm, closed=False).numpy()
    y_raw = y * sy + my
    pose_raw = x[:, :, TARGET_DIMS:] * sx[TARGET_DIMS:] + mx[TARGET_DIMS:]   # the previous pose, as captured
    held = np.repeat(pose_raw[:, :1], pose_raw.shape[1], axis=1)

    def mse(pred_raw: np.ndarray) -> tuple[float, float]:
        return (float(np.mean(((pred_raw - my) / sy - y) ** 2)), float(np.mean((pred_raw - y_raw) ** 2)))

    out: dict[str, Any] = {"split": split, "windows": len(w)}
    for key, pred in (("closed_loop", closed * sy + my), ("one_step", one * sy + my),
                      ("baseline_closed_loop", held), ("baseline_one_step", pose_raw)):
        out[f"{key}_mse"], out[f"{key}_mse_raw"] = mse(pred)
    return out


def load_model(model_dir: str | Path):
    """(module in eval mode, model.json) of a saved gaze_rnn model."""
    meta = read_model_json(model_dir)
    c = meta["config"]
    model = build_model(int(c["n_in"]), int(c["n_out"]), int(c["hidden"]), bool(c.get("residual", False)))
    load_state(model, Path(model_dir) / meta.get("weights", WEIGHTS))
    model.eval()
    return model, meta
