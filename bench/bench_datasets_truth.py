"""The gaze datasets built from hostile generated sessions, row by row against the ground truth.

Sessions from ``gazepipe.synth`` with the hazards of real capture (ghost spikes on any marker, 1–3 s occlusions
of trunk and neck markers inside the first rest and across the crop's edges, dense interior gaps), with the
ten-segment marker layout in a z-up lab and the four-segment layout in a y-up lab, for ``--seeds`` seeds. Each is
run through the whole pipeline (``gazepipe run``, serial). Printed per layout: takes that failed a stage; every
segment rotation of every (unmirrored) ``gaze_rnn`` and ``gaze_rnn_lod`` row against the truth (median, p99, max
degrees, and rows with a segment more than 5° off), and its target direction; the share of the frames with valid eyes inside the true crop
that ``gaze_rnn`` holds, and of the crop's frames that ``gaze_rnn_lod`` holds (and again leaving out the frames whose
target marker is hidden in a gap of more than a second: where the pole moves between goals, no fill can know it,
and those frames have no input); the frames each dataset dropped, by reason.

With ``--bursts N`` every mocap take gets N occlusion bursts (``SynthConfig.occlusion_bursts``: 30-80 % of the
subject's markers, on one side, gone for 0.2-1.5 s). With ``--swaps N`` every mocap take also gets N label swaps (``SynthConfig.label_swaps``); ``--no-repair`` runs
with ``clean.repair_swaps = false``, to see what the swaps cost without their repair.

With ``--clap-hazards S`` that share of the gaze_follow takes gets one of the clapper's hazards (a weak clap, a
hidden clap, dropped video frames, a clapper marker gap: ``SynthConfig.clap_hazards``).

Usage: ``python bench/bench_datasets_truth.py [--seeds 2] [--duration 30] [--swaps 0] [--no-repair] [--bursts 0]
[--clap-hazards 0]``
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
from scipy.spatial.transform import Rotation

from gazepipe.dag import run_pipeline
from gazepipe.io.session_toml import load_session
from gazepipe.pipeline.events import EventLog
from gazepipe.stages.geometry import from_wxyz, matrix_from_six
from gazepipe.synth import SynthConfig, generate_session
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENTS

LAYOUTS = {"10 segments, z up": (SEGMENTS, "z"), "4 segments, y up": (FOUR_SEGMENTS, "y")}


def dataset_rows(out: Path, name: str) -> list[dict]:
    """Unmirrored rows of a built dataset, per take: frames and the y features."""
    root = out / "datasets" / name
    if not (root / "_dataset.json").is_file():
        return []
    info = json.loads((root / "_dataset.json").read_text())
    takes = []
    for f in sorted(root.rglob("*.parquet")):
        t = pq.read_table(f, columns=["take", "mirrored", "frame", "x", "y"])
        keep = ~t.column("mirrored").to_numpy(zero_copy_only=False)
        if not keep.any():
            continue
        y = t.column("y").combine_chunks().flatten().to_numpy().reshape(t.num_rows, -1)[keep]
        x = t.column("x").combine_chunks().flatten().to_numpy().reshape(t.num_rows, -1)[keep]
        takes.append({"take": t.column("take")[0].as_py(), "frame": t.column("frame").to_numpy()[keep], "y": y,
                      "target": x[:, :3],
                      "segments": info["sizes"], "names": info["features"]["y"]})
    return takes


def segment_errors(folder: Path, rows: list[dict]) -> np.ndarray:
    """Angle (deg) between each row's segment rotations and the truth, (rows, segments) stacked over takes."""
    out = []
    for r in rows:
        truth = np.load(folder / "truth" / f"{r['take']}.npz")
        names = [n.split(".")[0] for n in r["names"][0::6]]
        names = [n for n in names if n in list(truth["segments"])]
        idx = [list(truth["segments"]).index(n) for n in names]
        six = r["y"][:, :6 * len(names)].reshape(len(r["frame"]), len(names), 6).astype(np.float64)
        got = Rotation.from_matrix(matrix_from_six(six.reshape(-1, 6)))
        want = from_wxyz(truth["seg_quat_char"][r["frame"]][:, idx].reshape(-1, 4).astype(np.float64))
        out.append(np.degrees((got * want.inv()).magnitude()).reshape(len(r["frame"]), len(names)))
    return np.concatenate(out) if out else np.zeros((0, 1))


