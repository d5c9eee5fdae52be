"""The face stage's QC record (:class:`FaceQC`, written by :func:`gazepipe.stages.face.stage.align_face`; the
unit adds the readers' warnings)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class FaceQC(QCRecord):
    """Rows read, dropped and matched when the tracked and clean Live Link Face tracks are aligned."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "face"

    rows_tracked: int
    rows_clean: int
    dropped_frames_tracked: int
    dropped_frames_clean: int
    rows_matched: int
    unmatched_tracked: int
    unmatched_clean: int
    last_frames_dropped: int
    rows_out: int
    k: int
    max_match_error_s: float
    dt_min_s: float
    dt_median_s: float
    dt_max_s: float
    warnings: tuple[str, ...]


__all__ = ["FaceQC"]
