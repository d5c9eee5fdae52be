"""How the stages' compiled kernels are compiled: one decorator for every kernel module.

A kernel is compiled by numba on its first call in a process, its machine code cached on disk (beside its module,
or in numba's user cache where that folder is read-only) so later processes and workers load it; with no writable
cache anywhere it is compiled once per process. ``fastmath`` stays off (the results are the bits of the array code
they replace) and ``error_model="numpy"``: a division by zero gives inf or NaN, as numpy does, never an exception.
Importing this module imports numba (a few tenths of a second): the stages import their kernels where first needed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])


def kernel(fn: F) -> F:
    """``fn`` compiled on its first call, its machine code cached on disk where numba finds a writable place."""
    try:
        return cast(F, numba.njit(cache=True, error_model="numpy")(fn))
    except RuntimeError:          # no writable cache directory at all: compiled once per process
        return cast(F, numba.njit(cache=False, error_model="numpy")(fn))
