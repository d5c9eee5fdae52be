"""Exports as users have them, against the truth: gaze dataset rows of sessions whose mocap is captured at a
stated rate that is no NTSC rate, partly exported as Vicon Nexus CSV, with face tracking lost at times (the
tables and rows ``bench_datasets_truth.py`` checks, with these exports).

The sessions, hazards (``--bursts``, ``--swaps``, ``--no-repair``, ``--clap-hazards``) and the rows, errors and
coverage printed per layout are ``bench_datasets_truth.py``'s (see its docstring).

Exports as users have them (issue 46): ``--rate HZ`` captures the mocap at that rate (69.9 Hz is no NTSC rate:
it must be read as 69.9 Hz, not 69.9301); ``--nexus-csv S`` exports that share of the mocap takes as Vicon Nexus
CSV files with subject-prefixed labels (``SynthConfig.nexus_csv``); ``--face-loss N`` adds two face takes (60 and
30 Hz, 12 s) whose tracked files have N tracking-loss stretches (``SynthConfig.face_tracking_loss``); ``--plain``
leaves out the hazards (spikes, long occlusions, dense gaps). Printed per layout as well: the mocap rate as
ingest read it against the truth's, the time that error makes at a take's last frame, whether every take names
its markers as the truth does (one name per marker across the session, whatever the export), and the face takes'
rows in ``face_clean`` against the truth's frames with tracking.

Usage: ``python bench/bench_exports_truth.py [--seeds 2] [--duration 30] [--swaps 0] [--no-repair] [--bursts 0]
[--clap-hazards 0] [--rate HZ] [--nexus-csv 0] [--face-loss 0] [--plain]``
"""

from __future__ import annotations

import argparse
import io
import json
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog
from gazepipe.synth import SynthConfig, generate_session

try:
    from bench.bench_datasets_truth import LAYOUTS, coverage, dataset_rows, segment_errors, target_errors
except ModuleNotFoundError:   # run as a script: its own folder is on the path
    from bench_datasets_truth import LAYOUTS, coverage, dataset_rows, segment_errors, target_errors  # type: ignore


def ingest_figures(folder: Path, out: Path, session_id: str) -> tuple[list[float], list[float], list[str]]:
    """Per mocap take: the rate ingest read minus the truth's (Hz), the time that makes at the last frame (ms),
    and the takes whose marker names differ from the truth's labels."""
    from gazepipe.schemas.markers import table_to_markers

    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    d_rate, d_time, misnamed = [], [], []
    for take, t in truth.items():
        path = out / "takes" / session_id / take / "markers_raw.parquet"
        if t["kind"] == "face" or not path.is_file():
            continue
        m = table_to_markers(pq.read_table(path))[0]
        d_rate.append(m.rate_hz - t["rate_hz"])
        d_time.append(1000.0 * (m.n_frames - 1) * (1.0 / m.rate_hz - 1.0 / t["rate_hz"]))
        if sorted(m.labels) != sorted(np.load(folder / "truth" / f"{take}.npz")["labels"].tolist()):
            misnamed.append(take)
    return d_rate, d_time, misnamed


