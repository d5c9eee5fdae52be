"""Speed of gap filling as the clean stage runs it (spike removal, then :func:`fill_gaps` with the markerset's
segments as rigid clusters, ``max_gap_s`` and ``max_fill_error_mm``), on real-sized takes.

Takes: every ``--step``-th C3D of ``bench/_work/klein_x10/klein_laying/mocap`` (written by ``bench/make_corpus.py``)
up to ``--takes``, and the sample session's takes. Prints the time per take and per gap (minimum over
``--repeats`` runs of the whole set; wall clock, and the process's CPU time, steadier on a busy machine) and a digest of the outputs (fill codes and filled positions), so two
versions can be checked for identical results.

With ``--against REV`` (a commit, e.g. ``b8bd9a1``) the same takes are also filled by that version, checked out
once under ``bench/_work/rev-<sha>``: each repeat runs the old and the new version in fresh processes one after the
other (old, new, old, new, ...), so both see the same machine load, and the table gives the CPU time per take of
each, ``fill_gaps`` alone and the whole clean stage (:func:`gazepipe.stages.clean.stage.clean_markers`), their
ratio, and whether the outputs are the same bits. The clean stage gets the set's subject references for its
label-swap repair, as the pipeline gives it its session's; computing them, once per session and worker in the
pipeline, is timed apart (last column).

With ``--rate`` two more sets: one take of a high capture rate (``--rate-hz``, default 10 kHz; ``--rate-s``
seconds, default 20) generated gap-free with the markerset's rigid segments, filled as it is and with
``--rate-gaps`` short gaps (default 2,267: one to 40 samples each, random markers and places, seeded) punched
into it. The table then gives, for each version, the gapped take's fill time over the gap-free one's: the cost of
its gaps, which should not grow with the rate (each gap's work bounded by its own length and by windows in
seconds read at a bounded number of samples). The generated take is cached under ``bench/_work/rate-*.npz``.

Usage: ``PYTHONPATH=. python bench/bench_fill_speed.py [--takes 8] [--repeats 3] [--profile] [--hostile]
[--klein PATH] [--rate] [--against REV]``
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _truth_takes import spikes_as_clean_finds_them  # bench/_truth_takes.py

from gazepipe.io.capture import read_markers
from gazepipe.io.session_toml import load_markerset
from gazepipe.stages.clean.gapfill import fill_gaps
from gazepipe.stages.clean.stage import CleanParams

ROOT = Path(__file__).resolve().parents[1]
KLEIN = ROOT / "bench" / "_work" / "klein_x10" / "klein_laying"
SAMPLE = ROOT / "sample_data" / "session01"
HOSTILE = ROOT / "bench" / "_work" / "hostile"


def load_takes(folder: Path, n: int, step: int) -> list[dict]:
    """Each take's spike-free positions, valid mask, rate and clusters, as ``clean._fill`` builds them."""
    ms = load_markerset(folder / "markerset.toml")
    files = sorted((folder / "mocap").glob("*.c3d"))[::step]
    if n:
        files = files[:n]
    p = CleanParams()
    out = []
    for f in files:
        mk = read_markers(f, default_units=ms.units)
        valid = mk.valid & np.isfinite(mk.xyz).all(axis=2)
        xyz = np.where(valid[..., None], mk.xyz, np.nan)
        pos = {lab.split(":")[-1]: i for i, lab in enumerate(mk.labels)}
        clusters = [[pos[x] for x in s.markers if x in pos] for s in ms.segments]
        t0 = time.process_time()
        valid &= ~spikes_as_clean_finds_them(xyz, valid, mk.rate_hz, clusters, p)
        spike_s = time.process_time() - t0
        xyz = np.where(valid[..., None], xyz, np.nan)
        out.append({"name": f"{folder.name}/{f.stem}", "xyz": xyz, "valid": valid, "rate": mk.rate_hz,
                    "markers": mk, "markerset": ms,
                    "clusters": [c for c in clusters if len(c) >= 2], "max_gap_s": p.max_gap_s,
                    "max_error_mm": p.max_fill_error_mm, "methods": tuple(p.fill_methods), "spike_s": spike_s})
    return out


def fill(t: dict):
    return fill_gaps(t["xyz"], t["valid"], t["rate"], clusters=t["clusters"], max_gap_s=t["max_gap_s"],
                     methods=t["methods"], max_error_mm=t["max_error_mm"])


