"""Variable projection: solve the parameters that enter linearly, search only the others.

Many hysteresis models are *separable*: y = B(θ_nl; u) · θ_lin, where B is a small basis
(PI: the play-operator outputs and a column of ones; Bouc–Wen: u, the unit-gain hysteretic
state and ones; NT: u, u̇, softsign(k2 u) and ones). For a candidate θ_nl the best θ_lin is a
linear least-squares problem, solved exactly here (within θ_lin's bounds), so an optimizer only
searches θ_nl — often 0–2 dimensions instead of 5–12 (Golub & Pereyra 1973).

A model declares its separable structure by returning a :class:`Separable` from
``model.separable(scale)``; ``None`` (the default) means no exploitable structure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import lsq_linear

from .objective import Series

#: basis_factory(u, dt) → basis(theta_nl (P, m)) → B (P, N, L)  (for m = 0, P may be 1)
BasisFactory = Callable[[np.ndarray, float], Callable[[np.ndarray], np.ndarray]]


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


def separable_by_simulation(model, linear: Sequence[int], d: int) -> Separable:
    """A :class:`Separable` for a model whose output is affine in θ[linear] for fixed other entries.

    The basis is obtained from the model's own simulator: for each candidate, one simulation with
    θ_lin = 0 (the known part C) and one per unit vector e_j (columns B_j = y(e_j) − C), all in
    one population call of P·(L+1) candidates. Exact whenever the model is affine in those
    parameters (checked for every model by the contract tests).
    """
    linear = tuple(int(i) for i in linear)
    nonlinear = tuple(i for i in range(d) if i not in linear)
    L = len(linear)

    def factory(u, dt):
        sim = model.simulator(u, dt)

        def basis(theta_nl):
            P = theta_nl.shape[0]
            th = np.zeros((P * (L + 1), d))
            th[:, list(nonlinear)] = np.repeat(theta_nl, L + 1, axis=0)
            for j, idx in enumerate(linear):
                th[j + 1::L + 1, idx] = 1.0
            with np.errstate(all="ignore"):
                Y = sim(th).reshape(P, L + 1, -1)
                C = Y[:, 0, :]
                B = np.ascontiguousarray((Y[:, 1:, :] - C[:, None, :]).transpose(0, 2, 1))
            return B, C

        return basis

    return Separable(linear, nonlinear, factory)


def _bounded_solve(G: np.ndarray, c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """argmin θᵀGθ − 2cᵀθ over lo ≤ θ ≤ hi, via the Cholesky factor (an L×L least-squares problem)."""
    L = G.shape[0]
    ridge = 1e-12 * max(np.trace(G) / L, 1e-300)
    try:
        R = np.linalg.cholesky(G + ridge * np.eye(L)).T
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(G)
        R = (V * np.sqrt(np.maximum(w, ridge))).T
    rhs = np.linalg.lstsq(R.T, c, rcond=None)[0]
    return lsq_linear(R, rhs, bounds=(lo, hi), method="bvls", tol=1e-12).x


class ProjectedObjective:
    """MSE over θ_nl with θ_lin solved exactly per candidate (pooled over captures).

    ``__call__(Θ_nl (P, m)) → (P,)``; :meth:`full` returns the complete θ (P, d) of the last
    solved candidates, so the winner can be turned back into a full parameter vector.
    """

    def __init__(self, sep: Separable, series: Sequence[Series], lower: np.ndarray, upper: np.ndarray) -> None:
        self.sep = sep
        self.series = list(series)
        self.bases = [sep.basis_factory(s.u, s.dt) for s in self.series]
        self.lin = np.asarray(sep.linear, dtype=int)
        self.nl = np.asarray(sep.nonlinear, dtype=int)
        self.lo_lin, self.hi_lin = lower[self.lin], upper[self.lin]
        self.d = len(self.lin) + len(self.nl)
        self.n_total = int(sum(s.y.shape[0] for s in self.series))
        self.nfev = 0

    def solve(self, theta_nl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best θ_lin for each candidate and the resulting MSE: ((P, L), (P,)).

        Candidates are processed in blocks so the basis (block, N, L) stays within
        :data:`hystfit.objective.BLOCK_ELEMENTS` elements: memory is bounded for long captures.
        """
        from .objective import BLOCK_ELEMENTS

        theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
        P = theta_nl.shape[0] if len(self.nl) else 1
        L = max(len(self.lin), 1)
        n_max = max(s.y.shape[0] for s in self.series)
        block = max(1, BLOCK_ELEMENTS // (n_max * (L + 1) * max(len(self.series), 1)))
        if P <= block:
            return self._solve_block(theta_nl)
        lins, mses = zip(*(self._solve_block(theta_nl[i:i + block]) for i in range(0, P, block)))
        return np.vstack(lins), np.concatenate(mses)

    def _solve_block(self, theta_nl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = theta_nl.shape[0] if len(self.nl) else 1
        L = len(self.lin)
        G = np.zeros((P, L, L))
        c = np.zeros((P, L))
        kept = []
        with np.errstate(all="ignore"):
            for basis, s in zip(self.bases, self.series):
                B = basis(theta_nl)  # (P, N, L) or ((P, N, L), (P, N))
                C = None
                if isinstance(B, tuple):
                    B, C = B
                kept.append((B, C))
                target = s.y[None, :] if C is None else s.y[None, :] - C
                target = np.broadcast_to(target, (B.shape[0], B.shape[1]))
                G += np.einsum("pnl,pnk->plk", B, B)
                c += np.einsum("pnl,pn->pl", B, target)
        theta_lin = np.full((P, L), np.nan)
        ok = np.all(np.isfinite(G.reshape(P, -1)), axis=1) & np.all(np.isfinite(c), axis=1)
        for p in np.flatnonzero(ok):
            try:
                x = np.linalg.solve(G[p] + 1e-12 * np.trace(G[p]) / L * np.eye(L), c[p])
            except np.linalg.LinAlgError:
                x = np.full(L, np.nan)
            if not (np.all(np.isfinite(x)) and np.all(x >= self.lo_lin) and np.all(x <= self.hi_lin)):
                x = _bounded_solve(G[p], c[p], self.lo_lin, self.hi_lin)
            theta_lin[p] = x
        # residuals recomputed explicitly (not from G, c: that would cancel catastrophically near the floor)
        sse = np.zeros(P)
        with np.errstate(all="ignore"):
            for (B, C), s in zip(kept, self.series):
                e = np.einsum("pnl,pl->pn", B, theta_lin) - s.y[None, :]
                if C is not None:
                    e += C
                sse += np.einsum("pn,pn->p", e, e)
        mse = sse / self.n_total
        return theta_lin, np.where(np.isfinite(mse), mse, np.inf)

    def __call__(self, theta_nl: np.ndarray) -> np.ndarray:
        theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
        self.nfev += theta_nl.shape[0]
        return self.solve(theta_nl)[1]

    def full(self, theta_nl: np.ndarray) -> np.ndarray:
        """Complete θ (P, d) for candidates θ_nl (P, m), with the exact linear part."""
        theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
        theta_lin, _ = self.solve(theta_nl)
        P = theta_lin.shape[0]
        out = np.empty((P, self.d))
        out[:, self.lin] = theta_lin
        if len(self.nl):
            out[:, self.nl] = theta_nl
        return out
