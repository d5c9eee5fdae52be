"""Importing gazepipe's command line changes nothing in the process: the BLAS thread caps are set by the
``gazepipe`` command itself, before numpy loads."""

from __future__ import annotations

import os
import subprocess
import sys

VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _run(code: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_importing_the_command_line_leaves_the_environment_alone():
    code = f"import os, gazepipe.cli.main, gazepipe.cli.train; print([os.environ.get(v) for v in {VARIABLES!r}])"
    assert _run(code) == "[None, None, None]"


def test_the_command_caps_the_threads_the_user_left_unset_before_numpy_loads():
    code = ("import os, sys\n"
            "os.environ['MKL_NUM_THREADS'] = '3'\n"
            "from gazepipe.cli.threads import cap_blas_threads, capped\n"
            "assert 'numpy' not in sys.modules\n"
            "cap_blas_threads()\n"
            f"print([os.environ.get(v) for v in {VARIABLES!r}], capped('OMP_NUM_THREADS'), capped('MKL_NUM_THREADS'))")
    assert _run(code) == "['1', '1', '3'] True False"
