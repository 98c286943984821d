"""``auto``: the fastest route to the best fit for the model at hand."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box
from .lsq import polisher
from .pso import PSO


@optimizers.register
@dataclass
class Auto(Optimizer):
    """Exact solves for linear parameters, a global search only over the nonlinear ones, then a polish.

    1. If the objective is a hystfit identification objective whose model declares a separable
       structure (:mod:`hystfit.separable`), the parameters that enter linearly are solved
       exactly (bounded linear least squares) inside every evaluation (variable projection).
       A model with no nonlinear parameter (PI with fixed thresholds, Hammerstein with a fixed
       linear part) is solved in one step: the exact optimum.
    2. The remaining nonlinear parameters (often 1–2) are searched by PSO (``pop`` × ``iters``,
       stall stop after ``stall_iter`` iterations without relative improvement ``stall_tol``;
       with m > 2 nonlinear parameters at least 5m particles, 15m iterations, a 3m stall window and
       two independent searches). The first search's swarm includes ``x0`` (the model's defaults).
       ``restarts`` independent searches (own seeds from ``rng``) guard against a local basin.
    3. A bounded least-squares polish of the full θ from the best point (skipped for linear models).

    Without separable structure it falls back to PSO over all parameters plus the polish.
    Bounds: as PSO (reflection) and the linear solve (exact box constraints).
    """

    name = "auto"
    title = "Automatic (variable projection + PSO + least squares)"
    reference = "Golub & Pereyra (1973) variable projection; paper 001 PSO; scipy least_squares"
    population_based = True

    pop: int = 24
    iters: int = 60
    stall_iter: int = 12
    stall_tol: float = 1e-7
    restarts: int = 1
    max_evals: int | None = None
    time_limit_s: float | None = None

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        model = getattr(objective, "model", None)
        series = getattr(objective, "series", None)
        sep = None
        if model is not None and series is not None and hasattr(model, "separable"):
            sep = model.separable()
        tr = Tracker(objective, StopRules(), callback)
        if sep is None:
            pso = PSO(pop=max(self.pop, 30), iters=max(self.iters, 150), stall_iter=max(self.stall_iter, 30),
                      stall_tol=self.stall_tol, max_evals=self.max_evals, time_limit_s=self.time_limit_s)
            g = pso.minimize(objective, lower, upper, rng=rng, x0=x0, callback=callback)
            start, hist_b, hist_m, nfev = g.x, list(g.history_best), list(g.history_mean), g.nfev
        else:
            from ..separable import ProjectedObjective

            proj = ProjectedObjective(sep, series, lower, upper)
            nl = np.asarray(sep.nonlinear, dtype=int)
            hist_b, hist_m, nfev = [], [], 0
            if nl.size == 0:
                full = proj.full(np.empty((1, 0)))[0]
                f = tr.evaluate(full[None, :])
                tr.end_iteration(f)
                tr.message = "exact linear least-squares solution (no nonlinear parameter)"
                tr.status = 5
                return tr.result(self.name)
            best_nl, best_f = None, np.inf
            m = int(nl.size)
            # the search grows with the number of nonlinear parameters (1–2 for most models, 10 for gpi)
            pop = max(self.pop, 5 * m) if m > 2 else self.pop
            iters = max(self.iters, 15 * m) if m > 2 else self.iters
            stall = max(self.stall_iter, 3 * m) if m > 2 else self.stall_iter
            restarts = max(self.restarts, 2 if m > 2 else 1)
            for r in range(restarts):
                pso = PSO(pop=pop, iters=iters, stall_iter=stall, stall_tol=self.stall_tol,
                          max_evals=self.max_evals, time_limit_s=self.time_limit_s)
                g = pso.minimize(proj, lower[nl], upper[nl], rng=rng,
                                 x0=None if (x0 is None or r > 0) else np.asarray(x0)[nl], callback=callback)
                hist_b += list(g.history_best)
                hist_m += list(g.history_mean)
                nfev += g.nfev
                if g.fun < best_f:
                    best_nl, best_f = g.x, g.fun
            start = proj.full(best_nl[None, :])[0]
        f = tr.evaluate(np.clip(start, lower, upper)[None, :])
        pol = polisher().minimize(objective, lower, upper, rng=rng, x0=np.clip(start, lower, upper))
        tr.evaluate(pol.x[None, :])
        tr.nfev += nfev + pol.nfev
        tr.hist_best = [min(hist_b[: i + 1]) for i in range(len(hist_b))] + [tr.best_f]
        tr.hist_mean = hist_m + [float(f[0])]
        tr.nit = len(tr.hist_best)
        tr.status, tr.message = 5, "global search over nonlinear parameters + least-squares polish"
        return tr.result(self.name)
