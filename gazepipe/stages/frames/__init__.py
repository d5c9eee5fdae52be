"""The ``frames`` stage (SPEC §2, §3.3, Pejsa 5.2.2.2): segment orientations in the character frame.

Takes: a take's cleaned ``markers``, the markerset, and the neutral pose (the session's ``neutral`` take
cleaned, else the take's own first rest period). Gives: the ``joints`` table: per frame the character frame,
each segment's global and parent-relative rotation (quaternions and the 6-number form), the eyes' centre and
the unit direction to the target. Records in QC: the neutral frames used per segment, the frames without a
character frame or a segment, where the neutral pose came from, and warnings.

Everything is in :mod:`.stage` (:func:`compute_frames`), read top-down; :mod:`.neutral` chooses the neutral
poses a take is calibrated against (the session's, its own first rest, other takes' first rests).
"""

from gazepipe.stages import lazy_exports

__all__ = ["FramesParams", "Joints", "compute_frames"]
__getattr__ = lazy_exports(__name__, {name: ".stage" for name in __all__})
