"""Particle swarm optimization with linearly decreasing inertia (paper 001 eq. 4–5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box, reflect


@optimizers.register
@dataclass
class PSO(Optimizer):
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

    pop: int = 40
    iters: int = 200
    w_start: float = 0.9
    w_end: float = 0.4
    phi1: float = 2.0
    phi2: float = 2.0
    vmax_frac: float = 0.2
    max_evals: int | None = None
    stall_iter: int | None = None
    stall_tol: float = 1e-9
    target: float | None = None
    time_limit_s: float | None = None

    def __post_init__(self) -> None:
        if self.pop < 2 or self.iters < 1:
            raise ConfigError(f"pso: pop must be ≥ 2 and iters ≥ 1 (got pop={self.pop}, iters={self.iters})")

    def _rules(self) -> StopRules:
        return StopRules(self.iters, self.max_evals, self.stall_iter, self.stall_tol, self.target, self.time_limit_s)

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        d, P = lower.size, self.pop
        width = upper - lower
        vmax = self.vmax_frac * width
        tr = Tracker(objective, self._rules(), callback)
        x = lower + rng.random((P, d)) * width
        if x0 is not None:
            x[0] = np.clip(np.asarray(x0, float), lower, upper)
        v = (rng.random((P, d)) * 2 - 1) * vmax
        f = tr.evaluate(x)
        pbest, pbest_f = x.copy(), f.copy()
        g = int(np.argmin(pbest_f))
        if tr.end_iteration(f):
            return tr.result(self.name)
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
            better = f < pbest_f
            pbest[better] = x[better]
            pbest_f[better] = f[better]
            g = int(np.argmin(pbest_f))
            if tr.end_iteration(f):
                return tr.result(self.name)
