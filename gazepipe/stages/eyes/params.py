"""Parameters of the eyes stage (SPEC §3.5), shared by its modules."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["SHORT_VIDEO_SHARE", "EyesParams"]

#: a head-camera video shorter than this share of its take is too short to be the take's (see
#: :func:`gazepipe.stages.eyes.stage.eyes_take`; the sync stage notes such a video too)
SHORT_VIDEO_SHARE = 0.5


@dataclass(frozen=True)
class EyesParams:
    """Parameters of the eyes stage (SPEC §3.5); speeds in degrees per second, times in seconds.

    Attributes
    ----------
    min_confidence : OpenFace confidence at or above which a sample can be valid.
    max_eye_gap_s : longest invalid run (between two valid samples) filled by slerp.
    head_segment : the head segment's name in the joints; ``None`` = ``"head"``, else the last segment.
    smooth_s : moving-average window of the directions whose central differences give angular speeds (used
        only to choose the frames of the camera-rotation fit).
    max_target_speed_deg_s : fastest the target may move (lab axes when the joints give the character frame's
        orientation, else character axes; after the lag) for a frame to enter the fit: during pursuit the eyes
        trail a moving target, more the faster it goes.
    max_gaze_speed_deg_s : fastest the gaze may move in camera axes (saccades are far faster; pursuit and the
        vestibulo-ocular reflex during head turns are slower).
    settle_s : frames this soon after a faster target move stay out (the eyes land after the catch-up saccade).
    max_eccentricity_deg : frames whose target lies further than this from the head's forward axis stay out (the
        eyes rotate at most about 45-50 degrees in the head; beyond that they do not reach the target).
    max_lag_s : longest eye-behind-target delay searched; the eyes follow a target about 0.2 s late.
    keep_percentile : after each fit, frames whose error is above this percentile are left out of the next fit.
    refit_iterations : number of trimmed re-fits after the first fit.
    min_fixation_frames : fewest fixation frames needed to estimate the camera rotation.
    min_target_spread_deg : below this RMS spread of the target directions the estimate is poorly conditioned
        (a warning in QC).

    Each field's metadata gives its allowed values (:func:`gazepipe.pipeline.registry.value_problem`) and its one
    line of help (``help``: what ``gazepipe params`` prints).
    """

    min_confidence: float = field(default=0.8, metadata={
        "min": 0, "max": 1, "help": "OpenFace samples below this confidence are not used"})
    max_eye_gap_s: float = field(default=0.1, metadata={
        "min": 0, "help": "longest run of unusable eye samples, in s, bridged by interpolation"})
    head_segment: str | None = field(default=None, metadata={
        "help": "the head segment the gaze is measured from (default: the one named head, else the last)"})
    smooth_s: float = field(default=0.2, metadata={
        "min": 0, "help": "smoothing window, in s, of the gaze directions used to find fixations"})
    max_target_speed_deg_s: float = field(default=30.0, metadata={
        "gt": 0, "help": "frames where the target moves faster than this (degrees/s) are not used to find "
            "the camera rotation"})
    max_gaze_speed_deg_s: float = field(default=60.0, metadata={
        "gt": 0, "help": "frames where the gaze moves faster than this (degrees/s) are not used either"})
    settle_s: float = field(default=0.15, metadata={
        "min": 0, "help": "frames this soon (s) after a fast target move are not used either"})
    max_eccentricity_deg: float = field(default=50.0, metadata={
        "gt": 0, "max": 180, "help": "frames whose target is further than this (degrees) from straight "
            "ahead are not used"})
    max_lag_s: float = field(default=0.5, metadata={
        "min": 0, "help": "longest delay, in s, of the eyes behind the target that is searched"})
    keep_percentile: float = field(default=75.0, metadata={
        "gt": 0, "max": 100, "help": "after each fit, frames whose error is above this percentile are left "
            "out"})
    refit_iterations: int = field(default=3, metadata={
        "min": 0, "help": "how many times the camera rotation is re-fitted without the worst frames"})
    min_fixation_frames: int = field(default=30, metadata={
        "min": 1, "help": "fewest usable frames needed to estimate the camera rotation"})
    min_target_spread_deg: float = field(default=5.0, metadata={
        "min": 0, "help": "warn when the targets looked at span less than this, in degrees"})
