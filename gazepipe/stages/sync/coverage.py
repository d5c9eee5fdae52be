"""Whether a take's video covers it: a note when it lasts far less than the take (the eyes stage names the video
when that makes it fail)."""

from __future__ import annotations

import numpy as np

from gazepipe.stages.eyes.params import SHORT_VIDEO_SHARE


def short_video_note(ts: np.ndarray, take_s: float) -> list[str]:
    """A note when a video (frame times ``ts``, s) lasts less than half its take (``take_s``, s): it cannot
    cover the take's eye data."""
    video_s = float(ts[-1] - ts[0]) if ts.size >= 2 else 0.0
    if video_s < SHORT_VIDEO_SHARE * take_s:
        return [f"the video lasts {video_s:.1f} s but the take {take_s:.1f} s: frames after the video's end have "
                "no eye data"]
    return []
