"""Blocks: effects that follow any hysteresis model (one file each; see :mod:`hystfit.blocks.base`).

Each module registers one block on :data:`hystfit.registry.blocks`; a model expression such as
``pi+creep+delay`` chains them after a base model (:mod:`hystfit.models.composite`).
"""

from .base import Block
from . import dynamics, creep, asymmetry, drift, delay, lti  # noqa: F401  (registration; this order is the order diagnose reports ties in)

__all__ = ["Block"]
