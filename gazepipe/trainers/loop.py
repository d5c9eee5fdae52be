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
    patience : stop after this many epochs without a lower validation loss and keep the best epoch's weights
        (``None``: run every epoch, keep the last weights).
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
    params = [p for p in model.parameters() if p.requires_grad]
    asked = cfg.epochs
    for epoch in range(1, cfg.epochs + 1):
        t0 = time.perf_counter()
        model.train()
        total = torch.zeros((), device=data.device)
        for b, idx in enumerate(batches(data.n, cfg.batch, rng), start=1):
            for g in optimizer.param_groups:
                g["lr"] = _lr(cfg, step, total_steps)
            step += 1
            optimizer.zero_grad(set_to_none=True)
            loss, shown = loss_fn(data.batch(idx))
            loss.backward()
            if cfg.clip:
                torch.nn.utils.clip_grad_norm_(params, cfg.clip)
            optimizer.step()
            total += shown.detach() * len(idx)
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
            if cfg.patience is not None:
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


def fit_config(options: TrainOptions) -> FitConfig:
    """The loop's settings from the options (the torch trainers' common defaults: 50 epochs, lr 1e-3 on a
    cosine, 64 per minibatch, gradients clipped to norm 1)."""
    schedule = str(options.get("schedule", "cosine"))
    if schedule not in ("cosine", "constant"):
        raise ConfigError(None, f"option schedule must be cosine or constant, got {schedule!r}")
    clip = float(options.get("clip", 1.0))
    max_s = options.get("max_seconds", None)
    fc = FitConfig(epochs=int(options.get("epochs", 50)), batch=int(options.get("batch", 64)),
                   lr=float(options.get("lr", 1e-3)), schedule=schedule, clip=clip if clip > 0 else None,
                   patience=None if options.patience is None else int(options.patience),
                   max_seconds=None if max_s is None else float(max_s))
    if fc.epochs < 1 or fc.batch < 1 or (fc.patience is not None and fc.patience < 1):
        raise ConfigError(None, "epochs, batch and patience must be at least 1")
    return fc


def history_metrics(hist: dict[str, Any]) -> dict[str, Any]:
    """What a trainer's metrics keep of :func:`fit`'s history."""
    return {"train_loss": hist["train_loss"], "val_loss": hist["val_loss"], "epoch_seconds": hist["epoch_seconds"],
            "epochs_run": hist["epochs_run"], "best_epoch": hist["best_epoch"], "stopped": hist["stopped"],
            "kept": hist["kept"]}


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
