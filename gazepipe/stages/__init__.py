"""gazepipe's stages, one package each, in the order a take goes through them (SPEC §3).

``clean`` (spikes, gap filling, stabilisation, rests and crop) → ``frames`` (segment orientations in the
character frame) → ``sync`` (mocap and video claps, the clock map) → ``eyes`` (OpenFace gaze into the character
frame); ``face`` (Live Link Face tracks aligned) runs on face takes; ``build`` turns every take's tables into
the training datasets. :mod:`~gazepipe.stages.geometry` holds the vectors and rotations they all use.

Stages are pure functions on arrays and Arrow tables: they never read or write a file (``gazepipe.io`` does) and
know nothing of the engine that runs them (``gazepipe.dag`` wires them to it). A stage package's ``__init__``
says what the stage takes, gives and records in QC, and re-exports its entry point; the entry point is imported
on first use (:func:`lazy_exports`), so importing a stage's parameters to plan a run stays cheap.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, exports: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` (PEP 562) for the package ``package``: ``exports`` maps a name to the submodule
    (relative, e.g. ``".stage"``) that defines it, imported when the name is first asked for."""
    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(exports[name], package), name)
    return __getattr__
