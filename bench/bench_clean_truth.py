"""Gap filling as the clean stage runs it, on hostile generated captures, against their ground truth.

Sessions from ``gazepipe.synth`` with the hazards of real capture: ghost spikes (``--spikes`` per marker per
minute), 1–3 s occlusions of trunk and neck markers (``--long`` per take: inside the first rest, across the
crop's edges, anywhere) and dense interior gaps (``--gaps`` per marker per minute), at 30 Hz, for ``--seeds``
seeds. Each take goes through the clean stage's spike removal and gap filling with its default parameters
(:func:`gazepipe.stages.clean.spikes.find_spikes`, then :func:`gazepipe.stages.clean.gapfill.fill_gaps` with
``max_gap_s``, ``max_fill_error_mm`` and the markerset's segments as clusters). Printed: error of the filled
samples against the noise-free truth (mean, p95, max, mm) per gap length, the share of gap samples filled, the
share of the samples of the 1–3 s trunk and neck occlusions filled, how the estimated error (``fill_error_mm``)
compares with the real one, and the time per take.

With ``--bursts N`` every take also gets N occlusion bursts (30–80 % of one side's markers gone for 0.2–1.5 s).
With ``--still-gap LO,HI`` every gaze_shift take's root marker is lost for LO–HI s inside its (lengthened) final
rest (``SynthConfig.root_final_rest_gap_s``): longer than ``max_gap_s``, filled only as a still marker; those
gaps are also reported apart. ``--skeleton four``: markers on four segments in a y-up lab.
Per gap length, the share of filled samples whose real error exceeds twice the estimate plus 1 mm says how honest
the estimates are.

Usage: ``python bench/bench_clean_truth.py [--seeds 3] [--spikes 1] [--long 4] [--gaps 3] [--bursts 0]
[--still-gap 3,4] [--skeleton ten|four]``
"""

from __future__ import annotations

import argparse
import inspect
import tempfile
import time
from pathlib import Path

import numpy as np
from _truth_takes import generated_takes, spikes_as_clean_finds_them  # bench/_truth_takes.py

from gazepipe.io.session_toml import load_markerset
from gazepipe.stages.clean.gapfill import fill_gaps, find_gaps
from gazepipe.stages.clean.stage import CleanParams, _moving_groups
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.markers import LONG_GAP_SEGMENTS
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENT_MARKERS

BINS = ((1, 5), (6, 15), (16, 30), (31, 90), (91, 10_000))


