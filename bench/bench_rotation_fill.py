"""Rotation fills across marker gaps: the frames stage's estimated error against the true one (SPEC §3.3).

Where a segment's markers stay unfilled, the frames stage fills its parent-relative rotation across the gap when
its hold-out estimate of the error is at most ``frames.max_fill_error_deg`` (2°). The estimate must bound the
error on the gap's own motion. Sessions from ``gazepipe.synth`` with the hazards that leave markers unfilled
(1–3 s trunk and neck occlusions across the crop's edges and inside it, ``--bursts`` occlusion bursts: 30–80 % of
the markers on one side gone for 0.2–1.5 s), both marker layouts, ``--seeds`` seeds, run through the pipeline
(serial). For every filled rotation gap: the estimate (QC ``rotation_gaps[].error_deg``) against the true error
(the mean, over the gap, of the filled rotation's angle from the truth, after the segment's constant offset from
the truth in its measured frames within a second of the gap is taken out), and the largest true error.

Printed per layout: gaps filled, refused (estimate above the limit) and not tried; among the filled gaps, those
whose true mean error is above 2° (each one gives rows that are off), and those whose truth exceeds the estimate
by more than 1°; the worst of them.

``--rate-hz`` captures at another mocap rate; ``--own-motion DEG`` lets each segment also turn on its own in the
gaze_follow takes (``SynthConfig.own_motion_deg``): gaps whose motion their neighbours do not share.

Usage: ``PYTHONPATH=. python bench/bench_rotation_fill.py [--seeds 2] [--bursts 2] [--rate-hz 29.97]
[--own-motion 0] [--layouts 10,4]``
"""

from __future__ import annotations

import argparse
import io
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog
from gazepipe.schemas.joints import joints_arrays
from gazepipe.stages.clean.filters import true_runs
from gazepipe.stages.geometry import from_wxyz
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENTS

LAYOUTS = {"10 segments, z up": (SEGMENTS, "z"), "4 segments, y up": (FOUR_SEGMENTS, "y")}


def _take_outputs(folder: Path, out: Path, session: str, take: str) -> tuple[dict, dict, Any] | None:
    """A take's joints table (as arrays), its frames unit's QC record and its ground truth; None when the run
    wrote no joints for it."""
    jpath = out / "takes" / session / take / "joints.parquet"
    qpath = out / ".gazepipe" / "units" / session / take / "frames.json"
    if not jpath.is_file() or not qpath.is_file():
        return None
    qc = json.loads(qpath.read_text()).get("qc", {})
    return joints_arrays(pq.read_table(jpath)), qc, np.load(folder / "truth" / f"{take}.npz")


def gap_errors(folder: Path, out: Path, session: str, take: str) -> list[dict]:
    """Per filled rotation gap of a take: segment, frames, estimate, true mean and max error (deg)."""
    got = _take_outputs(folder, out, session, take)
    if got is None:
        return []
    j, qc, truth = got
    names = list(j["segments"])
    tnames = list(truth["segments"])
    frame = np.asarray(j["frame"], dtype=np.int64)
    rows = frame - int(frame[0])
    records = [g for g in qc.get("rotation_gaps", []) if g.get("filled")]
    filled = np.asarray(j["rot_filled"], dtype=bool)
    out_rows = []
    for k, name in enumerate(names):
        if name not in tnames:
            continue
        want = from_wxyz(truth["seg_quat_char"][frame, tnames.index(name)].astype(np.float64))
        q = np.asarray(j["quat"][:, k], dtype=np.float64)
        ok = np.isfinite(q).all(axis=1)
        for s, e in true_runs(filled[:, k]):
            near = ok & ~filled[:, k]
            near[: max(0, s - int(j["meta"].get("rate_hz", 30) or 30))] = False
            near[e + 30:] = False
            if near.sum() < 5:
                continue
            got_near = from_wxyz(q[near])
            offset = (got_near.inv() * want[near]).mean()      # the segment's constant calibration offset
            err = np.degrees((from_wxyz(q[s:e]) * offset * want[s:e].inv()).magnitude())
            # a record's frames count from the joints' first row (negative where the gap began before it)
            g = next((r for r in records if int(r["segment"]) == k and int(r["start"]) <= int(rows[s]) < int(r["stop"])),
                     {})
            out_rows.append({"take": take, "segment": name, "start": int(rows[s]), "frames": int(e - s),
                             "estimate": g.get("error_deg"), "method": g.get("method"),
                             "mean": float(err.mean()), "max": float(err.max())})
    return out_rows


