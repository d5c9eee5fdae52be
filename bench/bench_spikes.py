"""Spike removal against ground truth: how many ghost spikes the clean stage takes out, and how many other samples.

Sessions from ``gazepipe.synth`` with ghost-reflection spikes (15–50 mm, 1–2 frames, on any marker: the root
segment's, the head's and the target's included; ``--per-min`` per marker per minute), at 30 Hz and 120 Hz, for
``--seeds`` seeds. Every take's capture is read as the pipeline reads it and spikes are found as the clean stage
finds them (:func:`gazepipe.stages.clean.spikes.find_spikes`, the markerset's segments as clusters, the clean
stage's default thresholds). Printed per rate: spike samples removed (recall) and the share of the other measured
samples removed (false positives), with the markers that had misses; then, on the real C3D files of the corpus
(no truth: every flagged sample is counted), the share flagged; then the time per take.

Usage: ``python bench/bench_spikes.py [--seeds 3] [--per-min 1.0]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from _truth_takes import generated_takes, spikes_as_clean_finds_them  # bench/_truth_takes.py

from gazepipe.io.capture import read_markers
from gazepipe.stages.clean.gapfill import find_rigid_clusters
from gazepipe.synth import SynthConfig, generate_session

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "tests" / "data" / "corpus" / "c3d"


def session_figures(folder: Path) -> dict:
    out = {"spikes": 0, "caught": 0, "other": 0, "flagged": 0, "missed": Counter(), "times": []}
    for _, truth, markers, clusters in generated_takes(folder):
        t0 = time.perf_counter()
        flagged = spikes_as_clean_finds_them(markers.xyz, markers.valid, markers.rate_hz, clusters)
        out["times"].append(time.perf_counter() - t0)
        spiked = truth["spike_mask"]
        measured = ~truth["gap_mask"]
        out["spikes"] += int(spiked.sum())
        out["caught"] += int((flagged & spiked).sum())
        out["other"] += int((measured & ~spiked).sum())
        out["flagged"] += int((flagged & measured & ~spiked).sum())
        out["missed"].update(markers.labels[m] for m in np.nonzero(spiked & ~flagged)[1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--per-min", type=float, default=1.0, help="spikes per marker per minute")
    args = ap.parse_args()
    print(f"ghost spikes 15-50 mm, 1-2 frames, {args.per_min:g} per marker per minute; seeds 0..{args.seeds - 1}")
    print(f"{'rate':>8} {'spike samples':>14} {'removed':>9} {'other samples':>14} {'flagged':>9}  missed on")
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (30000.0 / 1001.0, 120.0):
            tot = {"spikes": 0, "caught": 0, "other": 0, "flagged": 0, "missed": Counter()}
            for seed in range(args.seeds):
                cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=30.0, head_camera=False,
                                  face_takes=(), spikes_per_marker_min=args.per_min, rate_hz=rate)
                folder = generate_session(Path(tmp) / f"s{rate:.0f}_{seed}", seed=seed, config=cfg)
                got = session_figures(folder)
                for k in ("spikes", "caught", "other", "flagged"):
                    tot[k] += got[k]
                tot["missed"].update(got["missed"])
                times.extend(got["times"])
            print(f"{rate:6.2f}Hz {tot['spikes']:14d} {100 * tot['caught'] / max(tot['spikes'], 1):8.1f}% "
                  f"{tot['other']:14d} {100 * tot['flagged'] / max(tot['other'], 1):8.4f}%  "
                  f"{dict(tot['missed'].most_common(6))}")
    print("\nreal C3D files (no truth: every removed sample counted)")
    for path in sorted(CORPUS.glob("*.c3d")):
        markers = read_markers(path)
        valid = markers.valid & np.isfinite(markers.xyz).all(axis=2)
        t0 = time.perf_counter()
        flagged = spikes_as_clean_finds_them(markers.xyz, markers.valid, markers.rate_hz,
                                             find_rigid_clusters(markers.xyz, valid))
        dt = time.perf_counter() - t0
        print(f"  {path.name:34s} {markers.rate_hz:6.1f} Hz  {int(flagged.sum()):5d} of {int(valid.sum()):7d} "
              f"measured samples ({100 * flagged.sum() / max(valid.sum(), 1):.3f} %), {1000 * dt:.0f} ms")
    print(f"\nspike search per generated take: median {1000 * np.median(times):.1f} ms, "
          f"max {1000 * np.max(times):.1f} ms")


if __name__ == "__main__":
    main()
