"""The frames stage's QC record (:class:`FramesQC`, written by :func:`gazepipe.stages.frames.stage.compute_frames`;
the unit adds ``neutral_source``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord, absent_when


@dataclass(frozen=True)
class RotationGapQC(QCRecord):
    """One gap of a segment's rotation (frames ``[start, stop)`` of the take) and whether it was filled."""

    #: the segment's index in the markerset
    segment: int
    start: int
    stop: int
    #: null: no method could be tried beside the gap
    method: str | None
    #: null: no method could be tried
    error_deg: float | None
    filled: bool


@dataclass(frozen=True)
class FramesQC(QCRecord):
    """Which neutral pose calibrated each segment, and the frames without a full set of rotations."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "frames"

    warnings: tuple[str, ...]
    #: per segment, neutral frames used
    neutral_frames: Mapping[str, int]
    #: per segment, the neutral source it was calibrated on (null: none had enough frames)
    neutral_sources: Mapping[str, str | None]
    #: the first neutral source offered
    neutral_source: str
    heading_fitted_frames: int
    invalid_frames: int
    rotation_gaps: tuple[RotationGapQC, ...]
    #: per segment, frames whose rotation the filled markers' estimated errors may turn by more than
    #: ``max_fit_uncertainty_deg`` (treated as a gap of the segment's markers)
    fill_uncertain_frames: Mapping[str, int]
    #: per segment, frames whose rotation jumped away and back (a flip) and were made a gap of its markers
    flip_frames: Mapping[str, int]
    #: frames whose character frame's heading jumped away and back (a flip): no character frame there
    heading_flip_frames: int
    #: per segment, frames whose rotation fitted to gap-filled markers the fill across them contradicted (made a
    #: gap of its markers)
    fit_refuted_frames: Mapping[str, int]
    # absent when the markerset has no head_centre marker: nothing is carried
    head_centre_carried_frames: int | None = absent_when("the markerset names no head_centre marker")


__all__ = ["FramesQC", "RotationGapQC"]
