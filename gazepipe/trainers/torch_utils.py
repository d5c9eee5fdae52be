"""Shared plumbing of the PyTorch trainers: the lazy import, devices, a deterministic session, data on the
device, saving and loading weights.

Only the torch trainers import this module, and it imports torch only inside its functions.

Determinism: on the CPU the same seed, data and thread count give the same weights byte for byte. On a CUDA GPU
:func:`deterministic` asks torch for its deterministic algorithms (``torch.use_deterministic_algorithms``, with
``CUBLAS_WORKSPACE_CONFIG=:4096:8`` for cuBLAS and cuDNN's deterministic mode); the trainers use only the cell
modules (``GRUCell``, ``LSTMCell``), linear layers and dropout, which have deterministic CUDA kernels, and not
cuDNN's fused ``nn.GRU`` / ``nn.LSTM``, whose results torch documents as not reproducible on some cuDNN and CUDA
versions. An operation without a deterministic kernel gives a warning (not an error), and the trainers record it
in their metrics (``nondeterministic``). GPU weights differ from CPU ones (other kernels, other rounding).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import ConfigError

#: what ``--device`` accepts
DEVICE_RE = re.compile(r"^(auto|cpu|cuda|cuda:\d+)$")
#: keep a training set on the GPU whole when it is at most this share of the free GPU memory
RESIDENT_SHARE = 0.5


def require_torch():
    """The ``torch`` module, or a one-line :class:`ConfigError` (exit 2) naming the extra to install."""
    try:
        import torch
    except ImportError:
        raise ConfigError(None, "this trainer needs PyTorch: pip install 'gazepipe[torch]'") from None
    return torch


def resolve_device(spec: str | None):
    """The ``torch.device`` for ``--device``: ``auto`` (or ``None``) is the first CUDA GPU when torch sees one,
    else the CPU; ``cpu``; ``cuda``; ``cuda:N``. A GPU asked for but not there is a one-line
    :class:`ConfigError` (exit 2)."""
    torch = require_torch()
    spec = "auto" if spec is None else str(spec).strip().lower()
    if not DEVICE_RE.match(spec):
        raise ConfigError(None, f"--device {spec!r}: expected auto, cpu, cuda or cuda:N")
    if spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if spec == "cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        why = " (this PyTorch is built without CUDA)" if torch.version.cuda is None else ""
        raise ConfigError(None, f"--device {spec}: PyTorch sees no CUDA GPU on this machine{why}; use --device cpu "
                                "or auto")
    index = int(spec.split(":")[1]) if ":" in spec else 0
    count = torch.cuda.device_count()
    if index >= count:
        raise ConfigError(None, f"--device {spec}: PyTorch sees {count} CUDA GPU(s), cuda:0 to cuda:{count - 1}")
    return torch.device("cuda", index)


def device_name(device) -> str:
    """A readable name: ``cpu (N threads)`` or ``cuda:0 (NVIDIA H100 80GB HBM3)``."""
    torch = require_torch()
    if device.type == "cuda":
        index = device.index if device.index is not None else torch.cuda.current_device()
        return f"cuda:{index} ({torch.cuda.get_device_name(index)})"
    n = torch.get_num_threads()
    return f"cpu ({n} thread{'' if n == 1 else 's'})"


class Determinism:
    """What :func:`deterministic` saw: ``nondeterministic`` lists the operations torch warned have no
    deterministic implementation on this device (empty when every one had)."""

    def __init__(self) -> None:
        self.nondeterministic: list[str] = []


@contextlib.contextmanager
def deterministic(seed: int, threads: int | None = None, device: Any = None) -> Iterator[Any]:
    """Seed torch (and CUDA), ask for deterministic algorithms, fix the thread count when given; restore the
    global settings after. Yields ``(torch, Determinism)``."""
    torch = require_torch()
    on_gpu = device is not None and getattr(device, "type", "cpu") == "cuda"
    if on_gpu:   # read when cuBLAS creates its handle: before the first matrix product on the GPU
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    was_det = torch.are_deterministic_algorithms_enabled()
    was_warn = torch.is_deterministic_algorithms_warn_only_enabled()
    was_threads = torch.get_num_threads()
    was_cudnn = (torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark)
    torch.manual_seed(int(seed))   # seeds every CUDA device too
    torch.use_deterministic_algorithms(True, warn_only=True)
    torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False
    if threads:
        torch.set_num_threads(int(threads))
    seen = Determinism()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield torch, seen
        for w in caught:
            text = str(w.message)
            if "deterministic" in text:
                seen.nondeterministic.append(" ".join(text.split())[:200])
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    finally:
        torch.use_deterministic_algorithms(was_det, warn_only=was_warn)
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = was_cudnn
        torch.set_num_threads(was_threads)


class DeviceArrays:
    """Training arrays for one device: moved there whole once when they fit (at most :data:`RESIDENT_SHARE`
    of the free GPU memory; always on the CPU), else kept in pinned host memory and moved a minibatch at a
    time. Never a sample at a time."""

    def __init__(self, arrays: dict[str, np.ndarray], device) -> None:
        torch = require_torch()
        self.device = device
        host = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in arrays.items()}
        size = sum(t.numel() * t.element_size() for t in host.values())
        self.resident = device.type != "cuda" or size <= RESIDENT_SHARE * torch.cuda.mem_get_info(device)[0]
        if self.resident:
            self.tensors = {k: t.to(device) for k, t in host.items()}
        else:
            self.tensors = {k: t.pin_memory() for k, t in host.items()}
        self.n = len(next(iter(arrays.values()))) if arrays else 0

    def batch(self, idx: np.ndarray) -> dict[str, Any]:
        """The rows ``idx`` (a numpy index array) of every array, as tensors on the device."""
        torch = require_torch()
        if self.resident:
            i = torch.as_tensor(idx, device=self.device)
            return {k: t.index_select(0, i) for k, t in self.tensors.items()}
        i = torch.as_tensor(idx)
        return {k: t.index_select(0, i).to(self.device, non_blocking=True) for k, t in self.tensors.items()}


def batches(n: int, batch: int, rng: np.random.Generator | None) -> Iterator[np.ndarray]:
    """Index arrays of minibatches over ``n`` items, shuffled by ``rng`` (in order when ``None``)."""
    order = rng.permutation(n) if rng is not None else np.arange(n)
    for i in range(0, n, batch):
        yield order[i:i + batch]


def subsample(n: int, limit: int | None, rng: np.random.Generator) -> np.ndarray:
    """Indices of at most ``limit`` of ``n`` items (a seeded random subset, sorted), all when ``limit`` is None."""
    if limit is None or limit >= n:
        return np.arange(n)
    return np.sort(rng.choice(n, size=int(limit), replace=False))


def state_bytes(module) -> bytes:
    """``torch.save`` bytes of a module's state_dict, every tensor on the CPU (a GPU-trained model loads
    anywhere)."""
    torch = require_torch()
    buf = io.BytesIO()
    torch.save({k: v.detach().cpu() for k, v in module.state_dict().items()}, buf)
    return buf.getvalue()


def save_trained(out_dir: str | Path, trainer: str, config: dict[str, Any], model, metrics: dict[str, Any],
                 data: Any, weights: str, nondeterministic: list[str]) -> None:
    """Write a trained model: its weights (``weights``, CPU tensors) and ``model.json``.

    ``metrics`` gets ``nondeterministic`` (the ops torch warned about); ``model.json`` leaves out the epoch
    timings, so that the same seed writes the same bytes.
    """
    from gazepipe.trainers.base import save_model_json, write_atomic

    out = Path(out_dir)
    write_atomic(out / weights, state_bytes(model))
    metrics["nondeterministic"] = nondeterministic
    saved = {k: v for k, v in metrics.items() if k != "epoch_seconds"}
    save_model_json(out, trainer, config, saved, data, weights)


def load_state(module, path: Path) -> None:
    """Load weights saved by :func:`state_bytes` into ``module`` (on the CPU)."""
    torch = require_torch()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        module.load_state_dict(state)
    except (OSError, RuntimeError) as exc:
        raise ConfigError(path, f"not readable torch weights ({' '.join(str(exc).split())[:200]})") from None


def l2_penalty(module):
    """Σ w² over the module's weight matrices (biases excluded), Klein's L² term."""
    return sum((p * p).sum() for name, p in module.named_parameters() if "weight" in name)


def pick_split(data, preferred: str = "val") -> str | None:
    """The evaluation split: ``preferred`` when it has rows, else ``test``, else ``None``."""
    for s in (preferred, "test"):
        if data.table(split=s).num_rows:
            return s
    return None
