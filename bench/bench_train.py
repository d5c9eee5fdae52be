"""Do the torch trainers learn, and how fast? Validation error against the baselines, and time per epoch per
device, on a generated session of ``--duration`` seconds.

The session (``gazepipe.synth``, seed ``--seed``): 60 s gaze_follow takes (standing and sitting in turn; every
fourth of each pose pinned to the val split, or the last when a pose has fewer than four, the rest to train)
and four 30 s Live Link Face takes at 60 Hz (the fourth pinned to val), with eye tracking as a well-lit head
camera gives it (as the sample session). ``--duration`` is the whole session's length: the face takes' 120 s
and as many gaze_follow takes as fill the rest. By default it is 600 s (eight gaze_follow takes), or Klein's
corpus size, 2027 s (Klein, Table 1: 60,800 frames at 30 Hz; 32 gaze_follow takes), when a CUDA device is
asked for, since the GPU figures are about that size and beyond.
``gazepipe run`` builds the datasets from it. Both are kept under ``--work`` and reused (the run is
incremental; the session is generated again only when its settings change).

Then ``gaze_rnn`` on the gaze_rnn dataset, on its LOD variant (gaze_rnn_lod) and ``face_clean`` train with
their defaults (``--hidden`` changes gaze_rnn's size on the gaze_rnn dataset only) for ``--epochs`` (default
per model, below) on each ``--device``, and the bench prints per model and device the validation error against
its baseline (holding the previous pose, closed loop and one step, for the gaze models; the raw tracked signal
for face_clean), the time per epoch (median of the training passes, validation apart) and the device.

Usage::

    python bench/bench_train.py                                   # all three, default device, a few minutes on 2 cores
    python bench/bench_train.py --models gaze_rnn --hidden 512 --epochs 3 --device cuda,cpu   # Klein-size, GPU vs CPU
    python bench/bench_train.py --duration 600 --models gaze_rnn --epochs 50                 # a 10-minute session

``--time-budget S`` bounds each training (seconds; epochs are cut after the first to what fits, so the
figures then depend on the machine); ``--train-seed`` the trainers' seed; ``--threads`` torch's CPU threads
(default every core).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

#: (trainer, dataset, default epochs): bounded so that all three take a few minutes on two CPU cores
MODELS: dict[str, tuple[str, str, int]] = {
    "gaze_rnn": ("gaze_rnn", "gaze_rnn", 20),
    "gaze_rnn_lod": ("gaze_rnn", "gaze_rnn_lod", 30),
    "face_clean": ("face_clean", "face_clean", 30),
}
POSES = ("standing", "sitting")
FOLLOW_S, FACE = 60.0, ((60.0, 30.0),) * 4
#: the default --duration, s: a 10-minute session; on a GPU, Klein's corpus (60,800 frames at 30 Hz)
DURATION_S, KLEIN_S = 600.0, 60_800 / 30.0


def follow_poses(duration_s: float) -> tuple[str, ...]:
    """The gaze_follow takes' poses (60 s each, standing and sitting in turn) filling ``duration_s`` less the
    face takes; at least one of each pose."""
    n = max(2, int(round((duration_s - sum(s for _, s in FACE)) / FOLLOW_S)))
    return tuple(POSES[i % 2] for i in range(n))


def session_config(session_id: str, duration_s: float):
    from gazepipe.synth import SynthConfig

    return SynthConfig(follow_poses=follow_poses(duration_s), follow_duration_s=FOLLOW_S, shift_targets=(),
                       face_takes=FACE, session_id=session_id, blink_every_s=(7.0, 15.0),
                       eye_dip_every_s=(15.0, 30.0))


def val_takes(poses: tuple[str, ...]) -> set[str]:
    """The takes pinned to val: every fourth gaze_follow take of each pose (its last when it has fewer than
    four) and the fourth face take."""
    out = {"face_04"}
    for pose in POSES:
        n = poses.count(pose)
        out |= {f"follow_{pose}_{i:02d}" for i in (range(4, n + 1, 4) if n >= 4 else (n,))}
    return out


def pin_splits(toml: Path, val: set[str]) -> None:
    """Pin the gaze_follow and face takes of session.toml to train, those in ``val`` to val (a fixed split,
    fair to both poses)."""
    text = toml.read_text()

    def pin(m: re.Match) -> str:
        return f'{m.group(0)}\nsplit = "{"val" if m.group(1) in val else "train"}"'

    toml.write_text(re.sub(r'(?m)^\[\[takes\]\]\nid = "((?:follow|face)_[^"]+)"$', pin, text))


def make_session(work: Path, seed: int, duration_s: float) -> Path:
    """The session folder under ``work``, generated when absent or made with other settings."""
    from gazepipe.synth import generate_session

    folder = work / f"session_{seed}_{duration_s:.0f}s"
    cfg = session_config(f"train{seed}", duration_s)
    stamp = json.dumps({"seed": seed, "config": repr(cfg)}, sort_keys=True)
    stamp_file = folder / "bench_settings.json"
    if stamp_file.is_file() and stamp_file.read_text() == stamp:
        return folder
    t0 = time.perf_counter()
    generate_session(folder, seed=seed, config=cfg)
    pin_splits(folder / "session.toml", val_takes(cfg.follow_poses))
    stamp_file.write_text(stamp)
    minutes = (len(cfg.follow_poses) * FOLLOW_S + sum(s for _, s in FACE)) / 60
    print(f"generated a {minutes:.0f}-minute session in {time.perf_counter() - t0:.1f} s: {folder}", flush=True)
    return folder


def run_pipeline(session: Path, out: Path) -> None:
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "gazepipe", "run", str(session), "--out", str(out), "--log-format", "json"]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        sys.exit(f"gazepipe run failed (exit {res.returncode}):\n{res.stderr[-3000:]}")
    print(f"gazepipe run: {time.perf_counter() - t0:.1f} s -> {out / 'datasets'}", flush=True)


def train_one(model: str, data_dir: Path, out: Path, device: str, epochs: int, hidden: int | None, seed: int,
              budget: float | None, threads: int | None) -> dict[str, Any]:
    from gazepipe.datasets import open_dataset
    from gazepipe.trainers.base import TrainOptions, load_trainer

    trainer, _, _ = MODELS[model]
    extra: dict[str, Any] = {}
    if budget is not None:
        extra["max_seconds"] = budget
    if threads:
        extra["threads"] = threads
    opts = TrainOptions(epochs=epochs, hidden=hidden, seed=seed, device=device, extra=extra)
    t0 = time.perf_counter()
    metrics = load_trainer(trainer).train(open_dataset(data_dir), out, opts)
    metrics["wall_s"] = time.perf_counter() - t0
    metrics["hidden"] = json.loads((out / "model.json").read_text())["config"]["hidden"]
    return metrics


def report(model: str, m: dict[str, Any]) -> list[str]:
    """The figures of one trained model, in lines."""
    secs = sorted(m["epoch_seconds"])
    median = secs[len(secs) // 2]
    step = (m.get("execution") or {}).get("training_step", "eager")
    head = (f"{model:13s} hidden {m['hidden']:4d}  {m['device']:28s} {step:10s} {m['epochs_run']:3d} epochs  "
            f"{median:7.3f} s/epoch  ({m['wall_s']:.0f} s in all)")
    lines = [head, *(f"    {s}" for s in m["summary"])]
    if (m.get("execution") or {}).get("cuda_graph_not_used"):
        lines.append(f"    CUDA graph not used: {m['execution']['cuda_graph_not_used']}")
    if m.get("nondeterministic"):
        lines.append(f"    nondeterministic operations: {m['nondeterministic']}")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--work", type=Path, default=REPO / "bench" / "_work" / "train",
                   help="Folder for the session, the run and the models (reused).")
    p.add_argument("--seed", type=int, default=0, help="Session generator seed.")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help=f"Session length, s (default {DURATION_S:.0f}; {KLEIN_S:.0f}, Klein's corpus, when a "
                        "CUDA device is asked for).")
    p.add_argument("--train-seed", type=int, default=0, help="Trainers' seed.")
    p.add_argument("--models", default=",".join(MODELS), help=f"Comma-separated, of {', '.join(MODELS)}.")
    p.add_argument("--device", default="auto", help="auto, cpu, cuda, cuda:N, or several comma-separated.")
    p.add_argument("--hidden", type=int, default=None, help="gaze_rnn's GRU size (default the trainer's, 512).")
    p.add_argument("--epochs", type=int, default=None, help="Epochs for every model (default per model: "
                   + ", ".join(f"{k} {v[2]}" for k, v in MODELS.items()) + ").")
    p.add_argument("--time-budget", type=float, default=None, help="Seconds of training per model at most.")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default every core).")
    a = p.parse_args(argv)
    from gazepipe.errors import GazepipeError

    models = [m.strip() for m in a.models.split(",") if m.strip()]
    unknown = [m for m in models if m not in MODELS]
    if unknown:
        p.error(f"unknown model(s) {', '.join(unknown)}")
    threads = a.threads or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count())
    work = a.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    devices = [d.strip() for d in a.device.split(",") if d.strip()]
    duration = a.duration or (KLEIN_S if any(d.startswith("cuda") for d in devices) else DURATION_S)
    session = make_session(work, a.seed, duration)
    out = work / f"out_{session.name}"
    run_pipeline(session, out)
    lines: list[str] = []
    per_epoch: dict[tuple[str, str], float] = {}
    for device in devices:
        for model in models:
            _, dataset, epochs = MODELS[model]
            hidden = a.hidden if model == "gaze_rnn" else None
            dest = work / "models" / f"{model}_{device.replace(':', '')}"
            try:
                m = train_one(model, out / "datasets" / dataset, dest, device, a.epochs or epochs, hidden,
                              a.train_seed, a.time_budget, threads)
            except GazepipeError as exc:
                print(f"error: {exc.one_line()}", file=sys.stderr)
                return exc.exit_code
            block = report(model, m)
            print("\n".join(block), flush=True)
            lines.extend(block)
            secs = sorted(m["epoch_seconds"])
            per_epoch[(model, device)] = secs[len(secs) // 2]
    print(f"\nsummary (session {session.name}: {duration:.0f} s, seed {a.seed}; train seed {a.train_seed})")
    print("\n".join(lines))
    for model in models:
        times = [(d, per_epoch[(model, d)]) for d in devices if (model, d) in per_epoch]
        if len(times) > 1:
            slowest = max(t for _, t in times)
            print(f"{model}: s/epoch " + ", ".join(f"{d} {t:.3f} ({slowest / t:.1f}x)" for d, t in times))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
