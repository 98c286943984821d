"""Optimizers. Each module registers one algorithm on :data:`hystfit.registry.optimizers`.

To add one: subclass :class:`~.base.IteratedSearch` (``pop`` and ``iters``) or
:class:`~.base.PopulationSearch` (``pop`` only) together with :class:`~.base.PopulationLoop`
and implement ``search`` (a particle swarm: :class:`~.pso.Swarm` and its ``velocity`` rule); or
subclass :class:`~.base.Optimizer` and implement ``minimize``. Declare each numeric setting with
the values it accepts (:func:`~.base.setting`); ``check_settings`` holds only the rules that
involve several settings. Stop rules come with the base class (``stop``, one
:class:`~.base.StopRules` value); docstrings share paragraphs through ``{name}`` lines
(:data:`~.base.DOC_SECTIONS`).
"""

from .base import (Accepts, IteratedSearch, OptimizeResult, Optimizer, PopulationLoop, PopulationSearch, StopRules,
                   Tracker, reflect, setting)
from . import pso, lsq, auto, pso_cf, ipso, ga, gwo, igwo, de  # noqa: F401  (registration)
from .pso import Swarm

__all__ = ["Optimizer", "OptimizeResult", "StopRules", "Tracker", "reflect", "PopulationSearch", "IteratedSearch",
           "PopulationLoop", "Swarm", "Accepts", "setting"]
