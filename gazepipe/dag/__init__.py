"""gazepipe's DAG: its stages and datasets, declared for the engine (:mod:`gazepipe.pipeline`).

- :mod:`.takes`: the take stages in dependency order (ingest → clean → frames; ingest → sync; frames and sync →
  eyes; face) and the session stages they read, as declarations; their runs (:mod:`.nodes`) wire a pure function
  of :mod:`gazepipe.stages` to the files it reads through :mod:`gazepipe.io` and the tables it writes
  (:mod:`gazepipe.schemas`);
- :mod:`.store`: the table store the engine writes and reads them with, and its look at a raw input;
- :mod:`.builds`: the training datasets, which stages' tables each reads, and the ``build`` parameters.

Importing this package registers nothing: :func:`declare` hands the declarations to the engine (once per process).
:func:`run_pipeline` and :func:`collect_status` are the engine's, called after :func:`declare`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

from gazepipe.dag import builds, takes
from gazepipe.dag.store import TABLE_STORE, check_source
from gazepipe.pipeline import registry, status
from gazepipe.pipeline.engine import run_pipeline as _run_pipeline

__all__ = ["collect_status", "declare", "run_pipeline"]


def declare() -> None:
    """Register gazepipe's table store, source check, session stages, take stages, ``build`` parameters,
    per-take dataset stages and datasets with the engine, in that order; a second call does nothing."""
    if registry.declared(__name__):
        return
    registry.set_table_store(TABLE_STORE)
    registry.set_source_check(check_source)
    for session_stage in takes.SESSION_STAGES:   # first: take stages read their tables
        registry.register_session_stage(session_stage)
    for stage in takes.TAKE_STAGES:
        registry.register(stage)
    for group in builds.PARAM_GROUPS:
        registry.register_params(group)
    for stage in builds.ROW_STAGES:
        registry.register(stage)
    for dataset in builds.DATASET_DECLARATIONS:
        registry.register_dataset(dataset)
    registry.declared_by(__name__)


P = ParamSpec("P")
R = TypeVar("R")


def _declared(fn: Callable[P, R]) -> Callable[P, R]:
    """``fn`` (an engine entry point) called with gazepipe's stages and datasets declared first; the same
    signature, so its callers' arguments stay checked."""

    @functools.wraps(fn)
    def with_declarations(*args: P.args, **kw: P.kwargs) -> R:
        declare()
        return fn(*args, **kw)

    return with_declarations


#: :func:`gazepipe.pipeline.engine.run_pipeline` with gazepipe's stages and datasets declared
run_pipeline = _declared(_run_pipeline)


def collect_status(out: Path, params: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The state of every unit in the output folder ``out`` (:func:`gazepipe.pipeline.status.collect_status`),
    its sessions read again from their ``session.toml``."""
    from gazepipe.io.session_toml import load_session

    declare()
    return status.collect_status(out, load_session, params)
