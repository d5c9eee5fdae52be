"""The clean stage against the take's length: time and peak memory of
:func:`gazepipe.stages.clean.stage.clean_markers` on takes of growing length made from the sample session's
``follow_standing_01`` take (30 Hz, 36 markers), played forward and backward in turn so the motion stays
continuous, with fresh 0.5 mm noise, ghost spikes (one per marker per minute) and gaps (three per marker per
minute, 2-40 frames; seeded). Each length runs in a fresh process, so its peak resident memory is its own.

Prints per length: frames, marker samples, CPU seconds, CPU microseconds per sample, peak resident memory (MB)
and what cleaning added to the process's memory (peak less the resident size once the take was in memory), per
sample (the stage cleans the take in place, as the clean unit has it do, where the tree's stage can); with ``--against REV`` the same for that commit, interleaved (see ``bench_fill_speed.py``).
Linear time shows as a constant time per sample.

The issue's figure, one hour at 120 Hz with 60 markers against two: ``--minutes 60,120 --rate-hz 120 --markers 60``.

``--unit`` measures the whole ``clean`` unit as ``gazepipe run`` runs it instead of the stage alone: the take's
``markers_raw`` table is first written as the ingest stage writes it (by a process of its own, the same file for
both sides), then a fresh process runs the unit through the engine (:func:`gazepipe.pipeline.runner.run_take_job`:
the node reads the table, cleans the take and the engine writes its tables atomically), the session's
``subject_geometry`` empty (no references: the take judges its swaps by its own frames). Its peak resident memory
and what the unit added to the process's (peak less the resident size before the unit); the unit's Parquet files'
SHA-256, which must be the same on both sides.

Usage: ``PYTHONPATH=. python bench/bench_clean_length.py [--minutes 5,10,20] [--rate-hz HZ] [--markers N]
[--unit] [--against REV]``
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "session01"


def long_take(minutes: float, rate_hz: float | None = None, n_markers: int | None = None):
    """The sample take stretched to ``minutes``, with noise, spikes and gaps, and its markerset; at ``rate_hz``
    (the sample's motion resampled by a cubic spline) and with ``n_markers`` markers (the extra ones midway
    between two markers of one segment, so they move rigidly with it, and added to that segment)."""
    from dataclasses import replace

    from scipy.interpolate import CubicSpline

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
        base[:np.argmax(ok), m] = base[np.argmax(ok), m]            # and before its first sample, the first
    labels = list(mk.labels)
    if n_markers and n_markers > len(labels):
        extra, segments = [], []
        pairs = [(s, a, b) for s in ms.segments for a, b in zip(s.markers, s.markers[1:], strict=False)]
        for k in range(n_markers - len(labels)):
            seg, a, b = pairs[k % len(pairs)]
            name = f"{a}_{b}_{k}"
            w = 0.25 + 0.5 * (k // len(pairs) % 3) / 2         # a quarter, half or three quarters of the way
            extra.append((seg.name, name, (1 - w) * base[:, labels.index(a)] + w * base[:, labels.index(b)]))
        for seg in ms.segments:
            segments.append(replace(seg, markers=tuple(seg.markers) + tuple(n for s, n, _ in extra if s == seg.name)))
        base = np.concatenate([base, np.stack([x for _, _, x in extra], axis=1)], axis=1)
        labels += [n for _, n, _ in extra]
        ms = replace(ms, segments=tuple(segments))
    rate = float(rate_hz or mk.rate_hz)
    if rate != mk.rate_hz:
        spline = CubicSpline(np.arange(base.shape[0]) / mk.rate_hz, base, axis=0)
        base = spline(np.arange(int((base.shape[0] - 1) / mk.rate_hz * rate) + 1) / rate)
    n_t = int(minutes * 60 * rate)
    period = 2 * base.shape[0] - 2
    rng = np.random.default_rng(0)
    n_m = base.shape[1]
    xyz = np.empty((n_t, n_m, 3))
    for lo in range(0, n_t, 65536):                   # in blocks: the take is the only full-size array made
        phase = np.arange(lo, min(n_t, lo + 65536)) % period
        rows = np.where(phase < base.shape[0], phase, period - phase)
        xyz[lo:lo + rows.size] = base[rows] + rng.normal(0.0, 0.5, (rows.size, n_m, 3))
    valid = np.ones((n_t, n_m), dtype=bool)
    per_min = n_t / (60 * rate)
    longest = max(3, int(round(40 * rate / mk.rate_hz)))     # gaps of 2-40 frames at 30 Hz: up to 1.3 s
    for _ in range(int(3 * per_min * n_m)):
        m, s = rng.integers(0, n_m), rng.integers(0, n_t - longest)
        valid[s:s + rng.integers(2, longest), m] = False
    for _ in range(int(per_min * n_m)):
        m, s = rng.integers(0, n_m), rng.integers(0, n_t - 2)
        xyz[s, m] += rng.normal(0.0, 25.0, 3)
    xyz[~valid] = np.nan
    return replace(mk, xyz=xyz, valid=valid, labels=labels, rate_hz=rate, warnings=[]), ms


def child(minutes: float, rate_hz: float | None, n_markers: int | None) -> None:
    from gazepipe.errors import StageError
    from gazepipe.stages.clean.stage import clean_markers

    markers, ms = long_take(minutes, rate_hz, n_markers)
    # the stage as the clean unit runs it: in place where it can be (the take's positions held once)
    in_place = {"in_place": True} if "in_place" in inspect.signature(clean_markers).parameters else {}
    before = int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    c0 = time.process_time()
    try:
        clean_markers(markers, ms, "gaze_follow", **in_place)
    except StageError:           # no rests: timed all the same
        pass
    cpu = time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print("RESULT " + json.dumps({"frames": markers.n_frames, "samples": markers.n_frames * markers.n_markers,
                                  "cpu_s": cpu, "peak_bytes": peak,
                                  "added_bytes": peak - before}))


def _session(ms, take_id: str):
    """The sample session with the long take's markerset and one take of the sample's, named ``take_id``."""
    from dataclasses import replace

    from gazepipe.io.session_toml import load_session

    session = load_session(SAMPLE)
    take = replace(next(t for t in session.takes if t.id == "follow_standing_01"), id=take_id)
    return replace(session, markerset=ms, takes=[take]), take


def prepare_unit(minutes: float, rate_hz: float | None, n_markers: int | None, out: Path) -> None:
    """Write the long take's ``markers_raw`` (as ingest writes it) and an empty ``subject_geometry`` under
    ``out``, as a run's earlier units would have."""
    from gazepipe.io.parquet import write_table
    from gazepipe.pipeline.state import OutLayout
    from gazepipe.schemas.markers import MARKERS_RAW, markers_to_table
    from gazepipe.schemas.poses import ARRAYS, geometry_to_table

    markers, ms = long_take(minutes, rate_hz, n_markers)
    session, take = _session(ms, "long")
    layout = OutLayout(out)
    raw = layout.table(session.id, take.id, "markers_raw")
    raw.parent.mkdir(parents=True, exist_ok=True)
    write_table(markers_to_table(markers), raw, MARKERS_RAW)
    geometry = layout.session_table(session.id, "subject_geometry")
    geometry.parent.mkdir(parents=True, exist_ok=True)
    write_table(geometry_to_table([], {}, []), geometry, ARRAYS)