def clean(t: dict, references=None) -> None:
    """The whole clean stage on the take as read (label swaps, spikes, fill, stabilisation, rests, crop), with
    the set's subject references when this version takes them (as the pipeline passes its session's)."""
    from gazepipe.errors import StageError
    from gazepipe.stages.clean.stage import clean_markers

    try:
        if references is None:
            clean_markers(t["markers"], t["markerset"], "gaze_follow")
        else:
            clean_markers(t["markers"], t["markerset"], "gaze_follow", references=references)
    except StageError:        # no rests: timed all the same
        pass


def subject_references(takes: list[dict]):
    """The set's subject references (what the pipeline computes once per session and worker), or None for a
    version without label-swap repair."""
    try:
        from gazepipe.stages.clean.swaps import pooled_references
    except ImportError:
        return None
    ms = takes[0]["markerset"]
    return pooled_references([(t["markers"].labels, t["markers"].xyz, t["markers"].valid) for t in takes],
                             markers=set(ms.subject_markers))


def digest_of(results: list) -> str:
    """A digest of fill results (codes and filled positions)."""
    digest = hashlib.sha256()
    for r in results:
        digest.update(np.ascontiguousarray(r.fill_code).tobytes())
        digest.update(np.nan_to_num(r.xyz, nan=-1e300).tobytes())
    return digest.hexdigest()[:16]


def rate_takes(rate_hz: float, seconds: float, n_gaps: int, seed: int = 0) -> list[tuple[str, list[dict]]]:
    """Two sets of one take each: a generated take at ``rate_hz`` (``seconds`` of a standing gaze_follow take,
    no gaps), and the same take with ``n_gaps`` short gaps (1 to 40 samples; never within 3 samples of another
    gap of the same marker), both as :func:`load_takes` gives them (no spikes to find: none generated)."""
    from gazepipe.io.capture import read_markers

    cache = ROOT / "bench" / "_work" / f"rate-{rate_hz:g}hz-{seconds:g}s-seed{seed}.npz"
    if not cache.is_file():
        from gazepipe.synth import SynthConfig, generate_session

        cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=seconds, shift_targets=(), neutral_s=1.0,
                          head_camera=False, face_takes=(), gaps=False, rate_hz=rate_hz)
        folder = generate_session(cache.with_suffix(""), seed=seed, config=cfg)
        mk = read_markers(folder / "mocap" / "follow_standing_01.c3d")
        ms = load_markerset(folder / "markerset.toml")
        pos = {lab.split(":")[-1]: i for i, lab in enumerate(mk.labels)}
        clusters = [[pos[x] for x in seg.markers if x in pos] for seg in ms.segments]
        np.savez(cache, xyz=mk.xyz, valid=mk.valid, rate=mk.rate_hz,
                 cluster_marker=np.concatenate([c for c in clusters if len(c) >= 2]),
                 cluster_size=np.array([len(c) for c in clusters if len(c) >= 2]))
    z = np.load(cache)
    xyz, valid = z["xyz"], z["valid"] & np.isfinite(z["xyz"]).all(axis=2)
    n_frames = int(round(seconds * float(z["rate"])))
    xyz, valid = np.ascontiguousarray(xyz[:n_frames]), valid[:n_frames]
    clusters = [c.tolist() for c in np.split(z["cluster_marker"], np.cumsum(z["cluster_size"])[:-1])]
    p = CleanParams()
    gapped = valid.copy()
    rng = np.random.default_rng(seed)
    made = 0
    while made < n_gaps:
        m, length = int(rng.integers(xyz.shape[1])), int(rng.integers(1, 41))
        start = int(rng.integers(5, n_frames - length - 5))
        if gapped[start - 3:start + length + 3, m].all():
            gapped[start:start + length, m] = False
            made += 1
    base = {"rate": float(z["rate"]), "clusters": clusters, "max_gap_s": p.max_gap_s,
            "max_error_mm": p.max_fill_error_mm, "methods": tuple(p.fill_methods), "spike_s": 0.0}
    label = f"{float(z['rate']) / 1000:g} kHz {seconds:g} s"
    return [(f"{label}, no gaps", [dict(base, name="plain", xyz=np.where(valid[..., None], xyz, np.nan),
                                        valid=valid)]),
            (f"{label}, {n_gaps} gaps", [dict(base, name="gapped", xyz=np.where(gapped[..., None], xyz, np.nan),
                                              valid=gapped)])]


def load_sets(args: argparse.Namespace) -> list[tuple[str, list[dict]]]:
    sets = []
    klein = Path(args.klein)
    if (klein / "mocap").is_dir():
        sets.append((klein.name, load_takes(klein, args.takes, args.step)))
    else:
        print(f"{klein} absent (run bench/make_corpus.py): skipped")
    if (SAMPLE / "mocap").is_dir():
        sets.append(("sample session01", load_takes(SAMPLE, 0, 1)))
    if args.hostile:
        from gazepipe.synth import SynthConfig, generate_session

        cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=45.0, head_camera=False,
                          face_takes=(), spikes_per_marker_min=1.0, long_gaps=4, gaps_per_marker_min=3.0)
        sets.append(("hostile generated session", load_takes(generate_session(HOSTILE, seed=0, config=cfg), 0, 1)))
    if args.rate:
        sets += rate_takes(args.rate_hz, args.rate_s, args.rate_gaps)
    return sets


