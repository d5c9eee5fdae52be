"""The ``clean`` stage (SPEC §3.2, Pejsa 5.2.2.1): a take's raw markers made fit to measure.

Takes: a take's ``markers_raw`` (mm, lab axes, a validity mask) and the session's markerset. Gives: the
``markers`` table (stabilised, cropped, each sample coded measured, filled by which method, or unfilled) and
``neutral`` (the first rest period's frames, for the frames stage's calibration). Records in QC: per marker its
gaps, longest gap, spikes removed and samples per fill method; every gap with its method, its fill's estimated
error and each method's validation error; the gaps left unfilled, per reason; frames without the root marker;
the low-pass; the rest periods, the crop and the frames kept.

Read top-down, in the order :func:`clean_markers` (:mod:`.stage`) runs them:

- :mod:`.spikes`: spikes become gaps (ghosts of a frame or two off the marker's path or its segment's
  distances, and implausible accelerations);
- :mod:`.gapfill`: every gap filled by the best of the methods of :mod:`.fill_methods` (rigid cluster, PCA,
  PCHIP, linear), chosen by hiding measured samples beside it, or for long gaps their frame-by-frame average
  (:mod:`.framewise`); a gap whose estimated error is above its limit, or cannot be estimated, stays a gap, and a
  marker still through a rest is filled past ``max_gap_s``;
- :mod:`.stabilise`: the root marker to the lab origin (optionally the heading removed);
- :mod:`.filters`: the optional zero-phase low-pass, run by run (and the Gaussian smoothing of rest speeds);
- :mod:`.rests`: rest periods from the subject's speed, and the crop the take's kind keeps.

:mod:`.standalone` is the same spike removal and gap filling on any capture file, without a session
(``gazepipe fill``). :mod:`.subject` pools the subject's marker geometry from every capture of a session, that
each take's label swaps are judged against.
"""

from gazepipe.stages import lazy_exports

__all__ = ["CleanParams", "CleanResult", "clean_markers", "fill_capture"]
__getattr__ = lazy_exports(__name__, {"CleanParams": ".stage", "CleanResult": ".stage", "clean_markers": ".stage",
                                      "fill_capture": ".standalone"})
