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
inter-vertex distance term needs a face mesh and is left out. Adam, lr 1e-3 decayed to 0 along a cosine over
the epochs (50), gradients clipped to norm 1. Chunks of 200 frames with a stride of 50 (Berson 4.1); each chunk
starts from the tracked value (x̂[0] = x_i[0], x̂'[−1] = 0), as inference on a new take does. The validation
loss of every epoch is the training loss on the validation chunks.

Inference: :class:`FaceCleaner` (``FaceCleaner.load(model_dir).clean(blendshapes, timestamps)``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

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
    load_state,
    pick_split,
    require_torch,
    resolve_device,
    save_trained,
    subsample,
)

WEIGHTS = "face_clean.pt"
COLUMNS = ("tracked", "clean", "tracked_d1", "clean_d1", "dt_s")
#: chunks per forward pass when evaluating
EVAL_CHUNK = 512


def build_model(n: int, hidden: int, dropout: float, scales: dict[str, np.ndarray]):
    """The cleaner for ``n`` channels; ``scales``: mean/std of ``clean``, ``clean_d1``, ``tracked_d1`` (stored
    as buffers so a saved model carries them)."""
    torch = require_torch()
    nn: Any = torch.nn   # torch is optional and untyped here; its classes are subclassed below

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
    knobs = ("epochs", "hidden", "lr", "device", "patience")
    options = options_table(
        Option("dropout", float, 0.3, "dropout after the LSTM", min=0, max=1, max_open=True),
        Option("w_der", float, 0.01, "weight of the derivative loss", min=0),
        *loop_options("chunks", "_dataset.json's, 200", "_dataset.json's, 50"),
    )

    def train(self, data, out_dir: Path, options: TrainOptions) -> dict[str, Any]:
        check_options(self, options)
        device = resolve_device(options.device)
        hidden = int(options.get("hidden", 128))
        dropout = float(options.get("dropout", 0.3))
        w_der = float(options.get("w_der", 0.01))
        window, stride = options.get("window", None), options.get("stride", None)
        max_windows = options.get("max_windows", None)
        rng = np.random.default_rng(options.seed)
        arrays, w = _chunks(data, "train", window, stride)
        if len(w) == 0:
            raise ConfigError(data.path, f"no training chunk of {w.window} frames (takes shorter than a chunk: "
                                         f"{w.short_runs})")
        pick = subsample(len(w), None if max_windows is None else int(max_windows), rng)
        arrays = {k: v[pick] for k, v in arrays.items()}
        stride = int(stride or data.stride or 50)
        split = pick_split(data)
        val_arrays = _chunks(data, split, w.window, stride)[0] if split else {}
        fc = fit_config(options, validation=len(val_arrays.get("tracked", ())) > 0, data_path=data.path)
        n = int(arrays["tracked"].shape[2])
        config = {"n_channels": n, "hidden": hidden, "dropout": dropout, "lr": fc.lr, "w_der": w_der,
                  "epochs": fc.epochs, "batch": fc.batch, "window": w.window, "stride": stride,
                  "seed": options.seed, "train_chunks": int(len(pick)), "k": 1,
                  "channels": list(data.features.get("clean", [])), "schedule": fc.schedule, "clip": fc.clip,
                  "patience": fc.patience, "keep": fc.keep}
        with deterministic(options.seed, options.get("threads", None), device) as (torch, det):
            model = build_model(n, hidden, dropout, _scales(data)).to(device)
            opt = make_adam(model, fc, device)
            train = DeviceArrays(arrays, device)
            val = DeviceArrays(val_arrays, device) if len(val_arrays.get("tracked", ())) else None

            def loss_fn(b):
                x, d = model(b["tracked"], b["tracked_d1"], b["dt_s"])
                loss_x = torch.mean(((x[:, :-1] - b["clean"][:, 1:]) / model.clean_std) ** 2)
                loss_d = torch.mean(((d - b["clean_d1"]) / model.clean_d1_std) ** 2)
                loss = loss_x + w_der * loss_d
                return loss, loss

            def val_fn() -> float:
                assert val is not None   # fit calls val_fn only when there are validation rows
                total = 0.0
                for i in range(0, val.n, EVAL_CHUNK):
                    idx = np.arange(i, min(i + EVAL_CHUNK, val.n))
                    total += float(loss_fn(val.batch(idx))[0]) * len(idx)
                return total / val.n

            hist = fit(model, opt, train, loss_fn, val_fn if val is not None else None, fc, rng, options.progress)
            metrics: dict[str, Any] = {"device": device_name(device), **history_metrics(hist),
                                       "train_chunks": int(len(pick)), "dropped_rows": w.dropped_rows}
            metrics["validation"] = evaluate(model, data, split, w.window, stride) if split else None
            metrics["summary"] = summary(metrics["validation"]) + validation_lines(hist, fc)
        # what torch warned about is known on leaving the block
        save_trained(out_dir, self.name, config, model, metrics, data, WEIGHTS, det.nondeterministic)
        return metrics


def _run(model, tracked: np.ndarray, tracked_d1: np.ndarray, dt: np.ndarray, device: Any = None) -> np.ndarray:
    """x̂ for frames 1..T of chunks (B, T, n) (``dt`` (B, T, 1), seconds), :data:`EVAL_CHUNK` at a time."""
    torch = require_torch()
    device = device or next(model.parameters()).device
    model.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(tracked), EVAL_CHUNK):
            parts = (torch.from_numpy(np.ascontiguousarray(a[i:i + EVAL_CHUNK], np.float32)).to(device)
                     for a in (tracked, tracked_d1, dt))
            out.append(model(*parts)[0].cpu().numpy())
    return np.concatenate(out) if out else np.zeros_like(tracked, np.float32)


