"""`gazepipe export` against the capture it came from and the generated ground truth (issue 46).

Generated sessions (seeds x the ten-segment z-up and four-segment y-up markersets x plain and hazard captures:
label swaps, occlusion bursts, ghost spikes, long gaps) are cleaned (`gazepipe clean`), and every mocap take is
exported to C3D. Per configuration it prints:

- frames: the frames the file holds, as a share of the capture's;
- measured max: the largest distance (mm) between a sample the capture measured (and the cleaning kept as
  measured) and the capture file's own value of it, over the frames the file holds (the lab frame: 0 when the
  export is the capture);
- filled mean / p95 / max: the filled samples' distance to the noise-free truth (mm, lab frame);
- swaps: the samples put back under their own names, and their largest distance to the truth (mm);
- marked: the share of filled samples whose fourth word is 0 (residual 0, no camera), and of measured samples
  whose word has both a residual and a camera byte (what every reader takes for measured, whichever byte it
  reads the residual from);
- crop: whether the file's EVENT group names the first and last kept frame.

``--against REV`` exports the same cleaned takes with that commit's `gazepipe export` too (checked out under
``bench/_work``), for the before/after table.

Usage: ``PYTHONPATH=. python bench/bench_export.py [--seeds 0,1,2] [--skeletons ten,four] [--kinds plain,hazard]
[--against REV]``
"""

from __future__ import annotations

import argparse
import io
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_fill_speed import checkout  # noqa: E402

from gazepipe.dag import run_pipeline  # noqa: E402
from gazepipe.io.c3d import read_c3d  # noqa: E402
from gazepipe.io.c3d_write import read_point_words, word_bytes  # noqa: E402
from gazepipe.io.session_toml import load_session  # noqa: E402
from gazepipe.model import FILL_CODES  # noqa: E402
from gazepipe.pipeline.events import EventLog  # noqa: E402
from gazepipe.schemas.markers import table_to_markers  # noqa: E402
from gazepipe.synth import SynthConfig, generate_session  # noqa: E402
from gazepipe.synth.skeleton import FOUR_SEGMENTS, SEGMENTS  # noqa: E402


def session(folder: Path, seed: int, skeleton: str, kind: str) -> Path:
    """A small generated session: a 25 s gaze_follow take, two gaze_shift takes, the neutral take."""
    hazard = kind == "hazard"
    cfg = SynthConfig(follow_poses=("standing",), follow_duration_s=25.0, head_camera=False, face_takes=(),
                      shift_targets=((36.0, 12.0), (-72.0, 0.0)),
                      segments=SEGMENTS if skeleton == "ten" else FOUR_SEGMENTS,
                      up_axis="z" if skeleton == "ten" else "y",
                      label_swaps=2 if hazard else 0, occlusion_bursts=2 if hazard else 0,
                      spikes_per_marker_min=2.0 if hazard else 0.0, long_gaps=2 if hazard else 0)
    return generate_session(folder, seed=seed, config=cfg)


def export(tree: Path, out: Path, take: str, dest: Path) -> None:
    """``gazepipe export OUT session01/TAKE --to DEST`` with the package of ``tree`` (a fresh process)."""
    name = take if tree != ROOT else f"session01/{take}"     # an older export took a bare take id
    env = dict(os.environ, PYTHONPATH=str(tree))
    # run from the tree itself: `python -m` puts the working folder first on the path
    subprocess.run([sys.executable, "-m", "gazepipe", "export", str(out), name, "--to", str(dest)], env=env,
                   check=True, capture_output=True, cwd=str(tree))


