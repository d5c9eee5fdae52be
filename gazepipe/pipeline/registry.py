"""The stage registry: what each stage is, what it reads, which parameters it uses.

A stage runs once per take (a *unit of work*). Its ``run`` receives a :class:`UnitContext` (the take, its
parameters, and a loader for upstream tables) and returns a :class:`UnitResult` (Arrow tables to write and a QC
record); the engine does all reading and writing, so the functions in :mod:`gazepipe.stages` stay pure.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from gazepipe.model import Session, Take


@dataclass
class UnitResult:
    """What a unit produced: tables by name (each with the schema it must match) and a JSON-able QC record."""

    tables: dict[str, tuple[pa.Table, pa.Schema]] = field(default_factory=dict)
    qc: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


@dataclass
class UnitContext:
    """Everything a stage may use while running on one take."""

    session: Session
    take: Take
    params: dict[str, Any]
    out_dir: Path
    loader: Callable[[str, str, str], pa.Table]
    all_params: dict[str, Any] = field(default_factory=dict)

    def params_of(self, stage: str) -> dict[str, Any]:
        """Another stage's parameter values (defaults overridden), for a stage that repeats its work."""
        st = get(stage)
        return {k: self.all_params.get(f"{stage}.{k}", v) for k, v in st.params.items()}

    def load(self, table: str, take_id: str | None = None) -> pa.Table:
        """Read an upstream table of this take (or of ``take_id`` in the same session), schema-checked."""
        return self.loader(self.session.id, take_id or self.take.id, table)


@dataclass(frozen=True)
class Stage:
    """A registered stage.

    Attributes
    ----------
    name, version : bump ``version`` whenever the stage's output for the same inputs changes.
    requires : upstream stages (same take) whose outputs it loads.
    params : the parameters it uses with their defaults; part of its fingerprint.
    outputs : table names it writes under ``takes/<session>/<take>/``.
    applies : which takes it runs on.
    sources : the raw input files it reads (content-hashed into its fingerprint).
    run : the work itself.
    """

    name: str
    version: str
    requires: tuple[str, ...]
    params: Mapping[str, Any]
    outputs: tuple[str, ...]
    applies: Callable[[Session, Take], bool]
    sources: Callable[[Session, Take], Sequence[str]]
    run: Callable[[UnitContext], UnitResult]
    help: str = ""


_STAGES: dict[str, Stage] = {}


def register(stage: Stage) -> Stage:
    if stage.name in _STAGES:
        raise ValueError(f"stage {stage.name} registered twice")
    for up in stage.requires:
        if up not in _STAGES:
            raise ValueError(f"stage {stage.name} requires unknown stage {up}")
    _STAGES[stage.name] = stage
    return stage


def stages() -> list[Stage]:
    """Registered stages in dependency order (registration order)."""
    _ensure_loaded()
    return list(_STAGES.values())


def get(name: str) -> Stage:
    _ensure_loaded()
    return _STAGES[name]


def upto(name: str) -> list[Stage]:
    """``name`` and every stage it depends on, in order."""
    _ensure_loaded()
    need = {name}
    for st in reversed(list(_STAGES.values())):
        if st.name in need:
            need.update(st.requires)
    return [st for st in _STAGES.values() if st.name in need]


def default_params() -> dict[str, Any]:
    """Every parameter as ``"stage.param": default`` (the take stages', then the dataset build's)."""
    from gazepipe.pipeline.datasets import default_build_params

    out = {f"{st.name}.{k}": v for st in stages() for k, v in st.params.items()}
    out.update(default_build_params())
    return out


def _ensure_loaded() -> None:
    if not _STAGES:
        import gazepipe.pipeline.steps  # noqa: F401  (registers the built-in stages)
