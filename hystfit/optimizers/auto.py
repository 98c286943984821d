"""``auto``: the fastest route to the best fit for the model at hand."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import Callback, IteratedSearch, Objective, OptimizeResult, StopRules, Tracker, check_box, stop_field
from .lsq import polisher
from .pso import PSO


@optimizers.register
@dataclass
class Auto(IteratedSearch):
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

    Settings: ``pop`` (24) particles and ``iters`` (60) iterations per search, ``stall_iter`` (12)
    and ``stall_tol`` (1e-7) for the stall stop of each search, ``restarts`` (1) searches (2 when
    m > 2), ``max_evals`` (None) and ``time_limit_s`` (None) for the whole run.

    Stop rules: each search stops after ``iters`` iterations or when the best value has not
    improved by more than ``stall_tol`` (relative) for ``stall_iter`` iterations; ``max_evals``
    and ``time_limit_s`` bound all searches together (what the first search used is taken off
    the budget of the next; a search is skipped when nothing is left). The polish has its own
    bounded budget (:func:`hystfit.optimizers.lsq.polisher`).

    Bounds: as PSO (reflection at the bounds) for the nonlinear parameters; the linear solve
    honours the box exactly (bounded least squares); the polish is bounded (trust region
    reflective).
    """

    name = "auto"
    title = "Automatic (variable projection + PSO + least squares)"
    reference = "Golub & Pereyra (1973) variable projection; paper 001 PSO; scipy least_squares"
    uses_start_point = True
    polishes_itself = True
    uses_separable_structure = True
    applied_stop_rules = ("max_evals", "stall_iter", "stall_tol", "time_limit_s")

    pop: int = 24
    iters: int = 60
    restarts: int = 1
    stop: StopRules = stop_field(stall_iter=12, stall_tol=1e-7)

    def check_settings(self) -> None:
        super().check_settings()
        if self.stop.stall_iter is None:
            raise ConfigError("auto: stall_iter must be a whole number ≥ 1 (each search stops on a stall); "
                              "set e.g. --opt-option stall_iter=12")
        if self.restarts < 1:
            raise ConfigError(f"auto: restarts must be ≥ 1, got {self.restarts}; set e.g. --opt-option restarts=2")

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
            pso = PSO(pop=max(self.pop, 30), iters=max(self.iters, 150),
                      stop=replace(self.stop, stall_iter=max(self.stop.stall_iter, 30)))
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
            stall = max(self.stop.stall_iter, 3 * m) if m > 2 else self.stop.stall_iter
            restarts = max(self.restarts, 2 if m > 2 else 1)
            t_start = time.perf_counter()
            for r in range(restarts):
                max_evals, time_limit_s = self.stop.max_evals, self.stop.time_limit_s
                evals_left = None if max_evals is None else max_evals - nfev
                time_left = None if time_limit_s is None else time_limit_s - (time.perf_counter() - t_start)
                if best_nl is not None and ((evals_left is not None and evals_left < pop)
                                            or (time_left is not None and time_left <= 0)):
                    break  # the budget is spent: keep the best search so far
                pso = PSO(pop=pop, iters=iters, stop=StopRules(
                    max_evals=None if evals_left is None else max(evals_left, pop), stall_iter=stall,
                    stall_tol=self.stop.stall_tol, time_limit_s=None if time_left is None else max(time_left, 1e-9)))
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
