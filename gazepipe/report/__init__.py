"""QC checks and the validation report (``gazepipe validate``): :func:`validate_output` writes
``OUT/qc/report.json`` (the source of truth), ``OUT/qc/takes.parquet`` and ``OUT/qc/report.html``."""

from __future__ import annotations

from gazepipe.report.checks import Check, Thresholds

__all__ = ["Check", "Thresholds"]
