"""Variable projection, the optimizer side: the projected objective over the nonlinear parameters,
with the linear ones solved exactly (within their box) for every candidate.

The model side — which parameters enter linearly and their basis — is
:class:`hystfit.models.separable.Separable`.
"""

from __future__ import annotations

import functools
import itertools
from typing import Sequence

import numpy as np

from .._jit import njit
from .._lazy import lazy_module
from ..models.separable import Separable
from ..objective import BLOCK_ELEMENTS, ObjectiveFunction, Series

optimize = lazy_module("scipy.optimize")  # imported on first use: keeps start-up fast


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
    return optimize.lsq_linear(R, rhs, bounds=(lo, hi), method="bvls", tol=1e-12).x


#: up to this many linear parameters, box constraints are handled by exact enumeration (3^L
#: active sets, vectorized over candidates); above it, per candidate by scipy's BVLS
ENUMERATE_MAX_L = 4


def solve_box_qp(G: np.ndarray, c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """argmin_θ θᵀG_pθ − 2c_pᵀθ subject to lo ≤ θ ≤ hi, for a stack of candidates → (P, L).

    G (P, L, L) positive semi-definite, c (P, L). Candidates with non-finite G or c get NaN.
    The unconstrained minimizer is one batched solve (a relative ridge of 1e-12·trace/L keeps
    singular G solvable); only candidates whose solution leaves the box are solved again with
    the bounds: for L ≤ :data:`ENUMERATE_MAX_L` by exact enumeration of the active sets (every
    parameter free, at its lower or at its upper bound; the feasible stationary point of lowest
    objective is the optimum of the convex problem; for L = 2 compiled, :func:`_enumerate_two`),
    otherwise by :func:`_shifted_nnls_solve`.
    """
    P, L = c.shape
    out = np.full((P, L), np.nan)
    ok = np.all(np.isfinite(G.reshape(P, -1)), axis=1) & np.all(np.isfinite(c), axis=1)
    if not np.any(ok) or L == 0:
        return out
    Gk, ck = G[ok], c[ok]
    ridge = 1e-12 * np.maximum(np.trace(Gk, axis1=1, axis2=2) / L, 1e-300)
    Gr = Gk + ridge[:, None, None] * np.eye(L)
    solved = True
    try:
        x = np.linalg.solve(Gr, ck[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a singular block: candidate by candidate
        x = np.stack([np.linalg.lstsq(g, v, rcond=None)[0] for g, v in zip(Gr, ck)])
        solved = False
    bad = ~(np.all(np.isfinite(x), axis=1) & np.all(x >= lo, axis=1) & np.all(x <= hi, axis=1))
    if np.any(bad):
        if L == 2 and solved and np.all(Gr[bad][:, [0, 1], [0, 1]] != 0.0):
            x[bad] = _enumerate_two(Gr[bad], ck[bad], x[bad], lo, hi)
        elif L <= ENUMERATE_MAX_L:
            x[bad] = _enumerate_box_qp(Gr[bad], ck[bad], lo, hi)
        else:
            x[bad] = np.stack([_shifted_nnls_solve(g, v, lo, hi) for g, v in zip(Gk[bad], ck[bad])])
    out[ok] = x
    return out


def _shifted_nnls_solve(G: np.ndarray, c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Box-constrained minimizer of θᵀGθ − 2cᵀθ: non-negative least squares on θ − lo (scipy's
    compiled NNLS, ≈ 13× faster than BVLS at L ≈ 12), which is the exact optimum whenever it
    respects the upper bounds too (the usual case: weights pushed below zero, not above their
    generous upper bounds); otherwise BVLS with both bounds (:func:`_bounded_solve`)."""
    if not np.all(np.isfinite(lo)):
        return _bounded_solve(G, c, lo, hi)
    from scipy.optimize import nnls

    L = G.shape[0]
    ridge = 1e-12 * max(np.trace(G) / L, 1e-300)
    try:
        R = np.linalg.cholesky(G + ridge * np.eye(L)).T
    except np.linalg.LinAlgError:
        return _bounded_solve(G, c, lo, hi)
    q = np.linalg.solve(R.T, c)
    try:
        shift, _ = nnls(R, q - R @ lo)
    except RuntimeError:  # iteration limit
        return _bounded_solve(G, c, lo, hi)
    x = shift + lo
    if np.all(x <= hi):
        return x
    return _bounded_solve(G, c, lo, hi)


@functools.lru_cache(maxsize=None)
def _active_sets(L: int) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """The 3^L active sets of :func:`_enumerate_box_qp` in its order (free indices, fixed indices,
    whether each fixed one sits at its lower bound), built once per L."""
    sets = []
    for pattern in itertools.product((0, 1, 2), repeat=L):  # 0 free, 1 at lower, 2 at upper
        pat = np.asarray(pattern)
        fixed = np.flatnonzero(pat != 0)
        sets.append((np.flatnonzero(pat == 0), fixed, pat[fixed] == 1))
    return tuple(sets)


@functools.lru_cache(maxsize=None)
def _active_set_groups(L: int) -> tuple[np.ndarray, tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]]:
    """The active sets of :func:`_active_sets` as the code of each parameter in each set (3^L, L)
    (0 free, 1 at its lower, 2 at its upper bound) and grouped by their number k of free
    parameters, k ≥ 1: per group (positions in the enumeration order (S,), free indices (S, k),
    fixed indices (S, L − k)), so that a group is solved in one batched call."""
    sets = _active_sets(L)
    codes = np.zeros((len(sets), L), dtype=np.int8)
    by_k: dict[int, list] = {}
    for pos, (free, fixed, at_lo) in enumerate(sets):
        codes[pos, fixed] = np.where(at_lo, 1, 2)
        if free.size:
            by_k.setdefault(free.size, []).append((pos, free, fixed))
    groups = tuple((np.array([g[0] for g in grp]), np.array([g[1] for g in grp], dtype=np.intp).reshape(len(grp), k),
                    np.array([g[2] for g in grp], dtype=np.intp).reshape(len(grp), L - k))
                   for k, grp in sorted(by_k.items()))
    return codes, groups


#: candidates × active sets per batched block of :func:`_enumerate_box_qp` (bounds its memory)
ENUMERATE_BLOCK_ROWS = 1 << 16


def _enumerate_box_qp(G: np.ndarray, c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Exact box-constrained minimizer of θᵀGθ − 2cᵀθ by enumerating the 3^L active sets (small L).

    Every active set fixes some parameters at a bound and solves for the free ones; the feasible
    stationary point of lowest objective (the first in :func:`_active_sets` order on a tie) wins.
    The sets with the same number of free parameters are solved in one batched call
    (:func:`_active_set_groups`): each candidate's arithmetic is that of solving the sets one
    by one, so the result is the same, bit for bit, at a fraction of the Python overhead."""
    P, L = c.shape
    S = 3 ** L
    rows = max(1, ENUMERATE_BLOCK_ROWS // S)
    if P > rows:
        return np.vstack([_enumerate_box_qp(G[i:i + rows], c[i:i + rows], lo, hi) for i in range(0, P, rows)])
    codes, groups = _active_set_groups(L)
    at = np.where(codes == 1, lo, hi)  # (S, L): each set's fixed values (its free entries are solved below)
    X = np.repeat(at[:, None, :], P, axis=1)
    feasible = np.ones((S, P), dtype=bool)
    tol = 1e-12 * (hi - lo)
    cand = np.arange(P)
    for pos, free, fixed in groups:
        sol = _free_solve(G, c, free, fixed, at[pos[:, None], fixed])  # (n_sets, P, k)
        X[pos[:, None, None], cand[None, :, None], free[:, None, :]] = sol
        feasible[pos] = np.all((sol >= (lo - tol)[free][:, None, :]) & (sol <= (hi + tol)[free][:, None, :]), axis=2)
    X = np.clip(X, lo, hi)
    f = _set_objectives(X, G, c)
    f = np.where(feasible & np.isfinite(f), f, np.inf)
    first = np.argmin(f, axis=0)  # the first set of lowest objective, as a strict "<" over the sets in order
    best = np.full((P, L), np.nan)
    take = np.isfinite(f[first, cand])
    best[take] = X[first[take], cand[take]]
    return best


@njit(cache=True)
def _enumerate_two(G, c, x_free, lo, hi):
    """:func:`_enumerate_box_qp` for two linear parameters (gpi's and pi2's ρ, y0), compiled, with
    its numbers bit for bit: the set with both free is ``x_free`` (the batched LAPACK solve of
    :func:`solve_box_qp`, which the enumeration would repeat), one free parameter is a division
    (LAPACK's 1 × 1 solve), and θᵀGθ − 2cᵀθ is summed in the order of numpy's einsum — in
    sequence over (i, j) for several candidates, by rows for one. Needs G_ii ≠ 0."""
    P = c.shape[0]
    out = np.full((P, 2), np.nan)
    lo_ok0, lo_ok1 = lo[0] - 1e-12 * (hi[0] - lo[0]), lo[1] - 1e-12 * (hi[1] - lo[1])
    hi_ok0, hi_ok1 = hi[0] + 1e-12 * (hi[0] - lo[0]), hi[1] + 1e-12 * (hi[1] - lo[1])
    for p in range(P):
        best = np.inf
        for code in range(9):  # itertools.product((0, 1, 2), repeat=2): 0 free, 1 at lower, 2 at upper
            c0, c1 = code // 3, code % 3
            v0 = lo[0] if c0 == 1 else hi[0]
            v1 = lo[1] if c1 == 1 else hi[1]
            if c0 == 0 and c1 == 0:
                v0, v1 = x_free[p, 0], x_free[p, 1]
                if not (lo_ok0 <= v0 <= hi_ok0 and lo_ok1 <= v1 <= hi_ok1):
                    continue
            elif c0 == 0:
                v0 = (c[p, 0] - (0.0 + G[p, 0, 1] * v1)) / G[p, 0, 0]
                if not lo_ok0 <= v0 <= hi_ok0:
                    continue
            elif c1 == 0:
                v1 = (c[p, 1] - (0.0 + G[p, 1, 0] * v0)) / G[p, 1, 1]
                if not lo_ok1 <= v1 <= hi_ok1:
                    continue
            v0 = v0 if v0 > lo[0] else lo[0]  # np.clip
            v0 = v0 if v0 < hi[0] else hi[0]
            v1 = v1 if v1 > lo[1] else lo[1]
            v1 = v1 if v1 < hi[1] else hi[1]
            t00, t01 = (v0 * G[p, 0, 0]) * v0, (v0 * G[p, 0, 1]) * v1
            t10, t11 = (v1 * G[p, 1, 0]) * v0, (v1 * G[p, 1, 1]) * v1
            if P == 1:
                quad = (((0.0 + t00) + t01) + 0.0) + ((0.0 + t10) + t11)
            else:
                quad = (((0.0 + t00) + t01) + t10) + t11
            f = quad - 2.0 * ((0.0 + c[p, 0] * v0) + c[p, 1] * v1)
            if np.isfinite(f) and f < best:
                best = f
                out[p, 0], out[p, 1] = v0, v1
    return out


def _set_objectives(X: np.ndarray, G: np.ndarray, c: np.ndarray) -> np.ndarray:
    """θᵀGθ − 2cᵀθ (S, P) at the points X (S, P, L) of every active set, each summed as numpy's
    einsum sums it for one set's (P, L) points (for P = 1 it sums in another order with a
    candidate axis of several rows: then set by set)."""
    S, P, L = X.shape
    if P == 1:
        return np.stack([np.einsum("pi,pij,pj->p", x, G, x) - 2.0 * np.einsum("pi,pi->p", c, x) for x in X])
    Xs = X.reshape(S * P, L)
    Gs, cs = np.concatenate((G,) * S), np.concatenate((c,) * S)
    return (np.einsum("pi,pij,pj->p", Xs, Gs, Xs) - 2.0 * np.einsum("pi,pi->p", cs, Xs)).reshape(S, P)


def _free_solve(G: np.ndarray, c: np.ndarray, free: np.ndarray, fixed: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The free parameters (S, P, k) of S active sets with k free parameters each (``free``
    (S, k); ``fixed`` (S, L − k) at the values ``at`` (S, L − k)): G_ff θ_f = c_f − G_fx θ_x in
    one batched solve, or set by set where a block is singular (least squares). A single free
    parameter is a division (what LAPACK's solve computes for a 1 × 1 system, bit for bit)."""
    n_sets, k = free.shape
    P = c.shape[0]
    m = fixed.shape[1]
    rhs = c[:, free].transpose(1, 0, 2).reshape(n_sets * P, k)
    if m:  # c_f − 0 = c_f exactly: no product when every parameter is free
        # the operands in the memory layout of one set's fancy-indexed G[:, free][:, :, fixed] and
        # x[:, fixed] (candidates innermost; for one candidate, each G block column-major): numpy's
        # einsum then sums in the same order (its loops differ with the layout, some fuse multiply-adds)
        G_fx = G[:, free[:, :, None], fixed[:, None, :]].transpose(1, 0, 2, 3).reshape(n_sets * P, k, m)
        if P == 1:
            G_fx, x_fx = np.ascontiguousarray(G_fx.transpose(0, 2, 1)).transpose(0, 2, 1), at
        else:
            G_fx, x_fx = np.asfortranarray(G_fx), np.asfortranarray(np.repeat(at, P, axis=0))
        rhs = rhs - np.einsum("pij,pj->pi", G_fx, x_fx)
    G_ff = G[:, free[:, :, None], free[:, None, :]].transpose(1, 0, 2, 3).reshape(n_sets * P, k, k)
    if k == 1 and np.all(G_ff != 0.0):  # (a zero pivot: LAPACK's singular error, handled below)
        return (rhs / G_ff[:, :, 0]).reshape(n_sets, P, 1)
    try:
        return np.linalg.solve(G_ff, rhs[:, :, None])[:, :, 0].reshape(n_sets, P, k)
    except np.linalg.LinAlgError:
        pass
    G_ff, rhs = G_ff.reshape(n_sets, P, k, k), rhs.reshape(n_sets, P, k)
    out = np.empty((n_sets, P, k))
    for s in range(n_sets):
        try:
            out[s] = np.linalg.solve(G_ff[s], rhs[s][:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            out[s] = np.stack([np.linalg.lstsq(g, v, rcond=None)[0] for g, v in zip(G_ff[s], rhs[s])])
    return out


class ProjectedObjective(ObjectiveFunction):
    """MSE over θ_nl with θ_lin solved exactly per candidate (pooled over captures).

    ``__call__(Θ_nl (P, m)) → (P,)``; :meth:`full` returns the complete θ (P, d) of the last
    solved candidates, so the winner can be turned back into a full parameter vector.
    """

    def __init__(self, sep: Separable, series: Sequence[Series], lower: np.ndarray, upper: np.ndarray) -> None:
        self.sep = sep
        self.series = list(series)
        self.bases = [sep.basis_factory(s.u, s.dt) for s in self.series]
        self.grams = ([sep.gram_factory(s.u, s.dt, s.y) for s in self.series]
                      if sep.gram_factory is not None else None)
        # a warm-up (Series.skip) leaves the first samples out: their normal equations are
        # subtracted (exact for causal models), the explicit bases are sliced
        self.prefix_grams = ([sep.gram_factory(s.u[:s.skip], s.dt, s.y[:s.skip]) for s in self.series if s.skip]
                             if sep.gram_factory is not None else [])
        self.lin = np.asarray(sep.linear, dtype=int)
        self.nl = np.asarray(sep.nonlinear, dtype=int)
        self.lo_lin, self.hi_lin = lower[self.lin], upper[self.lin]
        self.d = len(self.lin) + len(self.nl)
        self.n_total = int(sum(s.y.shape[0] - s.skip for s in self.series))
        self.nfev = 0

    def solve(self, theta_nl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best θ_lin for each candidate and the resulting MSE: ((P, L), (P,)).

        Candidates are processed in blocks so the basis (block, N, L) stays within
        :data:`hystfit.objective.BLOCK_ELEMENTS` elements: memory is bounded for long captures.
        """
        theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
        P = theta_nl.shape[0] if len(self.nl) else 1
        L = max(len(self.lin), 1)
        n_max = max(s.y.shape[0] for s in self.series)
        block = max(1, BLOCK_ELEMENTS // (n_max * (L + 1) * max(len(self.series), 1)))
        if self.sep.fused(self.series):
            block = P  # the fused normal equations need O(P·L²) memory only
        if P <= block:
            return self._solve_block(theta_nl)
        lins, mses = zip(*(self._solve_block(theta_nl[i:i + block]) for i in range(0, P, block)))
        return np.vstack(lins), np.concatenate(mses)

    def _solve_block(self, theta_nl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = theta_nl.shape[0] if len(self.nl) else 1
        L = len(self.lin)
        G = np.zeros((P, L, L))
        c = np.zeros((P, L))
        yy = 0.0
        kept = []
        with np.errstate(all="ignore"):
            for gram in (self.grams or ()):
                g_p, c_p, yy_p = gram(theta_nl)
                G += g_p
                c += c_p
                yy += yy_p
            for gram in (self.prefix_grams if self.grams is not None else ()):
                g_p, c_p, yy_p = gram(theta_nl)
                G -= g_p
                c -= c_p
                yy -= yy_p
            for basis, s in zip(self.bases if self.grams is None else (), self.series):
                B = basis(theta_nl)  # (P, N, L) or ((P, N, L), (P, N))
                C = None
                if isinstance(B, tuple):
                    B, C = B
                    C = C[:, s.skip:]
                B = B[:, s.skip:, :]
                kept.append((B, C))
                target = s.y[None, s.skip:] if C is None else s.y[None, s.skip:] - C
                target = np.broadcast_to(target, (B.shape[0], B.shape[1]))
                Bt = B.transpose(0, 2, 1)
                G += Bt @ B
                c += (Bt @ target[:, :, None])[:, :, 0]
        theta_lin = solve_box_qp(G, c, self.lo_lin, self.hi_lin)
        if self.grams is not None:
            # Σ(Bθ − y)² = yᵀy − 2cᵀθ + θᵀGθ of the θ actually used (rounding ≈ 3·eps·yᵀy whatever
            # the conditioning of G: ~1e-10 relative to the noise floor of a 16-bit sensor)
            with np.errstate(all="ignore"):
                sse = yy - 2.0 * np.einsum("pl,pl->p", c, theta_lin) + np.einsum("pl,plk,pk->p", theta_lin, G,
                                                                                 theta_lin)
            mse = np.maximum(sse, 0.0) / self.n_total
            return theta_lin, np.where(np.isfinite(mse), mse, np.inf)
        # residuals recomputed explicitly from the stored basis
        sse = np.zeros(P)
        with np.errstate(all="ignore"):
            for (B, C), s in zip(kept, self.series):
                e = (B @ theta_lin[:, :, None])[:, :, 0] - s.y[None, s.skip:]
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
