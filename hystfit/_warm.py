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

import sys
import threading
from typing import Callable, Sequence


def _import_numba() -> None:
    from . import _jit

    _jit._load_numba()


def _first_kernel() -> None:
    # numba's typing and lowering registries (which import scipy.linalg) and its code generator,
    # set up at the first cached kernel a process calls: ≈ 0.7 s (benchmarks/bench_startup.py)
    import numpy as np

    from ._jit import readonly
    from .models._kernels import _play_recurrence

    _play_recurrence(readonly(np.zeros(2)), readonly(np.zeros(1)), readonly(np.zeros(1)))  # the form fits pass


def import_optimize() -> None:
    """``scipy.optimize``: the local optimizers and the polish import it on first use."""
    import scipy.optimize  # noqa: F401


#: numba and its set-up, in the order a fit meets them
KERNELS: tuple[Callable[[], None], ...] = (_import_numba, _first_kernel)

#: everything, in the order a fit meets it
STEPS: tuple[Callable[[], None], ...] = (*KERNELS, import_optimize)


class Abandoned(BaseException):
    """Raised out of :func:`load_ahead` when its ``abandon()`` said so (not an ``Exception``: the
    step under way, and any ``except Exception`` in the code it imports, must not catch it)."""


class _AbandonAtImport:
    """A ``sys.meta_path`` finder that finds nothing: at each import the steps make in ``thread`` it
    asks ``abandon()``, and raises :class:`Abandoned` when it answers True."""

    def __init__(self, abandon: Callable[[], bool], thread: int) -> None:
        self.abandon, self.thread = abandon, thread

    def find_spec(self, name, path=None, target=None):
        if threading.get_ident() == self.thread and self.abandon():
            raise Abandoned(name)
        return None


def load_ahead(steps: Sequence[Callable[[], None]] = STEPS, stop: Callable[[], bool] = lambda: False,
               abandon: Callable[[], bool] | None = None) -> None:
    """Run ``steps`` in order, asking ``stop()`` before each; a step that fails is left to the fit
    that needs it (which then raises its own error).

    ``abandon()``: asked at every module the steps import (it must be cheap, and must not import
    nor compute); once it answers True the step under way is abandoned at once and
    :class:`Abandoned` raised — for when what the steps load will not be used and the process ends
    right after (the captures read meanwhile were refused: the console script ends with the
    loader's error). A module whose import is cut short is half-loaded (its package gone from
    ``sys.modules``, some of its submodules left): the process must not fit afterwards. A step is
    mostly imports of half a second or more, which ``stop()`` cannot cut short: without this a
    refused capture waited for them (≈ 1 s)."""
    finder = _AbandonAtImport(abandon, threading.get_ident()) if abandon is not None else None
    if finder is not None:
        sys.meta_path.insert(0, finder)
    try:
        for step in steps:
            if stop():
                return
            if finder is not None and abandon():
                raise Abandoned(getattr(step, "__name__", "step"))
            try:
                step()
            except Exception:  # noqa: BLE001, S112 - only saves time
                continue
    finally:
        if finder is not None and finder in sys.meta_path:  # a step may have rebound sys.meta_path
            sys.meta_path.remove(finder)
