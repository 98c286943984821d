"""What a process that fits loads once before its first fit: numba, numba's set-up at its first
cached kernel, and ``scipy.optimize`` — done ahead, step by step.

Two users: the local pools' fork server (:mod:`hystfit._pool_preload`), which loads it all before it
forks any worker, and a command that fits in its own process
(:func:`hystfit.io.load_captures` with ``ahead``), which loads what its fit is sure to need while a
forked child reads the captures, and stops as soon as they are read (what is left loads at the
first fit, as it would have anyway). Not numba for a command that may not need it: a PI fit of
short captures runs without it (:func:`hystfit.models._kernels.play_matrix_from`). Loading ahead
changes no number: the same modules, the same cached machine code.
"""

from __future__ import annotations

from typing import Callable, Sequence


def _import_numba() -> None:
    from . import _jit

    _jit._load_numba()


def _first_kernel() -> None:
    # numba's typing and lowering registries (which import scipy.linalg) and its code generator,
    # set up at the first cached kernel a process calls: ≈ 0.7 s (benchmarks/bench_startup.py)
    import numpy as np

    from .models._kernels import _play_recurrence

    _play_recurrence(np.zeros(2), np.zeros(1), np.zeros(1))


def import_optimize() -> None:
    """``scipy.optimize``: the local optimizers and the polish import it on first use."""
    import scipy.optimize  # noqa: F401


#: numba and its set-up, in the order a fit meets them
KERNELS: tuple[Callable[[], None], ...] = (_import_numba, _first_kernel)

#: everything, in the order a fit meets it
STEPS: tuple[Callable[[], None], ...] = (*KERNELS, import_optimize)


def load_ahead(steps: Sequence[Callable[[], None]] = STEPS, stop: Callable[[], bool] = lambda: False) -> None:
    """Run ``steps`` in order, asking ``stop()`` before each; a step that fails is left to the fit
    that needs it (which then raises its own error)."""
    for step in steps:
        if stop():
            return
        try:
            step()
        except Exception:  # noqa: BLE001, S112 - only saves time
            continue
