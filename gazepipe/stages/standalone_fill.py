"""`gazepipe fill`: the gap filler on any capture, with no session or markerset.

Rigid clusters are found from the data (markers whose mutual distances stay stable); every gap gets the
per-gap method choice of :func:`gazepipe.stages.gapfill.fill_gaps`; gaps it cannot fill stay gaps.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from gazepipe.model import FILL_CODES, FILL_NAMES, Markers
from gazepipe.stages.gapfill import METHODS, fill_gaps, find_rigid_clusters


def fill_capture(markers: Markers, *, max_gap_s: float = 1.0,
                 methods: tuple[str, ...] = METHODS) -> tuple[Markers, dict[str, Any]]:
    """Fill the gaps of ``markers``; return the filled markers and a summary of what was filled, by method.

    Summary: ``samples`` per fill code over all markers, ``gaps`` (total, filled, unfilled), ``clusters`` (the
    rigid clusters found, by label), and per marker the samples filled by each method and those left unfilled.
    """
    clusters = find_rigid_clusters(markers.xyz, markers.valid)
    res = fill_gaps(markers.xyz, markers.valid, markers.rate_hz, clusters=clusters, max_gap_s=max_gap_s,
                    methods=methods)
    code = np.asarray(res.fill_code)
    unfilled = code == FILL_CODES["unfilled"]
    filled = dataclasses.replace(markers, xyz=np.where(unfilled[..., None], np.nan, res.xyz), valid=~unfilled,
                                 warnings=list(markers.warnings))
    counts = np.stack([(code == c).sum(axis=0) for c in range(len(FILL_NAMES))], axis=1)  # (M, codes)
    per_marker = {lab: {name: int(counts[i, c]) for c, name in enumerate(FILL_NAMES) if counts[i, c]}
                  for i, lab in enumerate(markers.labels)}
    n_gaps = len(res.gaps)
    n_unfilled = sum(g.method == "unfilled" for g in res.gaps)
    summary = {
        "frames": markers.n_frames, "markers": markers.n_markers, "rate_hz": markers.rate_hz,
        "max_gap_s": max_gap_s,
        "samples": {name: int(counts[:, c].sum()) for c, name in enumerate(FILL_NAMES)},
        "gaps": {"total": n_gaps, "filled": n_gaps - n_unfilled, "unfilled": n_unfilled},
        "clusters": [[markers.labels[i] for i in c] for c in clusters],
        "per_marker": per_marker,
    }
    return filled, summary
