"""Eyes stage accuracy and speed on synthetic takes with known truth.

Per seed, a 60 s take from the generator of ``bench/_av.py`` (shared with ``tests/stages/eyes/test_eyes.py``): a camera below and in front of the face,
head turns, a target 1.5–3 m away that either jumps between goals and stays ("jumps") or keeps moving from goal
to goal ("pursuit", as Klein's pole), eyes 0.2 s behind it, per-eye angular noise, confidence dips, blinks and
lost tracking with junk gaze, a video clock with an offset and a 400 ppm rate error. Reported: the eye direction
error in the character frame over valid mocap frames (median, p95, degrees; median over seeds), the estimated
camera rotation's error (median and worst over seeds) and residual, the fitted eye lag, the valid share; then
the same without the lag search (``max_lag_s = 0``); then the bias when the target direction is measured from
the head markers' centroid (about 10 cm off the eyes) instead of the eyes' centre (SPEC §3.5); then the time of
a 10-minute take. When the sample session exists, the same figures on its three gaze_follow takes (the
generator's own eye model: pursuit with catch-up saccades, a 45° eye limit), with and without the lag search.

Usage: ``PYTHONPATH=. python bench/bench_eyes.py [--seeds N]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _av import SAMPLE, eyes_on_truth, make_scene, sample_scene  # bench/_av.py

from gazepipe.stages.eyes.params import EyesParams
from gazepipe.stages.eyes.stage import eyes_take
from gazepipe.stages.geometry import angle_between, from_wxyz


def run(seed: int, noise_deg: float, centre_error_mm=(0.0, 0.0, 0.0), duration_s: float = 60.0,
        pursuit: bool = False, params: EyesParams | None = None) -> dict:
    sc = make_scene(seed, duration_s=duration_s, noise_deg=noise_deg, centre_error_mm=centre_error_mm,
                    pursuit=pursuit)
    t0 = time.perf_counter()
    res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, params=params)
    elapsed = time.perf_counter() - t0
    v = res.valid
    err = np.rad2deg(angle_between(res.eye_dir_char[v], sc.eye_dir_char[v]))
    cam_err = float(np.rad2deg((from_wxyz(res.camera_rotation) * sc.cam.inv()).magnitude()))
    return {"median": float(np.median(err)), "p95": float(np.percentile(err, 95)), "cam": cam_err,
            "resid": res.qc["camera_residual_deg"], "lag": res.qc["eye_lag_s"], "valid": res.qc["valid_share"],
            "used": res.qc["camera_frames_used"], "time_s": elapsed, "frames": res.n_frames}


def generated_openface(take: str) -> str:
    tr, _, res = eyes_on_truth(SAMPLE, take)
    v = res.valid
    err = np.rad2deg(angle_between(res.eye_dir_char[v], tr["eye_dir_char"][v].astype(np.float64)))
    cam = from_wxyz(np.asarray(tr["session"]["camera_to_head_quat"]))
    cam_err = float(np.rad2deg((from_wxyz(res.camera_rotation) * cam.inv()).magnitude()))
    return (f"{take:<20} eye error median {np.median(err):.2f}° p95 {np.percentile(err, 95):.2f}°; camera error "
            f"{cam_err:.2f}°, residual {res.qc['camera_residual_deg']:.2f}°, lag {res.qc['eye_lag_s']:.3f} s; "
            f"gated {res.qc['gated_share']:.1%}, valid frames {res.qc['valid_share']:.1%}")


def table(rows: list[dict], label: str) -> str:
    def med(k: str) -> float:
        return float(np.median([r[k] for r in rows]))
    cam = [r["cam"] for r in rows]
    return (f"{label:<22} {med('median'):>7.2f} {med('p95'):>6.2f} {np.median(cam):>8.3f} {np.max(cam):>8.3f} "
            f"{med('resid'):>6.2f} {med('lag'):>6.3f} {med('valid'):>6.1%} {int(med('used')):>6d}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    args = ap.parse_args()
    seeds = range(args.seeds)

    print(f"{args.seeds} seeds x 60 s; angles in degrees, lag in seconds (truth 0.2)")
    print(f"{'target, noise per eye':<22} {'median':>7} {'p95':>6} {'cam med':>8} {'cam max':>8} {'resid':>6} "
          f"{'lag':>6} {'valid':>6} {'fit n':>6}")
    for pursuit in (False, True):
        for noise in (1.0, 2.5, 4.0):
            rows = [run(s, noise, pursuit=pursuit) for s in seeds]
            print(table(rows, f"{'pursuit' if pursuit else 'jumps'}, {noise:.1f}"))
    for pursuit in (False, True):
        rows = [run(s, 2.5, pursuit=pursuit, params=EyesParams(max_lag_s=0.0)) for s in seeds]
        print(table(rows, f"{'pursuit' if pursuit else 'jumps'}, 2.5, no lag"))

    print("\ncamera rotation error when the target direction is measured from the wrong point (pursuit, 2.5°)")
    for label, off in (("eyes' centre", (0.0, 0.0, 0.0)), ("centroid 10 cm up/back", (0.0, 60.0, -80.0))):
        rows = [run(s, 2.5, off, pursuit=True) for s in seeds]
        cam = [r["cam"] for r in rows]
        print(f"  {label:<24} camera error median {np.median(cam):.2f}°, max {np.max(cam):.2f}°; eye error median "
              f"{np.median([r['median'] for r in rows]):.2f}°")

    if (SAMPLE / "truth" / "truth.json").exists():
        print("\nsample session (gazepipe.synth) eyes through its true camera, 2.5° noise per eye")
        for take in ("follow_standing_01", "follow_standing_02", "follow_sitting_01"):
            sc, truth = sample_scene(take)
            for label, p in (("lag search", None), ("no lag", EyesParams(max_lag_s=0.0))):
                res = eyes_take(sc.eye, sc.joints, sc.mocap_time_s, sc.clock, params=p)
                v = res.valid
                err = np.rad2deg(angle_between(res.eye_dir_char[v], truth[v]))
                cam = float(np.rad2deg((from_wxyz(res.camera_rotation) * sc.cam.inv()).magnitude()))
                print(f"  {take:<20} {label:<10} eye error median {np.median(err):.2f}° p95 "
                      f"{np.percentile(err, 95):.2f}°; camera error {cam:.2f}°, residual "
                      f"{res.qc['camera_residual_deg']:.2f}°, lag {res.qc['eye_lag_s']:.3f} s")

    if (SAMPLE / "eyes").is_dir():
        print("\nsample session's own OpenFace CSVs (read_openface, the generator's noise, dips, blinks, clocks)")
        for take in ("follow_standing_01", "follow_standing_02", "follow_sitting_01"):
            print("  " + generated_openface(take))

    r = run(0, 2.5, duration_s=600.0, pursuit=True)
    print(f"\n10-minute take ({r['frames']} mocap frames, 60 Hz video, camera estimated): {r['time_s']:.2f} s")


if __name__ == "__main__":
    main()
