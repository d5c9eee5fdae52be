"""The sync stage's QC record (:class:`SyncQC`, written by :func:`gazepipe.stages.sync.stage.sync_take`; the unit
adds the video reader's warnings)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from gazepipe.stages.qc import QCRecord
from gazepipe.stages.sync.clock import bound_over


@dataclass(frozen=True)
class ClapQC(QCRecord):
    """One mocap clap and the video clap paired with it (the video fields null when none was found)."""

    mocap_s: float
    mocap_confidence: float
    #: how well the mocap clap is timed (ms, one standard deviation)
    mocap_timing_ms: float
    #: the video clap's time on the video clock; null: no video clap found for this mocap clap
    video_s: float | None
    #: null: no video clap
    video_confidence: float | None
    #: null: no video clap, or one found without a profile match
    video_match: float | None
    #: how well the video clap is timed (ms, one standard deviation); null: no video clap
    video_timing_ms: float | None
    #: what timed the video clap: displacement, match or burst (``VideoClap.timed_by``); null: no video clap
    video_timed_by: str | None
    mocap_gap_frames: int
    #: whether the clock map rests on this clap
    used: bool
    #: whether the clap was set aside (it disagrees with the others and the camera tolerance)
    set_aside: bool

    @property
    def timing_ms(self) -> float:
        """The pair's timing (ms, one standard deviation; NaN without a video clap)."""
        if self.video_timing_ms is None:
            return float("nan")
        return float(np.hypot(self.mocap_timing_ms, self.video_timing_ms))


@dataclass(frozen=True)
class SyncQC(QCRecord):
    """The clock map from the video to the mocap and the claps it rests on."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "sync"

    #: mocap minus video clock at the first clap, s
    offset_s: float
    offset_at_video_zero_s: float
    ratio: float
    drift_ppm: float
    drift_ms_over_take: float
    #: clap pairs the map rests on
    n_claps: int
    #: largest misfit of a clap pair the map rests on, ms (0 with one or two pairs)
    residual_ms: float
    claps: tuple[ClapQC, ...]
    frames_without_video: int
    frames_decoded: int
    video_frames: int
    #: the video's first and last frame time, s (video clock)
    video_span_s: tuple[float, float]
    #: how far the map may be off anywhere over the video, ms (:meth:`bound_over` the video's span)
    clock_bound_ms: float
    #: video time of the map's reference point, s, and the covariance of (its mocap time there, the ratio):
    #: variance s², covariance s, variance
    clock_ref_s: float
    clock_cov: tuple[float, float, float]
    #: the ratio's prior standard deviation (what cameras do), ppm
    clock_prior_ppm: float
    #: how many standard deviations of the map's error its bound is
    clock_bound_sigmas: float
    #: 1-based numbers of the claps used
    claps_used: tuple[int, ...]
    warnings: tuple[str, ...]

    def bound_over(self, span_video_s: tuple[float, float]) -> tuple[float, float, int | None]:
        """How far the map may be off over ``span_video_s`` (video clock, s): (bound ms, video time s where it is
        reached, the 1-based clap whose timing limits it there, or None when the nominal rate does: the map
        rests on one clap there) (:func:`gazepipe.stages.sync.clock.bound_over`)."""
        used = [j for j, c in enumerate(self.claps) if c.used and c.video_s is not None]
        tv = np.array([self.claps[j].video_s for j in used], dtype=np.float64)
        sd = np.array([self.claps[j].timing_ms for j in used]) / 1000.0
        bound, at, k = bound_over(self.clock_cov, self.clock_ref_s, self.clock_prior_ppm * 1e-6, tv, sd,
                                  span_video_s, self.clock_bound_sigmas)
        return bound, at, None if k is None else used[k] + 1


__all__ = ["ClapQC", "SyncQC"]
