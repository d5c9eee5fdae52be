"""The clean stage against the take's length: time and peak memory of
:func:`gazepipe.stages.clean.stage.clean_markers` on takes of growing length made from the sample session's
``follow_standing_01`` take (30 Hz, 36 markers), played forward and backward in turn so the motion stays
continuous, with fresh 0.5 mm noise, ghost spikes (one per marker per minute) and gaps (three per marker per
minute, 2-40 frames; seeded). Each length runs in a fresh process, so its peak resident memory is its own.

Prints per length: frames, marker samples, CPU seconds, CPU microseconds per sample, peak resident memory (MB)
and what cleaning added to the process's memory (peak less the resident size once the take was in memory), per
sample; with ``--against REV`` the same for that commit, interleaved (see ``bench_fill_speed.py``).
Linear time shows as a constant time per sample.

Usage: ``PYTHONPATH=. python bench/bench_clean_length.py [--minutes 5,10,20] [--against REV]``
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "session01"


def long_take(minutes: float):
    """The sample take stretched to ``minutes``, with noise, spikes and gaps, and its markerset."""
    from dataclasses import replace

    from gazepipe.io.capture import read_markers
    from gazepipe.io.session_toml import load_markerset

    ms = load_markerset(SAMPLE / "markerset.toml")
    mk = read_markers(SAMPLE / "mocap" / "follow_standing_01.c3d", default_units=ms.units)
    base = np.where(mk.valid[..., None], mk.xyz, np.nan)
    # forward, then backward, ...: a continuous path; the sample's own gaps filled by holding the last sample
    idx = np.arange(base.shape[0])
    for m in range(base.shape[1]):
        ok = np.isfinite(base[:, m, 0])
        base[:, m] = base[np.maximum.accumulate(np.where(ok, idx, 0)), m]
    n_t = int(minutes * 60 * mk.rate_hz)
    period = 2 * base.shape[0] - 2
    phase = np.arange(n_t) % period
    rows = np.where(phase < base.shape[0], phase, period - phase)
    rng = np.random.default_rng(0)
    xyz = base[rows] + rng.normal(0.0, 0.5, (n_t, base.shape[1], 3))
    valid = np.isfinite(xyz).all(axis=2)
    n_m = base.shape[1]
    per_min = n_t / (60 * mk.rate_hz)
    for _ in range(int(3 * per_min * n_m)):
        m, s = rng.integers(0, n_m), rng.integers(0, n_t - 40)
        valid[s:s + rng.integers(2, 40), m] = False
    for _ in range(int(per_min * n_m)):
        m, s = rng.integers(0, n_m), rng.integers(0, n_t - 2)
        xyz[s, m] += rng.normal(0.0, 25.0, 3)
    xyz[~valid] = np.nan
    return replace(mk, xyz=xyz, valid=valid, warnings=[]), ms


def child(minutes: float) -> None:
    from gazepipe.errors import StageError
    from gazepipe.stages.clean.stage import clean_markers

    markers, ms = long_take(minutes)
    before = int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    c0 = time.process_time()
    try:
        clean_markers(markers, ms, "gaze_follow")
    except StageError:           # no rests: timed all the same
        pass
    cpu = time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print("RESULT " + json.dumps({"frames": markers.n_frames, "samples": markers.n_frames * markers.n_markers,
                                  "cpu_s": cpu, "peak_bytes": peak,
                                  "added_bytes": peak - before}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", default="5,10,20")
    ap.add_argument("--against", metavar="REV")
    ap.add_argument("--child", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None:
        child(args.child)
        return 0
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_fill_speed import checkout

    trees = {"new": ROOT} if not args.against else {"old": checkout(args.against), "new": ROOT}
    rows = []
    for minutes in [float(x) for x in args.minutes.split(",")]:
        for side, tree in trees.items():
            env = dict(os.environ, PYTHONPATH=str(tree))
            run = subprocess.run([sys.executable, __file__, "--child", str(minutes)], env=env, cwd=ROOT,
                                 capture_output=True, text=True, check=True)
            r = json.loads(next(x for x in run.stdout.splitlines() if x.startswith("RESULT "))[7:])
            rows.append((minutes, side, r))
    print(f"{'minutes':>7} {'side':>4} {'frames':>8} {'samples':>10} {'CPU s':>7} {'us/sample':>9} "
          f"{'peak MB':>8} {'added B/sample':>14}")
    for minutes, side, r in rows:
        print(f"{minutes:7g} {side:>4} {r['frames']:8d} {r['samples']:10d} {r['cpu_s']:7.2f} "
              f"{1e6 * r['cpu_s'] / r['samples']:9.2f} {r['peak_bytes'] / 2**20:8.0f} "
              f"{r['added_bytes'] / r['samples']:14.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
