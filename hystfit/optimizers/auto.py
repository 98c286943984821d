"""``auto``: the fastest route to the best fit for the model at hand."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..effects import CaptureView, Effect, EffectFit, Inserted, Linearization
from ..models.composite import Composite
from ..objective import Objective as Obj, Series, as_objective
from ..registry import optimizers
from .base import Callback, IteratedSearch, Objective, OptimizeResult, StopRules, Tracker, check_box, setting, stop_field
from .lsq import polisher
from .projection import ProjectedObjective
from .pso import PSO


#: cost evaluations of the polish on all samples after a search and a polish on a subsample
#: (:func:`_search_series`): a few steps from a start that is already a local optimum
POLISH_EVALS_AFTER_SUBSAMPLE = 30

#: the global search over more than this many nonlinear parameters is sized by their number (below);
#: up to it (bw, fp, nt: 1–2, ch, dahl: 3, lugre: 4) the settings' 16 × 30 (stall 6) search, whose
#: polished fits matched those of 24 × 60 (12) on 77 conditions × 2 seeds (``benchmarks/restarts.py``)
SEARCH_SCALED_ABOVE = 4
#: the global search over m > SEARCH_SCALED_ABOVE nonlinear parameters has at least this many particles per
#: parameter, iterations per parameter and stall-window iterations per parameter (the settings
#: ``pop``, ``iters`` and ``stall_iter`` when larger). gpi and pi2 (m = 10): 50 particles, 150
#: iterations, a 30-iteration stall window. A search of 3m × 7.5m (1.5m) polished to lower RMSE on
#: average (``benchmarks/restarts.py``: the RMSE of this search over it 1.07 for gpi and pi2, at
#: 1.3–1.4× the CPU) but gave the pi2 of ``benchmarks/feedforward_acceptance.py`` an inverse that
#: missed the 1 % target at 1–5 Hz (1.13–1.51 % of stroke against 0.44–0.84 %): kept at 5m × 15m
SEARCH_POP_PER_PARAMETER = 5
SEARCH_ITERS_PER_PARAMETER = 15
SEARCH_STALL_PER_PARAMETER = 3


@optimizers.register
@dataclass
class Auto(IteratedSearch):
    """Exact solves for linear parameters, a global search only over the nonlinear ones, then a polish.

    1. If the objective is a hystfit identification objective whose model declares a separable
       structure (:mod:`hystfit.models.separable`), the parameters that enter linearly are solved
       exactly (bounded linear least squares) inside every evaluation (variable projection).
       A model with no nonlinear parameter (PI with fixed thresholds, Hammerstein with a fixed
       linear part) is solved in one step: the exact optimum.
    2. The remaining nonlinear parameters (often 1–2) are searched by PSO (``pop`` × ``iters``,
       stall stop after ``stall_iter`` iterations without relative improvement ``stall_tol``;
       with m > 4 nonlinear parameters at least 5m particles, 15m iterations and a 3m stall
       window: :data:`SEARCH_SCALED_ABOVE`, :data:`SEARCH_POP_PER_PARAMETER` …).
       The first search's swarm includes ``x0`` (the model's defaults). ``restarts`` independent
       searches (own seeds from ``rng``) guard against a local basin.
    3. A bounded least-squares polish of the full θ from the search's best point (skipped for
       linear models). With ``restarts`` > 1 the best point of *every* search is polished and the
       best polished fit is kept: on models with many nonlinear parameters the polish decides
       (gpi, pi2: it lowers the search's cost 1.6–40×), and the search value does not predict
       where a polish ends — keeping the best search and polishing only it bought no measurable
       RMSE over one search, polishing each does. ``benchmarks/restarts.py`` (77 conditions × 2
       seeds of shipped, synthetic and real data): the RMSE over the best any run reached,
       geometric mean, with 1 / 2 / 3 restarts is 1.29 / 1.17 / 1.08 for gpi and 1.27 / 1.16 /
       1.09 for pi2 at 1 / 1.8–1.9 / 2.7–2.8× the CPU, 1.005 / 1.001 / 1.001 for lugre and 1.000
       for dahl and ch: one search is the default, ``restarts=3`` gives the best gpi/pi2 fits.

    A model may name the samples the search needs (``search_samples(u)``: gpi on a capture of more
    than 20,000 samples, a time-uniform subsample plus the turning points, on which its outputs are
    exact): steps 1–2 then run on those samples, followed by a polish on them and a short polish
    (:data:`POLISH_EVALS_AFTER_SUBSAMPLE` cost evaluations) on every sample.

    Without separable structure it falls back to one PSO over all parameters plus the polish
    (``restarts`` does not apply).

    Settings: ``pop`` (16) particles and ``iters`` (30) iterations per search, ``stall_iter`` (6)
    and ``stall_tol`` (1e-7) for the stall stop of each search, ``restarts`` (1) searches, each
    polished, ``max_evals`` (None) and ``time_limit_s`` (None) for all searches together.

    Stop rules: each search stops after ``iters`` iterations or when the best value has not
    improved by more than ``stall_tol`` (relative) for ``stall_iter`` iterations; ``max_evals``
    and ``time_limit_s`` bound all searches together (what the first search used is taken off
    the budget of the next; a search is skipped when nothing is left). Each polish has its own
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
    libraries = ("scipy.optimize",)
    applied_stop_rules = ("max_evals", "stall_iter", "stall_tol", "time_limit_s")
    required_stop_rules = {"stall_iter": "each search stops on a stall"}

    pop: int = 16
    iters: int = 30
    restarts: int = setting(1, whole=True, at_least=1, example=2)
    stop: StopRules = stop_field(stall_iter=6, stall_tol=1e-7)

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        objective = as_objective(objective)
        model, series = objective.model, objective.series
        sep = model.separable() if model is not None and series else None
        tr = Tracker(objective, StopRules(), callback)
        final = polisher()  # the polish on every sample
        done = None  # the fit when the searches' polishes were on every sample already
        composition = model.composition if (model is not None and series) else None
        if composition is not None and all(b.nuisance for b in composition[1]):
            composition = None  # base + nuisance only: variable projection on the projected basis
        if composition is not None:
            start, nfev = self._composite_start(objective, composition, lower, upper, rng, x0)
            hist_b, hist_m = [], []
        elif sep is None:
            pso = PSO(pop=max(self.pop, 30), iters=max(self.iters, 150),
                      stop=replace(self.stop, stall_iter=max(self.stop.stall_iter, 30)))
            g = pso.minimize(objective, lower, upper, rng=rng, x0=x0, callback=callback)
            start, hist_b, hist_m, nfev = g.x, list(g.history_best), list(g.history_mean), g.nfev
        else:
            proj = ProjectedObjective(sep, _search_series(model, series), lower, upper)
            nl = np.asarray(sep.nonlinear, dtype=int)
            hist_b, hist_m, nfev = [], [], 0
            if nl.size == 0:
                full = proj.full(np.empty((1, 0)))[0]
                f = tr.evaluate(full[None, :])
                tr.end_iteration(f)
                tr.message = "exact linear least-squares solution (no nonlinear parameter)"
                tr.status = 5
                return tr.result(self.name)
            found: list[np.ndarray] = []  # the best point of each search
            m = int(nl.size)
            # the search grows with the number of nonlinear parameters (1–2 for most models, 10 for gpi)
            many = m > SEARCH_SCALED_ABOVE
            pop = max(self.pop, SEARCH_POP_PER_PARAMETER * m) if many else self.pop
            iters = max(self.iters, round(SEARCH_ITERS_PER_PARAMETER * m)) if many else self.iters
            stall = max(self.stop.stall_iter, round(SEARCH_STALL_PER_PARAMETER * m)) if many else self.stop.stall_iter
            t_start = time.perf_counter()
            for r in range(self.restarts):
                max_evals, time_limit_s = self.stop.max_evals, self.stop.time_limit_s
                evals_left = None if max_evals is None else max_evals - nfev
                time_left = None if time_limit_s is None else time_limit_s - (time.perf_counter() - t_start)
                if found and ((evals_left is not None and evals_left < pop)
                              or (time_left is not None and time_left <= 0)):
                    break  # the budget is spent: polish the searches so far
                pso = PSO(pop=pop, iters=iters, stop=StopRules(
                    max_evals=None if evals_left is None else max(evals_left, pop), stall_iter=stall,
                    stall_tol=self.stop.stall_tol, time_limit_s=None if time_left is None else max(time_left, 1e-9)))
                g = pso.minimize(proj, lower[nl], upper[nl], rng=rng,
                                 x0=None if (x0 is None or r > 0) else np.asarray(x0)[nl], callback=callback)
                hist_b += list(g.history_best)
                hist_m += list(g.history_mean)
                nfev += g.nfev
                found.append(g.x)
            starts = [np.clip(proj.full(x[None, :])[0], lower, upper) for x in found]
            subsampled = any(a is not b for a, b in zip(proj.series, series))
            start = starts[0]
            if subsampled or len(starts) > 1:
                # each search's best polished (on the searched samples); the best polished fit is kept
                on = Obj(model, proj.series) if subsampled else objective
                polished = [polisher().minimize(on, lower, upper, rng=rng, x0=x) for x in starts]
                nfev += sum(p.nfev for p in polished)
                best = min(polished, key=lambda p: p.fun)  # the first of equals
                start = best.x
                if subsampled:  # then a short polish on every sample
                    final = replace(polisher(), stop=StopRules(max_evals=POLISH_EVALS_AFTER_SUBSAMPLE))
                else:  # polished on every sample already: that is the fit
                    done = best
        # the start's value (for a fit already polished on every sample, its own value: not scored again)
        f = np.array([done.fun]) if done is not None else tr.evaluate(np.clip(start, lower, upper)[None, :])
        if not hist_b:
            hist_b, hist_m = [float(f[0])], [float(f[0])]
        pol = done if done is not None else final.minimize(objective, lower, upper, rng=rng,
                                                           x0=np.clip(start, lower, upper))
        tr.evaluate(pol.x[None, :])
        tr.nfev += nfev + (pol.nfev if done is None else 0)
        tr.hist_best = [min(hist_b[: i + 1]) for i in range(len(hist_b))] + [tr.best_f]
        tr.hist_mean = hist_m + [float(f[0])]
        tr.nit = len(tr.hist_best)
        tr.status, tr.message = 5, ("staged start (base, then each block with its linear coefficients solved exactly) "
                                    "+ joint least-squares polish" if composition is not None else
                                    "global search over nonlinear parameters + least-squares polish")
        return tr.result(self.name)

    def _composite_start(self, objective: Objective, composition, lower, upper, rng, x0) -> tuple[np.ndarray, int]:
        """A start for a composite model (base + blocks), fitted in stages.

        1. The base alone (with the composite's nuisance blocks, e.g. per-capture drift) by this
           optimizer's own route (variable projection where the base is separable).
        2. Each block in the written order, on the prediction of the base and the blocks before
           it: its searched parameters (delay, f_n, ζ) by a grid and a local search, its linear
           coefficients (creep gains, asymmetry coefficients) solved exactly together with a
           Gauss–Newton step of every parameter before it (:meth:`hystfit.effects.Effect.fit`);
           the step is kept only if it lowers the objective. A block whose operator is the
           identity (asymmetry, creep) written before a block that has one (dynamics, delay, lti)
           is left at the identity (its coefficients 0) while those are fitted, then fitted in its
           place, its regressors pushed through the later blocks (:func:`_fit_in_place`), as
           ``diagnose`` inserts an effect: fitted before the stage, a bow (or creep) would be
           fitted to the stage's ringing on a step or PRBS capture and start the polish at its
           coefficient bounds, where the polish stopped (a 60 V raised cosine and a PRBS through a
           600 Hz stage: RMSE 0.24 µm with both coefficients at a bound, against 0.008 µm).
        3. (in :meth:`minimize`) a bounded least-squares polish of the whole vector: the joint optimum.
        """
        base, blocks = composition
        series = list(objective.series)
        sizes = [b.n_theta for b in blocks]
        d_b = lower.size - sum(sizes)
        nuisance = tuple(b for b in blocks if b.nuisance)
        base_model = Composite(base, nuisance) if nuisance else base
        sub = Auto(pop=self.pop, iters=self.iters, restarts=self.restarts, stop=self.stop)
        rb = sub.minimize(Obj(base_model, series), lower[:d_b], upper[:d_b], rng=rng,
                          x0=None if x0 is None else np.asarray(x0)[:d_b])
        nfev = rb.nfev
        theta = np.clip(np.asarray(x0, dtype=np.float64) if x0 is not None else 0.5 * (lower + upper), lower, upper)
        theta[:d_b] = rb.x
        start = d_b
        deferred = []  # (k, start, end) of the blocks fitted in place after the stages
        for k, (b, size) in enumerate(zip(blocks, sizes)):
            if b.nuisance:
                continue
            end = start + size
            if _static_before_a_stage(blocks, k):
                theta[start:end] = np.clip(0.0, lower[start:end], upper[start:end])  # the identity
                deferred.append((k, start, end))
                start = end
                continue
            active = tuple(x for x in blocks[:k] if not x.nuisance)
            prefix = Composite(base, active) if active else base
            upto = Composite(base, tuple(x for x in blocks[:k + 1] if not x.nuisance or x in nuisance))
            full_obj = Obj(upto, series)
            raw_obj = Obj(prefix, series)
            th_p = theta[:start]
            yhats = raw_obj.predict(th_p)
            views = _views(series, yhats, base_model)
            J = raw_obj.jacobian(th_p, upper=upper[:start], lower=lower[:start])
            nfev += start + 1
            # the step moves every parameter before the block but those of the blocks left at the identity
            free = np.setdiff1d(np.arange(start), np.r_[tuple(np.arange(a, z) for _, a, z in deferred)]
                                if deferred else np.empty(0, int))
            jacs = _per_capture(J[:, free], series)
            cols = tuple(np.arange(free.size) for _ in series)
            lin = Linearization(tuple(jacs), cols, lower[free] - th_p[free], upper[free] - th_p[free])
            candidates, n = _block_candidates(b, yhats, views, lin, theta[:end], free, start, end,
                                              lower[:end], upper[:end])
            nfev += n
            if not candidates:
                start = end
                continue
            scores = full_obj(np.vstack(candidates))
            nfev += len(candidates)
            theta[:end] = candidates[int(np.argmin(scores))]
            start = end
        for k, s0, s1 in deferred:
            theta, n = _fit_in_place(objective, base_model, base, blocks, sizes, k, s0, s1, theta, lower, upper)
            nfev += n
        return theta, nfev


def _view(s: Series, y: np.ndarray, index: int) -> CaptureView:
    """Capture ``index`` as the blocks' fit sees it: the target ``y``, fitted after the warm-up."""
    n = s.y.shape[0]
    return CaptureView(t=np.arange(n) * s.dt, dt=s.dt, y=y, fit=np.arange(n) >= s.skip, index=index)


def _block_candidates(effect, preds, views, lin, theta, moved, a: int, b: int, lower, upper) -> tuple[list, int]:
    """The block's fit (``effect``: its coefficients θ[a:b]) with the Gauss–Newton step ``lin`` of the
    parameters ``moved`` and without it, each as a full vector (``theta`` with the block's
    coefficients and, with the step, θ[moved] + δ; clipped to the box); and the evaluations spent.
    A fit that fails (singular, invalid) gives no candidate."""
    candidates, nfev = [], 0
    for use_lin in (True, False):
        try:
            fit = effect.fit(preds, views, lin if use_lin else None)
        except (np.linalg.LinAlgError, ValueError):
            continue
        nfev += fit.evaluations
        cand = theta.copy()
        if use_lin and fit.delta.size:
            cand[moved] = theta[moved] + fit.delta
        cand[a:b] = np.concatenate([fit.phi, fit.shared])
        candidates.append(np.clip(cand, lower, upper))
    return candidates, nfev


def _views(series, preds, base_model) -> list[CaptureView]:
    """Every capture as a block's fit sees it (:func:`_view`): the target with the current
    per-capture nuisance estimate (the base model's ``nuisance_basis`` fitted to y − ``preds``) taken off."""
    views = []
    for c, (s, p) in enumerate(zip(series, preds)):
        y = s.y
        R = base_model.nuisance_basis(s.y.shape[0], s.dt)
        if R is not None:
            y = y - R @ np.linalg.lstsq(R, y - p, rcond=None)[0]
        views.append(_view(s, y, c))
    return views


def _per_capture(J: np.ndarray, series) -> tuple[np.ndarray, ...]:
    """The rows of an objective's Jacobian (the scored samples, capture after capture) per capture,
    over all of its samples (the warm-up's rows zero: not scored)."""
    out, row = [], 0
    for s in series:
        m = s.y.shape[0] - s.skip
        out.append(np.vstack([np.zeros((s.skip, J.shape[1])), J[row:row + m]]))
        row += m
    return tuple(out)


def _has_operator(block) -> bool:
    return type(block).operator is not Effect.operator


def _static_before_a_stage(blocks, k: int) -> bool:
    """Whether block ``k`` (not a nuisance) acts as the identity operator plus regressors (asymmetry,
    creep) and a block with an operator (a stage: dynamics, delay, lti) follows it."""
    b = blocks[k]
    return (not b.nuisance and not _has_operator(b) and b.searched_bounds()[0].size == 0
            and any(not x.nuisance and _has_operator(x) for x in blocks[k + 1:]))


def _fit_in_place(objective, base_model, base, blocks, sizes, k: int, s0: int, s1: int, theta, lower, upper
                  ) -> tuple[np.ndarray, int]:
    """Block ``k``'s coefficients θ[s0:s1] fitted where it acts, the other blocks as ``theta`` has
    them: the regressors at its input pushed through the tangents of the blocks after it
    (:class:`hystfit.effects.Inserted`; exact for blocks linear in their input). Kept when the
    whole model's objective is lower with them; returns θ and the objective evaluations."""
    series = list(objective.series)
    C = len(series)
    d_b = theta.size - sum(sizes)
    xs = Obj(base, series).predict(theta[:d_b])
    at, later, preds = [], [], []
    for c, (x, s) in enumerate(zip(xs, series)):
        x = np.asarray(x, dtype=np.float64)
        links, off = [], d_b
        x_k = None
        for j, (b, size) in enumerate(zip(blocks, sizes)):
            part = theta[off:off + size]
            off += size
            if b.nuisance:
                continue
            if j == k:
                x_k = x
            elif j > k:
                m = b.searched_bounds()[0].size
                links.append((EffectFit(b, part[:m], part[m:], np.zeros((C, 0)), np.empty(0), 0.0), x))
            x = b.apply_population(x[None, :], part[None, :], s.dt)[0]
        at.append(x_k)
        later.append(tuple(links))
        preds.append(x)
    views = _views(series, preds, base_model)
    # a Gauss–Newton step of every other parameter with it (the base fitted without the stage
    # made a compromise the block's coefficients alone would only follow)
    keep = np.r_[0:s0, s1:theta.size]
    chain = Composite(base, tuple(b for b in blocks if not b.nuisance))
    jacs = _per_capture(Obj(chain, series).jacobian(theta, upper=upper, lower=lower)[:, keep], series)
    nfev = theta.size + 1
    lin = Linearization(jacs, tuple(np.arange(keep.size) for _ in series),
                        lower[keep] - theta[keep], upper[keep] - theta[keep])
    fitted = Inserted(blocks[k], tuple(zip(at, later)))
    candidates, n = _block_candidates(fitted, preds, views, lin, theta, keep, s0, s1, lower, upper)
    nfev += n
    if not candidates:
        return theta, nfev
    scores = objective(np.vstack([theta] + candidates))
    return [theta, *candidates][int(np.argmin(scores))], nfev + len(candidates) + 1


def _search_series(model, series) -> list[Series]:
    """The captures the global search over the nonlinear parameters runs on: each capture's samples
    picked by the model's optional ``search_samples(u)`` (indices, or None for all; gpi: a
    subsample of a long capture on which its outputs are exact), else all. A warm-up (``skip``)
    keeps covering the same samples."""
    pick = getattr(model, "search_samples", None)
    out = []
    for s in series:
        idx = pick(s.u) if pick is not None else None
        out.append(s if idx is None else Series(s.u[idx], s.y[idx], s.dt, int(np.searchsorted(idx, s.skip))))
    return out
