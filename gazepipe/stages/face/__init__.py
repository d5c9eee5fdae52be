"""The ``face`` stage (SPEC §3.6, Berson 3.1): raw tracked and hand-cleaned Live Link Face blendshapes aligned.

Takes: a face take's tracked and clean Live Link Face CSVs. Gives: the ``face`` table: both tracks on the
frames they share (matched on timecode), the forward step dt to the next frame and the frame-rate-free forward
derivatives up to order k. Records in QC: rows read, matched and kept, frames dropped by either file, rows
without a counterpart, the match error and the range of dt.

Everything is in :mod:`.stage` (:func:`align_face`), read top-down; its parameters in :mod:`.params`.
"""

from gazepipe.stages import lazy_exports

__all__ = ["FaceAligned", "FaceParams", "align_face"]
__getattr__ = lazy_exports(__name__, {**{name: ".stage" for name in __all__}, "FaceParams": ".params"})
