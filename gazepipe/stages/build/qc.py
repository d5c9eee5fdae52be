"""The QC record of a take's part of a dataset (:class:`RowsQC`, the units ``rows_<dataset>``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gazepipe.stages.qc import QCRecord


@dataclass(frozen=True)
class RowsQC(QCRecord):
    """What a take gives a dataset: its rows, the split its take hash draws, and why it gives none."""

    #: the stages whose unit records hold it: ``rows_<dataset>``, one per dataset
    stage: ClassVar[str] = "rows"

    #: rows of the take's part (mirrored copies included); 0 when the take is left out
    rows: int
    #: the split the take's hash draws (the dataset build may move it to fill an empty split)
    split: str
    #: why the take is left out of the dataset; empty when it is not
    problem: str


__all__ = ["RowsQC"]
