"""`gazepipe fill`: the gap filler on any capture, with no session or markerset.

Rigid clusters are found from the data (markers whose mutual distances stay stable); every gap gets the
per-gap method choice of :func:`gazepipe.stages.clean.gapfill.fill_gaps`; gaps it cannot fill stay gaps.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from gazepipe.model import FILL_CODES, FILL_NAMES, Markers
from gazepipe.stages.clean.gapfill import (
    METHODS,
    FillResult,
    fastest_step,
    fill_gaps,
    find_rigid_clusters,
    take_statistics,
    unlabeled_markers,
)
from gazepipe.stages.clean.spikes import find_spikes
from gazepipe.stages.clean.stage import OWN_REFERENCES_MIN_S, CleanParams, unfilled_counts
from gazepipe.stages.clean.swaps import judged_columns, repair_swaps


def fill_capture(markers: Markers, *, max_gap_s: float = CleanParams.max_gap_s, methods: tuple[str, ...] = METHODS,
                 spikes: bool = False, swaps: bool = False, unlabeled: bool = False
                 ) -> tuple[Markers, dict[str, Any], np.ndarray]:
    """Fill the gaps of ``markers``; return the filled markers, a summary of what was filled, by method, and
    the (T, M) mask of measured samples changed other than by filling (taken out as spikes, or moved or taken out
    by a swap repair): the writers write those anew.

    With ``swaps``, label swaps are repaired first (:func:`~gazepipe.stages.clean.swaps.repair_swaps` against
    the file's own marker geometry, for a capture of at least
    :data:`~gazepipe.stages.clean.stage.OWN_REFERENCES_MIN_S`; the summary's ``swaps`` lists the stretches).

    Spikes (glitches off a marker's path or its rigid cluster, and implausible accelerations:
    :func:`~gazepipe.stages.clean.spikes.find_spikes` with the clean stage's defaults, clusters found from the
    data) are always counted; with ``spikes`` they become gaps before filling (else the measured samples are
    kept as they are). Either way they are no measure of how fast the capture moves: the fastest step a fill may
    take (:func:`~gazepipe.stages.clean.gapfill.step_limits`) comes from the other measured samples.

    A gap is filled only where its fill's error can be estimated; unlabeled trajectories
    (:func:`~gazepipe.stages.clean.gapfill.unlabeled_markers`) are left alone unless ``unlabeled``, and are no
    donors to the other markers' fills either way.

    Summary: ``samples`` per fill code over all markers (every sample once: they add up to frames × markers;
    ``swap_repaired`` counts the samples put back under their own names that stay measured, i.e. ``swaps``'s
    ``samples_repaired`` less its ``samples_removed_as_spikes``), ``gaps`` (total, filled, unfilled, and filled gaps
    at the start or end: filled from other markers only), ``unfilled_reasons`` (gaps per reason) and
    ``unfilled_by_reason`` (gaps and samples per reason), ``unlabeled`` (the unlabeled trajectories and whether
    they were filled), ``fastest_measured_step_mm``, ``clusters`` (the rigid clusters found, by label), per
    marker the samples filled by each method and those left unfilled, and ``gap_list``: every gap with its file
    frame numbers, method, weights, validation errors and estimated error.
    """
    changed = np.zeros(markers.valid.shape, dtype=bool)
    repaired = np.zeros(markers.valid.shape, dtype=bool)
    swap_summary: dict[str, Any] = {"looked_for": False, "stretches": []}
    if swaps and markers.n_frames >= OWN_REFERENCES_MIN_S * markers.rate_hz:
        # every named marker judged, as the clean stage judges them; unlabeled trajectories are no marker
        fixed = repair_swaps(markers.xyz, markers.valid, markers=judged_columns(markers.labels, None, ()))
        changed, repaired = fixed.repaired | fixed.removed, fixed.repaired
        swap_summary = {"looked_for": True, "samples_repaired": int(fixed.repaired.sum()),
                        "samples_removed": int(fixed.removed.sum()), "samples_removed_as_spikes": 0,
                        "stretches": [{"markers": [markers.labels[r.first], markers.labels[r.second]],
                                       "first_frame": markers.first_frame + r.start,
                                       "last_frame": markers.first_frame + r.stop - 1, "repaired": r.repaired}
                                      for r in fixed.records]}
        markers = dataclasses.replace(markers, xyz=fixed.xyz, valid=fixed.valid, warnings=list(markers.warnings))
    clusters = find_rigid_clusters(markers.xyz, markers.valid)
    spiky = find_spikes(markers.xyz, markers.valid, markers.rate_hz, clusters)
    n_spiky = spiky.sum(axis=0)
    valid = markers.valid & ~spiky if spikes else markers.valid
    if spikes:
        clusters = find_rigid_clusters(markers.xyz, valid)
    stray = unlabeled_markers(markers.labels)
    labelled = [i for i in range(markers.n_markers) if i not in set(stray)]
    xyz = np.where(valid[..., None], markers.xyz, np.nan)
    stats = take_statistics(xyz, valid & ~spiky)
    res = fill_gaps(xyz, valid, markers.rate_hz, clusters=clusters, max_gap_s=max_gap_s, methods=methods,
                    stats=stats, in_place=True, leave=() if unlabeled else stray,
                    groups=None if unlabeled or not stray else [labelled])
    code = np.array(res.fill_code)
    if swap_summary["looked_for"]:
        # a sample put back under its own name is measured, coded as the clean stage codes it; one that is then a
        # spike taken out is counted apart, so that the two counts agree
        kept = repaired & (code == FILL_CODES["measured"])
        code[kept] = FILL_CODES["swap_repaired"]
        swap_summary["samples_removed_as_spikes"] = int((repaired & ~kept).sum())
    unfilled = code == FILL_CODES["unfilled"]
    filled = dataclasses.replace(markers, xyz=np.where(unfilled[..., None], np.nan, res.xyz), valid=~unfilled,
                                 warnings=list(markers.warnings))
    summary = _summary(markers, res, code, max_gap_s)
    summary.update({
        "unlabeled": {"markers": [markers.labels[i] for i in stray], "filled": bool(unlabeled)},
        "fastest_measured_step_mm": fastest_step(xyz, valid & ~spiky),
        "spikes": {"samples": int(spiky.sum()), "removed": bool(spikes),
                   "per_marker": {markers.labels[i]: int(n) for i, n in enumerate(n_spiky) if n}},
        "swaps": swap_summary,
        "clusters": [[markers.labels[i] for i in c] for c in clusters],
    })
    summary["gap_list"] = summary.pop("gap_list")       # last: the long list after the facts
    return filled, summary, (spiky if spikes else np.zeros_like(spiky)) | changed


def _summary(markers: Markers, res: FillResult, code: np.ndarray, max_gap_s: float) -> dict[str, Any]:
    """The counts of a fill: samples per fill code, gaps filled and left (per reason), per marker, every gap."""
    counts = np.stack([(code == c).sum(axis=0) for c in range(len(FILL_NAMES))], axis=1)  # (M, codes)
    per_marker = {lab: {name: int(counts[i, c]) for c, name in enumerate(FILL_NAMES) if counts[i, c]}
                  for i, lab in enumerate(markers.labels)}
    n_gaps = len(res.gaps)
    n_t = markers.n_frames
    at_edge = [g.start == 0 or g.stop == n_t for g in res.gaps]
    by_reason = unfilled_counts(res.gaps)
    return {
        "frames": markers.n_frames, "markers": markers.n_markers, "rate_hz": markers.rate_hz,
        "first_frame": markers.first_frame, "max_gap_s": max_gap_s,
        "samples": {name: int(counts[:, c].sum()) for c, name in enumerate(FILL_NAMES)},
        "gaps": {"total": n_gaps, "filled": n_gaps - sum(v["gaps"] for v in by_reason.values()),
                 "unfilled": sum(v["gaps"] for v in by_reason.values()),
                 "edge_filled": sum(e and g.method != "unfilled" for g, e in zip(res.gaps, at_edge, strict=True))},
        "unfilled_reasons": {k: v["gaps"] for k, v in by_reason.items()},
        "unfilled_by_reason": by_reason,
        "per_marker": per_marker,
        "gap_list": [_gap_entry(markers, g, e) for g, e in zip(res.gaps, at_edge, strict=True)],
    }


def _gap_entry(markers: Markers, g: Any, at_edge: bool) -> dict[str, Any]:
    """One gap for the JSON summary: marker, file frame numbers (first, last), length, method, blend weights,
    validation errors (mm), the estimated error of its fill (mm; the one it was kept or refused on), whether it
    touches the start or end, and the reason when not filled as chosen."""
    return {
        "marker": markers.labels[g.marker], "first_frame": markers.first_frame + g.start,
        "last_frame": markers.first_frame + g.stop - 1, "frames": g.length, "method": g.method,
        "weights": {k: round(v, 4) for k, v in g.weights.items()},
        "validation_mm": {k: round(v, 3) for k, v in g.errors.items() if np.isfinite(v)},
        "error_mm": round(float(g.error_mm), 3) if np.isfinite(g.error_mm) else None,
        "at_edge": at_edge, "reason": g.reason,
    }