def measure(dest: Path, capture: Path, out: Path, take: str, truth: dict) -> dict:
    """The figures of one exported take (see the module's docstring)."""
    import ezc3d

    raw, got = read_c3d(capture), read_c3d(dest)
    _, frames, fill, _ = table_to_markers(pq.read_table(out / "takes" / "session01" / take / "markers.parquet"))
    rows = np.arange(got.n_frames) + (got.first_frame - raw.first_frame)     # capture row of each file row
    code = np.full(raw.valid.shape, FILL_CODES["measured"], np.int8)
    code[frames] = fill
    code, valid_raw = code[rows], raw.valid[rows]
    words, _ = read_point_words(dest)
    low, high = word_bytes(words)
    measured = valid_raw & (code == FILL_CODES["measured"]) & got.valid
    filled = got.valid & np.isin(code, [FILL_CODES[k] for k in ("linear", "pchip", "rigid", "pca")])
    swapped = got.valid & (code == FILL_CODES["swap_repaired"])
    lab = truth["markers_true"][rows]
    err = np.linalg.norm(got.xyz[filled] - lab[filled], axis=-1)
    sw = np.linalg.norm(got.xyz[swapped] - lab[swapped], axis=-1)
    events = ezc3d.c3d(str(dest))["parameters"].get("EVENT", {})
    labels = list(events.get("LABELS", {}).get("value", [])) if events else []
    crop = False
    if "gazepipe crop start" in labels:
        t = events["TIMES"]["value"]
        seconds = dict(zip(labels, t[0] * 60 + t[1], strict=True))
        crop = (round(seconds["gazepipe crop start"] * raw.rate_hz) + 1 == raw.first_frame + frames[0]
                and round(seconds["gazepipe crop end"] * raw.rate_hz) + 1 == raw.first_frame + frames[-1])
    return {"frames": got.n_frames / raw.n_frames,
            "measured_max": float(np.max(np.linalg.norm(got.xyz[measured] - raw.xyz[rows][measured], axis=-1))),
            "filled": err, "swaps": sw,
            "marked_filled": float(np.mean(words[filled] == 0)) if filled.any() else float("nan"),
            "marked_measured": float(np.mean((low[measured] > 0) & (high[measured] > 0))),
            "crop": crop}


def run(args: argparse.Namespace) -> None:
    trees = {"new": ROOT} if not args.against else {"old": checkout(args.against), "new": ROOT}
    rows: list[tuple] = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for seed in [int(s) for s in args.seeds.split(",")]:
            for skeleton in args.skeletons.split(","):
                for kind in args.kinds.split(","):
                    folder = session(tmp / f"s{seed}{skeleton}{kind}", seed, skeleton, kind)
                    out = tmp / f"o{seed}{skeleton}{kind}"
                    run_pipeline([load_session(folder / "session.toml")], out, until="frames", executor="serial",
                                 log=EventLog(fmt="json", stream=io.StringIO()))
                    for side, tree in trees.items():
                        figs = []
                        for c3d in sorted((folder / "mocap").glob("*.c3d")):
                            dest = tmp / f"{side}_{c3d.name}"
                            export(tree, out, c3d.stem, dest)
                            figs.append(measure(dest, c3d, out, c3d.stem, dict(np.load(folder / "truth" /
                                                                                        f"{c3d.stem}.npz"))))
                        rows.append((seed, skeleton, kind, side, figs))
    print(f"{'seed':>4} {'layout':<6} {'capture':<7} {'export':<6} {'frames':>6} {'meas max':>9} "
          f"{'filled n':>8} {'mean':>6} {'p95':>6} {'max':>6} {'swaps':>5} {'max':>6} {'marked f/m':>11} {'crop':>5}")
    for seed, skeleton, kind, side, figs in rows:
        err = np.concatenate([f["filled"] for f in figs])
        sw = np.concatenate([f["swaps"] for f in figs])
        frames = min(f["frames"] for f in figs)
        meas = max(f["measured_max"] for f in figs)
        mf = np.nanmean([f["marked_filled"] for f in figs])
        mm = np.mean([f["marked_measured"] for f in figs])
        crop = all(f["crop"] for f in figs)
        print(f"{seed:>4} {skeleton:<6} {kind:<7} {side:<6} {frames:>6.2f} {meas:>9.3g} {err.size:>8} "
              f"{err.mean() if err.size else float('nan'):>6.2f} "
              f"{np.percentile(err, 95) if err.size else float('nan'):>6.2f} "
              f"{err.max() if err.size else float('nan'):>6.2f} {sw.size:>5} "
              f"{sw.max() if sw.size else float('nan'):>6.2f} {mf:>5.2f}/{mm:<5.2f} {'yes' if crop else 'no':>5}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--skeletons", default="ten,four")
    ap.add_argument("--kinds", default="plain,hazard")
    ap.add_argument("--against", metavar="REV")
    run(ap.parse_args())


if __name__ == "__main__":
    main()
