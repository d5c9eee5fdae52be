"""The clean stage's QC record (:class:`CleanQC`, written by :func:`gazepipe.stages.clean.stage.clean_markers`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from gazepipe.model import FILL_CODES
from gazepipe.stages.qc import QCRecord, absent_when


@dataclass(frozen=True)
class MarkerQC(QCRecord):
    """One marker's gaps (after spike removal) and how its samples ended up."""

    gaps: int
    longest_gap_frames: int
    longest_gap_s: float
    spikes_removed: int
    #: samples per fill code name, ``unfilled`` apart
    samples: Mapping[str, int]
    unfilled: int


@dataclass(frozen=True)
class GapQC(QCRecord):
    """One gap the filler decided (frames ``[start, stop)`` of the uncropped take)."""

    marker: str
    start: int
    stop: int
    #: the fill method chosen (a fill code name of :data:`gazepipe.model.FILL_CODES`), or ``unfilled``
    method: str
    #: the fill's estimated error (of the blend, when several methods were averaged), mm: the one the fill was kept
    #: or refused on, as the markers table's ``fill_error_mm`` stores it (float32); null when none could be made
    error_mm: float | None
    reason: str
    #: every configured method's validation error (null: it could not apply or nothing could be hidden)
    errors_mm: Mapping[str, float | None]
    weights: Mapping[str, float]

    def problems(self) -> list[tuple[str, str]]:
        if self.method not in FILL_CODES:
            return [("method", f"{self.method!r} is not a fill code ({', '.join(FILL_CODES)})")]
        if self.method != "unfilled" and self.method not in self.errors_mm:
            return [("errors_mm", f"has no entry for the gap's method {self.method!r}")]
        return []

    @property
    def method_error_mm(self) -> float | None:
        """The raw validation error of the method chosen (null for an unfilled gap, or one not validated): one
        input to ``error_mm``, which is what a fill is graded on."""
        return None if self.method == "unfilled" else self.errors_mm[self.method]


@dataclass(frozen=True)
class UnfilledQC(QCRecord):
    """The gaps left unfilled for one reason, and their samples."""

    gaps: int
    samples: int


@dataclass(frozen=True)
class SwapQC(QCRecord):
    """One stretch where two markers carried each other's names."""

    markers: tuple[str, str]
    start: int
    stop: int
    #: put back under their names (else both markers' samples there became gaps)
    repaired: bool


@dataclass(frozen=True)
class SwapPairQC(QCRecord):
    """Per marker pair ``"A/B"`` (any two markers the table carries, listed in the markerset or not):
    stretches repaired and stretches made gaps, and their samples apart."""

    repaired: int
    removed: int
    #: samples put back under their own names (both markers')
    repaired_samples: int | None = absent_when(
        "the record was written by a clean stage older than version 26, which counted stretches only")
    #: samples made gaps (both markers')
    removed_samples: int | None = absent_when(
        "the record was written by a clean stage older than version 26, which counted stretches only")


@dataclass(frozen=True)
class LowpassQC(QCRecord):
    cutoff_hz: float
    order_per_pass: int
    runs_unfiltered: int


@dataclass(frozen=True)
class CleanQC(QCRecord):
    """What the clean stage recorded of a take (see :func:`~gazepipe.stages.clean.stage.clean_markers`)."""

    #: the stage whose unit records hold it
    stage: ClassVar[str] = "clean"

    warnings: tuple[str, ...]
    failures: tuple[str, ...]
    #: every swapped stretch
    swaps: tuple[SwapQC, ...]
    #: per pair ``"A/B"``: stretches repaired and made gaps, and their samples
    swap_pairs: Mapping[str, SwapPairQC]
    spikes_removed: int
    #: every gap the filler decided (none when the take had no gap)
    gaps: tuple[GapQC, ...]
    markers: Mapping[str, MarkerQC]
    root_missing_frames: int
    #: rest periods, ``[start, stop)`` frames of the uncropped take
    rests: tuple[tuple[int, int], ...]
    #: kept frames ``[start, stop)`` of the uncropped take
    crop: tuple[int, int]
    kept_frames: int
    # the keys a clean stage writes only sometimes (last: the fields without one come first)
    # absent when swaps were looked for (or their repair is switched off): only a take too short to tell swaps
    # by itself, cleaned without the session's references, says why they were not
    swaps_not_checked: str | None = absent_when("swaps were looked for, or clean.repair_swaps is off")
    # absent unless clean.lowpass_hz is set: nothing was low-passed
    lowpass: LowpassQC | None = absent_when("clean.lowpass_hz is not set")
    # the gaps left unfilled, by reason (too long, no error estimate, an unlabeled trajectory, ...); every gap is
    # in ``gaps`` with its reason too, so a record written before the count was kept still reads
    unfilled_gaps: Mapping[str, UnfilledQC] | None = absent_when(
        "the record was written by a clean stage older than version 25, which did not count them apart")
    #: per crop bound, the frames against it where too few of the subject's markers are seen to tell rest from
    #: motion (the bound may be off by up to that many; 0: that bound is seen)
    crop_hidden: tuple[int, int] | None = absent_when("both crop bounds are seen")


__all__ = ["CleanQC", "GapQC", "LowpassQC", "MarkerQC", "SwapPairQC", "SwapQC", "UnfilledQC"]
