"""gazepipe's DAG: its stages and datasets, registered with the engine (:mod:`gazepipe.pipeline`) on import.

- :mod:`.takes`: the take stages in dependency order (ingest → clean → frames; ingest → sync; frames and sync →
  eyes; face), each wiring a pure function of :mod:`gazepipe.stages` to the files it reads through
  :mod:`gazepipe.io` and the tables it writes (:mod:`gazepipe.schemas`), and the table store the engine writes
  and reads them with;
- :mod:`.builds`: the training datasets, which stages' tables each reads, and the ``build`` parameters.

Import this package (the command line does) before using the engine. :func:`run_pipeline` is the engine's, here
with gazepipe's stages and datasets registered; :func:`collect_status` is the engine's with gazepipe's session
loader.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from gazepipe.dag import builds, takes  # noqa: F401  (registers the stages, then the datasets)
from gazepipe.pipeline import status
from gazepipe.pipeline.engine import run_pipeline

__all__ = ["collect_status", "run_pipeline"]


def collect_status(out: Path, params: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """The state of every unit in the output folder ``out`` (:func:`gazepipe.pipeline.status.collect_status`),
    its sessions read again from their ``session.toml``."""
    from gazepipe.io.session_toml import load_session

    return status.collect_status(out, load_session, params)
