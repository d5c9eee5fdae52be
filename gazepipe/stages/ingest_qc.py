"""The ingest stage's QC record (:class:`IngestQC`).

Ingest has no stage package: reading a capture is :mod:`gazepipe.io` (:func:`gazepipe.io.capture.read_markers`)
and the unit that runs it is declared with the others in :mod:`gazepipe.dag.takes` (``run_ingest`` writes this
record). Its QC type sits here, beside the other stages' ``stages/<stage>/qc.py``, so that the report imports no
reader and no DAG module to read it; it moves into ``stages/ingest/`` when ingest gets a package of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class IngestQC(QCRecord):
    """What ingest recorded of a take's capture (``run_ingest`` in :mod:`gazepipe.dag.takes`)."""

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


__all__ = ["IngestQC"]