def face_rows(folder: Path, out: Path) -> tuple[int, int]:
    """(unmirrored rows of ``face_clean``, the truth's tracked frames that have tracking and a row in both files)."""
    rows = sum(int((~pq.read_table(f, columns=["mirrored"]).column("mirrored").to_numpy(zero_copy_only=False)).sum())
               for f in (out / "datasets" / "face_clean").rglob("*.parquet")) \
        if (out / "datasets" / "face_clean").is_dir() else 0
    want = 0
    for take, t in json.loads((folder / "truth" / "truth.json").read_text())["takes"].items():
        if t["kind"] == "face":
            tr = np.load(folder / "truth" / f"{take}.npz")
            ok = ~tr["face_tracked_dropped"] & ~tr["face_clean_dropped"]
            if "face_tracked_lost" in tr.files:
                ok &= ~tr["face_tracked_lost"]
            want += int(ok.sum()) - 1                  # the last aligned row has no forward derivative
    return rows, want


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="2",
                    help="a count (seeds 0..N-1) or a comma-separated list of seeds (\"3,\" is seed 3 alone; \"1,3\")")
    ap.add_argument("--layouts", default="10,4", help="which marker layouts: 10, 4 or both (10,4)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of each gaze_follow take")
    ap.add_argument("--swaps", type=int, default=0, help="label swaps per mocap take")
    ap.add_argument("--no-repair", action="store_true", help="clean.repair_swaps = false")
    ap.add_argument("--bursts", type=int, default=0, help="occlusion bursts per mocap take")
    ap.add_argument("--clap-hazards", type=float, default=0.0,
                    help="share of gaze_follow takes with a clap hazard (SynthConfig.clap_hazards)")
    ap.add_argument("--rate", type=float, default=None, help="mocap rate, Hz (default the generator's 29.97)")
    ap.add_argument("--nexus-csv", type=float, default=0.0, help="share of mocap takes exported as Nexus CSV")
    ap.add_argument("--face-loss", type=int, default=0,
                    help="add two face takes with this many tracking-loss stretches each")
    ap.add_argument("--plain", action="store_true", help="no spikes, long occlusions or dense gaps")
    args = ap.parse_args()
    seeds = [int(x) for x in args.seeds.split(",") if x] if "," in args.seeds else list(range(int(args.seeds)))
    layouts = {k: v for k, v in LAYOUTS.items() if k.split()[0] in args.layouts.split(",")}
    hazards = dict(spikes_per_marker_min=0.0, long_gaps=0, gaps_per_marker_min=0.0) if args.plain else dict(
        spikes_per_marker_min=1.0, long_gaps=4, gaps_per_marker_min=3.0)
    exports = dict(nexus_csv=args.nexus_csv, face_tracking_loss=args.face_loss,
                   face_takes=((60.0, 12.0), (30.0, 12.0)) if args.face_loss else ())
    if args.rate is not None:
        exports["rate_hz"] = args.rate
    print(("hazards: none beyond the generator's gaps, " if args.plain else
           "hazards: spikes 1/marker/min, 4 trunk/neck occlusions of 1-3 s per take, 3 gaps/marker/min, ")
          + f"{args.swaps} label swaps per take{' (not repaired)' if args.no_repair else ''}, "
          f"{args.bursts} occlusion bursts per take; "
          f"seeds {seeds}; two {args.duration:g} s gaze_follow takes and 10 gaze_shift takes per session")
    params = {"clean.repair_swaps": False} if args.no_repair else None
    for label, (segments, up) in layouts.items():
        errs = {"gaze_rnn": [], "gaze_rnn_lod": []}
        terrs: dict[str, list[np.ndarray]] = {"gaze_rnn": [], "gaze_rnn_lod": []}
        cover = {"gaze_rnn": [0, 0, 0], "gaze_rnn_lod": [0, 0, 0]}
        dropped = {"gaze_rnn": Counter(), "gaze_rnn_lod": Counter()}
        failed: list[str] = []
        d_rate: list[float] = []
        d_time: list[float] = []
        misnamed: list[str] = []
        faces = [0, 0]
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=args.duration,
                                  segments=segments, up_axis=up, label_swaps=args.swaps,
                                  occlusion_bursts=args.bursts, clap_hazards=args.clap_hazards,
                                  **hazards, **exports)
                folder = generate_session(Path(tmp) / f"s{seed}", seed=seed, config=cfg)
                out = Path(tmp) / f"out{seed}"
                summary = run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                                       params=params, log=EventLog(fmt="json", stream=io.StringIO()))
                failed += [f"{o.take} {o.stage}: {o.error}" for o in summary.failed if o.take != "-"]
                r, t, bad = ingest_figures(folder, out, cfg.session_id)
                d_rate += r
                d_time += t
                misnamed += [f"s{seed}/{b}" for b in bad]
                if args.face_loss:
                    got, want = face_rows(folder, out)
                    faces[0] += got
                    faces[1] += want
                for name in errs:
                    rows = dataset_rows(out, name)
                    errs[name].append(segment_errors(folder, rows))
                    terrs[name].append(target_errors(folder, rows))
                    h, n, hid = coverage(folder, out, cfg.session_id, rows, eyes=name == "gaze_rnn")
                    cover[name][0] += h
                    cover[name][1] += n
                    cover[name][2] += hid
                    info = out / "datasets" / name / "_dataset.json"
                    if info.is_file():
                        dropped[name].update(json.loads(info.read_text())["counts"].get("dropped_frames", {}))
        print(f"\n{label}: takes failing a stage: {len(failed)}" + "".join(f"\n  {f}" for f in failed[:5]))
        if d_rate:
            print(f"  ingest: mocap rate read - truth's: max |{max(abs(x) for x in d_rate):.3g}| Hz; time error at a "
                  f"take's last frame: max |{max(abs(x) for x in d_time):.3g}| ms; takes naming their markers "
                  f"otherwise than the truth: {len(misnamed)} {misnamed[:4]}")
        if args.face_loss:
            print(f"  face_clean: {faces[0]} unmirrored rows for the {faces[1]} frames with tracking in both files")
        for name in errs:
            e = np.concatenate([x for x in errs[name] if x.size]) if any(x.size for x in errs[name]) else None
            h, n, hid = cover[name]
            what = "frames with valid eyes in the crop" if name == "gaze_rnn" else "crop frames"
            if e is None or not e.size:
                print(f"  {name:13s} no rows; {what}: {n}")
                continue
            worst = e.max(axis=1)
            print(f"  {name:13s} {len(e):6d} rows: segment error median {np.median(e):.2f}°, p99 "
                  f"{np.percentile(e, 99):.2f}°, max {e.max():.1f}°; rows with a segment > 5°: {(worst > 5).sum()}; "
                  f"holds {100 * h / max(n, 1):.1f} % of the {n} {what} ({hid} of them with the target "
                  f"marker hidden for more than a second; {100 * h / max(n - hid, 1):.1f} % of the rest)")
            te = np.concatenate(terrs[name])
            print(f"  {'':13s} target direction error median {np.median(te):.2f}°, p99 {np.percentile(te, 99):.2f}°, "
                  f"max {te.max():.1f}°")
            print(f"  {'':13s} dropped frames: {dict(dropped[name])}")


if __name__ == "__main__":
    main()
