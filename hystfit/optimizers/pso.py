"""Particle swarm optimization with linearly decreasing inertia (paper 001 eq. 4–5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import optimizers
from .base import IteratedSearch, PopulationLoop, Tracker, reflect


def fly(x: np.ndarray, v: np.ndarray, vmax: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """One move of the swarm: v clamped to ±vmax (in place), x + v as a new array (the objective
    may keep the previous one); a coordinate that leaves the box is reflected back inside and its
    velocity component reversed (in place). Used by ``pso-cf`` and ``ipso``; :class:`PSO` reflects
    every coordinate (its numbers predate this helper)."""
    np.clip(v, -vmax, vmax, out=v)
    x = x + v
    out = (x < lower) | (x > upper)
    if out.any():
        x = reflect(x, lower, upper)
        np.negative(v, out=v, where=out)
    return x


def update_personal_bests(pbest: np.ndarray, pbest_f: np.ndarray, x: np.ndarray, f: np.ndarray) -> None:
    """Replace (in place) the personal bests that ``x`` improves on."""
    better = f < pbest_f
    pbest[better] = x[better]
    pbest_f[better] = f[better]


@optimizers.register
@dataclass
class PSO(PopulationLoop, IteratedSearch):
    """Global-best PSO with inertia weight (paper 001 eq. 4–5; ``shared/papers/README.md``).

    v ← W v + φ1 r1 (p_i − x) + φ2 r2 (p_g − x),  x ← x + v,
    W decreasing linearly from ``w_start`` (0.9) to ``w_end`` (0.4) over ``iters`` iterations,
    φ1 = φ2 = 2, velocity clamped to ``vmax_frac``·(upper − lower).

    Bounds: a particle that leaves the box is *reflected* back inside and the offending velocity
    component reversed (periodic wrapping, pyswarms' default, is known to ruin PI fits).

    Settings: ``pop`` (40) particles, ``iters`` (200) iterations, ``w_start``/``w_end`` (0.9/0.4),
    ``phi1``/``phi2`` (2.0/2.0) cognitive and social acceleration, ``vmax_frac`` (0.2).

    Stop rules: ``iters`` iterations, or ``max_evals`` evaluations, or no relative improvement
    above ``stall_tol`` for ``stall_iter`` iterations, or ``target`` reached, or ``time_limit_s``.

    Initialisation: uniform in the box; if ``x0`` is given it replaces the first particle.
    """

    name = "pso"
    title = "Particle swarm (inertia weight)"
    reference = "paper 001 eq. 4–5"

    w_start: float = 0.9
    w_end: float = 0.4
    phi1: float = 2.0
    phi2: float = 2.0
    vmax_frac: float = 0.2

    def search(self, tr: Tracker, x: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rng: np.random.Generator) -> None:
        P, d = x.shape
        vmax = self.vmax_frac * (upper - lower)
        v = (rng.random((P, d)) * 2 - 1) * vmax
        pbest, pbest_f = x.copy(), f.copy()
        g = int(np.argmin(pbest_f))
        while True:
            frac = min(tr.nit / max(self.iters - 1, 1), 1.0)
            w = self.w_start + (self.w_end - self.w_start) * frac
            r1 = rng.random((P, d))
            r2 = rng.random((P, d))
            v = w * v + self.phi1 * r1 * (pbest - x) + self.phi2 * r2 * (pbest[g] - x)
            np.clip(v, -vmax, vmax, out=v)
            x_new = x + v
            out = (x_new < lower) | (x_new > upper)
            x = reflect(x_new, lower, upper)
            v = np.where(out, -v, v)
            f = tr.evaluate(x)
            update_personal_bests(pbest, pbest_f, x, f)
            g = int(np.argmin(pbest_f))
            if tr.end_iteration(f):
                return
