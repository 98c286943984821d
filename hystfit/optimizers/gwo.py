"""Grey wolf optimizer (Mirjalili et al. 2014; paper 004 eq. 3–9)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..registry import optimizers
from .base import IteratedSearch, PopulationLoop, Tracker


def linear_convergence_factor(t: float, T: float) -> float:
    """GWO's convergence factor a = 2 (1 − t/T) (paper 004 eq. 6): 2 at t = 0, 0 at t = T."""
    return 2.0 * (1.0 - min(t / T, 1.0))


def schedule_length(iters: int, pop: int, max_evals: int | None) -> int:
    """Number of position updates the convergence-factor schedule spans.

    The initial population is iteration 1, so ``iters`` iterations give ``iters − 1`` updates.
    An evaluation budget that ends the run earlier shortens the schedule, so that a still
    reaches (nearly) 0 when the run ends.
    """
    n_iter = iters if max_evals is None else min(iters, math.ceil(max_evals / pop))
    return max(n_iter - 1, 1)


def update_leaders(leaders: np.ndarray, leaders_f: np.ndarray, x: np.ndarray,
                   f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The α, β, δ wolves: the three best points seen so far (previous leaders ∪ current pack).

    Returns the leaders (3, d) and their values (3,), best first.
    """
    pool_f = np.concatenate((leaders_f, f))
    top = np.argpartition(pool_f, 2)[:3]
    top = top[np.argsort(pool_f[top], kind="stable")]
    pool = np.concatenate((leaders, x))
    return pool[top], pool_f[top]


def hunt(leaders: np.ndarray, x: np.ndarray, a: float, rng: np.random.Generator) -> np.ndarray:
    """Positions guided by α, β, δ (paper 004 eq. 5, 7, 8), one per leader.

    For leader L_k (k = 1, 2, 3) and each wolf X, with r1, r2 ~ U(0, 1) per wolf and dimension::

        A_k = 2 a r1 − a,   C_k = 2 r2,   D_k = |C_k L_k − X|,   X_k = L_k − A_k D_k

    Parameters
    ----------
    leaders : ndarray, shape (3, d)
    x : ndarray, shape (P, d)
    a : float
        Convergence factor.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (3, P, d)
        X_1, X_2, X_3; eq. 9 averages them.
    """
    r = rng.random((2, 3) + x.shape)
    L = leaders[:, None, :]
    A = r[0]
    A *= 2.0 * a
    A -= a                       # A = 2 a r1 − a
    D = r[1]
    D *= 2.0
    D *= L
    D -= x
    np.abs(D, out=D)             # D = |C L − X|, C = 2 r2
    A *= D
    return np.subtract(L, A, out=A)


@optimizers.register
@dataclass
class GWO(PopulationLoop, IteratedSearch):
    """Grey wolf optimizer (paper 004 eq. 3–9, Mirjalili, Mirjalili & Lewis 2014).

    The three best points found so far are the α, β, δ wolves (L_1, L_2, L_3). Each iteration
    every wolf X moves to::

        a   = 2 (1 − t/T)                                   (eq. 6, t = 0 … T − 1 updates)
        A_k = 2 a r1 − a,  C_k = 2 r2                         (eq. 5)
        D_k = |C_k L_k − X|,  X_k = L_k − A_k D_k            (eq. 7–8)
        X  ← (X_1 + X_2 + X_3) / 3                           (eq. 9)

    with r1, r2 ~ U(0, 1) drawn per leader, wolf and dimension (see :func:`hunt`). T is the
    number of position updates, ``iters − 1``, shortened when ``max_evals`` ends the run
    earlier (:func:`schedule_length`), so that a reaches ≈ 0 at the end of the run.

    Parameters
    ----------
    pop : int, default 40
        Pack size (≥ 3).
    {iters_param}
    {stop_rule_params}

    Notes
    -----
    {iterated_stop_rules}

    Bounds: positions that leave the box are *clipped* to the violated face, as in Mirjalili's
    reference code and paper 004 (Algorithm 1, step 14: "amend" agents beyond the search space).

    Initialisation: uniform in the box (eq. 3); if ``x0`` is given it replaces the first wolf
    (clipped into the box).
    """

    name = "gwo"
    title = "Grey wolf optimizer"
    reference = "paper 004 eq. 3–9 (Mirjalili et al. 2014)"
    min_pop = 3

    def convergence_factor(self, t: float, T: float) -> float:
        return linear_convergence_factor(t, T)

    def perturb(self, x_sum: np.ndarray, lower: np.ndarray, upper: np.ndarray, rng: np.random.Generator) -> None:
        """Change X_1 + X_2 + X_3 (in place) before eq. 9 averages it; GWO adds nothing."""

    def search(self, tr: Tracker, x: np.ndarray, f: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rng: np.random.Generator) -> None:
        T = schedule_length(self.iters, self.pop, self.stop.max_evals)
        leaders, leaders_f = update_leaders(np.empty((0, x.shape[1])), np.empty(0), x, f)
        t = 0
        while True:
            x = hunt(leaders, x, self.convergence_factor(t, T), rng).sum(axis=0)
            self.perturb(x, lower, upper, rng)
            x *= 1.0 / 3.0
            np.clip(x, lower, upper, out=x)
            f = tr.evaluate(x)
            leaders, leaders_f = update_leaders(leaders, leaders_f, x, f)
            t += 1
            if tr.end_iteration(f):
                return
