"""Improved particle swarm optimization (paper 000): rank-adaptive coefficients, no iteration count."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError
from ..registry import optimizers
from .base import PopulationSearch, StopRules, setting, stop_field
from .pso import Swarm


def rank_coefficients(pbest_f: np.ndarray, w_min: float = 0.4, w_max: float = 0.9, c_min: float = 1.5,
                      c_max: float = 2.5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rank-based inertia and acceleration coefficients of IPSO (paper 000, README formulation).

    With the s particles ranked by personal-best value (rank 1 = best, ties broken by index)::

        w_i  = w_min + (w_max − w_min)(s − rank_i)/(s − 1)
        λ_i  = (w_i − w_min)/(w_max − w_min) = (s − rank_i)/(s − 1)
        c1_i = c_min + (c_max − c_min) λ_i
        c2_i = c_max − (c_max − c_min) λ_i

    Better particles get the larger inertia and cognitive weight (they explore), worse ones the
    smaller inertia and the larger social weight (they converge).

    Parameters
    ----------
    pbest_f : ndarray, shape (s,)
        Personal-best values, s ≥ 2.
    w_min, w_max, c_min, c_max : float
        Ranges of the inertia weight and the acceleration coefficients.

    Returns
    -------
    rank : ndarray of int, shape (s,)
        1-based rank of each particle.
    w, c1, c2 : ndarray, shape (s,)
        Inertia, cognitive and social coefficient of each particle.
    """
    s = pbest_f.shape[0]
    order = np.argsort(pbest_f, kind="stable")
    rank = np.empty(s, dtype=np.int64)
    rank[order] = np.arange(1, s + 1)
    lam = (s - rank) / (s - 1.0)
    w = w_min + (w_max - w_min) * lam
    c1 = c_min + (c_max - c_min) * lam
    c2 = c_max - (c_max - c_min) * lam
    return rank, w, c1, c2


def social_attractors(rank: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Diverse equilibrium points: whose personal best each particle follows (paper 000, README).

    Particle i of rank r_i > 1 follows a particle drawn uniformly among ranks 1 … r_i − 1; the
    best particle (rank 1) follows itself, i.e. the global best.

    Parameters
    ----------
    rank : ndarray of int, shape (s,)
        1-based ranks, a permutation of 1 … s (from :func:`rank_coefficients`).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray of int, shape (s,)
        Index of the particle whose personal best is particle i's social attractor.
    """
    s = rank.shape[0]
    by_rank = np.empty(s, dtype=np.intp)
    by_rank[rank - 1] = np.arange(s)          # by_rank[k] = particle of rank k + 1
    return by_rank[(rng.random(s) * (rank - 1)).astype(np.intp)]


@optimizers.register
@dataclass
class IPSO(Swarm, PopulationSearch):
    """Improved PSO of paper 000 as ``shared/papers/README.md`` formulates it.

    Each iteration the particles are ranked by personal-best value (rank 1 = best, s particles);
    with λ_i = (s − rank_i)/(s − 1)::

        w_i  = w_min + (w_max − w_min) λ_i            (better particles: larger inertia, explore)
        c1_i = c_min + (c_max − c_min) λ_i,  c2_i = c_max − (c_max − c_min) λ_i
        v_i ← w_i v_i + c1_i r1 (p_i − x_i) + c2_i r2 (p_{e(i)} − x_i),   x_i ← x_i + v_i

    (see :func:`rank_coefficients`). *Diverse equilibrium points*: the social attractor p_{e(i)}
    is the personal best of a particle drawn uniformly among those ranked better than i; the
    best particle uses the global best (:func:`social_attractors`). r1, r2 ~ U(0, 1) per particle
    and dimension. With c1 + c2 = 4 for every particle, the top ranks (w near 0.9) lie outside
    PSO's second-order stability region and keep exploring at up to V_max; convergence comes
    from the lower ranks, which settle between their own and a better particle's best.

    Parameters
    ----------
    pop : int, default 40
        Swarm size s (≥ 2); paper 000 uses 200.
    w_min, w_max : float, default 0.4, 0.9
        Inertia range.
    c_min, c_max : float, default 1.5, 2.5
        Acceleration coefficient range.
    vmax_frac : float, default 0.2
        Velocity clamp as a fraction of (upper − lower), as in :class:`~hystfit.optimizers.pso.PSO`.
    max_evals : int or None, default 60000
        Evaluation budget (200 particles × 300 iterations, paper 000's budget).
    stall_iter : int or None, default 50
        Stall window in iterations. This formulation improves in bursts (the top-ranked,
        high-inertia particles keep exploring); with a window of 30 it stopped at 2–3× worse
        values on the BW, Rosenbrock and Rastrigin checks than with 50.
    stall_tol : float, default 1e-6
        Relative improvement of the best value that must be exceeded within the stall window.
    target, time_limit_s : float or None
        Stop when the best value reaches ``target`` or after ``time_limit_s`` seconds.

    Notes
    -----
    Stop rules: there is *no preset iteration count* (paper 000's point: the inertia does not
    follow an iteration schedule). The run stops when the best value improves by less than
    ``stall_tol`` (relative) over ``stall_iter`` iterations (status 1), at ``max_evals``
    evaluations (status 0), at ``target`` (2) or after ``time_limit_s`` (3). At least one of
    ``max_evals``, ``stall_iter``, ``target``, ``time_limit_s`` must be set. ``--iters`` does
    not apply.

    {swarm_notes}
    """

    name = "ipso"
    title = "Improved particle swarm (rank-adaptive, stall stop)"
    reference = "paper 000 (improved PSO); shared/papers/README.md"

    w_min: float = setting(0.4, at_least=0)
    w_max: float = setting(0.9)
    c_min: float = setting(1.5, at_least=0)
    c_max: float = setting(2.5)
    vmax_frac: float = setting(0.2, above=0)
    stop: StopRules = stop_field(max_evals=60_000, stall_iter=50, stall_tol=1e-6)

    def check_settings(self) -> None:
        super().check_settings()
        if not self.w_min < self.w_max:
            raise ConfigError(f"ipso: need w_min < w_max (got {self.w_min:g}, {self.w_max:g})")
        if not self.c_min <= self.c_max:
            raise ConfigError(f"ipso: need c_min ≤ c_max (got {self.c_min:g}, {self.c_max:g})")
        s = self.stop
        if s.max_evals is None and s.stall_iter is None and s.target is None and s.time_limit_s is None:
            raise ConfigError("ipso: has no iteration count; set at least one of max_evals, stall_iter, "
                              "target, time_limit_s (e.g. --opt-option max_evals=60000)")

    def velocity(self, nit: int, x: np.ndarray, v: np.ndarray, pbest: np.ndarray, pbest_f: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
        rank, w, c1, c2 = rank_coefficients(pbest_f, self.w_min, self.w_max, self.c_min, self.c_max)
        att = social_attractors(rank, rng)
        r = rng.random((2,) + x.shape)
        return (w[:, None] * v + c1[:, None] * r[0] * (pbest - x)
                + c2[:, None] * r[1] * (pbest[att] - x))
