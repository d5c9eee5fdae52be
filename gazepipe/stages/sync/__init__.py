"""The ``sync`` stage (SPEC §3.4, Klein 5.1): the head camera's clock mapped onto the mocap clock.

Takes: a take's ``markers_raw`` (the clapper's two markers) and its head-camera video (frame timestamps, and
windows of frames around each expected clap). Gives: the ``sync`` table, one row per clap (times on both
clocks, confidences) with the clock map t_mocap = offset + ratio · t_video. Records in QC: every clap, the
offset and ratio, their drift and residual, frames decoded, mocap frames without video, and warnings.

Read top-down: :mod:`.stage` (:func:`sync_take`) pairs the claps found by :mod:`.clap` (the mocap side: the
contact instant of the clapper's arms) and :mod:`.video` (the video side: the end of the closing burst of
motion energy) and fits :mod:`.clock` (the clock map, and resampling video-clock signals onto mocap frames,
which the eyes stage uses). :mod:`.coverage` notes a video far shorter than its take.
"""

from gazepipe.stages import lazy_exports

__all__ = ["SyncParams", "SyncResult", "sync_take"]
__getattr__ = lazy_exports(__name__, {name: ".stage" for name in __all__})