def child(args: argparse.Namespace) -> int:
    """One timed pass of every set (run in a fresh process by :func:`against`): JSON on stdout."""
    from threadpoolctl import threadpool_limits

    sets = load_sets(args)
    out = {}
    with threadpool_limits(limits=1):
        # the first fill of a process loads (or, with no cache yet, compiles) the filler's compiled kernels: timed
        # apart, on a small take, so the figures below are those of a warm worker
        c0 = time.process_time()
        warm_up()
        out["warm-up"] = {"first_cpu": time.process_time() - c0}
        for name, takes in sets:
            c0 = time.process_time()
            results = [fill(t) for t in takes]
            fill_cpu = time.process_time() - c0
            refs_cpu = clean_cpu = float("nan")
            if "markers" in takes[0]:         # the generated high-rate take is timed in fill_gaps only
                c0 = time.process_time()
                references = subject_references(takes)
                refs_cpu = time.process_time() - c0
                c0 = time.process_time()
                for t in takes:
                    clean(t, references)
                clean_cpu = time.process_time() - c0
            out[name] = {"takes": len(takes), "fill_cpu": fill_cpu, "clean_cpu": clean_cpu, "refs_cpu": refs_cpu,
                         "digest": digest_of(results)}
    print("RESULT " + json.dumps(out))
    return 0


def warm_up() -> None:
    """One small fill with every method (2 s at 60 Hz, a few gaps): what a worker's first take pays once."""
    rng = np.random.default_rng(0)
    t = np.arange(120)[:, None, None] / 60.0
    xyz = 100.0 * np.sin(t + rng.uniform(0, 6, (1, 8, 3))) + rng.normal(0, 0.5, (120, 8, 3))
    valid = np.ones((120, 8), dtype=bool)
    valid[40:43, 0] = valid[60:80, 3] = valid[90:92, 5] = False
    fill_gaps(np.where(valid[..., None], xyz, np.nan), valid, 60.0, clusters=[[0, 1, 2, 3], [4, 5, 6, 7]])


def checkout(rev: str) -> Path:
    """The tree of ``rev``, checked out once under ``bench/_work/rev-<sha>``."""
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=12", rev], check=True,
                         capture_output=True, text=True).stdout.strip()
    tree = ROOT / "bench" / "_work" / f"rev-{sha}"
    if not (tree / "gazepipe").is_dir():
        tree.mkdir(parents=True, exist_ok=True)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", sha, "gazepipe"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return tree