def refused_errors(folder: Path, out: Path, session: str, take: str) -> list[dict]:
    """Per refused rotation gap inside a take (known rotations on both sides, parent known through it): its
    estimate and the true mean and max error (deg) a slerp of the parent-relative rotation across it would have
    had (the segment's constant offset from the truth taken out as in :func:`gap_errors`): how much the refusals
    cost that a fill could have had."""
    from scipy.spatial.transform import Slerp

    got = _take_outputs(folder, out, session, take)
    if got is None:
        return []
    j, qc, truth = got
    names, tnames = list(j["segments"]), list(truth["segments"])
    parents = [int(p) for p in j["meta"]["parents"]]
    frame = np.asarray(j["frame"], dtype=np.int64)
    quat = np.asarray(j["quat"], dtype=np.float64)
    ok = np.isfinite(quat).all(axis=2)
    rows = []
    for g in qc.get("rotation_gaps", []):
        k, s, e = int(g["segment"]), int(g["start"]), int(g["stop"])
        p = parents[k]
        if g.get("filled") or g.get("error_deg") is None or s < 1 or e >= len(frame) or names[k] not in tnames:
            continue
        if not (ok[s - 1, k] and ok[e, k]) or (p >= 0 and not ok[s - 1:e + 1, p].all()):
            continue
        loc = from_wxyz(quat[:, k]) if p < 0 else None
        if p >= 0:
            par = from_wxyz(np.where(ok[:, p, None], quat[:, p], [1.0, 0, 0, 0]))
            ends = par[[s - 1, e]].inv() * from_wxyz(quat[[s - 1, e], k])
            fill = par[s:e] * Slerp([s - 1, e], ends)(np.arange(s, e, dtype=float))
        else:
            assert loc is not None
            fill = Slerp([s - 1, e], loc[[s - 1, e]])(np.arange(s, e, dtype=float))
        want = from_wxyz(truth["seg_quat_char"][frame, tnames.index(names[k])].astype(np.float64))
        near = ok[:, k].copy()
        near[s:e] = False
        near[:max(0, s - 30)] = False
        near[e + 30:] = False
        offset = (from_wxyz(quat[near, k]).inv() * want[near]).mean()
        err = np.degrees((fill * offset * want[s:e].inv()).magnitude())
        rows.append({"take": take, "segment": names[k], "start": s, "frames": e - s, "estimate": g["error_deg"],
                     "mean": float(err.mean()), "max": float(err.max())})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--bursts", type=int, default=2, help="occlusion bursts per mocap take")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of each gaze_follow take")
    ap.add_argument("--rate-hz", type=float, default=None, help="mocap rate (default: the generator's 29.97 Hz)")
    ap.add_argument("--own-motion", type=float, default=0.0, metavar="DEG",
                    help="each segment's own motion in gaze_follow takes, RMS deg (SynthConfig.own_motion_deg)")
    ap.add_argument("--layouts", default="10,4", help="which marker layouts: 10, 4 or both (10,4)")
    args = ap.parse_args()
    extra = {} if args.rate_hz is None else {"rate_hz": args.rate_hz}
    for label, (segments, up) in LAYOUTS.items():
        if label.split()[0] not in args.layouts.split(","):
            continue
        gaps: list[dict] = []
        missed: list[dict] = []
        refused = untried = 0
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seeds):
                cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=args.duration,
                                  face_takes=(), spikes_per_marker_min=1.0, long_gaps=4, gaps_per_marker_min=3.0,
                                  segments=segments, up_axis=up, occlusion_bursts=args.bursts, head_camera=False,
                                  own_motion_deg=args.own_motion, **extra)
                folder = generate_session(Path(tmp) / f"s{seed}", seed=seed, config=cfg)
                out = Path(tmp) / f"out{seed}"
                run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                             log=EventLog(fmt="json", stream=io.StringIO()))
                truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
                for take in truth:
                    if truth[take]["kind"] in ("face",):
                        continue
                    gaps += [dict(g, seed=seed) for g in gap_errors(folder, out, cfg.session_id, take)]
                    missed += [dict(g, seed=seed) for g in refused_errors(folder, out, cfg.session_id, take)]
                    qpath = out / ".gazepipe" / "units" / cfg.session_id / take / "frames.json"
                    if qpath.is_file():
                        for g in json.loads(qpath.read_text()).get("qc", {}).get("rotation_gaps", []):
                            if not g.get("filled"):
                                refused += g.get("error_deg") is not None
                                untried += g.get("error_deg") is None
        bad = [g for g in gaps if g["mean"] > 2.0]
        under = [g for g in gaps if g["estimate"] is not None and g["mean"] > g["estimate"] + 1.0]
        print(f"\n{label}: {len(gaps)} rotation gaps filled ({sum(g['frames'] for g in gaps)} segment-frames), "
              f"{refused} refused by their estimate, {untried} not tried")
        if gaps:
            m = np.array([g["mean"] for g in gaps])
            print(f"  true mean error per filled gap: median {np.median(m):.2f}°, max {m.max():.2f}°; "
                  f"filled gaps truly above 2°: {len(bad)} ({sum(g['frames'] for g in bad)} segment-frames); "
                  f"truth above the estimate by more than 1°: {len(under)}")
            for g in sorted(gaps, key=lambda g: -g["mean"])[:5]:
                est = "-" if g["estimate"] is None else f"{g['estimate']:.2f}°"
                print(f"    s{g['seed']} {g['take']} {g['segment']} rows {g['start']}+{g['frames']} "
                      f"({g['method']}): estimate {est}, truth mean {g['mean']:.2f}° max {g['max']:.2f}°")
            mx = np.array([g["max"] for g in gaps])
            print(f"  filled rotations truly more than 5° off: {sum(int((g['max'] > 5.0) * g['frames']) for g in gaps)} "
                  f"segment-frames at most (gaps whose worst frame is): {int((mx > 5.0).sum())} gaps")
        if missed:
            ok = [g for g in missed if g["max"] <= 3.0]
            print(f"  refused gaps inside the take (parent known through them): {len(missed)} "
                  f"({sum(g['frames'] for g in missed)} segment-frames); a slerp across would have been within 3° "
                  f"on every frame of {len(ok)} ({sum(g['frames'] for g in ok)} segment-frames), within 2° mean of "
                  f"{sum(g['mean'] <= 2.0 for g in missed)}")


if __name__ == "__main__":
    main()
