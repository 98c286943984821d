"""Bounded nonlinear least squares (scipy ``least_squares``, trust-region reflective)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box, setting, stop_field
from ..objective import as_objective
from .projection import solve_box_qp

#: residual count × parameter count above which the polish takes the memory-bounded
#: normal-equation route (when the objective offers ``normal_equations``): 4·10⁶ elements is a
#: 32 MB Jacobian, of which scipy's ``least_squares`` keeps ≈ 8 copies (≈ 260 MB); below it scipy
#: is used unchanged. A 10⁶-sample capture with 5 parameters (bw) is 5·10⁶.
NORMAL_EQUATIONS_ABOVE = 4_000_000

#: parameter count from which the polish takes the normal-equation route whatever the size (when
#: the objective offers ``normal_equations``): scipy's exact trust-region solver takes an SVD of the
#: (M, d) Jacobian at every iteration, the normal-equation route one (d, d) product J'J. Measured on
#: this machine (one BLAS thread), 40,788 residuals × 85 parameters (``pi+creep+delay`` on
#: sample_data): an SVD 0.18 s, J'J 0.02 s; the whole polish 3.0 s against 1.5 s, same RMSE to 12
#: digits. Below it the simulations dominate and scipy's route is kept.
NORMAL_EQUATIONS_FROM_PARAMS = 32


@optimizers.register
@dataclass
class LSQ(Optimizer):
    """Local bounded least squares from a start point (scipy ``least_squares``, method ``trf``;
    on large problems a memory-bounded Levenberg–Marquardt on the normal equations).

    Needs residuals: the objective must expose ``objective.residuals(theta (d,)) → (M,)``
    (hystfit's identification objectives do); otherwise ``sqrt(objective)`` is used as a single
    residual. Start point: ``x0`` if given, else the box centre. Also the *polish* after every
    global optimizer (:func:`polisher`: ``max_evals`` = 300, tolerances 1e-9). ``x_scale='jac'``
    makes the steps invariant to parameter units. When the objective offers
    ``jacobian(theta, upper=..., lower=...)`` (hystfit's do), the forward-difference Jacobian is one
    population call of d + 1 candidates instead of d single simulations; each counts as d + 1
    evaluations.

    Two routes (the result's ``message`` says which one was taken):

    * *scipy* (small problems): ``least_squares`` needs the residual vector (M,) and the Jacobian
      (M, d) in memory and keeps ≈ 8 copies of the Jacobian.
    * *normal equations* (large problems: M·d > :data:`NORMAL_EQUATIONS_ABOVE` = 4·10⁶
      elements, a 32 MB Jacobian, and the objective offers ``normal_equations(theta, upper=..., lower=...)
      → (JᵀJ, Jᵀr, rᵀr, M)`` and ``n_total`` = M, as hystfit's identification objectives do): a
      bounded Levenberg–Marquardt that never forms J nor r, only the d×d sums (computed capture by
      capture in time chunks), so a 10⁶-sample capture polishes in O(d·N) memory for one
      capture's population simulation. Each iteration: at θ, one Jacobian (d + 1 evaluations),
      then trial steps δ = argmin ½δᵀ(JᵀJ + λD)δ + (Jᵀr)ᵀδ subject to lower ≤ θ + δ ≤ upper,
      solved exactly as a box-constrained QP (:func:`hystfit.optimizers.projection.solve_box_qp`, in
      variables scaled by √D). D is Marquardt's diag(JᵀJ), kept as its running maximum over the
      iterations (as MINPACK does) and floored at 10⁻¹² of its largest entry; λ starts at
      ``damping0`` (10⁻³).
      A trial is scored by the true cost (the MSE of ``objective(theta[None, :])``, one
      evaluation) and accepted when the gain ratio ρ = actual / predicted reduction > 10⁻⁴
      (then λ ← λ·max(1/3, 1 − (2ρ − 1)³)); otherwise λ grows by a factor 2, 4, 8, …
      (Nielsen 1999). Non-finite entries of JᵀJ or Jᵀr freeze those parameters for the iteration.

    Parameters
    ----------
    max_evals : int, default 2000
        Residual evaluations (scipy's ``max_nfev``): on the normal-equation route, the cost
        evaluations at the start and at the trial points (Jacobians not counted, as in scipy).
    ftol, xtol, gtol : float, default 1e-10
        Relative tolerances on the cost, the step and the gradient (scipy's on the scipy route;
        the same meaning on the normal-equation route, see Stop rules).
    damping0 : float, default 1e-3
        The normal-equation route's first damping λ, relative to the Jacobi-scaled JᵀJ (unit
        diagonal): Madsen, Nielsen & Tingleff (*Methods for non-linear least squares problems*,
        2004, §3.2) advise 10⁻⁶ when the start is believed close to the optimum and 10⁻³ (or up to
        1) otherwise. Too large a λ from a close start damps every poorly determined direction and
        the iterations crawl (λ falls by at most 3× per accepted step); too small a λ from a far
        start costs a few rejected trials (each one cost evaluation, λ then grows 2×, 4×, 8×, …).
        The scipy route has its own trust region and ignores it.

    Notes
    -----
    Stop rules: scipy's tolerances ``ftol``/``xtol``/``gtol`` (status 5, converged) or
    ``max_evals`` residual evaluations (status 0). No stall, target or time-limit rule: a local
    solve is short. On the normal-equation route the same settings with scipy's meanings: ``ftol``
    when an accepted step lowers the cost by less than ``ftol`` × cost with ρ > 0.25, or (MINPACK's
    test) when a step's actual and predicted reductions are both at most ``ftol`` × cost and
    ρ ≤ 2 (near the optimum, where rounding makes ρ erratic, the model has nothing left to gain);
    ``xtol`` when a step (accepted or not) is shorter than ``xtol`` · (``xtol`` + ‖θ‖); ``gtol`` when the
    projected gradient, scaled as MINPACK's (the largest |Jⱼᵀr| / (‖Jⱼ‖·‖r‖) over the parameters
    not held at a bound by their gradient), is below ``gtol`` (all status 5); ``max_evals`` cost
    evaluations (status 0); a callback asking to stop (status 4, the callback is called after
    every trial step).

    Bounds: scipy's trust-region reflective method keeps every iterate strictly inside the box
    (reflection of the step at the faces); the start is clipped into the box, 10⁻¹⁰ of its width
    inside the faces. The normal-equation route solves every step within the box exactly (its
    iterates may lie on a face, where a parameter stays while its gradient points outwards;
    finite-difference steps at an upper face are taken backwards), from the same start.
    """

    name = "lsq"
    title = "Least squares (trust-region reflective)"
    reference = "scipy.optimize.least_squares (Branch, Coleman & Li 1999)"
    libraries = ("scipy.optimize",)
    uses_start_point = True
    polishes_itself = True
    applied_stop_rules = ("max_evals",)
    required_stop_rules = {"max_evals": "a local solve needs a budget"}

    ftol: float = 1e-10
    xtol: float = 1e-10
    gtol: float = 1e-10
    damping0: float = setting(1e-3, above=0, what="first damping of the normal-equation route")
    stop: StopRules = stop_field(max_evals=2000)

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        objective = as_objective(objective)
        tr = Tracker(objective, StopRules(), callback)
        start = 0.5 * (lower + upper) if x0 is None else np.clip(np.asarray(x0, float), lower, upper)
        # keep the start strictly inside: trf needs an interior point
        eps = 1e-10 * (upper - lower)
        start = np.clip(start, lower + eps, upper - eps)
        m_total = objective.n_total
        if (objective.normal_equations is not None and m_total is not None
                and (int(m_total) * start.size > NORMAL_EQUATIONS_ABOVE
                     or start.size >= NORMAL_EQUATIONS_FROM_PARAMS)):
            return self._normal_equation_lm(objective, objective.normal_equations, int(m_total), lower, upper, start,
                                            tr)
        residuals = objective.residuals
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
        population_jacobian = objective.jacobian
        if population_jacobian is not None and objective.residuals is not None:
            def jac(th):  # noqa: E306
                J = np.asarray(population_jacobian(th, upper=upper, lower=lower), float)
                tr.nfev += th.size + 1
                finite = np.isfinite(J)
                # a model linear in every parameter gives its cached basis (read-only: scipy's trf
                # does not write to it); a non-finite entry makes a fresh array
                return J if finite.all() else np.where(finite, J, 0.0)

        f0 = tr.evaluate(start[None, :])
        tr.end_iteration(f0)
        from scipy.optimize import least_squares  # deferred: keeps start-up fast

        sol = least_squares(fun, start, jac=jac, bounds=(lower, upper), method="trf", x_scale="jac",
                            ftol=self.ftol, xtol=self.xtol, gtol=self.gtol, max_nfev=self.stop.max_evals)
        f = tr.evaluate(sol.x[None, :])
        tr.end_iteration(f)
        tr.status = 5 if sol.status > 0 else 0
        tr.message = f"scipy least_squares (trf): {sol.message}"
        return tr.result(self.name)

    def _normal_equation_lm(self, objective: Objective, normal_equations, m_total: int, lower: np.ndarray,
                            upper: np.ndarray, start: np.ndarray, tr: Tracker) -> OptimizeResult:
        """The memory-bounded route: bounded Levenberg–Marquardt on (JᵀJ, Jᵀr, rᵀr) (see the class
        docstring). Costs are MSE (rᵀr / M); the quadratic model of the cost at θ is
        (rᵀr + 2(Jᵀr)ᵀδ + δᵀJᵀJδ) / M."""

        d = start.size
        route = f"normal-equation Levenberg-Marquardt ({m_total} residuals x {d} parameters)"
        theta = start.copy()
        f0 = tr.evaluate(theta[None, :])
        n_cost = 1  # cost evaluations, the budget's unit (scipy's nfev)
        if tr.end_iteration(f0):
            tr.message = f"{route}: {tr.message}"
            return tr.result(self.name)
        f = float(f0[0])
        if not np.isfinite(f):
            tr.status, tr.message = 0, f"{route}: non-finite cost at the start, no step taken"
            return tr.result(self.name)

        def system(th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            JtJ, Jtr, _, _ = normal_equations(th, upper=upper, lower=lower)
            tr.nfev += d + 1
            JtJ, Jtr = np.array(JtJ, dtype=np.float64), np.array(Jtr, dtype=np.float64)
            bad = ~(np.all(np.isfinite(JtJ), axis=1) & np.isfinite(Jtr) & np.isfinite(np.diag(JtJ)))
            if np.any(bad):  # a diverging perturbation: freeze that parameter for this iteration
                JtJ[bad, :] = 0.0
                JtJ[:, bad] = 0.0
                Jtr[bad] = 0.0
            return JtJ, Jtr

        A, g = system(theta)
        D = np.zeros(d)
        lam, nu = self.damping0, 2.0
        status, why = 0, f"evaluation budget max_evals = {self.stop.max_evals} reached"
        done = False
        while not done:
            D = np.maximum(D, np.diag(A))
            D = np.maximum(D, 1e-12 * max(float(np.max(D)), 1e-300))
            s = 1.0 / np.sqrt(D)  # δ = s·z: the scaled problem has JᵀJ of (about) unit diagonal
            As = A * s[:, None] * s[None, :]
            gs = g * s
            # gtol: MINPACK's scaled gradient |Jⱼᵀr| / (‖Jⱼ‖·‖r‖), projected on the box
            width = upper - lower
            at_lo = theta <= lower + 1e-12 * width
            at_hi = theta >= upper - 1e-12 * width
            free = ~((at_lo & (g > 0)) | (at_hi & (g < 0)))
            rnorm = np.sqrt(f * m_total)
            colnorm = np.sqrt(np.maximum(np.diag(A), 0.0))
            with np.errstate(all="ignore"):
                cosine = np.where(free & (colnorm > 0), np.abs(g) / (colnorm * rnorm), 0.0)
            if rnorm == 0.0 or float(np.max(cosine, initial=0.0)) < self.gtol:
                status, why = 5, "projected scaled gradient below gtol"
                break
            lo_z, hi_z = (lower - theta) / s, (upper - theta) / s
            while True:  # trial steps at growing λ until one is accepted or a stop rule fires
                if n_cost >= self.stop.max_evals:
                    done = True
                    break
                G = As + lam * np.eye(d)
                z = solve_box_qp(G[None], -gs[None], lo_z, hi_z)[0]
                if not np.all(np.isfinite(z)):
                    z = np.zeros(d)
                step = s * z
                trial = np.clip(theta + step, lower, upper)
                step = trial - theta
                pred = -(2.0 * float(g @ step) + float(step @ A @ step)) / m_total
                f_new = float(tr.evaluate(trial[None, :])[0])
                n_cost += 1
                if tr.end_iteration(np.array([f_new])):  # the callback asked to stop
                    status, why = tr.status, tr.message
                    done = True
                actual = f - f_new if np.isfinite(f_new) else -np.inf
                rho = actual / pred if pred > 0 else -np.inf
                accepted = rho > 1e-4
                if not done:
                    if np.linalg.norm(step) < self.xtol * (self.xtol + np.linalg.norm(theta)):
                        status, why, done = 5, "relative step below xtol", True
                    elif accepted and actual < self.ftol * f and rho > 0.25:
                        status, why, done = 5, "relative cost reduction below ftol", True
                    elif abs(actual) <= self.ftol * f and pred <= self.ftol * f and rho <= 2.0:
                        # MINPACK's test: the quadratic model itself has nothing left to gain
                        status, why, done = 5, "actual and predicted relative reductions below ftol", True
                if accepted:
                    theta, f = trial, f_new
                    lam = max(lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e-12)
                    nu = 2.0
                else:
                    lam, nu = lam * nu, 2.0 * nu
                if done:
                    break
                if accepted:
                    if n_cost >= self.stop.max_evals:
                        done = True
                    else:
                        A, g = system(theta)
                    break
        tr.status, tr.message = status, f"{route}: {why}"
        return tr.result(self.name)


#: the first damping of a polish from a start that is already a fit of the same model (Madsen, Nielsen
#: & Tingleff 2004, §3.2: 10⁻⁶ "if x0 is believed to be a good approximation"); see :class:`LSQ`
CLOSE_START_DAMPING = 1e-6


def polisher(close_start: bool = False) -> LSQ:
    """The least-squares polish used after global searches: a bounded budget (300 residual
    evaluations) and tolerances of 1e-9, enough to land on the noise floor from a good start
    without hundreds of iterations along a flat, poorly identifiable direction.

    ``close_start``: the start is already a fit of the same model (diagnose's hand-over, fitted on
    part of the data): the first damping is :data:`CLOSE_START_DAMPING` instead of 10⁻³. On
    sample_data's hand-over (pi + creep + delay, 80 operators, 86 parameters) the polish then takes
    349 evaluations (4 Jacobians) instead of 871 (10), 0.30 against 0.69 s, and no parameter ends
    more than 0.007 of its standard error from where the default damping ends; the same RMSE to six
    digits on every data set of ``benchmarks/diagnose_handover.py``, which measures this."""
    return LSQ(ftol=1e-9, xtol=1e-9, gtol=1e-9, damping0=CLOSE_START_DAMPING if close_start else 1e-3,
               stop=StopRules(max_evals=300))
