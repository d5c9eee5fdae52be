"""Worker processes die with the run that started them.

A run killed with SIGKILL (the out-of-memory killer, a batch system's time limit) cannot stop its workers
itself. On Linux each helper process asks the kernel for SIGKILL when its parent dies
(``prctl(PR_SET_PDEATHSIG)``): the forkserver of the process executor (its parent is the run), each of its
workers (their parent is the forkserver) and each worker of a local Dask cluster (its parent is the run).
Multiprocessing's resource tracker then ends by itself: it stops when the last process holding its pipe is
gone. Elsewhere nothing is asked; local workers still check that the run is alive before every unit.

:mod:`gazepipe.pipeline.lifeline_preload` applies :func:`die_with_parent` when it is imported: it is the
forkserver's and the Dask workers' preload module.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

#: ``prctl`` option: the signal the calling process gets when the thread that created it ends
PR_SET_PDEATHSIG = 1


def die_with_parent() -> bool:
    """Ask for SIGKILL when this process's parent dies (Linux; elsewhere nothing, ``False``). A parent that died
    while this was being asked (the process was handed to another) ends the process at once."""
    if not sys.platform.startswith("linux"):
        return False
    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if os.getppid() != parent:
        os._exit(1)
    return True


def worker_initializer() -> None:
    """``ProcessPoolExecutor`` initializer: the worker dies with the forkserver that forked it."""
    die_with_parent()
