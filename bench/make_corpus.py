"""Write a Klein-size gaze_follow corpus (Klein, Table 1: four poses, 60,800 mocap frames) or a multiple of it.

``python bench/make_corpus.py --scale 1 bench/_work/klein_x1`` writes one session per pose
(``klein_<pose>``: a neutral take and that pose's share of the corpus as ``--take-s`` long gaze_follow takes) and
prints the frame count per pose. ``--no-video`` leaves out the head-camera videos and OpenFace CSVs (generating
video dominates the time of the 10x corpus). Same arguments, same bytes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from gazepipe.synth import SynthConfig, generate_session, klein_config  # noqa: E402
from gazepipe.synth.session import KLEIN_POSE_SECONDS  # noqa: E402


def pose_configs(scale: float, take_s: float, head_camera: bool) -> list[SynthConfig]:
    """One configuration per pose: ``round(seconds · scale / take_s)`` takes whose lengths add up to the pose's
    share of Klein's corpus times ``scale``."""
    base = klein_config(scale=scale, take_s=take_s)
    out = []
    for pose, secs in KLEIN_POSE_SECONDS.items():
        n = max(1, int(round(secs * scale / take_s)))
        out.append(dataclasses.replace(base, follow_poses=(pose,) * n, follow_duration_s=secs * scale / n,
                                       session_id=f"klein_{pose}", head_camera=head_camera))
    return out


def _one(args: tuple[str, int, SynthConfig]) -> tuple[str, int, float]:
    folder, seed, cfg = args
    t0 = time.perf_counter()
    generate_session(folder, seed=seed, config=cfg)
    truth = json.loads((Path(folder) / "truth" / "truth.json").read_text())
    frames = 0
    for t in truth["takes"].values():
        if t.get("kind") == "gaze_follow":
            frames += int(t["n_frames"])
    return folder, frames, time.perf_counter() - t0


def make_corpus(out_dir: str | Path, scale: float = 1.0, take_s: float = 60.0, head_camera: bool = True,
                seed: int = 0, jobs: int = 2) -> list[Path]:
    """Write the corpus under ``out_dir`` (one session folder per pose); return the session folders."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    work = [(str(out / cfg.session_id), seed + k, cfg)
            for k, cfg in enumerate(pose_configs(scale, take_s, head_camera))]
    total = 0
    with ProcessPoolExecutor(max_workers=jobs) as ex:
        for folder, frames, secs in ex.map(_one, work):
            total += frames
            print(f"{folder}: {frames} gaze_follow frames ({secs:.1f} s to generate)", flush=True)
    print(f"total: {total} gaze_follow mocap frames", flush=True)
    return [Path(w[0]) for w in work]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out_dir")
    p.add_argument("--scale", type=float, default=1.0, help="Multiple of Klein's corpus (1 or 10).")
    p.add_argument("--take-s", type=float, default=60.0, help="Approximate length of each gaze_follow take.")
    p.add_argument("--no-video", action="store_true", help="No head-camera video / OpenFace CSVs.")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=int, default=2, help="Sessions generated at once.")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    make_corpus(a.out_dir, a.scale, a.take_s, not a.no_video, a.seed, a.jobs)
    print(f"generated in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
