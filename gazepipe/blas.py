"""One BLAS thread around numerical work, whatever the executor: results must not depend on where a unit ran (a
multi-threaded BLAS sums in another order), and takes already run in parallel.

Finding the thread pools means scanning the process's loaded libraries (about 0.7 ms); the scan is kept and
reused (a limit then costs about 0.01 ms) until a module has been imported since, which may have loaded a
library with a pool of its own.
"""

from __future__ import annotations

import sys
from contextlib import AbstractContextManager
from typing import Any

_scan: tuple[int, Any] | None = None


def one_blas_thread() -> AbstractContextManager[Any]:
    """A context manager that limits every BLAS and OpenMP pool of the process to one thread inside it."""
    global _scan
    if _scan is None or _scan[0] != len(sys.modules):
        import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS must be loaded to be found)
        from threadpoolctl import ThreadpoolController

        controller = ThreadpoolController()
        _scan = (len(sys.modules), controller)
    return _scan[1].limit(limits=1)
