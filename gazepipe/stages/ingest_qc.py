"""The ingest stage's QC record (:class:`IngestQC`), and which markers a take cannot do without.

Ingest has no stage package: reading a capture is :mod:`gazepipe.io` (:func:`gazepipe.io.capture.read_markers`)
and the unit that runs it is declared with the others in :mod:`gazepipe.dag.takes` (its run,
:mod:`gazepipe.dag.nodes.ingest`, writes this record). Its QC type sits here, beside the other stages' ``stages/<stage>/qc.py``, so that the report imports no
reader and no DAG module to read it; it moves into ``stages/ingest/`` when ingest gets a package of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from gazepipe.model import Markers, MarkerSet
from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class IngestQC(QCRecord):
    """What ingest recorded of a take's capture (:func:`ingest_record`)."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "ingest"

    frames: int
    rate_hz: float
    first_frame: int
    #: POINT:UNITS or the units row as the file gives them; None when the file does not say (a QTM TSV, a wide
    #: CSV: the markerset's ``units`` were assumed)
    units_found: str | None
    markers: int
    #: per marker (capture label, renamed to the markerset's), the share of frames that are gaps
    gap_fraction: Mapping[str, float]
    model_outputs: int


def ingest_record(markers: Markers) -> dict:
    """The :class:`IngestQC` record of a capture read (labels as the markerset names them), as JSON."""
    gap = markers.gap_fraction()
    return {
        "frames": markers.n_frames, "rate_hz": markers.rate_hz, "first_frame": markers.first_frame,
        "units_found": markers.units, "markers": markers.n_markers,
        "gap_fraction": {lab: round(float(g), 6) for lab, g in zip(markers.labels, gap, strict=True)},
        "model_outputs": len(markers.model_outputs),
    }


def required_markers(ms: MarkerSet, kind: str, has_video: bool) -> list[str]:
    """Markers a take of this ``kind`` cannot do without: the subject's, the target when the subject follows it
    (``gaze_follow``), the clapper when a video must be synchronised."""
    names = list(ms.subject_markers)
    if kind == "gaze_follow" and ms.target:
        names.append(ms.target)
    if has_video and ms.clapper:
        names.extend(ms.clapper)
    return names


__all__ = ["IngestQC", "ingest_record", "required_markers"]
