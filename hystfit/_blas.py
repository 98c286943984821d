"""One BLAS thread: the variables that choose numpy's and scipy's BLAS threads, the command line's
defaults for them, and whether those defaults came in time.

A BLAS library reads its variable once, when it loads. The command line sets
``OPENBLAS_NUM_THREADS`` and its kin to 1 before numpy loads (:mod:`hystfit.cli`), so its BLAS runs
one thread. When a program imported numpy before :mod:`hystfit.cli` (a test suite running the
command line through typer's ``CliRunner``, a notebook calling :func:`hystfit.cli.main`), the
defaults come too late: numpy's BLAS already runs a thread per core, and a variable the command line
set must not then be taken for the user's choice (:func:`user_chose_blas_threads`), or the
library's limit (:func:`hystfit.parallel.one_blas_thread`) would leave the threads as they are —
``diagnose`` on sample_data then took ≈ 3× as long, with other numbers than the console script's.

This module imports nothing heavy: the command line imports it before numpy.
"""

from __future__ import annotations

import os
import sys

#: the variables a user sets to choose the BLAS threads; set, they are left alone
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "OMP_NUM_THREADS")

#: the variables the command line sets to 1 where the user has not
CLI_DEFAULTS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")

#: the variables :func:`set_cli_defaults` set after numpy had loaded (its BLAS did not read them)
_set_too_late: set[str] = set()


def set_cli_defaults() -> None:
    """One BLAS thread, as the command line runs: each of :data:`CLI_DEFAULTS` the user has not set
    is set to 1, noting those set after numpy had loaded."""
    late = "numpy" in sys.modules
    for var in CLI_DEFAULTS:
        if var not in os.environ:
            os.environ[var] = "1"
            if late:
                _set_too_late.add(var)


def user_chose_blas_threads() -> bool:
    """Whether the user chose the BLAS threads: one of :data:`BLAS_THREAD_VARS` is set, and not by
    :func:`set_cli_defaults` after numpy had loaded (nor changed since)."""
    return any(var in os.environ and not (var in _set_too_late and os.environ[var] == "1")
               for var in BLAS_THREAD_VARS)