def target_errors(folder: Path, rows: list[dict]) -> np.ndarray:
    """Angle (deg) between each row's target direction (x's first three numbers) and the truth's."""
    out = []
    for r in rows:
        want = np.load(folder / "truth" / f"{r['take']}.npz")["target_dir_char"][r["frame"]].astype(np.float64)
        got = r["target"].astype(np.float64)
        got = got / np.linalg.norm(got, axis=1, keepdims=True)
        want = want / np.linalg.norm(want, axis=1, keepdims=True)
        out.append(np.degrees(np.arccos(np.clip((got * want).sum(axis=1), -1.0, 1.0))))
    return np.concatenate(out) if out else np.zeros(0)


def coverage(folder: Path, out: Path, session_id: str, rows: list[dict], eyes: bool) -> tuple[int, int, int]:
    """(rows, usable frames, usable frames whose target marker is hidden in a gap longer than a second): frames
    inside the true crop of every gaze_follow take, with valid eyes when ``eyes``."""
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    got = {r["take"]: len(r["frame"]) for r in rows}
    have = need = hidden = 0
    for take, t in truth.items():
        if t["kind"] != "gaze_follow" or not t.get("crop"):
            continue
        a, b = t["crop"]
        frames = set(range(a, b))
        if eyes:
            path = out / "takes" / session_id / take / "eyes.parquet"
            if path.is_file():
                e = pq.read_table(path, columns=["frame", "valid"]).to_pydict()
                frames &= {f for f, v in zip(e["frame"], e["valid"], strict=True) if v}
        need += len(frames)
        have += got.get(take, 0)
        tr = np.load(folder / "truth" / f"{take}.npz")
        labels = list(tr["labels"])
        if "POLE" in labels:
            gone = tr["gap_mask"][:, labels.index("POLE")]
            long = np.zeros_like(gone)
            rate = float(t.get("rate_hz", 29.97))
            edges = np.flatnonzero(np.diff(np.concatenate([[0], gone.astype(np.int8), [0]])))
            for a0, b0 in zip(edges[0::2], edges[1::2], strict=True):
                if b0 - a0 > rate:
                    long[a0:b0] = True
            hidden += sum(1 for f in frames if long[f])
    return have, need, hidden


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
    args = ap.parse_args()
    seeds = [int(x) for x in args.seeds.split(",") if x] if "," in args.seeds else list(range(int(args.seeds)))
    layouts = {k: v for k, v in LAYOUTS.items() if k.split()[0] in args.layouts.split(",")}
    print(f"hazards: spikes 1/marker/min, 4 trunk/neck occlusions of 1-3 s per take, 3 gaps/marker/min, "
          f"{args.swaps} label swaps per take{' (not repaired)' if args.no_repair else ''}, "
          f"{args.bursts} occlusion bursts per take; "
          f"seeds {seeds}; two {args.duration:g} s gaze_follow takes and 10 gaze_shift takes per session")
    params = {"clean.repair_swaps": False} if args.no_repair else None
    for label, (segments, up) in layouts.items():
        errs = {"gaze_rnn": [], "gaze_rnn_lod": []}
        terrs: dict[str, list[np.ndarray]] = {"gaze_rnn": [], "gaze_rnn_lod": []}
        cover = {"gaze_rnn": [0, 0, 0], "gaze_rnn_lod": [0, 0, 0]}
        dropped = {"gaze_rnn": Counter(), "gaze_rnn_lod": Counter()}
        failed: list[str] = []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                cfg = SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=args.duration,
                                  face_takes=(), spikes_per_marker_min=1.0, long_gaps=4, gaps_per_marker_min=3.0,
                                  segments=segments, up_axis=up, label_swaps=args.swaps,
                                  occlusion_bursts=args.bursts, clap_hazards=args.clap_hazards)
                folder = generate_session(Path(tmp) / f"s{seed}", seed=seed, config=cfg)
                out = Path(tmp) / f"out{seed}"
                summary = run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                                       params=params, log=EventLog(fmt="json", stream=io.StringIO()))
                failed += [f"{o.take} {o.stage}: {o.error}" for o in summary.failed if o.take != "-"]
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
