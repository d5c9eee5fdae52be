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

With ``--rate-hz R[,R...]`` the sessions are captured at those mocap rates (``SynthConfig.rate_hz``; default the
generator's 29.97 Hz): the held-out captures ran at 30 to 120 Hz. ``--plain`` leaves out the cleaning hazards
(no spikes, no long occlusions, no extra interior gaps: only the generator's ordinary gaps), so a figure can be
told apart from the hazards; ``--long-gaps N`` sets how many 1–3 s trunk/neck occlusions each take gets.
``--own-motion DEG``: each segment also turns on its own in the gaze_follow takes (``SynthConfig.own_motion_deg``,
RMS degrees), unlike its neighbours: captures whose motion the code was not tuned on.

Usage: ``python bench/bench_datasets_truth.py [--seeds 2] [--layouts 10,4] [--rate-hz 29.97] [--duration 30]
[--plain] [--long-gaps 4] [--own-motion 0] [--swaps 0] [--no-repair] [--bursts 0] [--clap-hazards 0]``
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
from gazepipe.schemas.joints import joints_arrays
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


def session_config(args: argparse.Namespace, segments: tuple[str, ...], up: str, rate: float | None) -> SynthConfig:
    """The generated session of one layout and rate with the hazards the arguments ask for."""
    hazards = ({} if args.plain else
               {"spikes_per_marker_min": 1.0, "long_gaps": args.long_gaps, "gaps_per_marker_min": 3.0})
    extra = {} if rate is None else {"rate_hz": rate}
    return SynthConfig(follow_poses=("standing", "sitting"), follow_duration_s=args.duration, face_takes=(),
                       segments=segments, up_axis=up, label_swaps=args.swaps, occlusion_bursts=args.bursts,
                       clap_hazards=args.clap_hazards, own_motion_deg=args.own_motion, **hazards, **extra)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="2",
                    help="a count (seeds 0..N-1) or a comma-separated list of seeds (\"3,\" is seed 3 alone; \"1,3\")")
    ap.add_argument("--layouts", default="10,4", help="which marker layouts: 10, 4 or both (10,4)")
    ap.add_argument("--rate-hz", default="",
                    help="mocap rates, comma-separated (default: the generator's 29.97 Hz)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of each gaze_follow take")
    ap.add_argument("--plain", action="store_true", help="no spikes, long occlusions or extra interior gaps")
    ap.add_argument("--long-gaps", type=int, default=4, help="1-3 s trunk/neck occlusions per mocap take")
    ap.add_argument("--swaps", type=int, default=0, help="label swaps per mocap take")
    ap.add_argument("--no-repair", action="store_true", help="clean.repair_swaps = false")
    ap.add_argument("--bursts", type=int, default=0, help="occlusion bursts per mocap take")
    ap.add_argument("--clap-hazards", type=float, default=0.0,
                    help="share of gaze_follow takes with a clap hazard (SynthConfig.clap_hazards)")
    ap.add_argument("--own-motion", type=float, default=0.0, metavar="DEG",
                    help="each segment's own motion in gaze_follow takes, RMS deg (SynthConfig.own_motion_deg)")
    args = ap.parse_args()
    seeds = [int(x) for x in args.seeds.split(",") if x] if "," in args.seeds else list(range(int(args.seeds)))
    layouts = {k: v for k, v in LAYOUTS.items() if k.split()[0] in args.layouts.split(",")}
    rates: list[float | None] = [float(x) for x in args.rate_hz.split(",") if x] or [None]
    cleaning = ("no cleaning hazards" if args.plain else
                f"spikes 1/marker/min, {args.long_gaps} trunk/neck occlusions of 1-3 s per take, 3 gaps/marker/min")
    print(f"hazards: {cleaning}, {args.swaps} label swaps per take{' (not repaired)' if args.no_repair else ''}, "
          f"{args.bursts} occlusion bursts per take, clap hazards in {args.clap_hazards:g} of the gaze_follow "
          f"takes, segments' own motion {args.own_motion:g}° RMS; seeds {seeds}; two {args.duration:g} s gaze_follow takes and 10 gaze_shift takes per session")
    params = {"clean.repair_swaps": False} if args.no_repair else None
    for rate in rates:
        for label, (segments, up) in layouts.items():
            run_layout(args, seeds, f"{label}, {rate or 29.97:g} Hz", segments, up, rate, params)


def run_layout(args: argparse.Namespace, seeds: list[int], label: str, segments: tuple[str, ...], up: str,
               rate: float | None, params: dict | None) -> None:
    """Run every seed of one layout and rate and print its figures."""
    errs: dict[str, list[np.ndarray]] = {"gaze_rnn": [], "gaze_rnn_lod": []}
    terrs: dict[str, list[np.ndarray]] = {"gaze_rnn": [], "gaze_rnn_lod": []}
    cover = {"gaze_rnn": [0, 0, 0], "gaze_rnn_lod": [0, 0, 0]}
    dropped: dict[str, Counter] = {"gaze_rnn": Counter(), "gaze_rnn_lod": Counter()}
    why: dict[str, Counter] = {"gaze_rnn": Counter(), "gaze_rnn_lod": Counter()}
    worst: dict[str, list[tuple[float, str]]] = {"gaze_rnn": [], "gaze_rnn_lod": []}
    bad_how: dict[str, Counter] = {"gaze_rnn": Counter(), "gaze_rnn_lod": Counter()}
    crops: list[int] = []
    crop_bad: list[str] = []
    said: list[int] = []
    whole: list[str] = []
    failed: list[str] = []
    flipped: Counter = Counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            cfg = session_config(args, segments, up, rate)
            folder = generate_session(Path(tmp) / f"s{seed}", seed=seed, config=cfg)
            out = Path(tmp) / f"out{seed}"
            summary = run_pipeline([load_session(folder / "session.toml")], out, executor="serial",
                                   params=params, log=EventLog(fmt="json", stream=io.StringIO()))
            failed += [f"s{seed} {o.take} {o.stage}: {o.error}" for o in summary.failed if o.take != "-"]
            crop_errors(folder, out, cfg.session_id, seed, crops, crop_bad, said, whole)
            flipped.update(flip_counts(folder, out, cfg.session_id))
            for name in errs:
                rows = dataset_rows(out, name)
                add_how(out, cfg.session_id, rows)
                e = segment_errors(folder, rows)
                errs[name].append(e)
                terrs[name].append(target_errors(folder, rows))
                worst[name] += worst_rows(rows, e, seed)
                bad_how[name].update(how_counts(rows, e))
                h, n, hid = coverage(folder, out, cfg.session_id, rows, eyes=name == "gaze_rnn")
                cover[name][0] += h
                cover[name][1] += n
                cover[name][2] += hid
                why[name].update(missing_reasons(folder, out, cfg.session_id, rows, name))
                info = out / "datasets" / name / "_dataset.json"
                if info.is_file():
                    dropped[name].update(json.loads(info.read_text())["counts"].get("dropped_frames", {}))
    ce = np.array(crops)
    print(f"\n{label}: takes failing a stage: {len(failed)}" + "".join(f"\n  {f}" for f in failed[:5]))
    print(f"  crop bounds: {len(ce) + len(said)}, largest error {ce.max() if ce.size else 0} frames, "
          f"{int((ce > 3).sum())} more than 3 frames off unannounced, {len(said)} more than 3 off where the stage "
          f"said they may be (markers hidden against them); {len(whole)} gaze_shift takes kept whole without a crop "
          "(a rest not found, said so)" + "".join(f"\n    {b}" for b in crop_bad[:8])
          + (f"\n    kept whole: {', '.join(whole)}" if whole else ""))
    print(f"  frames made gaps by the frames stage's continuity check (flips), gaze_follow takes: "
          f"{flipped['segment']} segment rotations, {flipped['heading']} character frames")
    for name in errs:
        print_dataset(name, errs[name], terrs[name], cover[name], dropped[name], why[name], worst[name],
                      bad_how[name])


def print_dataset(name: str, errs: list[np.ndarray], terrs: list[np.ndarray], cover: list[int],
                  dropped: Counter, why: Counter, worst: list[tuple[float, str]], bad_how: Counter) -> None:
    """One dataset's figures over a layout's seeds."""
    e = np.concatenate([x for x in errs if x.size]) if any(x.size for x in errs) else None
    h, n, hid = cover
    what = "frames with valid eyes in the crop" if name == "gaze_rnn" else "crop frames"
    if e is None or not e.size:
        print(f"  {name:13s} no rows; {what}: {n}")
        return
    worst_seg = e.max(axis=1)
    print(f"  {name:13s} {len(e):6d} rows: segment error median {np.median(e):.2f}°, p99 "
          f"{np.percentile(e, 99):.2f}°, max {e.max():.1f}°; rows with a segment > 5°: {(worst_seg > 5).sum()}; "
          f"holds {100 * h / max(n, 1):.1f} % of the {n} {what} ({hid} of them with the target "
          f"marker hidden for more than a second; {100 * h / max(n - hid, 1):.1f} % of the rest)")
    te = np.concatenate(terrs)
    print(f"  {'':13s} target direction error median {np.median(te):.2f}°, p99 {np.percentile(te, 99):.2f}°, "
          f"max {te.max():.1f}°")
    print(f"  {'':13s} dropped frames: {dict(sorted(dropped.items()))}")
    print(f"  {'':13s} usable frames without a row, by cause: {dict(why.most_common())}")
    if bad_how:
        print(f"  {'':13s} segment rotations more than 5° off in rows, by how they were made: {dict(bad_how)}")
    bad = sorted(worst, reverse=True)[:4]
    if bad and bad[0][0] > 3.0:
        print(f"  {'':13s} worst rows: " + "".join(f"\n  {'':15s}{w}" for a, w in bad if a > 3.0))


def add_how(out: Path, session: str, rows: list[dict]) -> None:
    """Add to each take's rows how each segment rotation was made (``how`` (rows, S): ``measured``, ``filled``
    across a gap, or ``fit`` to gap-filled markers), from its joints table."""
    for r in rows:
        j = joints_arrays(pq.read_table(out / "takes" / session / r["take"] / "joints.parquet"))
        segs = list(j["segments"])
        keep = [segs.index(n.split(".")[0]) for n in r["names"][0::6] if n.split(".")[0] in segs]
        pos = np.searchsorted(np.asarray(j["frame"]), r["frame"])
        filled = np.asarray(j["rot_filled"], dtype=bool)[pos][:, keep]
        measured = np.asarray(j["rot_measured"], dtype=bool)[pos][:, keep]
        r["how"] = np.where(filled, "filled", np.where(measured, "measured", "fit"))


def worst_rows(rows: list[dict], err: np.ndarray, seed: int) -> list[tuple[float, str]]:
    """The worst row of each take (segment error, deg) with where it is and how that rotation was made."""
    out: list[tuple[float, str]] = []
    k = 0
    for r in rows:
        e = err[k:k + len(r["frame"])]
        k += len(r["frame"])
        if not len(e):
            continue
        i, j = np.unravel_index(int(np.argmax(e)), e.shape)
        names = [x.split(".")[0] for x in r["names"][0::6]]
        out.append((float(e[i, j]), f"s{seed} {r['take']} frame {int(r['frame'][i])} {names[j]} {e[i, j]:.1f}° "
                                    f"({r['how'][i, j]}; {int((e.max(axis=1) > 5).sum())} rows > 5° in the take)"))
    return out


def how_counts(rows: list[dict], err: np.ndarray) -> Counter:
    """Segment rotations more than 5° off, by how they were made."""
    c: Counter = Counter()
    k = 0
    for r in rows:
        e = err[k:k + len(r["frame"])]
        k += len(r["frame"])
        c.update(r["how"][e > 5.0].tolist())
    return c


def crop_errors(folder: Path, out: Path, session: str, seed: int, crops: list[int], bad: list[str],
                said: list[int], whole: list[str]) -> None:
    """Each mocap take's crop bounds against the truth (frames), appended to ``crops``; those beyond 3 to ``bad``.
    A bound more than 3 frames off that the clean stage said may be off (QC ``crop_hidden``: frames hidden
    against it) by at least as much goes to ``said`` instead of ``crops``; a gaze_shift take kept whole, without
    a crop, because one of its rests was not found (a warning says so) goes to ``whole``."""
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    for take, t in truth.items():
        if t["kind"] in ("face", "neutral") or not t.get("crop"):
            continue
        path = out / ".gazepipe" / "units" / session / take / "clean.json"
        rec = json.loads(path.read_text()) if path.is_file() else {}
        if rec.get("status") != "ok":
            bad.append(f"s{seed} {take}: clean failed")
            continue
        if any("kept whole" in w for w in rec["qc"].get("warnings", [])):
            whole.append(f"s{seed} {take}")     # one rest found: no crop, said so (gaze_map leaves it out)
            continue
        e = [abs(rec["qc"]["crop"][i] - t["crop"][i]) for i in (0, 1)]
        hidden = rec["qc"].get("crop_hidden") or [0, 0]
        # a bound the stage said may be off (frames hidden against it) and off within that is not counted
        crops.extend(x if x <= 3 or not (0 < x <= h + 3) else 0 for x, h in zip(e, hidden, strict=True))
        said.extend(x for x, h in zip(e, hidden, strict=True) if x > 3 and 0 < x <= h + 3)
        if max(e) > 3:
            bad.append(f"s{seed} {take}: crop {rec['qc']['crop']} truth {t['crop']}"
                       + (f" (said to be off by up to {hidden} frames)" if any(hidden) else ""))


def flip_counts(folder: Path, out: Path, session: str) -> Counter:
    """Segment rotations and character frames the frames stage made gaps as flips, over the gaze_follow takes
    (QC ``flip_frames``, ``heading_flip_frames``; none where the stage does not record them)."""
    c: Counter = Counter()
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    for take, t in truth.items():
        path = out / ".gazepipe" / "units" / session / take / "frames.json"
        if t["kind"] != "gaze_follow" or not path.is_file():
            continue
        qc = json.loads(path.read_text()).get("qc", {})
        c["segment"] += sum(qc.get("flip_frames", {}).values())
        c["heading"] += qc.get("heading_flip_frames", 0)
    return c


def missing_reasons(folder: Path, out: Path, session: str, rows: list[dict], name: str) -> Counter:
    """Why the usable frames of each gaze_follow take (inside the true crop, target marker not hidden for more
    than a second, eyes valid for gaze_rnn) have no row: the first cause found of ``no joints``, ``no target``,
    ``eyes`` (gaze_rnn), ``no character frame``, a segment's rotation missing (``refused fill`` inside a rotation
    gap whose estimate was above the limit, ``open gap`` where no fill was tried, ``no rotation`` otherwise:
    e.g. refused by the frames stage's checks), ``first of run`` (the frame before it gave no previous pose)."""
    out_c: Counter = Counter()
    truth = json.loads((folder / "truth" / "truth.json").read_text())["takes"]
    got = {r["take"]: set(int(f) for f in r["frame"]) for r in rows}
    for take, t in truth.items():
        if t["kind"] != "gaze_follow" or not t.get("crop"):
            continue
        a, b = t["crop"]
        jpath = out / "takes" / session / take / "joints.parquet"
        if not jpath.is_file():
            out_c["no joints"] += b - a
            continue
        j = joints_arrays(pq.read_table(jpath))
        segs = list(j["segments"])
        info = out / "datasets" / name / "_dataset.json"
        ynames = json.loads(info.read_text())["features"]["y"] if info.is_file() else []
        keep = [segs.index(n.split(".")[0]) for n in ynames[0::6] if n.split(".")[0] in segs] or list(range(len(segs)))
        frame = np.asarray(j["frame"], dtype=np.int64)
        pos = {int(f): i for i, f in enumerate(frame)}
        qpath = out / ".gazepipe" / "units" / session / take / "frames.json"
        gaps = json.loads(qpath.read_text()).get("qc", {}).get("rotation_gaps", []) if qpath.is_file() else []
        state = np.zeros((len(frame), len(segs)), dtype=np.int8)      # 1 refused, 2 not tried
        for g in gaps:
            if not g["filled"]:
                state[max(0, g["start"]):max(0, g["stop"]), g["segment"]] = 1 if g["error_deg"] is not None else 2
        eyes_ok = None
        if name == "gaze_rnn":
            path = out / "takes" / session / take / "eyes.parquet"
            if path.is_file():
                e = pq.read_table(path, columns=["frame", "valid"]).to_pydict()
                eyes_ok = {f for f, v in zip(e["frame"], e["valid"], strict=True) if v}
        tr = np.load(folder / "truth" / f"{take}.npz")
        labels = list(tr["labels"])
        hidden = np.zeros(len(tr["gap_mask"]), dtype=bool)
        if "POLE" in labels:
            rate = float(t.get("rate_hz", 29.97))
            gone = tr["gap_mask"][:, labels.index("POLE")]
            edges = np.flatnonzero(np.diff(np.concatenate([[0], gone.astype(np.int8), [0]])))
            for a0, b0 in zip(edges[0::2], edges[1::2], strict=True):
                if b0 - a0 > rate:
                    hidden[a0:b0] = True
        have = got.get(take, set())
        for f in range(a, b):
            if hidden[f] or f in have or (eyes_ok is not None and f not in eyes_ok):
                continue
            i = pos.get(f)
            out_c[frame_cause(j, i, keep, state)] += 1
    return out_c


def frame_cause(j: dict, i: int | None, keep: list[int], state: np.ndarray) -> str:
    """Why joints row ``i`` gives no row (see :func:`missing_reasons`)."""
    if i is None:
        return "no joints"
    if not np.isfinite(j["target_dir"][i]).all():
        return "no target"
    if not np.isfinite(j["char_rot"][i]).all():
        return "no character frame"
    q = j["quat"][i, keep]
    miss = [k for k, s in enumerate(keep) if not np.isfinite(q[k]).all()]
    if miss:
        st = max(int(state[i, keep[k]]) for k in miss)
        return {1: "refused fill", 2: "open gap"}.get(st, "no rotation")
    return "first of run"


if __name__ == "__main__":
    main()
