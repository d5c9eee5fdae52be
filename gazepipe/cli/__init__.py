"""The command line. Importing it caps BLAS threads before numpy loads.

Stages work on small matrices and the engine runs takes in parallel, so a multi-threaded BLAS only contends
(numpy's OpenBLAS on a busy machine is slower than one thread by an order of magnitude). Worker processes
inherit the setting; a user's own environment variables win.
"""

import os

#: the thread variables set here (not by the user): ``gazepipe train`` gives torch every core back
CAPPED = tuple(v for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS") if v not in os.environ)
for _var in CAPPED:
    os.environ[_var] = "1"
