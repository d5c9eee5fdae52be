"""The eyes stage's QC record (:class:`EyesQC`: the gate's counts, :func:`gazepipe.stages.eyes.gate.gate`, and
the take's, :func:`gazepipe.stages.eyes.stage.eyes_take`; the unit adds the reader's warnings)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class EyesQC(QCRecord):
    """How much of the OpenFace gaze was kept, and the camera rotation into the head."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "eyes"

    # the gate, on the video's samples
    samples: int
    #: null when the video's frame step is not finite (fewer than two samples)
    video_rate_hz: float | None
    gated_share: float
    #: share of samples gated out per reason (success, confidence, blink, no_gaze)
    gated_by: Mapping[str, float]
    filled_samples: int
    invalid_share: float
    longest_invalid_run_s: float
    missing_video_frames: int
    min_confidence: float
    max_eye_gap_s: float
    warnings: tuple[str, ...]
    # the take, on the mocap frames
    frames: int
    valid_frames: int
    valid_share: float
    frames_without_coverage: int
    frames_without_head: int
    clock_offset_s: float
    clock_ratio: float
    #: w, x, y, z
    camera_rotation: tuple[float, float, float, float]
    #: ``configured`` or ``estimated``
    camera_rotation_source: str
    #: null: too few fixation frames to measure it
    camera_residual_deg: float | None
    camera_frames_used: int
    #: null: the eyes' delay behind the target could not be fitted
    eye_lag_s: float | None
    #: null: fewer than three frames with both a valid eye and a target direction
    camera_target_spread_deg: float | None


__all__ = ["EyesQC"]
