"""Bounded nonlinear least squares (scipy ``least_squares``, trust-region reflective)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box


@optimizers.register
@dataclass
class LSQ(Optimizer):
    """Local bounded least squares from a start point (scipy ``least_squares``, method ``trf``).

    Needs residuals: the objective must expose ``objective.residuals(theta (d,)) → (M,)``
    (hystfit's identification objectives do); otherwise ``sqrt(objective)`` is used as a single
    residual. Start point: ``x0`` if given, else the box centre. Also the *polish* after every
    global optimizer (:func:`polisher`: ``max_evals`` = 300, tolerances 1e-9). ``x_scale='jac'``
    makes the steps invariant to parameter units. When the objective offers
    ``jacobian(theta, upper=...)`` (hystfit's do), the forward-difference Jacobian is one
    population call of d + 1 candidates instead of d single simulations; each counts as d + 1
    evaluations.

    Parameters
    ----------
    max_evals : int, default 2000
        Residual evaluations (scipy's ``max_nfev``).
    ftol, xtol, gtol : float, default 1e-10
        scipy's relative tolerances on the cost, the step and the gradient.

    Notes
    -----
    Stop rules: scipy's tolerances ``ftol``/``xtol``/``gtol`` (status 5, converged) or
    ``max_evals`` residual evaluations (status 0). No stall, target or time-limit rule: a local
    solve is short.

    Bounds: scipy's trust-region reflective method keeps every iterate strictly inside the box
    (reflection of the step at the faces); the start is clipped into the box, 10⁻¹⁰ of its width
    inside the faces.
    """

    name = "lsq"
    title = "Least squares (trust-region reflective)"
    reference = "scipy.optimize.least_squares (Branch, Coleman & Li 1999)"
    population_based = False

    max_evals: int = 2000
    ftol: float = 1e-10
    xtol: float = 1e-10
    gtol: float = 1e-10

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        tr = Tracker(objective, StopRules(), callback)
        start = 0.5 * (lower + upper) if x0 is None else np.clip(np.asarray(x0, float), lower, upper)
        # keep the start strictly inside: trf needs an interior point
        eps = 1e-10 * (upper - lower)
        start = np.clip(start, lower + eps, upper - eps)
        residuals = getattr(objective, "residuals", None)
        if residuals is None:
            def residuals(th):  # noqa: E306
                return np.sqrt(np.maximum(objective(th[None, :]), 0.0))

        def fun(th: np.ndarray) -> np.ndarray:
            r = np.asarray(residuals(th), float)
            tr.nfev += 1
            if not np.all(np.isfinite(r)):
                r = np.where(np.isfinite(r), r, 1e150)
            return r

        jac = "2-point"
        population_jacobian = getattr(objective, "jacobian", None)
        if population_jacobian is not None and getattr(objective, "residuals", None) is not None:
            def jac(th):  # noqa: E306
                J = np.asarray(population_jacobian(th, upper=upper), float)
                tr.nfev += th.size + 1
                return np.where(np.isfinite(J), J, 0.0)

        f0 = tr.evaluate(start[None, :])
        tr.end_iteration(f0)
        from scipy.optimize import least_squares  # deferred: keeps start-up fast

        sol = least_squares(fun, start, jac=jac, bounds=(lower, upper), method="trf", x_scale="jac",
                            ftol=self.ftol, xtol=self.xtol, gtol=self.gtol, max_nfev=self.max_evals)
        f = tr.evaluate(sol.x[None, :])
        tr.end_iteration(f)
        tr.status = 5 if sol.status > 0 else 0
        tr.message = sol.message
        return tr.result(self.name)


def polisher() -> LSQ:
    """The least-squares polish used after global searches: a bounded budget (300 residual
    evaluations) and tolerances of 1e-9, enough to land on the noise floor from a good start
    without hundreds of iterations along a flat, poorly identifiable direction."""
    return LSQ(max_evals=300, ftol=1e-9, xtol=1e-9, gtol=1e-9)
