"""Optimizers. Each module registers one algorithm on :data:`hystfit.registry.optimizers`."""

from .base import OptimizeResult, Optimizer, StopRules, Tracker, reflect
from . import pso, lsq, auto, pso_cf, ipso, ga, gwo, igwo, de  # noqa: F401  (registration)

__all__ = ["Optimizer", "OptimizeResult", "StopRules", "Tracker", "reflect"]
