"""What the eyes stage reads of a take's ``joints`` table and gives back per mocap frame: the head's motion
(:class:`~gazepipe.stages.eyes.stage.HeadMotion`) from the table's arrays, and which valid frames were bridged.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gazepipe.stages.eyes.stage import EyesResult, HeadMotion
from gazepipe.stages.sync.clock import ClockMap, resample_to_mocap


def head_motion(ja: dict[str, Any]) -> HeadMotion:
    """The head's motion from the ``joints`` table's arrays (:func:`gazepipe.schemas.joints.joints_arrays`)."""
    return HeadMotion(segments=tuple(ja["segments"]), quat=ja["quat"], rate_hz=float(ja["meta"]["rate_hz"]),
                      target_dir=ja["target_dir"], char_rot=ja["char_rot"])


def filled_frames(res: EyesResult, time_s: np.ndarray, clock: ClockMap) -> np.ndarray:
    """(N,) bool: a valid mocap frame (times ``time_s``, s) is filled when either video sample around it was
    bridged by slerp."""
    g = res.gated
    not_filled, _ = resample_to_mocap(g.time_s, (~g.filled).astype(np.float64), "confidence", time_s, clock)
    return res.valid & (not_filled == 0)
