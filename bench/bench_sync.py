"""Clapper sync accuracy and speed.

1. Accuracy over generated takes: each take has mocap clapper markers (rate 29.97, 59.94 or 120 Hz, marker noise
   0.3–2 mm) and a 160x120 head-camera video labelled 60 fps (sensor noise 1–4 grey levels), with a clap near the
   start and one near the end (55 s apart), on a camera clock with a random offset (−4..+4 s) and rate ratio (0.999..1.001,
   and the 59.94-for-60 case). Reported per take and summarised: mocap clap error (mocap frames), video clap
   error (video frames), offset error at the first clap (ms), ratio error (ppm). Sync runs without a prior.
2. Speed: sync of a 1-minute and a 10-minute 60 fps video (written once into ``bench/_work/``), with and without
   an offset prior; the probe (which walks the container's packets) is timed apart. Sync time and frames
   decoded must not grow with the video's length.

3. The sample session (``sample_data/session01``, when present): its gaze_follow takes against their truth.
   Its clapper arm is 8 px tall and moves up to ~28 px per frame, so frame differences saturate near the
   contact and the video clap comes out late by a fraction of a frame; the table shows by how much.

The synthetic clapper, its video rendering and the counting reader (one FrameReader per take, as the pipeline
reads a video) come from ``bench/_av.py``, shared with ``tests/stages/sync/test_sync.py``.

Usage: ``PYTHONPATH=. python bench/bench_sync.py [--takes N] [--seed S]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _av import FPS, CountingReader, clapper_markers, write_clapper_video  # bench/_av.py

from gazepipe.io.video import probe_video
from gazepipe.stages.sync.stage import sync_take

WORK = Path(__file__).resolve().parent / "_work"


def accuracy(n_takes: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    rows = []
    (WORK / "acc").mkdir(parents=True, exist_ok=True)
    print(f"{'take':>4} {'rate':>6} {'noise':>5} {'sens':>4} {'offset':>7} {'ratio':>9} | "
          f"{'mocap err (fr)':>15} {'video err (fr)':>15} {'offset err ms':>13} {'ratio err ppm':>13}")
    for k in range(n_takes):
        rate = float(rng.choice([29.97, 59.94, 120.0]))
        noise = float(rng.uniform(0.3, 2.0))
        sens = float(rng.uniform(1.0, 4.0))
        offset = float(rng.uniform(-4.0, 4.0))
        ratio = 60.0 / 59.94 if k % 4 == 0 else float(rng.uniform(0.999, 1.001))
        video_s = 60.0
        tv = np.array([rng.uniform(1.5, 3.0), rng.uniform(56.0, 58.0)])  # clap instants, video clock
        contacts = offset + ratio * tv
        closing = rng.uniform(0.06, 0.12, 2)
        mocap_start = min(0.0, contacts[0] - 1.5)  # the mocap starts before the first clap
        t_c = contacts - mocap_start
        path = write_clapper_video(WORK / "acc" / f"take{k:02d}.mp4", int(video_s * FPS), t_c, closing,
                                   offset=offset - mocap_start, ratio=ratio, seed=seed + k, sensor_noise=sens)
        a, b, va, vb = clapper_markers(rng, int((t_c[1] + 3.0) * rate), rate, t_c, closing, noise)
        probe = probe_video(path)
        res = sync_take(a, b, va, vb, rate, probe.timestamps_s, CountingReader(path, probe.timestamps_s))
        if res.qc["warnings"]:
            print("      " + " | ".join(w.split(": ", 1)[-1] for w in res.qc["warnings"]))
        m_err = np.array([c.time_s for c in res.mocap_claps]) - t_c
        v_err = np.array([np.nan if v is None else v.time_s for v in res.video_claps]) - tv
        off_true = t_c[0] - tv[0]
        row = (np.abs(m_err).max() * rate, np.nanmax(np.abs(v_err)) * FPS,
               abs(res.clock.offset_at_first_clap_s - off_true) * 1e3, (res.clock.ratio - ratio) * 1e6)
        rows.append(row)
        print(f"{k:4d} {rate:6.2f} {noise:5.2f} {sens:4.1f} {offset:7.3f} {ratio:9.6f} | "
              f"{row[0]:15.3f} {row[1]:15.3f} {row[2]:13.3f} {row[3]:13.1f}")
    r = np.abs(np.array(rows))
    print(f"{'':>43} median | {np.median(r[:, 0]):15.3f} {np.median(r[:, 1]):15.3f} "
          f"{np.median(r[:, 2]):13.3f} {np.median(r[:, 3]):13.1f}")
    print(f"{'':>43}    max | {r[:, 0].max():15.3f} {r[:, 1].max():15.3f} {r[:, 2].max():13.3f} "
          f"{r[:, 3].max():13.1f}")
    print("(per take: the worse of its two claps; errors are absolute)")


def speed(seed: int) -> None:
    offset, ratio = 2.5, 60.0 / 59.94
    print(f"\n{'video':>7} {'frames':>7} {'probe s':>8} {'sync s (prior)':>15} {'decoded':>8} "
          f"{'sync s (no prior)':>18} {'decoded':>8} {'offset err ms':>13}")
    for minutes in (1, 10):
        n = int(minutes * 60 * FPS)
        tv = np.array([2.0, minutes * 60 - 3.0])
        contacts = offset + ratio * tv
        closing = np.array([0.08, 0.08])
        path = WORK / f"sync_{minutes}min.mp4"
        if not path.exists():
            write_clapper_video(path, n, contacts, closing, offset=offset, ratio=ratio, seed=seed)
        rng = np.random.default_rng(seed)
        rate = 29.97
        a, b, va, vb = clapper_markers(rng, int((contacts[1] + 3) * rate), rate, contacts, closing, 0.5)
        t0 = time.perf_counter()
        probe = probe_video(path)
        t_probe = time.perf_counter() - t0
        out = []
        for guess in (offset + 0.5, None):
            reader = CountingReader(path, probe.timestamps_s)
            t0 = time.perf_counter()
            res = sync_take(a, b, va, vb, rate, probe.timestamps_s, reader, offset_guess_s=guess)
            out.append((time.perf_counter() - t0, reader.frames, res))
        err = abs(out[0][2].clock.offset_s - offset) * 1e3
        print(f"{minutes:5d} m {probe.n_frames:7d} {t_probe:8.3f} {out[0][0]:15.3f} {out[0][1]:8d} "
              f"{out[1][0]:18.3f} {out[1][1]:8d} {err:13.3f}")


def sample_session() -> None:
    root = Path(__file__).resolve().parents[1] / "sample_data" / "session01"
    truth_path = root / "truth" / "truth.json"
    if not truth_path.exists():
        print("\n(no sample_data/session01: skipped)")
        return
    import json

    from gazepipe.io.capture import read_markers

    takes = json.loads(truth_path.read_text())["takes"]
    print(f"\n{'sample take':>20} {'mocap err ms':>16} {'video err (fr)':>16} {'offset err ms':>13} "
          f"{'ratio err ppm':>13} {'uncovered':>9} {'sync s':>7}")
    for take, tr in takes.items():
        if "video" not in tr:
            continue
        m = read_markers(root / "mocap" / f"{take}.c3d")
        ia, ib = m.labels.index("CLAP1"), m.labels.index("CLAP2")
        path = root / tr["video"]["path"]
        probe = probe_video(path)
        t0 = time.perf_counter()
        res = sync_take(m.xyz[:, ia], m.xyz[:, ib], m.valid[:, ia], m.valid[:, ib], m.rate_hz,
                        probe.timestamps_s, CountingReader(path, probe.timestamps_s))
        dt = time.perf_counter() - t0
        me = (np.array([c.time_s for c in res.mocap_claps]) - tr["video"]["clap_times_mocap_s"]) * 1e3
        ve = (np.array([np.nan if c is None else c.time_s for c in res.video_claps])
              - tr["video"]["clap_times_video_s"]) * FPS
        oe = (res.clock.offset_at_first_clap_s - tr["video"]["offset_at_first_clap_s"]) * 1e3
        re = (res.clock.ratio - tr["video"]["ratio"]) * 1e6
        print(f"{take:>20} {' '.join(f'{x:+7.2f}' for x in me):>16} {' '.join(f'{x:+7.3f}' for x in ve):>16} "
              f"{oe:+13.2f} {re:+13.1f} {res.frames_without_video:5d}/{tr['video']['mocap_frames_without_video']:<3d} "
              f"{dt:7.2f}")
    print("(signed errors per clap; uncovered: mocap frames without video, found/true)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--takes", type=int, default=24)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    WORK.mkdir(parents=True, exist_ok=True)
    accuracy(args.takes, args.seed)
    speed(args.seed)
    sample_session()


if __name__ == "__main__":
    main()