def child_unit(minutes: float, rate_hz: float | None, n_markers: int | None, out: Path) -> None:
    """Run the ``clean`` unit on the take :func:`prepare_unit` wrote, through the engine, and print its figures."""
    import hashlib

    from gazepipe import dag
    from gazepipe.io.parquet import count_rows, read_schema
    from gazepipe.pipeline import registry
    from gazepipe.pipeline.runner import TakeJob, UnitPlan, run_take_job
    from gazepipe.pipeline.state import OutLayout
    from gazepipe.schemas.base import read_meta

    dag.declare()
    _, ms = long_take(0.05, rate_hz, n_markers)          # the markerset only: the take is read from its table
    session, take = _session(ms, "long")
    layout = OutLayout(out)
    raw = layout.table(session.id, take.id, "markers_raw")
    samples, frames = count_rows(raw), read_meta(read_schema(raw))["n_frames"]
    import gc

    gc.collect()
    before = int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    plan = UnitPlan(session.id, take.id, "clean", "bench", {}, True, "bench")
    c0 = time.process_time()
    [outcome] = run_take_job(TakeJob(str(out), session, take, [plan], {}, dag=registry.modules()))
    cpu = time.process_time() - c0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    digests = {name: hashlib.sha256(layout.table(session.id, take.id, name).read_bytes()).hexdigest()[:16]
               for name in ("markers", "neutral", "rest_speed") if layout.table(session.id, take.id, name).exists()}
    print("RESULT " + json.dumps({"frames": frames, "samples": samples, "cpu_s": cpu, "peak_bytes": peak,
                                  "added_bytes": peak - before, "status": outcome.status,
                                  "error": outcome.error, "sha256": digests}))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", default="5,10,20")
    ap.add_argument("--rate-hz", type=float, help="resample the take to this rate (default: the sample's 30 Hz)")
    ap.add_argument("--markers", type=int, help="add markers on the segments up to this many (default: 36)")
    ap.add_argument("--against", metavar="REV")
    ap.add_argument("--unit", action="store_true", help="the whole clean unit through the engine, not the stage")
    ap.add_argument("--child", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--prepare", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.prepare is not None:
        prepare_unit(args.prepare, args.rate_hz, args.markers, args.out)
        return 0
    if args.child is not None:
        if args.unit:
            child_unit(args.child, args.rate_hz, args.markers, args.out)
        else:
            child(args.child, args.rate_hz, args.markers)
        return 0
    shape = [f"--rate-hz={args.rate_hz}"] * bool(args.rate_hz) + [f"--markers={args.markers}"] * bool(args.markers)
    sys.path.insert(0, str(ROOT / "bench"))
    from bench_fill_speed import checkout

    trees = {"new": ROOT} if not args.against else {"old": checkout(args.against), "new": ROOT}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_clean_length_") as tmp:
        for minutes in [float(x) for x in args.minutes.split(",")]:
            unit = []
            if args.unit:
                unit = ["--unit", f"--out={tmp}"]
                subprocess.run([sys.executable, __file__, "--prepare", str(minutes), *shape, f"--out={tmp}"],
                               env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=ROOT, check=True)
            for side, tree in trees.items():
                env = dict(os.environ, PYTHONPATH=str(tree))
                run = subprocess.run([sys.executable, __file__, "--child", str(minutes), *shape, *unit], env=env,
                                     cwd=ROOT, capture_output=True, text=True, check=True)
                r = json.loads(next(x for x in run.stdout.splitlines() if x.startswith("RESULT "))[7:])
                rows.append((minutes, side, r))
    _print(rows, args.unit)
    return 0


def _print(rows: list, unit: bool) -> None:
    print(f"{'minutes':>7} {'side':>4} {'frames':>8} {'samples':>10} {'CPU s':>7} {'us/sample':>9} "
          f"{'peak MB':>8} {'added B/sample':>14}" + "  unit's files (SHA-256)" * unit)
    for minutes, side, r in rows:
        files = " ".join(f"{k}={v}" for k, v in sorted(r.get("sha256", {}).items()))
        status = f" {r['status']}: {r['error']}" if unit and r["status"] != "ok" else ""
        print(f"{minutes:7g} {side:>4} {r['frames']:8d} {r['samples']:10d} {r['cpu_s']:7.2f} "
              f"{1e6 * r['cpu_s'] / r['samples']:9.2f} {r['peak_bytes'] / 2**20:8.0f} "
              f"{r['added_bytes'] / r['samples']:14.0f}" + f"  {files}{status}" * unit)
    by = {(m, side): r for m, side, r in rows}
    lengths = sorted({m for m, _, _ in rows})
    for side in dict.fromkeys(side for _, side, _ in rows):
        for a, b in zip(lengths, lengths[1:], strict=False):
            ra, rb = by[(a, side)], by[(b, side)]
            print(f"{side}: {b:g} min against {a:g} min: CPU {rb['cpu_s'] / ra['cpu_s']:.2f}x, "
                  f"peak memory {rb['peak_bytes'] / ra['peak_bytes']:.2f}x")

if __name__ == "__main__":
    raise SystemExit(main())