def clean_fill(markers, clusters, p: CleanParams, ms):
    """Spikes removed, then gaps filled, as the clean stage does before stabilising (its groups of markers that
    move apart, and its still-marker rule where the filler has one)."""
    valid = markers.valid & np.isfinite(markers.xyz).all(axis=2)
    valid &= ~spikes_as_clean_finds_them(markers.xyz, valid, markers.rate_hz, clusters, p)
    pos = {lab.split(":")[-1]: i for i, lab in enumerate(markers.labels)}
    extra = ({"still_speed_mm_s": p.rest_speed_mm_s}
             if "still_speed_mm_s" in inspect.signature(fill_gaps).parameters else {})
    return fill_gaps(np.where(valid[..., None], markers.xyz, np.nan), valid, markers.rate_hz,
                     clusters=[c for c in clusters if len(c) >= 2], max_gap_s=p.max_gap_s,
                     methods=tuple(p.fill_methods), max_error_mm=p.max_fill_error_mm,
                     groups=_moving_groups(pos, ms), **extra), valid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--spikes", type=float, default=1.0)
    ap.add_argument("--long", type=int, default=4)
    ap.add_argument("--gaps", type=float, default=3.0)
    ap.add_argument("--bursts", type=int, default=0, help="occlusion bursts per take (SynthConfig.occlusion_bursts)")
    ap.add_argument("--still-gap", default="", metavar="LO,HI",
                    help="seconds of a root-marker gap inside every gaze_shift take's final rest "
                         "(SynthConfig.root_final_rest_gap_s; default none)")
    ap.add_argument("--skeleton", choices=("ten", "four"), default="ten")
    args = ap.parse_args()
    still = tuple(float(x) for x in args.still_gap.split(",")) if args.still_gap else None
    layout = {} if args.skeleton == "ten" else {"segments": FOUR_SEGMENTS, "up_axis": "y"}
    if still is not None:
        layout["root_final_rest_gap_s"] = still
    p = CleanParams()
    trunk_names = {n for s in LONG_GAP_SEGMENTS for n in SEGMENT_MARKERS[s]}
    per_bin = {b: [] for b in BINS}
    gap_samples = {b: [0, 0] for b in BINS}         # [samples, filled]
    long_trunk = [0, 0]
    over: list = [0, 0, [], []]                    # gaps over max_gap_s: samples, filled, real errors, estimates
    est_vs_real: list[tuple[float, float]] = []
    honest = {b: [0, 0] for b in BINS}             # [filled samples with an estimate, real > 2 x estimate + 1 mm]
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=45.0, head_camera=False,
                              face_takes=(), spikes_per_marker_min=args.spikes, long_gaps=args.long,
                              gaps_per_marker_min=args.gaps, occlusion_bursts=args.bursts, **layout)
            folder = generate_session(Path(tmp) / f"s{seed}", seed=seed, config=cfg)
            ms = load_markerset(folder / "markerset.toml")
            for _, truth, mk, clusters in generated_takes(folder):
                t0 = time.perf_counter()
                res, valid = clean_fill(mk, clusters, p, ms)
                times.append(time.perf_counter() - t0)
                true = truth["markers_true"].astype(np.float64)
                filled = ~valid & res.valid
                err = np.linalg.norm(res.xyz - true, axis=2)
                for m in range(mk.n_markers):
                    for s, e in find_gaps(valid[:, m]):
                        b = next(b for b in BINS if b[0] <= e - s <= b[1])
                        gap_samples[b][0] += e - s
                        gap_samples[b][1] += int(filled[s:e, m].sum())
                        per_bin[b].extend(err[s:e, m][filled[s:e, m]].tolist())
                        est, real = res.error_mm[s:e, m][filled[s:e, m]], err[s:e, m][filled[s:e, m]]
                        est_vs_real.extend(zip(est.tolist(), real.tolist(), strict=True))
                        known = np.isfinite(est)
                        honest[b][0] += int(known.sum())
                        honest[b][1] += int((real[known] > 2.0 * est[known] + 1.0).sum())
                        if mk.labels[m] in trunk_names and e - s >= mk.rate_hz * 1.0 - 1:
                            long_trunk[0] += e - s
                            long_trunk[1] += int(filled[s:e, m].sum())
                        if (e - s) / mk.rate_hz > p.max_gap_s:
                            over[0] += e - s
                            over[1] += int(filled[s:e, m].sum())
                            over[2].extend(err[s:e, m][filled[s:e, m]].tolist())
                            over[3].extend(est[np.isfinite(est)].tolist())
    print(f"hazards: spikes {args.spikes:g}/marker/min, {args.long} trunk/neck occlusions of 1-3 s per take, "
          f"{args.gaps:g} gaps/marker/min, {args.bursts} occlusion bursts per take"
          + (f", a {still[0]:g}-{still[1]:g} s root gap in each gaze shift's final rest" if still else "")
          + f"; {args.skeleton} segments; {args.seeds} seeds; max_gap_s {p.max_gap_s:g}, "
          f"max_fill_error_mm {p.max_fill_error_mm:g}")
    print(f"{'gap frames':>12} {'samples':>8} {'filled':>7} {'mean':>6} {'p95':>6} {'max':>7}  (error of filled samples, "
          f"mm)  real > 2 x estimate + 1 mm")
    everything = []
    for b in BINS:
        e = np.array(per_bin[b])
        everything.extend(per_bin[b])
        n, f = gap_samples[b]
        label = f"{b[0]}-{b[1]}" if b[1] < 10_000 else f">{b[0] - 1}"
        if len(e):
            h = honest[b]
            print(f"{label:>12} {n:8d} {100 * f / max(n, 1):6.1f}% {e.mean():6.2f} {np.percentile(e, 95):6.2f} "
                  f"{e.max():7.2f}  {100 * h[1] / max(h[0], 1):5.1f} % of {h[0]}")
        else:
            print(f"{label:>12} {n:8d} {100 * f / max(n, 1):6.1f}%")
    e = np.array(everything)
    print(f"{'all':>12} {sum(v[0] for v in gap_samples.values()):8d} "
          f"{100 * sum(v[1] for v in gap_samples.values()) / max(sum(v[0] for v in gap_samples.values()), 1):6.1f}% "
          f"{e.mean():6.2f} {np.percentile(e, 95):6.2f} {e.max():7.2f}")
    print(f"samples of 1-3 s trunk/neck gaps filled: {long_trunk[1]} of {long_trunk[0]} "
          f"({100 * long_trunk[1] / max(long_trunk[0], 1):.1f} %)")
    if over[0]:
        o_err, o_est = np.array(over[2]), np.array(over[3])
        print(f"gaps over max_gap_s: {over[1]} of {over[0]} samples filled ({100 * over[1] / over[0]:.1f} %)"
              + (f"; error mean {o_err.mean():.2f}, max {o_err.max():.2f} mm; estimate mean {o_est.mean():.2f} mm"
                 if o_err.size else ""))
    ev = np.array(est_vs_real)
    known = np.isfinite(ev[:, 0])
    if known.any():
        ratio = ev[known, 1] / np.maximum(ev[known, 0], 1e-6)
        print(f"estimated error known for {100 * known.mean():.1f} % of filled samples; real / estimated: "
              f"median {np.median(ratio):.2f}, p95 {np.percentile(ratio, 95):.2f}")
    print(f"spike removal and gap filling per take: median {np.median(times):.2f} s, max {np.max(times):.2f} s")


if __name__ == "__main__":
    main()
