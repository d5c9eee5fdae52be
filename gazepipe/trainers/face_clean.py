"""The ``face_clean`` trainer (Berson 3.1, 3.2): an LSTM that turns tracked blendshapes into clean ones.

Derivative parametrisation (Berson eq. 1, 2; K = 1): at frame n the network sees its previous estimate x̂[n],
its previous derivative x̂'[n−1] and the corrective derivative x_c[n] = (x_i[n+1] − x̂[n]) / Δt[n] of the
tracked input x_i (computed from the stored ``tracked`` and ``tracked_d1``: x_i[n+1] = x_i[n] + Δt[n]·x_i'[n]),
and predicts the forward derivative x̂'[n]; then x̂[n+1] = x̂[n] + Δt[n]·x̂'[n]. Residual connection: x̂'[n] =
x_c[n] + the network's output, so an untrained network (its output layer starts at zero) reproduces the tracked
input exactly and training learns the correction. Inputs and the output are scaled by the dataset's training
statistics (``clean``, ``clean_d1``, ``tracked_d1``).

Network: LSTM cell (128 units) → dropout 0.3 → linear (Berson 3.2). Loss: MSE of x̂ against ``clean`` plus
0.01 × MSE of x̂' against ``clean_d1`` (both in units of the training standard deviation); Berson's
inter-vertex distance term needs a face mesh and is left out. Adam, lr 1e-3. Chunks of 200 frames with a
stride of 50 (Berson 4.1); each chunk starts from the tracked value (x̂[0] = x_i[0], x̂'[−1] = 0), as inference
on a new take would.
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
    load_state,
    pick_split,
    require_torch,
    state_bytes,
    subsample,
)

WEIGHTS = "face_clean.pt"
COLUMNS = ("tracked", "clean", "tracked_d1", "clean_d1", "dt_s")


def build_model(n: int, hidden: int, dropout: float, scales: dict[str, np.ndarray]):
    """The cleaner for ``n`` channels; ``scales``: mean/std of ``clean``, ``clean_d1``, ``tracked_d1`` (stored
    as buffers so a saved model carries them)."""
    torch = require_torch()
    nn = torch.nn

    class FaceClean(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.cell = nn.LSTMCell(3 * n, hidden)
            self.drop = nn.Dropout(dropout)
            self.out = nn.Linear(hidden, n)
            nn.init.zeros_(self.out.weight)
            nn.init.zeros_(self.out.bias)
            for k, v in scales.items():
                self.register_buffer(k, torch.as_tensor(np.asarray(v, np.float32)))

        def forward(self, tracked, tracked_d1, dt):
            """tracked, tracked_d1 (B, T, n), dt (B, T, 1) → (x̂ for frames 1..T (B, T, n), x̂' (B, T, n))."""
            b, t, _ = tracked.shape
            h = tracked.new_zeros(b, self.cell.hidden_size)
            c = tracked.new_zeros(b, self.cell.hidden_size)
            x = tracked[:, 0]
            dprev = torch.zeros_like(x)
            xs, ds = [], []
            for i in range(t):
                xc = tracked_d1[:, i] + (tracked[:, i] - x) / dt[:, i]
                inp = torch.cat([(x - self.clean_mean) / self.clean_std,
                                 (dprev - self.clean_d1_mean) / self.clean_d1_std,
                                 (xc - self.tracked_d1_mean) / self.tracked_d1_std], dim=1)
                h, c = self.cell(inp, (h, c))
                d = xc + self.out(self.drop(h)) * self.clean_d1_std
                x = x + dt[:, i] * d
                xs.append(x)
                ds.append(d)
                dprev = d
            return torch.stack(xs, dim=1), torch.stack(ds, dim=1)

    return FaceClean()


def _chunks(data, split: str, window, stride) -> tuple[dict[str, np.ndarray], Any]:
    w = data.windows(split, window=window, stride=stride, normalise=False, columns=COLUMNS)
    return {c: w.stack(c).astype(np.float32) for c in COLUMNS}, w


def _scales(data) -> dict[str, np.ndarray]:
    out = {}
    for col in ("clean", "clean_d1", "tracked_d1"):
        m, s = data.mean_std(col)
        out[f"{col}_mean"], out[f"{col}_std"] = m, s
    return out


class FaceCleanTrainer:
    """Berson's facial-animation cleaner on a ``face_clean`` dataset (K = 1)."""

    name = "face_clean"
    dataset = "face_clean"
    schema_version = 1
    required_columns = COLUMNS
    options = {
        "dropout": "dropout after the LSTM (default 0.3)",
        "w_der": "weight of the derivative loss (default 0.01)",
        "batch": "chunks per minibatch (default 64)",
        "window": "frames per chunk (default _dataset.json's, 200)",
        "stride": "step between chunks (default _dataset.json's, 50)",
        "max_windows": "use at most this many training chunks (seeded subset; default all)",
        "threads": "torch CPU threads (default torch's)",
    }

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        hidden = int(options.get("hidden", 128))
        lr = float(options.get("lr", 1e-3))
        epochs = int(options.get("epochs", 50))
        dropout = float(options.get("dropout", 0.3))
        w_der = float(options.get("w_der", 0.01))
        batch = int(options.get("batch", 64))
        window, stride = options.get("window", None), options.get("stride", None)
        max_windows = options.get("max_windows", None)
        if not 0.0 <= dropout < 1.0:
            raise ConfigError(None, f"option dropout must be in [0, 1), got {dropout}")
        rng = np.random.default_rng(options.seed)
        arrays, w = _chunks(data, "train", window, stride)
        if len(w) == 0:
            raise ConfigError(data.path, f"no training chunk of {w.window} frames (takes shorter than a chunk: "
                                         f"{w.short_runs})")
        pick = subsample(len(w), None if max_windows is None else int(max_windows), rng)
        arrays = {k: v[pick] for k, v in arrays.items()}
        n = int(arrays["tracked"].shape[2])
        scales = _scales(data)
        config = {"n_channels": n, "hidden": hidden, "dropout": dropout, "lr": lr, "w_der": w_der,
                  "epochs": epochs, "batch": batch, "window": w.window, "stride": int(stride or data.stride or 50),
                  "seed": options.seed, "train_chunks": int(len(pick)), "k": 1,
                  "channels": list(data.features.get("clean", []))}
        with deterministic(options.seed, options.get("threads", None)) as torch:
            model = build_model(n, hidden, dropout, scales)
            opt = torch.optim.Adam(model.parameters(), lr=lr)
            t = {k: torch.from_numpy(v) for k, v in arrays.items()}
            cs, ds = model.clean_std, model.clean_d1_std
            losses = []
            for _ in range(epochs):
                model.train()
                total, count = 0.0, 0
                for idx in batches(len(pick), batch, rng):
                    opt.zero_grad()
                    x, d = model(t["tracked"][idx], t["tracked_d1"][idx], t["dt_s"][idx])
                    loss_x = torch.mean(((x[:, :-1] - t["clean"][idx, 1:]) / cs) ** 2)
                    loss_d = torch.mean(((d - t["clean_d1"][idx]) / ds) ** 2)
                    loss = loss_x + w_der * loss_d
                    loss.backward()
                    opt.step()
                    total += float(loss.detach()) * len(idx)
                    count += len(idx)
                losses.append(total / max(count, 1))
            metrics: dict[str, Any] = {"train_loss": losses, "train_chunks": int(len(pick)),
                                       "dropped_rows": w.dropped_rows}
            split = pick_split(data)
            metrics["validation"] = evaluate(model, data, split, w.window, config["stride"]) if split else None
            out = Path(out_dir)
            write_atomic(out / WEIGHTS, state_bytes(model))
        save_model_json(out, self.name, config, metrics, data, WEIGHTS)
        return metrics


def evaluate(model, data, split: str, window: int, stride: int) -> dict[str, Any]:
    """RMS error against ``clean`` on ``split``'s chunks (frames 1..T−1 of each, blendshape units) of the
    cleaned track and of the raw tracked input."""
    torch = require_torch()
    arrays, w = _chunks(data, split, window, stride)
    if len(w) == 0:
        return {"split": split, "chunks": 0}
    model.eval()
    with torch.no_grad():
        x, _ = model(*(torch.from_numpy(arrays[c]) for c in ("tracked", "tracked_d1", "dt_s")))
    clean = arrays["clean"][:, 1:]
    cleaned = x.numpy()[:, :-1]
    return {"split": split, "chunks": len(w),
            "cleaned_rmse": float(np.sqrt(np.mean((cleaned - clean) ** 2))),
            "tracked_rmse": float(np.sqrt(np.mean((arrays["tracked"][:, 1:] - clean) ** 2)))}


def load_model(model_dir: str | Path):
    """(module in eval mode, model.json) of a saved face_clean model."""
    meta = read_model_json(model_dir)
    c = meta["config"]
    zeros = {f"{col}_{s}": np.zeros(int(c["n_channels"]), np.float32)
             for col in ("clean", "clean_d1", "tracked_d1") for s in ("mean", "std")}
    model = build_model(int(c["n_channels"]), int(c["hidden"]), float(c["dropout"]), zeros)
    load_state(model, Path(model_dir) / meta.get("weights", WEIGHTS))
    model.eval()
    return model, meta
