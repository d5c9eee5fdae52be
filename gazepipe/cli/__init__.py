"""The command line (:mod:`gazepipe.cli.main`): a thin layer over :mod:`gazepipe.dag`, :mod:`gazepipe.io` and
:mod:`gazepipe.report`. Importing it changes nothing in the process; :func:`gazepipe.cli.main.main` caps the
BLAS threads (:mod:`gazepipe.cli.threads`) before any command runs."""
