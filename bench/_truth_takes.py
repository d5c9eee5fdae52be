"""Helpers shared by the benchmarks that check the clean stage against generated ground truth
(``bench_spikes.py``, ``bench_clean_truth.py``, ``bench_fill_speed.py``)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_markerset
from gazepipe.model import Markers
from gazepipe.stages.clean.spikes import find_spikes
from gazepipe.stages.clean.stage import CleanParams


def generated_takes(folder: Path) -> Iterator[tuple[str, dict, Markers, list[list[int]]]]:
    """Each mocap take of a generated session: its name, truth arrays, markers as the pipeline reads them, and
    the markerset's segments as clusters of marker indices."""
    ms = load_markerset(folder / "markerset.toml")
    for c3d in sorted((folder / "mocap").glob("*.c3d")):
        markers = read_markers(c3d, default_units=ms.units)
        pos = {lab.split(":")[-1]: i for i, lab in enumerate(markers.labels)}
        clusters = [[pos[n] for n in s.markers if n in pos] for s in ms.segments]
        yield c3d.stem, dict(np.load(folder / "truth" / f"{c3d.stem}.npz")), markers, clusters


def spikes_as_clean_finds_them(xyz: np.ndarray, valid: np.ndarray, rate_hz: float,
                               clusters: Sequence[Sequence[int]], p: CleanParams | None = None) -> np.ndarray:
    """The (T, M) samples the clean stage removes as spikes, with its parameters (default: its defaults)."""
    p = p or CleanParams()
    return find_spikes(xyz, valid, rate_hz, clusters, residual_mm=p.spike_residual_mm,
                       step_factor=p.spike_step_factor, cluster_mm=p.spike_cluster_mm,
                       max_accel_mm_s2=p.spike_max_accel_mm_s2, min_step_mm=p.spike_min_step_mm,
                       max_piece_s=p.spike_max_piece_s)
