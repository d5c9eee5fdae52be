"""The sync stage's QC record (:class:`SyncQC`, written by :func:`gazepipe.stages.sync.stage.sync_take`; the unit
adds the video reader's warnings)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class ClapQC(QCRecord):
    """One mocap clap and the video clap paired with it (the video fields null when none was found)."""

    mocap_s: float
    mocap_confidence: float
    #: the video clap's time on the video clock; null: no video clap found for this mocap clap
    video_s: float | None
    #: null: no video clap
    video_confidence: float | None
    #: null: no video clap, or one found without a profile match
    video_match: float | None
    #: how well the video clap is timed (ms, one standard deviation); null: no video clap
    video_timing_ms: float | None
    mocap_gap_frames: int
    #: whether the clock map rests on this clap
    used: bool


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
    #: largest clap-pair misfit, ms (0 with one or two pairs)
    residual_ms: float
    claps: tuple[ClapQC, ...]
    frames_without_video: int
    frames_decoded: int
    video_frames: int
    #: how far the map may be off anywhere over the video, ms
    clock_bound_ms: float
    #: 1-based numbers of the claps used
    claps_used: tuple[int, ...]
    warnings: tuple[str, ...]


__all__ = ["ClapQC", "SyncQC"]
