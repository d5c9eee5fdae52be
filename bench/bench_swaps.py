"""Label-swap repair against the generator's truth (SPEC §3.2 step 1, :mod:`gazepipe.stages.clean.swaps`).

Generates sessions with the ``label_swaps`` hazard (three swaps per mocap take, with spikes, long gaps and
occlusions) for several seeds and both skeletons, and runs :func:`~gazepipe.stages.clean.swaps.repair_swaps`
on every mocap take twice: with the take's own references and with the subject's, pooled from every take of the
session (:func:`~gazepipe.stages.clean.swaps.pooled_references`, what the clean stage uses). Prints, per seed,
skeleton and reference source: the samples written under a wrong name, the share of them now under the right
name or removed, the samples still wrong (more than 10 mm from the truth of the name they carry, spikes aside),
the samples made wrong (wrong after and not before, a name that had no sample given a wrong one included,
or right before and moved away or removed after) and the CPU time per take. With ``--bursts N`` every mocap
take also gets N occlusion bursts (``SynthConfig.occlusion_bursts``: 30-80 % of the subject's markers, on one
side, gone for 0.2-1.5 s), which hide the references that prove a swap.

Usage: ``PYTHONPATH=. python bench/bench_swaps.py [--seeds 0,1,2] [--swaps 3] [--bursts 0]``
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from gazepipe.io.capture import read_markers
from gazepipe.stages.clean.swaps import pooled_references, repair_swaps
from gazepipe.synth.session import SynthConfig, generate_session, sample_config
from gazepipe.synth.skeleton import CLAPPER_MARKERS, FOUR_SEGMENTS, SEGMENTS, TARGET_MARKER

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "bench" / "_work" / "swaps"
#: a sample more than this from the truth of the name it carries is wrong (swapped markers are 50-200 mm apart)
WRONG_MM = 10.0


def session(seed: int, skeleton: str, swaps: int, bursts: int = 0) -> Path:
    folder = WORK / (f"seed{seed}-{skeleton}-{swaps}" + (f"-b{bursts}" if bursts else ""))
    if not (folder / "session.toml").exists():
        base = sample_config()
        cfg: SynthConfig = replace(base, head_camera=False, face_takes=(), label_swaps=swaps,
                                   spikes_per_marker_min=1.0, long_gaps=2, gaps_per_marker_min=1.0,
                                   occlusion_bursts=bursts,
                                   segments=FOUR_SEGMENTS if skeleton == "four" else SEGMENTS)
        generate_session(folder, seed, cfg)
    return folder


def body_columns(labels: list[str]) -> list[int]:
    return [i for i, lab in enumerate(labels) if lab != TARGET_MARKER and lab not in CLAPPER_MARKERS]


def evaluate(folder: Path) -> dict[str, dict[str, float]]:
    takes = {c.stem: read_markers(c) for c in sorted((folder / "mocap").glob("*.c3d"))}
    pooled = pooled_references([(m.labels, m.xyz, m.valid) for m in takes.values()],
                               markers={lab for m in takes.values() for lab in m.labels} - {TARGET_MARKER,
                                                                                           *CLAPPER_MARKERS})
    out: dict[str, dict[str, float]] = {}
    for source in ("own", "session"):
        tot = dict(swapped=0, handled=0, still_wrong=0, made_wrong=0, cpu_s=0.0, takes=0)
        for name, mk in takes.items():
            truth = np.load(folder / "truth" / f"{name}.npz")
            if "swap_mask" not in truth:
                continue
            true_xyz, swapped, spiked = truth["markers_true"], truth["swap_mask"], truth["spike_mask"]
            refs = pooled.for_labels(mk.labels) if source == "session" else None
            t0 = time.process_time()
            res = repair_swaps(mk.xyz, mk.valid, references=refs, markers=body_columns(mk.labels))
            tot["cpu_s"] += time.process_time() - t0
            with np.errstate(invalid="ignore"):
                before = mk.valid & (np.linalg.norm(mk.xyz - true_xyz, axis=2) >= WRONG_MM) & ~spiked
                after = res.valid & (np.linalg.norm(res.xyz - true_xyz, axis=2) >= WRONG_MM) & ~spiked
            right_before = mk.valid & ~before & ~spiked
            tot["swapped"] += int(swapped.sum())
            # a swapped sample is handled when its frame no longer shows a wrong sample under either name
            tot["handled"] += int((swapped & ~after).sum())
            tot["still_wrong"] += int(after.sum())
            tot["made_wrong"] += int(((after & ~before) | (right_before & ~res.valid)).sum())
            tot["takes"] += 1
        out[source] = tot
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--swaps", type=int, default=3, help="swaps per mocap take")
    ap.add_argument("--bursts", type=int, default=0, help="occlusion bursts per mocap take")
    args = ap.parse_args(argv)
    print(f"{'seed':>4} {'skeleton':>8} {'refs':>8} {'swapped':>8} {'handled':>8} {'still wrong':>11} "
          f"{'made wrong':>10} {'ms/take':>8}")
    for seed in (int(s) for s in args.seeds.split(",")):
        for skeleton in ("ten", "four"):
            for source, t in evaluate(session(seed, skeleton, args.swaps, args.bursts)).items():
                print(f"{seed:4d} {skeleton:>8} {source:>8} {t['swapped']:8d} "
                      f"{100 * t['handled'] / max(t['swapped'], 1):7.1f}% {t['still_wrong']:11d} "
                      f"{t['made_wrong']:10d} {1000 * t['cpu_s'] / max(t['takes'], 1):8.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
