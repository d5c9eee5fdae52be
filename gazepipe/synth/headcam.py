"""The head-camera modality writer: per gaze_follow take, a 60 fps video on its own clock and the OpenFace CSV
of its eyes, with their truth (SPEC §1 video/eyes, §3.4, §3.5)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gazepipe.synth.openface import (
    BLINK_EVERY_S,
    CONF_THRESHOLD,
    DIP_EVERY_S,
    EYE_NOISE_DEG,
    eye_rows,
    write_openface_csv,
)
from gazepipe.synth.video import (
    HEIGHT,
    SAMPLE_LOOK,
    WIDTH,
    CameraClock,
    ClapperLook,
    camera_clock,
    write_head_video,
)

if TYPE_CHECKING:
    from gazepipe.synth.record import TakeRecord

#: no blink from this long before a clap to this long after it (mocap seconds): the clap stays the only motion
QUIET_BEFORE_S = 1.5
QUIET_AFTER_S = 1.0


def _exposures(n: int, clock: CameraClock, claps: np.ndarray, hazard: dict[str, Any] | None) -> np.ndarray:
    """The exposure index of each written frame: 0 … n − 1, less the frames a ``dropped_frames`` clap hazard
    drops (``frames`` of them, ``before_s`` mocap seconds before its clap)."""
    idx = np.arange(n)
    if hazard is None or hazard["kind"] != "dropped_frames":
        return idx
    k = int(np.floor(float(clock.to_video(claps[hazard["clap"]] - hazard["before_s"])) * clock.fps))
    return np.delete(idx, np.arange(max(k, 1), min(k + hazard["frames"], n - 1)))


def head_camera_writer(session_dir: Path, take: TakeRecord, blink_every_s: tuple[float, float] = BLINK_EVERY_S,
                       dip_every_s: tuple[float, float] = DIP_EVERY_S,
                       look: ClapperLook = SAMPLE_LOOK) -> dict[str, Any]:
    """Write ``video/<take>.mp4`` and ``eyes/<take>.csv`` for a gaze_follow take; add their truth to the take.

    The clock variant cycles with the take's index (see :func:`gazepipe.synth.video.camera_clock`); the take
    whose variant is 0 gets the older ", " OpenFace layout. ``look``: how the camera sees the clapper (the truth
    says which look when it is not the sample's).
    """
    if take.kind != "gaze_follow" or take.motion is None or take.kinematics is None:
        return {}
    motion, kin = take.motion, take.kinematics
    r_clock, r_eyes, r_video, r_csv = (np.random.default_rng(int(s)) for s in take.rng.integers(0, 2**63, size=4))
    variant = take.index % 3
    time_s = motion.time_s
    clock, n = camera_clock(r_clock, variant, float(time_s[-1]))
    claps = np.asarray(motion.clap_times_s, dtype=np.float64)
    exposures = _exposures(n, clock, claps, motion.design.get("clap_hazard"))
    n = exposures.size
    t_video = np.arange(n, dtype=np.float64) / clock.fps          # as the container stamps them
    t_m = clock.to_mocap(exposures / clock.fps)                   # when they were really exposed
    quiet = np.zeros(n, dtype=bool)
    for tc in claps:
        quiet |= (t_m >= tc - QUIET_BEFORE_S) & (t_m <= tc + QUIET_AFTER_S)

    cam = take.camera_to_head
    rows = eye_rows(r_eyes, kin, time_s, t_m, clock.fps, cam, quiet, blink_every_s, dip_every_s)
    video_rel = f"video/{take.id}.mp4"
    eyes_rel = f"eyes/{take.id}.csv"
    to_cam = cam.inv()
    write_head_video(session_dir / video_rel, r_video, clock, n, motion, to_cam.apply(rows.true_right_head),
                     to_cam.apply(rows.true_left_head), rows.lid, exposures, look)
    legacy = variant == 0
    write_openface_csv(session_dir / eyes_rel, r_csv, rows, cam, legacy=legacy)

    has_video = (time_s >= t_m[0]) & (time_s <= t_m[-1])
    # each clap on the video clock as the stamps read it (after a dropped frame they run behind)
    clap_video = clock.to_video(claps) if exposures[-1] + 1 == n else np.interp(claps, t_m, t_video)
    f4 = np.float32
    take.truth_arrays.update({
        "video_time_s": t_video,
        "video_mocap_time_s": t_m,
        "video_clap_times_s": clap_video,
        "mocap_has_video": has_video,
        "eyes_dir_head": rows.true_cyc_head.astype(f4),
        "eyes_dir_cam": to_cam.apply(rows.true_cyc_head).astype(f4),
        "eyes_left_head": rows.true_left_head.astype(f4),
        "eyes_right_head": rows.true_right_head.astype(f4),
        "eyes_valid": rows.valid,
        "eyes_blink": rows.blink,
        "eyes_success": rows.success,
        "eyes_low_conf": rows.low_conf,
        "eyes_in_mocap": rows.in_mocap,
    })
    take.truth_scalars["video"] = {
        "path": video_rel, "codec": "mp4v", "fps": clock.fps, "n_frames": int(n), "width": WIDTH, "height": HEIGHT,
        "exposure_s": look.exposure_s, "offset_s": clock.offset_s, "ratio": clock.ratio,
        "offset_at_first_clap_s": float(claps[0] - clap_video[0]) if claps.size else None,
        "clap_times_mocap_s": claps.tolist(), "clap_times_video_s": clap_video.tolist(),
        "starts_after_mocap": bool(clock.offset_s > 0),
        "mocap_frames_without_video": int((~has_video).sum()),
        "dropped_frames": int(exposures[-1] + 1 - n),
    }
    if look != SAMPLE_LOOK:
        take.truth_scalars["video"]["clapper_look"] = dataclasses.asdict(look)
    take.truth_scalars["eyes"] = {
        "path": eyes_rel, "layout": "openface_legacy" if legacy else "openface2", "rows": int(n),
        "noise_deg": EYE_NOISE_DEG, "confidence_threshold": CONF_THRESHOLD,
        "blink_frames": int(rows.blink.sum()), "failed_frames": int((~rows.success).sum()),
        "low_confidence_frames": int(rows.low_conf.sum()), "valid_fraction": float(rows.valid.mean()),
    }
    return {"video": video_rel, "eyes": eyes_rel}
