"""The eyes stage's run: a take's OpenFace gaze gated and rotated into the character frame
(:func:`gazepipe.stages.eyes.stage.eyes_take`) on its ``joints`` rows, with the ``sync`` clock map when it has a
video, written as its ``eyes`` table."""

from __future__ import annotations

import numpy as np

from gazepipe.dag.nodes.common import TakeContext, file_notes, given
from gazepipe.pipeline.registry import UnitResult, params_from


def run_eyes(ctx: TakeContext) -> UnitResult:
    from gazepipe.io.openface import read_openface
    from gazepipe.schemas.eyes_table import eyes_to_table
    from gazepipe.schemas.joints import joints_arrays
    from gazepipe.schemas.sync_table import clock_of, video_facts
    from gazepipe.schemas.tracks import EYES
    from gazepipe.stages.eyes.mocap import filled_frames, head_motion
    from gazepipe.stages.eyes.params import EyesParams
    from gazepipe.stages.eyes.stage import eyes_take, tag_mismatch
    from gazepipe.stages.sync.clock import ClockMap

    take, ms = ctx.take, given(ctx.session.markerset, "markerset")
    eyes_path = given(take.eyes, "eyes")
    eye = read_openface(eyes_path)
    ja = joints_arrays(ctx.load("joints"))
    joints = head_motion(ja)
    clock = ClockMap(offset_s=0.0, ratio=1.0, n_claps=0)
    video = None
    if take.video is not None:
        sync = ctx.load("sync")
        offset_s, ratio, n_claps = clock_of(sync)
        clock = ClockMap(offset_s=offset_s, ratio=ratio, n_claps=n_claps)
        seconds, frames, fps = video_facts(sync)
        video = (take.video, seconds * clock.ratio, frames, fps)
    camera = None if ms.camera_rotation is None else np.asarray(ms.camera_rotation, dtype=np.float64)
    res = eyes_take(eye, joints, ja["time_s"], clock if take.video is not None else None,
                    camera_rotation=camera, params=params_from(EyesParams, ctx.params), path=take.eyes,
                    take=take.id, video=video)
    table = eyes_to_table(ja, res.valid, filled_frames(res, ja["time_s"], clock), res.confidence,
                          res.eye_dir_char, res.eye_dir_head,
                          {"camera_rotation": [float(x) for x in res.camera_rotation],
                           "camera_source": res.camera_source, "rate_hz": float(joints.rate_hz)})
    qc = dict(res.qc)
    mismatch = tag_mismatch(video, eye)
    qc["warnings"] = (file_notes(ctx.session, eyes_path, eye.warnings) + list(qc.get("warnings", []))
                      + (file_notes(ctx.session, take.video, [mismatch]) if mismatch and take.video else []))
    return UnitResult(tables={"eyes": (table, EYES)}, qc=qc, warnings=qc["warnings"])
