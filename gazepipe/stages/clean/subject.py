"""The subject's marker geometry, pooled from every subject capture of a session, that each take's label swaps
are judged against (SPEC §3.2 step 1; :func:`gazepipe.stages.clean.swaps.pooled_references`).

Pure: captures in (their markers, already named as the markerset names them), references out; the session stage
``subject_geometry`` reads the captures and stores the references as named arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence

import numpy as np

from gazepipe.model import Markers
from gazepipe.stages.clean.swaps import (
    References,
    SubjectReferences,
    even_rows,
    judged_columns,
    pooled_references,
)

#: frames of each take kept for the subject's references (they sample the stack evenly again)
REFERENCE_FRAMES_PER_TAKE = 2000


def pool_subject(captures: Iterable[tuple[str, Markers]], target: str | None, clapper: Sequence[str]
                 ) -> tuple[SubjectReferences | None, list[str]]:
    """The subject's references from evenly spread frames of each capture ``(take id, markers)`` (None when there
    is none), and the takes used, in order. Every marker the captures carry is judged, listed in the markerset or
    not, but the ``target``, the ``clapper`` and unlabeled trajectories (:func:`judged_columns`)."""
    pooled, used = [], []
    for take, raw in captures:
        rows = even_rows(raw.n_frames, REFERENCE_FRAMES_PER_TAKE)
        pooled.append((raw.labels, raw.xyz[rows], raw.valid[rows]))
        used.append(take)
    if not pooled:
        return None, used
    judged = {labels[i] for labels, _, _ in pooled for i in judged_columns(labels, target, clapper)}
    return pooled_references(pooled, markers=judged), used


def references_arrays(refs: SubjectReferences | None) -> dict[str, np.ndarray]:
    """The references' arrays by field name (those that are set), for the ``subject_geometry`` table."""
    if refs is None:
        return {}
    out = {f.name: getattr(refs.references, f.name) for f in dataclasses.fields(refs.references)}
    return {k: v for k, v in out.items() if v is not None}


def references_from(labels: Sequence[str], arrays: dict[str, np.ndarray]) -> SubjectReferences | None:
    """The subject's references from their ``labels`` and arrays (:func:`references_arrays`); None without
    labels (no capture could be read)."""
    if not labels:
        return None
    return SubjectReferences(tuple(labels), References(**arrays))
