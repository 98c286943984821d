"""Real-coded genetic algorithm (the GA of paper 000's comparison): tournament, SBX, polynomial mutation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import Callback, Objective, Optimizer, OptimizeResult, StopRules, Tracker, check_box


def sbx_crossover(p1: np.ndarray, p2: np.ndarray, lower: np.ndarray, upper: np.ndarray, eta: float,
                  prob: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Bounded simulated binary crossover (Deb & Agrawal 1995; Deb's NSGA-II reference code).

    For a pair of parents with y1 = min(p1, p2) < y2 = max(p1, p2) in one gene and u ~ U(0, 1)::

        β  = 1 + 2 (y1 − lower)/(y2 − y1)           (for child 1; 1 + 2 (upper − y2)/(y2 − y1) for child 2)
        α  = 2 − β^{−(η+1)}
        βq = (u α)^{1/(η+1)}               if u ≤ 1/α
             (1 / (2 − u α))^{1/(η+1)}     otherwise
        c1 = ½ [(y1 + y2) − βq (y2 − y1)],   c2 = ½ [(y1 + y2) + βq (y2 − y1)]

    The bound-aware spread keeps the children's distribution inside the box; children are
    clipped for round-off. A pair crosses with probability ``prob``, each gene of a crossing
    pair with probability ½ (genes closer than 1e-14 are copied), and the children swap genes
    with probability ½.

    Parameters
    ----------
    p1, p2 : ndarray, shape (m, d)
        Paired parents.
    lower, upper : ndarray, shape (d,)
        The box.
    eta : float
        Distribution index η (larger: children closer to the parents).
    prob : float
        Crossover probability per pair.
    rng : numpy.random.Generator

    Returns
    -------
    c1, c2 : ndarray, shape (m, d)
    """
    m, d = p1.shape
    u = rng.random((2, m, d))
    y1 = np.minimum(p1, p2)
    y2 = np.maximum(p1, p2)
    diff = y2 - y1
    cross = (rng.random((m, 1)) < prob) & (u[1] < 0.5) & (diff > 1e-14)
    # both children at once: row 0 the child below the midpoint, row 1 the one above
    room = np.stack((y1 - lower, upper - y2))          # distance of each parent to its face
    room /= np.where(cross, diff, 1.0)
    beta = 1.0 + 2.0 * room
    alpha = 2.0 - beta ** -(eta + 1.0)                 # in (1, 2]
    ra = u[0] * alpha                                   # < 2, so 2 − ra > 0
    betaq = np.where(ra <= 1.0, ra, 1.0 / (2.0 - ra)) ** (1.0 / (eta + 1.0))
    betaq *= diff
    mid = 0.5 * (y1 + y2)
    lo_child = mid - 0.5 * betaq[0]
    hi_child = mid + 0.5 * betaq[1]
    np.clip(lo_child, lower, upper, out=lo_child)
    np.clip(hi_child, lower, upper, out=hi_child)
    swap = u[1] < 0.25                                  # independent of crossing (u[1] < 0.5) given it
    c1 = np.where(cross, np.where(swap, hi_child, lo_child), p1)
    c2 = np.where(cross, np.where(swap, lo_child, hi_child), p2)
    return c1, c2


def polynomial_mutation(x: np.ndarray, lower: np.ndarray, upper: np.ndarray, eta: float, prob: float,
                        rng: np.random.Generator) -> np.ndarray:
    """Bounded polynomial mutation (Deb & Goyal 1996; Deb's NSGA-II reference code).

    Each gene mutates with probability ``prob``. With δ1 = (x − lower)/(upper − lower),
    δ2 = (upper − x)/(upper − lower) and u ~ U(0, 1)::

        δq = [2u + (1 − 2u)(1 − δ1)^{η+1}]^{1/(η+1)} − 1               if u < ½
             1 − [2(1 − u) + 2(u − ½)(1 − δ2)^{η+1}]^{1/(η+1)}        otherwise
        x ← x + δq (upper − lower),   clipped into the box (round-off only).

    Parameters
    ----------
    x : ndarray, shape (m, d)
    lower, upper : ndarray, shape (d,)
    eta : float
        Distribution index η.
    prob : float
        Mutation probability per gene.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (m, d)
        The mutated copy.
    """
    y = x.copy()
    rows, cols = np.nonzero(rng.random(x.shape) < prob)
    if rows.size == 0:
        return y
    lo, width = lower[cols], upper[cols] - lower[cols]
    xm = x[rows, cols]
    r = rng.random(rows.size)
    e = eta + 1.0
    low = r < 0.5
    d1 = (xm - lo) / width          # in [0, 1]: x lies in the box
    one_minus = np.where(low, 1.0 - d1, d1)            # 1 − δ1 below, 1 − δ2 = δ1 above
    val = np.where(low, 2.0 * r + (1.0 - 2.0 * r) * one_minus ** e,
                   2.0 * (1.0 - r) + (2.0 * r - 1.0) * one_minus ** e) ** (1.0 / e)
    dq = np.where(low, val - 1.0, 1.0 - val)
    y[rows, cols] = np.clip(xm + dq * width, lo, lo + width)
    return y


