"""The ``eyes`` stage (SPEC §3.5, Klein 5.2 and 9): OpenFace gaze into the character frame.

Takes: a take's OpenFace CSV, its ``joints`` table and, with a video, its ``sync`` clock map. Gives: the
``eyes`` table: per mocap frame the cyclopean eye direction in the character frame and in the head's axes,
whether it is valid or bridged by slerp, and its confidence; the camera rotation used in the table's metadata.
Records in QC: valid frames and their share, frames without video coverage or head, the clock used, the camera
rotation (configured or estimated, with its residual, frames used and target spread), the eyes' lag behind the
target, and warnings.

Read top-down: :mod:`.stage` (:func:`eyes_take`) runs :mod:`.gate` (gating on success, confidence and blinks,
short gaps bridged; the cyclopean direction), resamples onto mocap frames, then :mod:`.camera` (camera → head →
character axes; the fixation rules and trimmed fit that estimate the camera rotation) and :mod:`.lag` (the lag
searched with it). :mod:`.params` holds the parameters; :mod:`.mocap` reads the head's motion from the
``joints`` table's arrays and marks the bridged frames.
"""

from gazepipe.stages import lazy_exports

__all__ = ["EyesParams", "EyesResult", "HeadMotion", "eyes_take"]
__getattr__ = lazy_exports(__name__, {"EyesParams": ".params", "EyesResult": ".stage", "HeadMotion": ".stage",
                                      "eyes_take": ".stage"})
