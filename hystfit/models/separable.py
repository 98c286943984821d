"""Variable projection: solve the parameters that enter linearly, search only the others.

Many hysteresis models are *separable*: y = B(θ_nl; u) · θ_lin, where B is a small basis
(PI: the play-operator outputs and a column of ones; Bouc–Wen: u, the unit-gain hysteretic
state and ones; NT: u, u̇, softsign(k2 u) and ones). For a candidate θ_nl the best θ_lin is a
linear least-squares problem, solved exactly here (within θ_lin's bounds), so an optimizer only
searches θ_nl — often 0–2 dimensions instead of 5–12 (Golub & Pereyra 1973).

A model declares its separable structure by returning a :class:`Separable` from
``model.separable()``; ``None`` (the default) means no exploitable structure. This module is the
model side (the declaration); the optimizer side — the projected objective and the box-constrained
solves — is :mod:`hystfit.optimizers.projection`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .._jit import readonly


#: basis_factory(u, dt) → basis(theta_nl (P, m)) → B (P, N, L)  (for m = 0, P may be 1)
BasisFactory = Callable[[np.ndarray, float], Callable[[np.ndarray], np.ndarray]]
#: gram_factory(u, dt, y) → gram(theta_nl (P, m)) → (BᵀB (P, L, L), Bᵀt (P, L), tᵀt (scalar or (P,)))
#: with t = y − C the target of the linear part (C the known part, if any)
GramFactory = Callable[[np.ndarray, float, np.ndarray], Callable[[np.ndarray], tuple]]


@dataclass(frozen=True)
class Separable:
    """Which entries of θ enter linearly, and the basis that multiplies them.

    ``linear`` and ``nonlinear`` are index arrays into θ (together a permutation of range(d));
    ``basis_factory(u, dt)`` returns a function of θ_nl (P, m) giving B (P, N, L) with
    L = len(linear), so that simulate(θ) = B(θ_nl) @ θ_lin exactly — or a pair (B, C) with a
    known part C (P, N): simulate(θ) = C(θ_nl) + B(θ_nl) @ θ_lin.
    """

    linear: tuple[int, ...]
    nonlinear: tuple[int, ...]
    basis_factory: BasisFactory
    #: optional: the normal equations directly (when every capture has one,
    #: :class:`ProjectedObjective` never materialises B as (P, N, L))
    gram_factory: GramFactory | None = None
    #: True when ``gram_factory`` needs O(P) memory only (a fused kernel that never stores the
    #: (N, P) trajectories); otherwise candidates are processed in blocks bounded by
    #: :data:`hystfit.objective.BLOCK_ELEMENTS`
    gram_fused: bool = False
    #: optional ``(n_samples, dt) → bool``: True when that capture's ``gram_factory`` is fused
    #: (O(P) memory), for a model whose long captures take a fused route and short ones do not
    fused_for: Callable[[int, float], bool] | None = None

    def fused(self, series) -> bool:
        """True when the normal equations of every capture in ``series`` need O(P) memory only."""
        if self.gram_factory is None:
            return False
        return self.gram_fused or (self.fused_for is not None
                                   and all(self.fused_for(s.y.shape[0], s.dt) for s in series))


#: grouped(u, dt) → sim(θ (P·g, d), g) → (P·g, N): the model's simulation of a population whose
#: consecutive groups of g rows share every nonlinear parameter (they differ in linear ones only)
GroupedSimulator = Callable[[np.ndarray, float], Callable[[np.ndarray, int], np.ndarray]]


def separable_by_simulation(model, linear: Sequence[int], d: int, grouped: GroupedSimulator | None = None) -> Separable:
    """A :class:`Separable` for a model whose output is affine in θ[linear] for fixed other entries.

    The basis is obtained from the model's own simulator: for each candidate, one simulation with
    θ_lin = 0 (the known part C) and one per unit vector e_j (columns B_j = y(e_j) − C), all in
    one population call of P·(L+1) candidates. Exact whenever the model is affine in those
    parameters (checked for every model by the contract tests). ``grouped``, if given, simulates
    such a population computing the nonlinear state once per group of L + 1 rows — the same
    numbers as the model's simulator (bit for bit), at a fraction of the cost.
    """
    linear = tuple(int(i) for i in linear)
    nonlinear = tuple(i for i in range(d) if i not in linear)
    L = len(linear)

    def simulator(u, dt):
        if grouped is None:
            return model.simulator(u, dt)
        sim_g = grouped(readonly(u), dt)
        return lambda th: sim_g(th, L + 1)

    def simulate_unit(sim, theta_nl):
        """Y (P, L+1, N): the outputs for θ_lin = 0 and for each unit vector e_j."""
        P = theta_nl.shape[0]
        th = np.zeros((P * (L + 1), d))
        th[:, list(nonlinear)] = np.repeat(theta_nl, L + 1, axis=0)
        for j, idx in enumerate(linear):
            th[j + 1::L + 1, idx] = 1.0
        with np.errstate(all="ignore"):
            return np.asarray(sim(th)).reshape(P, L + 1, -1)

    def factory(u, dt):
        sim = simulator(u, dt)

        def basis(theta_nl):
            Y = simulate_unit(sim, theta_nl)
            with np.errstate(all="ignore"):
                C = Y[:, 0, :]
                B = np.ascontiguousarray((Y[:, 1:, :] - C[:, None, :]).transpose(0, 2, 1))
            return B, C

        return basis

    def gram_factory(u, dt, y):
        """The normal equations straight from the (P, L, N) layout of the simulations: batched
        matrix products, no transposed copy of the basis."""
        sim = simulator(u, dt)
        y = np.asarray(y, dtype=np.float64)

        def gram(theta_nl):
            Y = simulate_unit(sim, theta_nl)
            with np.errstate(all="ignore"):
                C = Y[:, 0, :]
                D = Y[:, 1:, :] - C[:, None, :]  # (P, L, N): the basis, transposed
                t = y[None, :] - C  # (P, N)
                G = D @ D.transpose(0, 2, 1)
                c = (D @ t[:, :, None])[:, :, 0]
                tt = np.einsum("pn,pn->p", t, t)
            return G, c, tt

        return gram

    return Separable(linear, nonlinear, factory, gram_factory)


#: response(u, dt) → z(theta_nl (P, m)) → (N, P) the unit-scale output of each candidate
ResponseFactory = Callable[[np.ndarray, float], Callable[[np.ndarray], np.ndarray]]
#: moments(u, dt, y) → m(theta_nl (P, m)) → (P, 3): Σz², Σz, Σz·y per candidate
MomentsFactory = Callable[[np.ndarray, float, np.ndarray], Callable[[np.ndarray], np.ndarray]]


def scaled_response(linear: tuple[int, int], nonlinear: tuple[int, ...], response: ResponseFactory,
                    moments: MomentsFactory | None = None,
                    fused_for: Callable[[int, float], bool] | None = None) -> Separable:
    """A :class:`Separable` for y = ρ·z(θ_nl) + y0, ``linear`` = the indices of (ρ, y0) in θ.

    The basis is [z, 1]; its normal equations come from the moments Σz², Σz, Σz·y — computed from
    z (``response``) or, when given, by ``moments`` (a fused kernel that never stores z: then
    ``gram_fused``). With ``fused_for`` (n_samples, dt) → bool, ``moments`` applies to the
    captures it accepts only (it returns None for the others, whose moments come from z).
    """

    def factory(u, dt):
        u = readonly(u)
        z_of = response(u, dt)

        def basis(theta_nl):
            z = z_of(theta_nl)  # (N, P)
            B = np.empty((z.shape[1], u.shape[0], 2))
            B[:, :, 0] = z.T
            B[:, :, 1] = 1.0
            return B

        return basis

    def gram_factory(u, dt, y):
        u = readonly(u)
        y = readonly(y)
        n, sy, yy = float(u.shape[0]), float(y.sum()), float(y @ y)
        moments_of = moments(u, dt, y) if moments is not None else None
        if moments_of is None:
            z_of = response(u, dt)

            def moments_of(theta_nl):
                z = z_of(theta_nl)  # (N, P)
                return np.einsum("np,np->p", z, z), z.sum(axis=0), y @ z

        def gram(theta_nl):
            M = moments_of(theta_nl)
            P = M[0].shape[0]
            G = np.empty((P, 2, 2))
            G[:, 0, 0] = M[0]
            G[:, 0, 1] = G[:, 1, 0] = M[1]
            G[:, 1, 1] = n
            c = np.empty((P, 2))
            c[:, 0] = M[2]
            c[:, 1] = sy
            return G, c, yy

        return gram

    return Separable(tuple(linear), tuple(nonlinear), factory, gram_factory,
                     gram_fused=moments is not None and fused_for is None, fused_for=fused_for)


def linear_in_all(design_matrix: Callable[[np.ndarray, float], np.ndarray], d: int) -> Separable:
    """A :class:`Separable` for a model whose output is linear in all ``d`` parameters,
    y = Φ(u) θ with the regressors ``design_matrix(u, dt)`` (N, d): one bounded least-squares solve."""

    def factory(u, dt):
        B = design_matrix(u, dt)[None, :, :]
        return lambda theta_nl: B

    return Separable(tuple(range(d)), (), factory)