def evaluate(model, data, split: str, window: int, stride: int) -> dict[str, Any]:
    """RMS error against ``clean`` on ``split``'s chunks (frames 1..T−1 of each, blendshape units) of the
    cleaned track and of the raw tracked input."""
    arrays, w = _chunks(data, split, window, stride)
    if len(w) == 0:
        return {"split": split, "chunks": 0}
    x = _run(model, arrays["tracked"], arrays["tracked_d1"], arrays["dt_s"])
    clean = arrays["clean"][:, 1:]
    cleaned = x[:, :-1]
    return {"split": split, "chunks": len(w),
            "cleaned_rmse": float(np.sqrt(np.mean((cleaned - clean) ** 2))),
            "tracked_rmse": float(np.sqrt(np.mean((arrays["tracked"][:, 1:] - clean) ** 2)))}


def summary(v: dict[str, Any] | None) -> list[str]:
    """The validation metrics in words: the cleaned track against the raw tracked signal."""
    if not v or not v.get("chunks"):
        return ["no validation chunks: nothing to compare with a baseline"]
    return [verdict(f"cleaned ({v['chunks']} {v['split']} chunks), RMS error to the clean track",
                    v["cleaned_rmse"], v["tracked_rmse"], "for the raw tracked signal")]


class FaceCleaner:
    """A trained ``face_clean`` model: ``FaceCleaner.load("models/face_clean").clean(blendshapes, timestamps)``.

    Attributes
    ----------
    model : the torch module (eval mode); ``meta`` : model.json; ``channels`` : the blendshape names, in order.
    """

    def __init__(self, model, meta: dict[str, Any], device: Any = "cpu") -> None:
        self.model, self.meta, self.device = model, meta, device
        self.channels: list[str] = list(meta["config"].get("channels") or [])

    @classmethod
    def load(cls, model_dir: str | Path, device: str = "cpu") -> FaceCleaner:
        """The model saved in ``model_dir`` by ``gazepipe train face_clean``, on ``device`` (``cpu``, ``cuda``,
        ``cuda:N`` or ``auto``)."""
        dev = resolve_device(device)
        model, meta = load_model(model_dir)
        return cls(model.to(dev), meta, dev)

    def clean(self, blendshapes: np.ndarray, timestamps: np.ndarray) -> np.ndarray:
        """Clean a tracked blendshape sequence.

        Parameters
        ----------
        blendshapes : (T, n) or (B, T, n) tracked values (the dataset's ``tracked`` units, 0..1), channels in
            :attr:`channels` order.
        timestamps : (T,) or (B, T) seconds, strictly increasing (frame times; dropped frames are fine).

        Returns
        -------
        (T, n) or (B, T, n) float32 cleaned values; frame 0 is the tracked value (the recursion starts there).
        """
        x = np.asarray(blendshapes, np.float32)
        t = np.asarray(timestamps, np.float64)
        single = x.ndim == 2
        x, t = (x[None], t[None]) if single else (x, t)
        if t.shape != x.shape[:2] or x.shape[-1] != int(self.meta["config"]["n_channels"]):
            raise ValueError(f"blendshapes (B, T, {self.meta['config']['n_channels']}) and timestamps (B, T) "
                             f"expected, got {x.shape} and {t.shape}")
        out = x.copy()
        if x.shape[1] > 1:
            dt = np.diff(t, axis=1)
            if not np.all(dt > 0):
                raise ValueError("timestamps must be strictly increasing")
            d1 = np.diff(x.astype(np.float64), axis=1) / dt[..., None]
            out[:, 1:] = _run(self.model, x[:, :-1], d1.astype(np.float32), dt[..., None].astype(np.float32),
                              self.device)
        return out[0] if single else out


def load_model(model_dir: str | Path):
    """(module in eval mode on the CPU, model.json) of a saved face_clean model; see :class:`FaceCleaner`."""
    meta = read_model_json(model_dir)
    c = meta["config"]
    zeros = {f"{col}_{s}": np.zeros(int(c["n_channels"]), np.float32)
             for col in ("clean", "clean_d1", "tracked_d1") for s in ("mean", "std")}
    model = build_model(int(c["n_channels"]), int(c["hidden"]), float(c["dropout"]), zeros)
    load_state(model, Path(model_dir) / meta.get("weights", WEIGHTS))
    model.eval()
    return model, meta
