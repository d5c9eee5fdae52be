"""Label-swap repair against the generator's truth (SPEC §3.2 step 1, :mod:`gazepipe.stages.clean.swaps`).

Generates sessions with the ``label_swaps`` hazard (three swaps per mocap take, with spikes, long gaps and
occlusions) for several seeds, both skeletons and one or more capture rates, and runs
:func:`~gazepipe.stages.clean.swaps.repair_swaps` on every mocap take on the markers the clean stage judges
(:func:`~gazepipe.stages.clean.swaps.judged_columns`: every marker but the target and the clapper, listed in the
markerset or not), with the take's own references and with the subject's, pooled from every take of the session
(:func:`~gazepipe.stages.clean.swaps.pooled_references`, what the clean stage uses). With ``--unlisted`` the
subject also carries markers the markerset lists in no segment (``SynthConfig.unlisted_markers``: the shoulders,
or the shoulders and the elbows), and the swaps exchange them too (mirror pairs especially). With ``--bursts N``
every mocap take also gets N occlusion bursts (30-80 % of the subject's markers, on one side, gone for
0.2-1.5 s), which hide the references that prove a swap; ``--motion S`` scales how far the unlisted markers move
against the chest (``SynthConfig.unlisted_motion``). ``--swaps 0`` gives plain sessions: everything repaired or
removed there is a false positive. The take's own references are used only on takes of at least
``OWN_REFERENCES_MIN_S`` (20 s), as the clean stage and ``gazepipe fill`` use them; the shorter takes are left
out of the ``own`` rows.

Prints, per seed, skeleton, rate, reference source and marker class (``listed`` in a markerset segment, the root
or the head centre; ``unlisted``): the samples written under a wrong name (``swapped``), and of them those now
under their own name (``repaired``), made gaps (``removed``) and the rest (``missed``: still under the wrong
name, or gone some other way); the samples ``made wrong`` (a sample moved under a name not its own, or a measured
sample that was not swapped moved, removed or replaced); ``false pos.``: samples repaired or removed outside
every swapped stretch of the truth; and the CPU time per take. A sample is wrong when it lies more than
:data:`WRONG_MM` from the truth of the name it carries (a ghost spike, which moves with its sample, is judged
where it lands). Then the totals per rate, reference source and class over every seed and skeleton, and the
marker of each with the smallest share of its swapped samples repaired or removed. The four-segment sessions are
in y-up axes, as ``python -m gazepipe.synth --skeleton four`` writes them.

Usage: ``PYTHONPATH=. python bench/bench_swaps.py [--seeds 0,1,2] [--swaps 3] [--bursts 0] [--unlisted arms]
[--motion 1] [--rates 30,120] [--refs own,session]``
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from gazepipe.io.capture import read_markers
from gazepipe.io.markerset_toml import load_markerset
from gazepipe.stages.clean.stage import OWN_REFERENCES_MIN_S
from gazepipe.stages.clean.swaps import SwapResult, judged_columns, pooled_references, repair_swaps
from gazepipe.synth.session import MOCAP_RATE_HZ, SynthConfig, generate_session, sample_config
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENTS, UNLISTED_SETS

ROOT = Path(__file__).resolve().parents[1]
WORK = ROOT / "bench" / "_work" / "swaps"
#: a sample more than this from the truth of the name it carries is wrong (swapped markers are 50-500 mm apart)
WRONG_MM = 10.0
#: the capture rates the command line names: 30 is the sample's 29.97 Hz
RATES = {"30": MOCAP_RATE_HZ, "120": 4.0 * MOCAP_RATE_HZ}
COUNTS = ("swapped", "repaired", "removed", "missed", "made_wrong", "false_pos")


def session(seed: int, skeleton: str, swaps: int, bursts: int = 0, unlisted: str = "", rate: str = "30",
            motion: float = 1.0) -> Path:
    folder = WORK / (f"seed{seed}-{skeleton}-{swaps}" + (f"-b{bursts}" if bursts else "")
                     + (f"-{unlisted}" if unlisted else "") + (f"-m{motion:g}" if motion != 1.0 else "")
                     + (f"-{rate}hz" if rate != "30" else ""))
    if not (folder / "session.toml").exists():
        base = sample_config()
        cfg: SynthConfig = replace(base, head_camera=False, face_takes=(), label_swaps=swaps,
                                   spikes_per_marker_min=1.0, long_gaps=2, gaps_per_marker_min=1.0,
                                   occlusion_bursts=bursts, rate_hz=RATES[rate],
                                   unlisted_markers=UNLISTED_SETS[unlisted] if unlisted else (),
                                   unlisted_motion=motion,
                                   segments=FOUR_SEGMENTS if skeleton == "four" else SEGMENTS,
                                   up_axis="y" if skeleton == "four" else "z")
        generate_session(folder, seed, cfg)
    return folder


def _partners(shape: tuple[int, int], swaps: np.ndarray) -> np.ndarray:
    """(T, M) int: the column whose name each sample of a swapped stretch truly carries (−1 outside)."""
    out = np.full(shape, -1, dtype=np.int64)
    for a, b, s, e in swaps:
        out[s:e, a], out[s:e, b] = b, a
    return out


def _moved(res: SwapResult, mask: np.ndarray) -> np.ndarray:
    """``mask`` (T, M) of the capture's columns carried along with the repaired exchanges (a ghost spike moves
    with the sample it sits on)."""
    out = mask.copy()
    for r in res.records:
        if r.repaired:
            out[r.start:r.stop, [r.first, r.second]] = mask[r.start:r.stop, [r.second, r.first]]
    return out


def take_counts(mk, res: SwapResult, truth) -> dict[str, np.ndarray]:
    """Per column (M,): the counts of :data:`COUNTS` for one take."""
    true_xyz, spiked = truth["markers_true"], truth["spike_mask"]
    n_t, n_m = mk.valid.shape
    swapped = truth["swap_mask"] if "swap_mask" in truth else np.zeros((n_t, n_m), dtype=bool)
    partner = _partners((n_t, n_m), truth["swaps"] if "swaps" in truth else np.zeros((0, 4), np.int64))
    spiked_after = _moved(res, spiked)
    with np.errstate(invalid="ignore"):
        wrong_before = mk.valid & (np.linalg.norm(mk.xyz - true_xyz, axis=2) >= WRONG_MM) & ~spiked
        wrong_after = res.valid & (np.linalg.norm(res.xyz - true_xyz, axis=2) >= WRONG_MM) & ~spiked_after
    right_after = res.valid & ~wrong_after
    rows, cols = np.nonzero(swapped)
    own = partner[rows, cols]                         # the name the swapped sample truly carries
    repaired = np.zeros((n_t, n_m), dtype=bool)
    repaired[rows, cols] = res.repaired[rows, own] & right_after[rows, own]
    removed = swapped & res.removed & ~repaired
    right_before = mk.valid & ~wrong_before & ~spiked & ~swapped
    changed = right_before & (res.repaired | res.removed | ~res.valid | wrong_after)
    made_wrong = (res.repaired & wrong_after) | changed
    masks = {"swapped": swapped, "repaired": repaired, "removed": removed, "missed": swapped & ~repaired & ~removed,
             "made_wrong": made_wrong, "false_pos": (res.repaired | res.removed) & (partner < 0)}
    return {k: m.sum(axis=0) for k, m in masks.items()}


def evaluate(folder: Path, sources: list[str], per_marker: dict[tuple[str, str, str], list[int]]
             ) -> dict[str, dict[str, dict[str, float]]]:
    """Per reference source and marker class (``listed``, ``unlisted``): the counts and the CPU time; adds to
    ``per_marker`` (per source, class and marker) its swapped samples and those repaired or removed."""
    listed = set(load_markerset(folder / "markerset.toml").subject_markers)
    takes = {c.stem: read_markers(c) for c in sorted((folder / "mocap").glob("*.c3d"))}
    target_clapper = {"POLE", "CLAP1", "CLAP2"}
    pooled = pooled_references([(m.labels, m.xyz, m.valid) for m in takes.values()],
                               markers={lab for m in takes.values() for lab in m.labels} - target_clapper)
    out: dict[str, dict[str, dict[str, float]]] = {}
    for source in sources:
        tot = {cls: dict.fromkeys(COUNTS, 0) for cls in ("listed", "unlisted")}
        cpu, n_takes = 0.0, 0
        for name, mk in takes.items():
            if source == "own" and mk.n_frames < OWN_REFERENCES_MIN_S * mk.rate_hz:
                continue                # too short to judge by itself: not judged so (the stage, `gazepipe fill`)
            truth = np.load(folder / "truth" / f"{name}.npz")
            refs = pooled.for_labels(mk.labels) if source == "session" else None
            t0 = time.process_time()
            res = repair_swaps(mk.xyz, mk.valid, references=refs,
                               markers=judged_columns(mk.labels, "POLE", ("CLAP1", "CLAP2")))
            cpu += time.process_time() - t0
            n_takes += 1
            counts = take_counts(mk, res, truth)
            cls = np.array(["listed" if lab in listed or lab in target_clapper else "unlisted" for lab in mk.labels])
            for k, per_column in counts.items():
                for c in ("listed", "unlisted"):
                    tot[c][k] += int(per_column[cls == c].sum())
            for j, lab in enumerate(mk.labels):
                mine = per_marker.setdefault((source, str(cls[j]), lab), [0, 0])
                mine[0] += int(counts["swapped"][j])
                mine[1] += int(counts["repaired"][j] + counts["removed"][j])
        out[source] = {**tot, "time": {"ms_per_take": 1000 * cpu / max(n_takes, 1)}}
    return out


def _row(label: str, cls: str, t: dict[str, float], ms: float | None = None) -> str:
    share = {k: 100 * t[k] / max(t["swapped"], 1) for k in ("repaired", "removed", "missed")}
    return (f"{label} {cls:>8} {t['swapped']:8d} {t['repaired']:6d} {share['repaired']:5.1f}% {t['removed']:6d} "
            f"{share['removed']:5.1f}% {t['missed']:6d} {share['missed']:5.1f}% {t['made_wrong']:10d} "
            f"{t['false_pos']:10d}" + (f" {ms:8.0f}" if ms is not None else ""))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--swaps", type=int, default=3, help="swaps per mocap take (0: plain sessions)")
    ap.add_argument("--bursts", type=int, default=0, help="occlusion bursts per mocap take")
    ap.add_argument("--unlisted", choices=sorted(UNLISTED_SETS), default="",
                    help="markers in no markerset segment (SynthConfig.unlisted_markers)")
    ap.add_argument("--motion", type=float, default=1.0,
                    help="how far the unlisted markers move against the chest (SynthConfig.unlisted_motion)")
    ap.add_argument("--rates", default="30", help="capture rates, Hz: 30 (29.97) and/or 120 (119.88)")
    ap.add_argument("--refs", default="own,session", help="reference sources: own (the take's), session")
    args = ap.parse_args(argv)
    sources = args.refs.split(",")
    head = f"{'seed':>4} {'skeleton':>8} {'Hz':>4} {'refs':>8}"
    print(f"{head} {'class':>8} {'swapped':>8} {'repaired':>13} {'removed':>13} {'missed':>13} {'made wrong':>10} "
          f"{'false pos.':>10} {'ms/take':>8}")
    totals: dict[tuple[str, str, str], dict[str, float]] = {}
    per_marker: dict[tuple[str, str, str, str], list[int]] = {}
    for rate in args.rates.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            for skeleton in ("ten", "four"):
                folder = session(seed, skeleton, args.swaps, args.bursts, args.unlisted, rate, args.motion)
                mine: dict[tuple[str, str, str], list[int]] = {}
                for source, per_class in evaluate(folder, sources, mine).items():
                    for cls in ("listed", "unlisted"):
                        t = per_class[cls]
                        total = totals.setdefault((rate, source, cls), dict.fromkeys(COUNTS, 0))
                        for k in COUNTS:
                            total[k] += t[k]
                        if cls == "unlisted" and not args.unlisted:
                            continue
                        print(_row(f"{seed:4d} {skeleton:>8} {rate:>4} {source:>8}", cls, t,
                                   per_class["time"]["ms_per_take"]))
                for (source, cls, lab), (n, handled) in mine.items():
                    acc = per_marker.setdefault((rate, source, cls, lab), [0, 0])
                    acc[0], acc[1] = acc[0] + n, acc[1] + handled
    print("totals over the seeds and both skeletons:")
    for (rate, source, cls), t in totals.items():
        if cls == "unlisted" and not args.unlisted:
            continue
        print(_row(f"{'all':>4} {'both':>8} {rate:>4} {source:>8}", cls, t))
    print("the marker with the smallest share of its swapped samples repaired or removed, over the seeds and both "
          "skeletons:")
    for (rate, source, cls) in totals:
        shares = {lab: (h / n, n) for (r, s, c, lab), (n, h) in per_marker.items()
                  if (r, s, c) == (rate, source, cls) and n}
        if shares:
            lab = min(shares, key=lambda k: (shares[k][0], k))
            print(f"{rate:>4} Hz {source:>8} {cls:>8}: {lab} {100 * shares[lab][0]:5.1f}% of {shares[lab][1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
