"""Particle swarm optimization with Clerc's constriction factor (paper 001 eq. 6–7)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import IteratedSearch, setting
from .pso import Swarm


def constriction_factor(phi: float) -> float:
    """Clerc's constriction factor χ = 2 / |2 − φ − sqrt(φ² − 4φ)| (paper 001 eq. 7).

    Parameters
    ----------
    phi : float
        φ = φ1 + φ2; must exceed 4 (the square root is real and χ < 1 only then).

    Returns
    -------
    float
        χ; 0.729843… for the customary φ = 4.1.
    """
    if not phi > 4.0:
        raise ConfigError(f"pso-cf: phi1 + phi2 must be greater than 4, got {phi:g}")
    return 2.0 / abs(2.0 - phi - math.sqrt(phi * phi - 4.0 * phi))


@optimizers.register
@dataclass
class ConstrictionPSO(Swarm, IteratedSearch):
    """Global-best PSO with constriction factor (paper 001 eq. 6–7; ``shared/papers/README.md``).

    v ← χ [v + φ1 r1 (p_i − x) + φ2 r2 (p_g − x)],  x ← x + v,
    χ = 2 / |2 − φ − sqrt(φ² − 4φ)|,  φ = φ1 + φ2 = 4.1 (φ1 = φ2 = 2.05) ⇒ χ ≈ 0.7298,

    with r1, r2 ~ U(0, 1) drawn per particle and dimension, p_i the personal and p_g the global
    best. Eq. 6 of paper 001 also carries an inertia weight W inside the bracket; Clerc's
    constriction is the case W = 1, which is what we implement (χ alone damps the swarm, no
    inertia schedule is needed).

    Parameters
    ----------
    pop : int, default 40
        Swarm size (≥ 2).
    {iters_param}
    phi1, phi2 : float, default 2.05
        Cognitive and social acceleration; φ1 + φ2 must exceed 4.
    vmax_frac : float, default 1.0
        Velocity clamp as a fraction of (upper − lower). Constriction does not need a clamp;
        Eberhart & Shi (2000) still recommend V_max = X_max, i.e. the box width (1.0).
    {stop_rule_params}

    Notes
    -----
    {iterated_stop_rules}

    {swarm_notes}
    """

    name = "pso-cf"
    title = "Particle swarm (constriction factor)"
    reference = "paper 001 eq. 6–7 (Clerc & Kennedy 2002)"

    phi1: float = setting(2.05, at_least=0)
    phi2: float = setting(2.05, at_least=0)
    vmax_frac: float = setting(1.0, above=0)

    def check_settings(self) -> None:
        super().check_settings()
        constriction_factor(self.phi1 + self.phi2)  # validates φ > 4

    def velocity(self, nit: int, x: np.ndarray, v: np.ndarray, pbest: np.ndarray, pbest_f: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
        chi = constriction_factor(self.phi1 + self.phi2)
        r = rng.random((2,) + x.shape)
        g = int(np.argmin(pbest_f))
        # χ[v + φ1 r1 (p_i − x) + φ2 r2 (p_g − x)], with χ folded into the coefficients
        return chi * v + (chi * self.phi1) * r[0] * (pbest - x) + (chi * self.phi2) * r[1] * (pbest[g] - x)