@optimizers.register
@dataclass
class GA(Optimizer):
    """Real-coded genetic algorithm with elitism (the GA of paper 000's comparison; README).

    One generation::

        parents   ← tournament selection, k = 3 (the best of k uniformly drawn individuals)
        children  ← SBX crossover of parent pairs (η_c = 15, p_c = 0.9)   (:func:`sbx_crossover`)
        children  ← polynomial mutation (η_m = 20, p_m = 1/d per gene)  (:func:`polynomial_mutation`)
        population ← the ``elite`` best individuals unchanged + pop − elite children

    Everything is vectorized over the population: one objective call per generation with the
    pop − elite children (the elite are not re-evaluated).

    Parameters
    ----------
    pop : int, default 40
        Population size (≥ elite + 2).
    iters : int, default 200
        Generations, the initial population included:
        ``nfev = pop + (iters − 1)(pop − elite)`` when this rule stops.
    tournament : int, default 3
        Tournament size k.
    eta_c, p_crossover : float, default 15, 0.9
        SBX distribution index and probability per pair.
    eta_m : float, default 20
        Polynomial-mutation distribution index.
    p_mutation : float or None, default None
        Mutation probability per gene; None means 1/d.
    elite : int, default 2
        Individuals carried over unchanged (elitism; ≥ 1).
    max_evals, stall_iter, stall_tol, target, time_limit_s
        The common stop rules (:class:`~hystfit.optimizers.base.StopRules`).

    Notes
    -----
    Stop rules: ``iters`` generations, ``max_evals`` evaluations, no relative improvement above
    ``stall_tol`` over ``stall_iter`` generations, ``target`` reached, or ``time_limit_s``.

    Bounds: the operators are Deb's bounded variants (their spread distributions respect the box)
    and children are *clipped* into the box for round-off, as Deb's reference code does; no
    reflection is needed.

    Initialisation: uniform in the box; if ``x0`` is given it replaces the first individual
    (clipped into the box). ``history_mean`` is the mean value of the population after
    replacement (elite + children).
    """

    name = "ga"
    title = "Genetic algorithm (real-coded, SBX, polynomial mutation)"
    reference = "paper 000 (GA comparison); Deb & Agrawal 1995; Deb & Goyal 1996"

    pop: int = 40
    iters: int = 200
    tournament: int = 3
    eta_c: float = 15.0
    p_crossover: float = 0.9
    eta_m: float = 20.0
    p_mutation: float | None = None
    elite: int = 2
    max_evals: int | None = None
    stall_iter: int | None = None
    stall_tol: float = 1e-9
    target: float | None = None
    time_limit_s: float | None = None

    def __post_init__(self) -> None:
        if self.iters < 1:
            raise ConfigError(f"ga: iters must be ≥ 1, got {self.iters}")
        if self.elite < 1:
            raise ConfigError(f"ga: elite must be ≥ 1, got {self.elite}")
        if self.pop < self.elite + 2:
            raise ConfigError(f"ga: pop must be ≥ elite + 2 = {self.elite + 2}, got {self.pop}")
        if self.tournament < 1:
            raise ConfigError(f"ga: tournament must be ≥ 1, got {self.tournament}")
        if self.eta_c < 0 or self.eta_m < 0:
            raise ConfigError(f"ga: eta_c and eta_m must be ≥ 0 (got {self.eta_c:g}, {self.eta_m:g})")
        if not 0 <= self.p_crossover <= 1:
            raise ConfigError(f"ga: p_crossover must lie in [0, 1], got {self.p_crossover:g}")
        if self.p_mutation is not None and not 0 <= self.p_mutation <= 1:
            raise ConfigError(f"ga: p_mutation must lie in [0, 1] or be None, got {self.p_mutation:g}")

    def _rules(self) -> StopRules:
        return StopRules(self.iters, self.max_evals, self.stall_iter, self.stall_tol, self.target, self.time_limit_s)

    def minimize(self, objective: Objective, lower, upper, *, rng: np.random.Generator,
                 x0: np.ndarray | None = None, callback: Callback = None) -> OptimizeResult:
        lower, upper = check_box(lower, upper)
        d, P, E, k = lower.size, self.pop, self.elite, self.tournament
        p_mut = 1.0 / d if self.p_mutation is None else self.p_mutation
        n_child = P - E
        n_pair = (n_child + 1) // 2
        tr = Tracker(objective, self._rules(), callback)
        x = lower + rng.random((P, d)) * (upper - lower)
        if x0 is not None:
            x[0] = np.clip(np.asarray(x0, float), lower, upper)
        f = tr.evaluate(x)
        if tr.end_iteration(f):
            return tr.result(self.name)
        rows = np.arange(2 * n_pair)
        while True:
            # tournament selection of 2·n_pair parents
            cand = rng.integers(0, P, size=(2 * n_pair, k))
            parents = x[cand[rows, np.argmin(f[cand], axis=1)]]
            c1, c2 = sbx_crossover(parents[:n_pair], parents[n_pair:], lower, upper, self.eta_c,
                                   self.p_crossover, rng)
            children = polynomial_mutation(np.concatenate((c1, c2))[:n_child], lower, upper, self.eta_m,
                                           p_mut, rng)
            fc = tr.evaluate(children)
            keep = np.argpartition(f, E - 1)[:E]
            x = np.concatenate((x[keep], children))
            f = np.concatenate((f[keep], fc))
            if tr.end_iteration(f):
                return tr.result(self.name)
