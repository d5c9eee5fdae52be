"""The training loop the PyTorch trainers share: minibatches on the device, a cosine learning-rate schedule,
gradient clipping, the validation loss after every epoch, early stopping and progress reports.

Progress: :func:`fit` calls ``TrainOptions.progress`` (when set) with a dict: after every minibatch ``event`` =
``"batch"``, ``epoch`` (from 1), ``epochs``, ``batch`` (from 1), ``batches`` (per epoch); after every epoch
``event`` = ``"epoch"``, ``epoch``, ``epochs``, ``train_loss``, ``val_loss`` (``None`` without a validation
split), ``best`` (this epoch's validation loss is the lowest so far), ``lr``, ``seconds`` (the training pass)
and ``val_seconds``. ``gazepipe train`` draws a bar on a terminal and writes the epochs as JSON lines
otherwise.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gazepipe.errors import ConfigError
from gazepipe.trainers.base import TrainOptions
from gazepipe.trainers.torch_utils import DeviceArrays, batches, require_torch


@dataclass
class FitConfig:
    """How :func:`fit` trains.

    Attributes
    ----------
    epochs : passes over the training set (at most).
    batch : items per minibatch.
    lr : peak learning rate; ``schedule`` ``"cosine"`` decays it to 0 over ``epochs`` (per minibatch),
        ``"constant"`` keeps it.
    clip : largest gradient norm (``None``: no clipping).
    patience : stop after this many epochs without a lower validation loss (``None``: run every epoch).
    keep : which weights training ends with: ``"best"`` (the epoch of lowest validation loss; the last when
        there is no validation loss) or ``"last"``.
    cuda_graph : on a CUDA device, capture the training step as a CUDA graph (:class:`GraphStep`).
    max_seconds : a time budget for the training passes, seconds (``None``: none): after the first epoch the
        epochs are cut to what the budget holds at that pace (the schedule follows: it still ends at 0), and
        training stops after the epoch that passes it. Results then depend on the machine's speed.
    """

    epochs: int
    batch: int
    lr: float
    schedule: str = "cosine"
    clip: float | None = 1.0
    patience: int | None = None
    max_seconds: float | None = None
    keep: str = "best"
    cuda_graph: bool = True


#: the default ``--patience``, in epochs, when the dataset has a validation split
DEFAULT_PATIENCE = 10


def _lr(cfg: FitConfig, step: int, total: int) -> float:
    if cfg.schedule == "constant" or total <= 1:
        return cfg.lr
    return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * step / total))


def fit(model, optimizer, data: DeviceArrays, loss_fn: Callable[[dict[str, Any]], tuple[Any, Any]],
        val_fn: Callable[[], float] | None, cfg: FitConfig, rng: np.random.Generator,
        progress: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Train ``model`` in place and return its history.

    Parameters
    ----------
    data : the training items on the device; minibatches are drawn by ``rng`` (numpy: the same order on every
        device).
    loss_fn : minibatch (dict of tensors) → (the loss to minimise, the loss to report), scalar tensors.
    val_fn : the validation loss of the model as it is (in eval mode, without gradients), or ``None``.

    Returns
    -------
    ``train_loss``, ``val_loss``, ``epoch_seconds`` (training pass, s) per epoch run; ``epochs_run``,
    ``best_epoch`` (from 1; ``None`` without validation), ``best_val_loss``, ``stopped`` (``"patience"``,
    ``"time"`` or ``None``), ``kept`` (``"best"`` or ``"last"`` weights).
    """
    torch = require_torch()
    per_epoch = math.ceil(data.n / cfg.batch)
    total_steps = cfg.epochs * per_epoch
    hist: dict[str, Any] = {"train_loss": [], "val_loss": [], "epoch_seconds": [], "stopped": None}
    best, best_epoch, best_state = math.inf, None, None
    step, spent = 0, 0.0
    runner = step_runner(model, optimizer, data, loss_fn, cfg)
    hist["execution"] = {**runner.execution, "torch": str(torch.__version__)}
    asked = cfg.epochs
    for epoch in range(1, cfg.epochs + 1):
        t0 = time.perf_counter()
        model.train()
        total = torch.zeros((), device=data.device)
        for b, idx in enumerate(batches(data.n, cfg.batch, rng), start=1):
            shown = runner.step(idx, _lr(cfg, step, total_steps))
            step += 1
            total += shown * len(idx)
            if progress is not None:
                progress({"event": "batch", "epoch": epoch, "epochs": cfg.epochs, "batch": b, "batches": per_epoch})
        train_loss = float(total) / max(data.n, 1)   # float() waits for the device
        seconds = time.perf_counter() - t0
        spent += seconds
        if epoch == 1 and cfg.max_seconds is not None:
            fits = max(1, min(cfg.epochs, int(cfg.max_seconds // max(seconds, 1e-9))))
            if fits < cfg.epochs:
                cfg = dataclasses.replace(cfg, epochs=fits)
                total_steps = fits * per_epoch
        t1 = time.perf_counter()
        val = None
        if val_fn is not None:
            model.eval()
            with torch.no_grad():
                val = float(val_fn())
        is_best = val is not None and val < best
        if is_best and val is not None:
            best, best_epoch = val, epoch
            if cfg.keep == "best":
                best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        hist["train_loss"].append(train_loss)
        hist["val_loss"].append(val)
        hist["epoch_seconds"].append(seconds)
        if progress is not None:
            progress({"event": "epoch", "epoch": epoch, "epochs": cfg.epochs, "train_loss": train_loss,
                      "val_loss": val, "best": is_best, "lr": optimizer.param_groups[0]["lr"],
                      "seconds": seconds, "val_seconds": time.perf_counter() - t1})
        if cfg.patience is not None and best_epoch is not None and epoch - best_epoch >= cfg.patience:
            hist["stopped"] = "patience"
            break
        if epoch >= cfg.epochs:
            break
        if cfg.max_seconds is not None and spent >= cfg.max_seconds:
            hist["stopped"] = "time"
            break
    if best_state is not None:
        model.load_state_dict(best_state)
    if hist["stopped"] is None and cfg.epochs < asked:
        hist["stopped"] = "time"
    hist.update(epochs_run=len(hist["train_loss"]), best_epoch=best_epoch,
                best_val_loss=None if best_epoch is None else best,
                kept="best" if best_state is not None else "last")
    return hist


class EagerStep:
    """One optimisation step per minibatch, run operation by operation (every device)."""

    def __init__(self, model, optimizer, data: DeviceArrays, loss_fn: Callable[[dict[str, Any]], tuple[Any, Any]],
                 clip: float | None) -> None:
        self.optimizer, self.data, self.loss_fn, self.clip = optimizer, data, loss_fn, clip
        self.params = [p for p in model.parameters() if p.requires_grad]
        self.execution: dict[str, Any] = {"training_step": "eager"}

    def set_lr(self, lr: float) -> None:
        """Set every parameter group's learning rate (in place when it is a device tensor)."""
        for g in self.optimizer.param_groups:
            if hasattr(g["lr"], "fill_"):   # a tensor learning rate (capturable optimisers)
                g["lr"].fill_(lr)
            else:
                g["lr"] = lr

    def step(self, idx: np.ndarray, lr: float):
        """Train on the rows ``idx`` at learning rate ``lr``; the reported loss (a detached scalar tensor)."""
        torch = require_torch()
        self.set_lr(lr)
        self.optimizer.zero_grad(set_to_none=True)
        loss, shown = self.loss_fn(self.data.batch(idx))
        loss.backward()
        if self.clip:
            torch.nn.utils.clip_grad_norm_(self.params, self.clip)
        self.optimizer.step()
        return shown.detach()


class GraphStep(EagerStep):
    """The whole optimisation step (forward, backward, gradient clipping, Adam) captured once as a CUDA graph
    and replayed for every full minibatch: one launch per step instead of thousands of small kernels (a
    recurrent network's closed loop launches a dozen per frame). The minibatch's row indices are copied into
    a fixed index tensor on the device before each replay; the learning rate lives in a device tensor
    (``torch.optim.Adam(..., lr=tensor, capturable=True)``, see :func:`make_adam`). A short minibatch (the
    last of an epoch) runs eagerly with the same optimiser.

    Capture needs warm-up steps, which change the weights and Adam's moments; both are put back exactly
    (weights copied back, moments and step counts zeroed in place, keeping their memory, which the graph
    reads) before the capture, so training starts from the same state as an eager run.
    """

    #: warm-up steps before capture (PyTorch's CUDA graph notes: a few, on a side stream)
    WARMUP = 3

    def __init__(self, model, optimizer, data: DeviceArrays, loss_fn, clip: float | None, batch: int,
                 capture: Callable[[Callable[[], Any]], Callable[[], None]] | None = None) -> None:
        super().__init__(model, optimizer, data, loss_fn, clip)
        torch = require_torch()
        self.batch = batch
        self.index = torch.zeros(batch, dtype=torch.long, device=data.device)
        saved = {k: v.detach().clone() for k, v in model.state_dict().items()}
        self._warm_up(lambda: EagerStep.step(self, self.index.cpu().numpy(), 0.0))
        with torch.no_grad():
            for k, v in model.state_dict().items():
                v.copy_(saved[k])
            for state in optimizer.state.values():
                for v in state.values():
                    if hasattr(v, "zero_"):
                        v.zero_()
        optimizer.zero_grad(set_to_none=True)   # backward in the graph then writes, not adds, the gradients
        self.shown = None
        self.replay = (capture or capture_cuda_graph)(self._captured_body)
        self.execution = {"training_step": "cuda_graph", "graph_batch": batch}

    def _warm_up(self, one_step: Callable[[], Any]) -> None:
        torch = require_torch()
        if self.data.device.type != "cuda":
            for _ in range(self.WARMUP):
                one_step()
            return
        side = torch.cuda.Stream(self.data.device)
        side.wait_stream(torch.cuda.current_stream(self.data.device))
        with torch.cuda.stream(side):
            for _ in range(self.WARMUP):
                one_step()
        torch.cuda.current_stream(self.data.device).wait_stream(side)

    def _captured_body(self) -> None:
        torch = require_torch()
        batch = {k: t.index_select(0, self.index) for k, t in self.data.tensors.items()}
        loss, shown = self.loss_fn(batch)
        loss.backward()
        if self.clip:
            torch.nn.utils.clip_grad_norm_(self.params, self.clip)
        self.optimizer.step()
        self.shown = shown.detach()

    def step(self, idx: np.ndarray, lr: float):
        """Train on the rows ``idx`` at ``lr``: a replay of the graph for a full minibatch, else eagerly."""
        torch = require_torch()
        if len(idx) != self.batch:
            return EagerStep.step(self, idx, lr)
        self.set_lr(lr)
        host = torch.from_numpy(np.ascontiguousarray(idx, np.int64))
        if self.index.is_cuda:   # from pinned memory the copy is queued, so the host never waits on the GPU
            self.index.copy_(host.pin_memory(), non_blocking=True)
        else:
            self.index.copy_(host)
        self.replay()
        assert self.shown is not None
        return self.shown.clone()   # the next replay overwrites it


def capture_cuda_graph(body: Callable[[], Any]) -> Callable[[], None]:
    """``body`` captured as a CUDA graph; returns the graph's replay. The caller sets the gradients to none
    before, so that backward in the graph allocates them in the graph's memory pool and writes them afresh."""
    torch = require_torch()
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        body()
    return graph.replay


def step_runner(model, optimizer, data: DeviceArrays, loss_fn, cfg: FitConfig) -> EagerStep:
    """A :class:`GraphStep` when ``cfg.cuda_graph`` and the data sit whole on a CUDA device with at least one
    full minibatch, else an :class:`EagerStep`. A capture that fails falls back to eager steps, and the
    execution record says why."""
    eager = EagerStep(model, optimizer, data, loss_fn, cfg.clip)
    if not cfg.cuda_graph or data.device.type != "cuda":
        return eager
    why = ("the training set does not fit on the GPU" if not data.resident
           else "fewer items than one minibatch" if data.n < cfg.batch
           else "the optimiser is not capturable (use make_adam)" if not _capturable(optimizer) else None)
    if why is None:
        try:
            return GraphStep(model, optimizer, data, loss_fn, cfg.clip, cfg.batch)
        except RuntimeError as exc:   # torch reports a capture it cannot do as a RuntimeError
            why = f"capture failed: {' '.join(str(exc).split())[:200]}"
    eager.execution = {"training_step": "eager", "cuda_graph_not_used": why}
    return eager


def _capturable(optimizer) -> bool:
    return all(bool(g.get("capturable")) for g in optimizer.param_groups)


def make_adam(model, cfg: FitConfig, device, betas: tuple[float, float] = (0.9, 0.999)):
    """Adam over ``model``'s parameters at ``cfg.lr``; made capturable, with the learning rate in a device
    tensor, when the steps will be captured as CUDA graphs (``cfg.cuda_graph`` on a CUDA device)."""
    torch = require_torch()
    if cfg.cuda_graph and getattr(device, "type", "cpu") == "cuda":
        return torch.optim.Adam(model.parameters(), lr=torch.tensor(cfg.lr, device=device), betas=betas,
                                capturable=True, foreach=True)
    return torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=betas)


def fit_config(options: TrainOptions, validation: bool = True, data_path: Any = None) -> FitConfig:
    """The loop's settings from the options (the torch trainers' common defaults: 50 epochs, lr 1e-3 on a
    cosine, 64 per minibatch, gradients clipped to norm 1, the best validation epoch kept, patience
    :data:`DEFAULT_PATIENCE`; ``--patience 0`` runs every epoch).

    ``validation``: whether the dataset has validation items. Without them the last epoch is kept and there
    is no patience; asking for patience (or ``keep=best``) then is a :class:`ConfigError` naming
    ``data_path``."""
    asked_patience, asked_keep = options.patience, options.get("keep", None)
    if not validation and (asked_patience or asked_keep == "best"):
        what = "--patience" if asked_patience else "--option keep=best"
        raise ConfigError(data_path, f"{what} needs validation items; this dataset has none in its val or "
                                     "test split")
    patience = (None if asked_patience == 0 else DEFAULT_PATIENCE if asked_patience is None
                else int(asked_patience))
    keep = str(asked_keep or "best")
    if not validation:
        patience, keep = None, "last"
    schedule = str(options.get("schedule", "cosine"))
    if schedule not in ("cosine", "constant"):
        raise ConfigError(None, f"option schedule must be cosine or constant, got {schedule!r}")
    clip = float(options.get("clip", 1.0))
    max_s = options.get("max_seconds", None)
    fc = FitConfig(epochs=int(options.get("epochs", 50)), batch=int(options.get("batch", 64)),
                   lr=float(options.get("lr", 1e-3)), schedule=schedule, clip=clip if clip > 0 else None,
                   patience=patience, max_seconds=None if max_s is None else float(max_s), keep=keep,
                   cuda_graph=bool(options.get("cuda_graph", True)))
    if fc.keep not in ("best", "last"):
        raise ConfigError(None, f"option keep must be best or last, got {fc.keep!r}")
    if fc.epochs < 1 or fc.batch < 1 or (fc.patience is not None and fc.patience < 1):
        raise ConfigError(None, "epochs and batch must be at least 1, patience at least 0")
    return fc


def history_metrics(hist: dict[str, Any]) -> dict[str, Any]:
    """What a trainer's metrics keep of :func:`fit`'s history."""
    return {"execution": hist["execution"],
            "train_loss": hist["train_loss"], "val_loss": hist["val_loss"], "epoch_seconds": hist["epoch_seconds"],
            "epochs_run": hist["epochs_run"], "best_epoch": hist["best_epoch"], "stopped": hist["stopped"],
            "kept": hist["kept"], "kept_epoch": kept_epoch(hist)}


def kept_epoch(hist: dict[str, Any]) -> int:
    """The epoch (from 1) whose weights training ended with."""
    return int(hist["best_epoch"]) if hist["kept"] == "best" else int(hist["epochs_run"])


def validation_lines(hist: dict[str, Any], cfg: FitConfig) -> list[str]:
    """The validation loss over training in words: which epoch was best, which was kept, and whether (and by
    how much) the loss rose after the best epoch, e.g. ``validation loss: best 1.04 at epoch 10 of 20, rose
    25 % to 1.30 by the last epoch (overfitting); kept epoch 10 (stopped: no lower loss in 10 epochs)``."""
    losses = [v for v in hist["val_loss"] if v is not None]
    run = int(hist["epochs_run"])
    if not losses:
        return [f"no validation loss: kept the last epoch ({run}) of {run}"]
    best_epoch, best = int(hist["best_epoch"]), float(hist["best_val_loss"])
    last = float(losses[-1])
    text = f"validation loss: best {best:.4g} at epoch {best_epoch} of {run}"
    if run > best_epoch and best > 0 and last > best:
        text += f", rose {_percent((last - best) / best)} to {last:.4g} by epoch {run}"
    elif run > best_epoch:
        text += f", {last:.4g} at epoch {run}"
    kept = kept_epoch(hist)
    text += f"; kept epoch {kept}"
    if hist["kept"] == "last" and run > best_epoch and last > best:
        text += f" (asked for the last; the best epoch's loss was {_percent((last - best) / last)} lower)"
    if hist["stopped"] == "patience":
        text += f"; stopped early, no lower loss in {cfg.patience} epochs"
    elif hist["stopped"] == "time":
        text += "; stopped at the time limit"
    return [text]


def _percent(share: float) -> str:
    """``0.25`` → ``25 %``; under 1 % with one decimal (``0.3 %``), so a small rise does not read as none."""
    return f"{share * 100:.0f} %" if share >= 0.01 else f"{share * 100:.1f} %"


def verdict(what: str, model: float, baseline: float, baseline_is: str, digits: int = 3) -> str:
    """One sentence comparing a model's error with a baseline's (lower is better), e.g.
    ``closed loop: MSE 0.41 vs 0.94 holding the first pose: 56 % better``."""
    m, b = f"{model:.{digits}g}", f"{baseline:.{digits}g}"
    if not (math.isfinite(model) and math.isfinite(baseline)) or baseline <= 0:
        return f"{what}: {m} vs {b} {baseline_is}"
    change = (baseline - model) / baseline * 100.0
    if abs(change) < 0.5:
        word = "the same (within 0.5 %)"
    elif change > 0:
        word = f"{change:.0f} % better"
    else:
        word = f"{-change:.0f} % worse"
    return f"{what}: {m} vs {b} {baseline_is}: {word}"
