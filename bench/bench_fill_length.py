"""How the gap filler's time grows with the take's length: the same motion and gap density (one gap a second,
2-40 frames, on a random marker of a 12-marker body at 60 Hz, from ``tests/stages/clean/test_gapfill.body``), takes of
``--frames`` frames, in the column-major layout the Parquet loader gives. Prints the CPU time of
:func:`gazepipe.stages.clean.gapfill.fill_gaps` per take and per frame; with ``--against REV`` the same for that
commit, run in fresh processes interleaved with this tree's (see ``bench_fill_speed.py``). Linear time shows as a
constant time per frame.

Usage: ``PYTHONPATH=. python bench/bench_fill_length.py [--frames 3600,28800,57600] [--against REV]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def take(n_t: int) -> tuple[np.ndarray, np.ndarray, list[list[int]]]:
    """A take of ``n_t`` frames with one gap a second (seeded)."""
    sys.path.append(str(ROOT))     # after PYTHONPATH: gazepipe stays the version under test
    from tests.stages.clean.test_gapfill import body

    _, meas, clusters = body(n_t, seed=0)
    rng = np.random.default_rng(1)
    valid = np.ones(meas.shape[:2], bool)
    for _ in range(n_t // 60):
        m, s = rng.integers(0, 12), rng.integers(10, n_t - 60)
        valid[s:s + rng.integers(2, 40), m] = False
    return np.asfortranarray(np.where(valid[..., None], meas, np.nan)), valid, clusters


def child(frames: list[int]) -> None:
    from threadpoolctl import threadpool_limits

    from gazepipe.stages.clean.gapfill import fill_gaps

    out = {}
    with threadpool_limits(limits=1):
        for n_t in frames:
            xyz, valid, clusters = take(n_t)
            c0 = time.process_time()
            fill_gaps(xyz, valid, 60.0, clusters=clusters, max_gap_s=3.0, max_error_mm=5.0)
            out[n_t] = time.process_time() - c0
    print("RESULT " + json.dumps(out))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default="3600,28800,57600")
    ap.add_argument("--against", metavar="REV")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    frames = [int(x) for x in args.frames.split(",")]
    if args.child:
        child(frames)
        return 0
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_fill_speed import checkout

    trees = {"new": ROOT} if not args.against else {"old": checkout(args.against), "new": ROOT}
    times: dict[str, dict[str, float]] = {}
    for n_t in frames:        # one length at a time, old then new: both see the same machine load
        for side, tree in trees.items():
            env = dict(os.environ, PYTHONPATH=str(tree))
            run = subprocess.run([sys.executable, __file__, "--child", "--frames", str(n_t)], env=env,
                                 capture_output=True, text=True, check=True, cwd=ROOT)
            line = next(x for x in run.stdout.splitlines() if x.startswith("RESULT "))
            times.setdefault(side, {}).update(json.loads(line[len("RESULT "):]))
    print(f"{'frames':>8} " + " ".join(f"{side + ' s':>9} {side + ' us/frame':>13}" for side in trees))
    for n_t in frames:
        print(f"{n_t:8d} " + " ".join(f"{times[side][str(n_t)]:9.2f} {1e6 * times[side][str(n_t)] / n_t:13.1f}"
                                      for side in trees))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
