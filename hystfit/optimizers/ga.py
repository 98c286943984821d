"""Real-coded genetic algorithm (the GA of paper 000's comparison): tournament, SBX, polynomial mutation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from .._jit import njit

from ..errors import ConfigError
from ..registry import optimizers
from .base import IteratedSearch, PopulationLoop, Tracker, setting


@njit(cache=True)
def sbx_children(x1: float, x2: float, lower: float, upper: float, eta: float, u: float) -> tuple[float, float]:
    """Bounded simulated binary crossover of one gene (Deb & Agrawal 1995; Deb's NSGA-II code).

    With y1 = min(x1, x2) < y2 = max(x1, x2) and u ~ U(0, 1) (the same u for both children)::

        β  = 1 + 2 (y1 − lower)/(y2 − y1)    (child below; 1 + 2 (upper − y2)/(y2 − y1) above)
        α  = 2 − β^{−(η+1)}
        βq = (u α)^{1/(η+1)}               if u α ≤ 1
             (1 / (2 − u α))^{1/(η+1)}     otherwise
        c_lo = ½ [(y1 + y2) − βq (y2 − y1)],   c_hi = ½ [(y1 + y2) + βq (y2 − y1)]

    The bound-aware spread keeps the children's distribution inside [lower, upper]; they are
    clipped for round-off only. Requires y2 − y1 > 0.

    Returns
    -------
    (c_lo, c_hi) : the child below and the child above the parents' midpoint.
    """
    y1 = min(x1, x2)
    y2 = max(x1, x2)
    diff = y2 - y1
    e = eta + 1.0
    alpha = 2.0 - (1.0 + 2.0 * (y1 - lower) / diff) ** (-e)
    ra = u * alpha                       # < 2, so 2 − ra > 0
    bq = ra ** (1.0 / e) if ra <= 1.0 else (1.0 / (2.0 - ra)) ** (1.0 / e)
    c_lo = 0.5 * ((y1 + y2) - bq * diff)
    alpha = 2.0 - (1.0 + 2.0 * (upper - y2) / diff) ** (-e)
    ra = u * alpha
    bq = ra ** (1.0 / e) if ra <= 1.0 else (1.0 / (2.0 - ra)) ** (1.0 / e)
    c_hi = 0.5 * ((y1 + y2) + bq * diff)
    return min(max(c_lo, lower), upper), min(max(c_hi, lower), upper)


@njit(cache=True)
def polynomial_mutation(x: float, lower: float, upper: float, eta: float, r: float) -> float:
    """Bounded polynomial mutation of one gene (Deb & Goyal 1996; Deb's NSGA-II code).

    With δ1 = (x − lower)/(upper − lower), δ2 = (upper − x)/(upper − lower), r ~ U(0, 1)::

        δq = [2r + (1 − 2r)(1 − δ1)^{η+1}]^{1/(η+1)} − 1               if r < ½
             1 − [2(1 − r) + 2(r − ½)(1 − δ2)^{η+1}]^{1/(η+1)}        otherwise
        x' = x + δq (upper − lower),   clipped into the box (round-off only).
    """
    width = upper - lower
    e = eta + 1.0
    if r < 0.5:
        xy = 1.0 - (x - lower) / width
        dq = (2.0 * r + (1.0 - 2.0 * r) * xy ** e) ** (1.0 / e) - 1.0
    else:
        xy = 1.0 - (upper - x) / width
        dq = 1.0 - (2.0 * (1.0 - r) + 2.0 * (r - 0.5) * xy ** e) ** (1.0 / e)
    return min(max(x + dq * width, lower), upper)


def random_count(pop: int, elite: int, d: int, tournament: int) -> int:
    """Number of U(0, 1) variates :func:`make_children` consumes per generation."""
    n_child = pop - elite
    m = (n_child + 1) // 2
    return 2 * m * tournament + m + 2 * m * d + n_child * d


@njit(cache=True)
def make_children(x, f, lower, upper, n_child, tournament, eta_c, p_crossover, eta_m, p_mutation, u, out):
    """One generation's children: tournament selection, SBX, polynomial mutation (in ``out``).

    Parameters
    ----------
    x : ndarray (P, d), f : ndarray (P,)
        Population and its values.
    lower, upper : ndarray (d,)
    n_child : int
        Children to make (rows of ``out``).
    tournament : int
        Tournament size k: each parent is the best of k members drawn uniformly (with replacement).
    eta_c, p_crossover : float
        SBX distribution index and crossover probability per pair.
    eta_m, p_mutation : float
        Polynomial-mutation distribution index and probability per gene.
    u : ndarray
        :func:`random_count` U(0, 1) variates, all the randomness of the generation.
    out : ndarray (n_child, d)
        Receives the children.

    Notes
    -----
    m = ceil(n_child/2) pairs (parent i with parent m + i); child 1 of pair i goes to row i,
    child 2 to row m + i (dropped when n_child is odd). In a crossing pair each gene crosses
    with probability ½ (genes closer than 1e-14 of the box width are copied) and the two
    children swap the gene with probability ½. One variate serves both the gene choice and
    the swap (u_g < ½ crosses, u_g < ¼ swaps: independent given the crossing), and one both
    the mutation choice and its r (u < p_m mutates with r = u/p_m): exact, and fewer draws.
    """
    P, d = x.shape
    m = (n_child + 1) // 2
    parents = np.empty(2 * m, dtype=np.int64)
    pos = 0
    for i in range(2 * m):
        best = min(int(u[pos] * P), P - 1)
        pos += 1
        for _ in range(1, tournament):
            c = min(int(u[pos] * P), P - 1)
            pos += 1
            if f[c] < f[best]:
                best = c
        parents[i] = best
    for i in range(m):
        a = parents[i]
        b = parents[m + i]
        crossing = u[pos] < p_crossover
        pos += 1
        second = m + i < n_child
        for j in range(d):
            x1 = x[a, j]
            x2 = x[b, j]
            ug = u[pos]
            us = u[pos + 1]
            pos += 2
            if crossing and ug < 0.5 and abs(x1 - x2) > 1e-14 * (upper[j] - lower[j]):
                lo_c, hi_c = sbx_children(x1, x2, lower[j], upper[j], eta_c, us)
                if ug < 0.25:
                    x1, x2 = hi_c, lo_c
                else:
                    x1, x2 = lo_c, hi_c
            out[i, j] = x1
            if second:
                out[m + i, j] = x2
    for i in range(n_child):
        for j in range(d):
            um = u[pos]
            pos += 1
            if um < p_mutation:
                out[i, j] = polynomial_mutation(out[i, j], lower[j], upper[j], eta_m, um / p_mutation)


@optimizers.register
@dataclass
class GA(PopulationLoop, IteratedSearch):
    """Real-coded genetic algorithm with elitism (the GA of paper 000's comparison; README).

    One generation::

        parents    ← tournament selection, k = 3 (the best of k uniformly drawn members)
        children   ← SBX crossover of parent pairs (η_c = 15, p_c = 0.9)    (:func:`sbx_children`)
        children   ← polynomial mutation (η_m = 20, p_m = 1/d per gene)   (:func:`polynomial_mutation`)
        population ← the ``elite`` best members unchanged + (pop − elite) children

    One objective call per generation with the pop − elite children (the elite are not
    re-evaluated). Selection and variation of a whole generation run in one compiled kernel
    (:func:`make_children`, numba, ``cache=True``) fed with one array of U(0, 1) variates drawn
    from ``rng``: no per-individual Python calls.

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
    {stop_rule_params}

    Notes
    -----
    {iterated_stop_rules}

    Bounds: the operators are Deb's bounded variants (their spread distributions respect the box)
    and children are *clipped* into the box for round-off, as Deb's reference code does; no
    reflection is needed.

    Initialisation: uniform in the box; if ``x0`` is given it replaces the first individual
    (clipped into the box). ``history_mean`` is the mean value of the population after
    replacement (elite + children).
    """

    name = "ga"
    iteration_unit = "generations"
    title = "Genetic algorithm (real-coded, SBX, polynomial mutation)"
    reference = "paper 000 (GA comparison); Deb & Agrawal 1995; Deb & Goyal 1996"

    tournament: int = setting(3, whole=True, at_least=1)
    eta_c: float = setting(15.0, at_least=0)
    p_crossover: float = setting(0.9, at_least=0, at_most=1)
    eta_m: float = setting(20.0, at_least=0)
    p_mutation: float | None = setting(None, at_least=0, at_most=1, nullable=True, example=0.1,
                                       null_means="use 1/d", what="mutation probability per gene")
    elite: int = setting(2, whole=True, at_least=1)

    def check_settings(self) -> None:
        if self.pop < self.elite + 2:
            raise ConfigError(f"ga: pop must be ≥ elite + 2 = {self.elite + 2}, got {self.pop}")
        super().check_settings()

    def search(self, tr: Tracker, x: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rng: np.random.Generator) -> None:
        P, d = x.shape
        E, k = self.elite, self.tournament
        p_mut = 1.0 / d if self.p_mutation is None else float(self.p_mutation)
        eta_c, p_c, eta_m = float(self.eta_c), float(self.p_crossover), float(self.eta_m)
        n_child = P - E
        n_rand = random_count(P, E, d, k)
        while True:
            children = np.empty((n_child, d))
            make_children(x, f, lower, upper, n_child, k, eta_c, p_c, eta_m, p_mut, rng.random(n_rand), children)
            fc = tr.evaluate(children)
            keep = np.argpartition(f, E - 1)[:E]
            x = np.concatenate((x[keep], children))
            f = np.concatenate((f[keep], fc))
            if tr.end_iteration(f):
                return
