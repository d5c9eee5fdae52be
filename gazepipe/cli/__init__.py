"""The command line. Importing it caps BLAS threads before numpy loads.

Stages work on small matrices and the engine runs takes in parallel, so a multi-threaded BLAS only contends
(numpy's OpenBLAS on a busy machine is slower than one thread by an order of magnitude). Worker processes
inherit the setting; a user's own environment variables win.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
