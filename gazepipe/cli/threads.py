"""BLAS and OpenMP thread caps for a command-line run, set before numpy loads.

Stages work on small matrices and the engine runs takes in parallel, so a multi-threaded BLAS only contends
(numpy's OpenBLAS on a busy machine is slower than one thread by an order of magnitude). Worker processes
inherit the setting; a user's own environment variables win.
"""

from __future__ import annotations

import os

_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_capped: list[str] = []


def cap_blas_threads() -> None:
    """Set each thread variable the user did not set to 1 (once per process)."""
    if _capped:
        return
    _capped.extend(v for v in _VARIABLES if v not in os.environ)
    for var in _capped:
        os.environ[var] = "1"


def capped(variable: str) -> bool:
    """Whether ``variable`` was set by :func:`cap_blas_threads` rather than by the user (``gazepipe train``
    then gives torch every core back)."""
    return variable in _capped
