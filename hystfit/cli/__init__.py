"""Command-line interface: parsing and printing only (no numerics).

Every command lives in its own module and registers itself on :data:`app` when imported.

One BLAS thread. hystfit's heavy work is its numba kernels (threaded over candidates) and its
process pools; its linear algebra is small (Jacobians of a few columns, 3×3 normal equations),
where a multithreaded BLAS only adds synchronisation: measured on a 2-core machine with other
work running, one 5000 × 12 SVD inside the least-squares polish took 3 ms with one OpenBLAS
thread and 220 ms with two. So the command line sets ``OPENBLAS_NUM_THREADS``/``MKL_NUM_THREADS``
/``VECLIB_MAXIMUM_THREADS`` to 1 unless the user set them (it must happen before numpy loads;
where numpy was loaded first, the library's limit applies instead: :mod:`hystfit._blas`).
"""

from .._blas import set_cli_defaults as _set_cli_defaults

_set_cli_defaults()

from .app import app, main

# Command modules (import order = order in ``hystfit --help``).
from . import identify as _identify  # noqa: E402,F401
from . import simulate as _simulate  # noqa: E402,F401
from . import compare as _compare  # noqa: E402,F401
from . import synth as _synth  # noqa: E402,F401
from . import listing as _listing  # noqa: E402,F401

__all__ = ["app", "main"]
from . import diagnose as _diagnose  # noqa: E402,F401
from . import invert as _invert  # noqa: E402,F401
from . import track as _track  # noqa: E402,F401
from . import batch as _batch  # noqa: E402,F401
