"""The clock map under the clapper's hazards, against the ground truth (SPEC §3.4).

Sessions from ``gazepipe.synth`` whose every gaze_follow take has one clap hazard on one of its two claps, the
kinds taking turns (``SynthConfig.clap_hazards``): a slow, soft clap; the clapper mostly hidden from the camera
by an occluder that comes in a second before the clap; one or two video frames dropped 0.2–0.8 s before a clap
(the container still stamps frames at the nominal rate); a clapper marker missing for 2–5 frames across the
contact. Camera clocks cycle over a fast crystal (+200…+800 ppm), a 59.94 Hz camera labelled 60 (+1,000 ppm)
and a slow crystal started after the mocap. Both marker layouts, ``--seeds`` seeds, ``--takes`` takes each.

Each take's sync runs as the pipeline runs it (:func:`gazepipe.stages.sync.stage.sync_take` on the C3D's
clapper markers and the video, default parameters), and its QC goes through the report's sync checks. Printed
per take and summarised per hazard kind:

- whether sync failed the take (the acceptance: never, when another clap or the nominal rate can stand in);
- the largest error of the clock map over the video frames inside the take (those the eye samples come from):
  the fitted map at the frames' stamps against the instants they were really exposed (truth ``video_time_s``
  → ``video_mocap_time_s``), ms; and the same over the take's crop (the frames the datasets use);
- the report's ``clock_map`` check: the acceptance is an error within 5 ms, or a failed check naming the clap;
- the sync's warnings.

Usage: ``PYTHONPATH=. python bench/bench_claps_truth.py [--seeds 2] [--takes 4] [--duration 15]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from gazepipe.errors import StageError
from gazepipe.io.capture import read_markers
from gazepipe.io.video import FrameReader, probe_video
from gazepipe.report.checks import Thresholds, sync_checks
from gazepipe.stages.sync.qc import SyncQC
from gazepipe.stages.sync.stage import SyncParams, sync_take
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.skeleton import CLAPPER_MARKERS, FOUR_SEGMENTS, SEGMENTS

LAYOUTS = {"10 segments, z up": (SEGMENTS, "z"), "4 segments, y up": (FOUR_SEGMENTS, "y")}


def sync_one(folder: Path, take: str) -> tuple[dict | None, str | None]:
    """The take's sync QC as the pipeline makes it, or the error that failed it."""
    raw = read_markers(folder / "mocap" / f"{take}.c3d")
    a, b = (raw.labels.index(m) for m in CLAPPER_MARKERS)
    video = folder / "video" / f"{take}.mp4"
    ts = probe_video(video).timestamps_s
    p = SyncParams()
    kw = {k: getattr(p, k) for k in ("window_s", "search_s", "max_drift", "min_confidence")
          if hasattr(p, k)}
    try:
        with FrameReader(video, gray=True, scale=p.video_scale, timestamps_s=ts) as read_window:
            res = sync_take(raw.xyz[:, a], raw.xyz[:, b], raw.valid[:, a], raw.valid[:, b], raw.rate_hz, ts,
                            read_window, mocap_path=str(folder / "mocap" / f"{take}.c3d"), video_path=str(video),
                            take=take, **kw)
    except StageError as e:
        return None, str(e)
    return res.qc, None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--takes", type=int, default=4, help="gaze_follow takes per session (one hazard each)")
    ap.add_argument("--duration", type=float, default=15.0, help="seconds of each gaze_follow take")
    args = ap.parse_args()
    by_kind: dict[str, list[tuple[float | None, str, bool]]] = defaultdict(list)
    crop_errs: dict[str, list[float]] = defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        for label, (segments, up) in LAYOUTS.items():
            print(f"\n{label}:")
            print(f"  {'seed take':<24} {'hazard':<15} {'clap':>4} {'clock':>8} {'map err ms':>10} "
                  f"{'in crop':>8} {'clock_map':>9}  warnings / error")
            for seed in range(args.seeds):
                cfg = SynthConfig(follow_poses=("standing",) * args.takes, follow_duration_s=args.duration,
                                  shift_targets=(), face_takes=(), segments=segments, up_axis=up,
                                  clap_hazards=1.0, session_id=f"claps{seed}")
                folder = generate_session(Path(tmp) / f"{label[:2].strip()}{seed}", seed=seed, config=cfg)
                truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
                for take, t in truth.items():
                    if t["kind"] != "gaze_follow":
                        continue
                    hz = t["design"]["clap_hazard"]
                    tr = np.load(folder / "truth" / f"{take}.npz")
                    qc, err = sync_one(folder, take)
                    clock = f"{(t['video']['ratio'] - 1) * 1e6:+.0f}ppm"
                    if qc is None:
                        by_kind[hz["kind"]].append((None, "sync failed", False))
                        print(f"  s{seed} {take:<21} {hz['kind']:<15} {hz['clap']:>4} {clock:>8} {'-':>10} "
                              f"{'-':>9}  FAILED: {err}")
                        continue
                    # over the video frames that fall inside the take: those the eye samples are resampled from
                    inside = (tr["video_mocap_time_s"] >= 0.0) & \
                        (tr["video_mocap_time_s"] <= (int(t["n_frames"]) - 1) / float(t["rate_hz"]))
                    got = qc["offset_at_video_zero_s"] + qc["ratio"] * tr["video_time_s"][inside]
                    miss = np.abs(got - tr["video_mocap_time_s"][inside]) * 1e3
                    map_err = float(miss.max())
                    c0, c1 = (np.array(t["crop"], dtype=np.float64) - [0, 1]) / float(t["rate_hz"])
                    vm = tr["video_mocap_time_s"][inside]
                    crop_err = float(miss[(vm >= c0) & (vm <= c1)].max())
                    checks = sync_checks(SyncQC.from_record(qc), True, int(t["n_frames"]), float(t["rate_hz"]), Thresholds())
                    cm = next((c for c in checks if c.id == "clock_map"), None)
                    sev = cm.severity if cm is not None else "(none)"
                    ok = map_err <= 5.0 or sev == "fail"
                    by_kind[hz["kind"]].append((map_err, sev, ok))
                    crop_errs[hz["kind"]].append(crop_err)
                    warns = "; ".join(qc.get("warnings", []))
                    print(f"  s{seed} {take:<21} {hz['kind']:<15} {hz['clap']:>4} {clock:>8} {map_err:>10.2f} "
                          f"{crop_err:>8.2f} {sev:>9}  {'' if ok else 'NOT MET '}{warns}")
    print("\nper hazard: takes, sync failures, clock map error (ms) median / max, takes within 5 ms, "
          "takes over 5 ms whose clock_map check fails, acceptance met")
    for kind, rows in sorted(by_kind.items()):
        errs = np.array([e for e, _, _ in rows if e is not None])
        fails = sum(1 for e, _, _ in rows if e is None)
        within = int((errs <= 5.0).sum())
        flagged = sum(1 for e, s, _ in rows if e is not None and e > 5.0 and s == "fail")
        met = sum(1 for _, _, ok in rows if ok)
        print(f"  {kind:<15} {len(rows):>3} takes, {fails} failed, "
              f"{np.median(errs) if errs.size else float('nan'):6.2f} / {errs.max() if errs.size else float('nan'):6.2f} ms, "
              f"{within} within 5 ms, {flagged} flagged, {met} of {len(rows)} met; in the crop: max "
              f"{max(crop_errs[kind], default=float('nan')):.2f} ms")


if __name__ == "__main__":
    main()