def against(args: argparse.Namespace) -> int:
    """Old (``args.against``) and new interleaved in fresh processes; the table of CPU time per take."""
    trees = {"old": checkout(args.against), "new": ROOT}
    best: dict[tuple[str, str], dict] = {}
    first: dict[str, float] = {}
    base = [sys.executable, str(Path(__file__).resolve()), "--child", "--takes", str(args.takes),
            "--step", str(args.step), "--klein", str(args.klein)] + (["--hostile"] if args.hostile else [])
    if args.rate:
        base += ["--rate", "--rate-hz", str(args.rate_hz), "--rate-s", str(args.rate_s), "--rate-gaps",
                 str(args.rate_gaps)]
    for _ in range(args.repeats):
        for side, tree in trees.items():
            env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), str(ROOT / "bench")]))
            run = subprocess.run(base, env=env, capture_output=True, text=True, check=True)
            line = next(x for x in run.stdout.splitlines() if x.startswith("RESULT "))
            for name, r in json.loads(line[len("RESULT "):]).items():
                key = (name, side)
                if name == "warm-up":
                    first[side] = min(first.get(side, np.inf), r["first_cpu"])
                    continue
                if key not in best:
                    best[key] = r
                else:
                    best[key]["fill_cpu"] = min(best[key]["fill_cpu"], r["fill_cpu"])
                    best[key]["clean_cpu"] = min(best[key]["clean_cpu"], r["clean_cpu"])
                    best[key]["refs_cpu"] = min(best[key].get("refs_cpu", 0.0), r.get("refs_cpu", 0.0))
    print(f"old = {args.against}, new = working tree; CPU ms per take, min of {args.repeats} interleaved runs")
    print(f"{'set':28} {'fill old':>9} {'fill new':>9} {'ratio':>6} {'clean old':>10} {'clean new':>10} "
          f"{'ratio':>6}  same output  swap references (new, once per session)")
    for name in dict.fromkeys(k[0] for k in best):
        o, n = best[(name, "old")], best[(name, "new")]
        k = o["takes"]
        print(f"{name:28} {1000 * o['fill_cpu'] / k:9.1f} {1000 * n['fill_cpu'] / k:9.1f} "
              f"{n['fill_cpu'] / o['fill_cpu']:6.2f} {1000 * o['clean_cpu'] / k:10.1f} "
              f"{1000 * n['clean_cpu'] / k:10.1f} {n['clean_cpu'] / o['clean_cpu']:6.2f}  "
              f"{'yes' if o['digest'] == n['digest'] else 'no':>11}  {1000 * n.get('refs_cpu', 0.0):.0f} ms")
    print(f"first fill of a process (kernels loaded or compiled; not in the figures above), CPU: old "
          f"{1000 * first.get('old', np.nan):.0f} ms, new {1000 * first.get('new', np.nan):.0f} ms")
    names = list(dict.fromkeys(k[0] for k in best))
    plain = [x for x in names if x.endswith(", no gaps")]
    if args.rate and plain:
        gapped = next(x for x in names if x.startswith(plain[0][:-len("no gaps")]) and x != plain[0])
        for side in ("old", "new"):
            g, z = best[(gapped, side)]["fill_cpu"], best[(plain[0], side)]["fill_cpu"]
            print(f"{side}: {gapped} {g:.1f} s CPU, without the gaps {z:.1f} s: ratio {g / z:.1f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=8, help="Klein takes (0: all)")
    ap.add_argument("--step", type=int, default=6, help="use every step-th Klein take")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--profile", action="store_true", help="cProfile one pass and print the top functions")
    ap.add_argument("--hostile", action="store_true",
                    help="also a generated session with spikes, long trunk occlusions and dense gaps")
    ap.add_argument("--klein", default=str(KLEIN), help="the Klein session folder (default %(default)s)")
    ap.add_argument("--rate", action="store_true", help="also a generated high-rate take, with and without gaps")
    ap.add_argument("--rate-hz", type=float, default=10000.0)
    ap.add_argument("--rate-s", type=float, default=20.0)
    ap.add_argument("--rate-gaps", type=int, default=2267)
    ap.add_argument("--against", metavar="REV", help="also time this commit's filler, interleaved with this one")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return child(args)
    if args.against:
        return against(args)
    sets = load_sets(args)
    from threadpoolctl import threadpool_limits

    # one BLAS thread, as the pipeline runs every unit
    limit = threadpool_limits(limits=1)
    cpu_of: dict[str, float] = {}
    for name, takes in sets:
        n_gaps = 0
        digest = "-"
        best = best_cpu = np.inf
        for rep in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            results = [fill(t) for t in takes]
            best = min(best, time.perf_counter() - t0)
            best_cpu = min(best_cpu, time.process_time() - c0)
            if rep == 0:
                n_gaps = sum(sum(g.method != "unfilled" for g in r.gaps) for r in results)
                digest = digest_of(results)
        cpu_of[name] = best_cpu
        frames = sum(t["xyz"].shape[0] for t in takes)
        markers = np.mean([t["xyz"].shape[1] for t in takes])
        print(f"{name}: {len(takes)} takes, {frames / len(takes):.0f} frames x {markers:.0f} markers, "
              f"{n_gaps / len(takes):.1f} filled gaps per take; fill_gaps {1000 * best / len(takes):.1f} ms per take, "
              f"{1000 * best / max(n_gaps, 1):.2f} ms per gap (min of {args.repeats}); "
              f"CPU {1000 * best_cpu / len(takes):.1f} ms per take; "
              f"spike search {1000 * sum(t['spike_s'] for t in takes) / len(takes):.1f} ms CPU per take; "
              f"output digest {digest}")
        if args.profile:
            import cProfile
            import pstats

            pr = cProfile.Profile()
            pr.enable()
            for t in takes:
                fill(t)
            pr.disable()
            pstats.Stats(pr).sort_stats("cumulative").print_stats(25)
    limit.restore_original_limits()
    plain = [x for x in cpu_of if x.endswith(", no gaps")]
    if plain:
        gapped = next(x for x in cpu_of if x.startswith(plain[0][:-len("no gaps")]) and x != plain[0])
        print(f"{gapped}: {cpu_of[gapped]:.1f} s CPU, without the gaps {cpu_of[plain[0]]:.1f} s: "
              f"ratio {cpu_of[gapped] / cpu_of[plain[0]]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
