"""Optimizers. Each module registers one algorithm on :data:`hystfit.registry.optimizers`.

To add one: subclass :class:`~.base.IteratedSearch` (``pop`` and ``iters``) or
:class:`~.base.PopulationSearch` (``pop`` only) together with :class:`~.base.PopulationLoop`
and implement ``search``; or subclass :class:`~.base.Optimizer` and implement ``minimize``.
Stop rules come with the base class (``stop``, one :class:`~.base.StopRules` value).
"""

from .base import (IteratedSearch, OptimizeResult, Optimizer, PopulationLoop, PopulationSearch, StopRules, Tracker,
                   reflect)
from . import pso, lsq, auto, pso_cf, ipso, ga, gwo, igwo, de  # noqa: F401  (registration)

__all__ = ["Optimizer", "OptimizeResult", "StopRules", "Tracker", "reflect", "PopulationSearch", "IteratedSearch",
           "PopulationLoop"]
