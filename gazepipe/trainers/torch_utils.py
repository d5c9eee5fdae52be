"""Shared plumbing of the PyTorch trainers: the lazy import, a deterministic session, minibatches, saving.

Only the torch trainers import this module, and it imports torch only inside its functions.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from gazepipe.errors import ConfigError


def require_torch():
    """The ``torch`` module, or a one-line :class:`ConfigError` (exit 2) naming the extra to install."""
    try:
        import torch
    except ImportError:
        raise ConfigError(None, "this trainer needs PyTorch: pip install 'gazepipe[torch]'") from None
    return torch


@contextlib.contextmanager
def deterministic(seed: int, threads: int | None = None) -> Iterator[Any]:
    """Seed torch, ask for deterministic algorithms and optionally fix the thread count; restore both after."""
    torch = require_torch()
    was_det = torch.are_deterministic_algorithms_enabled()
    was_threads = torch.get_num_threads()
    torch.manual_seed(int(seed))
    torch.use_deterministic_algorithms(True, warn_only=True)
    if threads:
        torch.set_num_threads(int(threads))
    try:
        yield torch
    finally:
        torch.use_deterministic_algorithms(was_det)
        torch.set_num_threads(was_threads)


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
    """``torch.save`` bytes of a module's state_dict."""
    torch = require_torch()
    buf = io.BytesIO()
    torch.save(module.state_dict(), buf)
    return buf.getvalue()


def load_state(module, path: Path) -> None:
    torch = require_torch()
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise ConfigError(path, f"not readable torch weights ({' '.join(str(exc).split())[:200]})") from None
    module.load_state_dict(state)


def l2_penalty(module):
    """Σ w² over the module's weight matrices (biases excluded), Klein's L² term."""
    return sum((p * p).sum() for name, p in module.named_parameters() if "weight" in name)


def pick_split(data, preferred: str = "val") -> str | None:
    """The evaluation split: ``preferred`` when it has rows, else ``test``, else ``None``."""
    for s in (preferred, "test"):
        if data.table(split=s).num_rows:
            return s
    return None
