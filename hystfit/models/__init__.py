"""Hysteresis models. Each module registers one model on :data:`hystfit.registry.models`."""

from .base import Model
from . import pi, bw, ch, dahl, lugre, fp, nt, gpi, pi2, hammerstein  # noqa: F401  (registration)

__all__ = ["Model"]
