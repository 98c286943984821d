"""Hysteresis models. Each module registers one model on :data:`hystfit.registry.models`."""

from .base import FittedModel, Model
from . import pi, bw  # noqa: F401  (registration)

__all__ = ["Model", "FittedModel"]
