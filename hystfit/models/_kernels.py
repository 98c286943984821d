"""Compiled recurrences (numba, ``cache=True``).

Layout rule (see ``../shared/PERFORMANCE.md``): the time loop is sequential and outermost,
the population dimension is innermost and contiguous, so LLVM vectorizes across candidates.
Population outputs are written as ``(N, P)`` arrays and handed back transposed as ``(P, N)`` views.
Each variant (serial / parallel) is its own function: numba's cache is keyed on the function,
not on the ``parallel=`` flag.
"""

from __future__ import annotations

import numpy as np
from .._jit import njit, prange


@njit(cache=True)
def play_matrix(u, r):
    """Play-operator outputs of one input for several thresholds.

    F_r[u](k) = max(u_k − r, min(u_k + r, F_r[u](k−1))), initial state
    max(u_0 − r, min(u_0 + r, 0)) (paper 003 eq. 1–2; ``../shared/papers/README.md``).

    Parameters
    ----------
    u : (N,) float64 input (V).
    r : (n,) float64 thresholds (V), r ≥ 0.

    Returns
    -------
    (N, n) float64 operator outputs (V).
    """
    N = u.shape[0]
    n = r.shape[0]
    out = np.empty((N, n))
    if N == 0:
        return out
    for j in range(n):
        out[0, j] = max(u[0] - r[j], min(u[0] + r[j], 0.0))
    for k in range(1, N):
        uk = u[k]
        for j in range(n):
            prev = out[k - 1, j]
            out[k, j] = max(uk - r[j], min(uk + r[j], prev))
    return out


@njit(cache=True)
def play_matrix_from(u, r, state0):
    """Like :func:`play_matrix` but starting from given operator states ``state0`` (n,)."""
    N = u.shape[0]
    n = r.shape[0]
    out = np.empty((N, n))
    if N == 0:
        return out
    for k in range(N):
        uk = u[k]
        for j in range(n):
            prev = state0[j] if k == 0 else out[k - 1, j]
            out[k, j] = max(uk - r[j], min(uk + r[j], prev))
    return out


@njit(cache=True, inline="always")
def _bw_segment(h, dv, a, c):
    """Exact solution of dh/dv = a − c·h over an interval dv ≥ 0 (c may be 0 or negative)."""
    x = c * dv
    if abs(x) < 1e-8:
        return h + (a - c * h) * dv
    e = np.exp(-x)
    return h * e + a * (1.0 - e) / c


@njit(cache=True, inline="always")
def _bw_advance(h, du, a, beta, gamma):
    """Advance the Bouc–Wen state h (n = 1) exactly over one straight input segment du."""
    if du == 0.0:
        return h
    dv = abs(du)
    s = 1.0 if du > 0.0 else -1.0
    # In terms of g = s·h (the driven direction is positive):
    # dg/dv = a − β g − γ |g|  →  g ≥ 0: c = β + γ ;  g < 0: c = β − γ
    g = s * h
    c_pos = beta + gamma
    c_neg = beta - gamma
    # at g = 0 the regime is the one the solution moves into (sign of a)
    c = c_pos if (g > 0.0 or (g == 0.0 and a >= 0.0)) else c_neg
    g1 = _bw_segment(g, dv, a, c)
    if g != 0.0 and (g > 0.0) != (g1 > 0.0):
        # crossed zero: locate v* with g(v*) = 0 in this regime, continue in the other one
        if abs(c) * dv < 1e-8:
            vz = -g / a if a != 0.0 else dv
        else:
            ratio = a / (a - c * g)
            vz = -np.log(ratio) / c if ratio > 0.0 else dv
        vz = min(max(vz, 0.0), dv)
        c2 = c_pos if a >= 0.0 else c_neg
        g1 = _bw_segment(0.0, dv - vz, a, c2)
    return s * g1


#: |c·Δv| below which the exact Bouc–Wen update uses its (exact to 1e-13) series form
_BW_SERIES_MAX = 0.1


@njit(cache=True, inline="always", fastmath={"contract", "arcp", "nsz", "reassoc"})
def _bw_series_update(g, dv, a, c):
    """g·e^{−x} + a·dv·φ(x), x = c·dv, φ(x) = (1 − e^{−x})/x, by Horner (|x| ≤ 0.1: error < 3e-13)."""
    x = c * dv
    # e^{-x} = Σ (−x)^k / k!,  φ(x) = Σ (−x)^k / (k+1)!   (k = 0..8)
    e = 1.0 + (-x) * (1.0 + (-x) * (0.5 + (-x) * (1.0 / 6 + (-x) * (1.0 / 24 + (-x) * (1.0 / 120 + (-x) * (
        1.0 / 720 + (-x) * (1.0 / 5040 + (-x) * (1.0 / 40320))))))))
    phi = 1.0 + (-x) * (0.5 + (-x) * (1.0 / 6 + (-x) * (1.0 / 24 + (-x) * (1.0 / 120 + (-x) * (1.0 / 720 + (-x) * (
        1.0 / 5040 + (-x) * (1.0 / 40320 + (-x) * (1.0 / 362880))))))))
    return g * e + a * dv * phi


@njit(cache=True, fastmath={"contract", "arcp", "nsz", "reassoc"})
def _bw_block(u, alpha, beta, gamma, out, p0, p1):
    """Bouc–Wen over candidates p0:p1 (see :func:`bouc_wen_population`).

    Per sample, pass 1 is branch-free and call-free on contiguous 1-D state arrays (LLVM
    vectorizes it across candidates): the exact update in series form, assuming no sign change
    of h and |c·Δv| ≤ 0.1. Pass 2 redoes exactly, with exp/log, the few candidates where that
    assumption failed.
    """
    N = u.shape[0]
    m = p1 - p0
    h = np.zeros(m)
    hn = np.empty(m)
    bad = np.empty(m, dtype=np.uint8)
    a = alpha[p0:p1].copy()
    cp = beta[p0:p1] + gamma[p0:p1]
    cn = beta[p0:p1] - gamma[p0:p1]
    for i in range(m):
        out[0, p0 + i] = 0.0
    for k in range(1, N):
        du = u[k] - u[k - 1]
        if du != 0.0:
            dv = abs(du)
            s = 1.0 if du > 0.0 else -1.0
            nbad = 0
            for i in range(m):
                g = s * h[i]
                c = cp[i] if (g > 0.0) | ((g == 0.0) & (a[i] >= 0.0)) else cn[i]
                g1 = _bw_series_update(g, dv, a[i], c)
                b = (abs(c * dv) > _BW_SERIES_MAX) | ((g != 0.0) & ((g > 0.0) != (g1 > 0.0)))
                bad[i] = b
                nbad += b
                hn[i] = s * g1
            if nbad:
                for i in range(m):
                    if bad[i]:
                        hn[i] = _bw_advance(h[i], du, a[i], beta[p0 + i], gamma[p0 + i])
            for i in range(m):
                h[i] = hn[i]
        for i in range(m):
            out[k, p0 + i] = h[i]


@njit(cache=True)
def bouc_wen_population(u, alpha, beta, gamma):
    """Bouc–Wen hysteretic state h for a population, exponent n = 1, exact per sample.

    ḣ = α u̇ − β |u̇| h − γ u̇ |h|  (paper 004 eq. 2), h(0) = 0.

    The model is rate independent, so h is integrated in the input variable along each
    sample's straight-line input segment. For n = 1 and a fixed sign of u̇ and of h the
    equation is linear, dh/dv = a − c h with v = |Δu|, and is solved exactly; a sign change
    of h inside a segment is located exactly and the segment is split there. No sub-steps,
    no step-size limit: stable at any sample rate.

    Parameters
    ----------
    u : (N,) input (V).  alpha, beta, gamma : (P,) parameters (α in output/V, β, γ in 1/V).

    Returns
    -------
    (N, P) array of h (output units); the caller transposes.
    """
    P = alpha.shape[0]
    out = np.empty((u.shape[0], P))
    _bw_block(u, alpha, beta, gamma, out, 0, P)
    return out


@njit(cache=True, parallel=True)
def bouc_wen_population_parallel(u, alpha, beta, gamma, n_blocks):
    """:func:`bouc_wen_population` with ``n_blocks`` candidate blocks spread over threads."""
    P = alpha.shape[0]
    out = np.empty((u.shape[0], P))
    size = (P + n_blocks - 1) // n_blocks
    for b in prange(n_blocks):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _bw_block(u, alpha, beta, gamma, out, p0, p1)
    return out


@njit(cache=True)
def bouc_wen_step(h0, u_prev, u_new, alpha, beta, gamma):
    """One Bouc–Wen sample from state h0 for candidate inputs u_new (C,) → new states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    for i in range(C):
        out[i] = _bw_advance(h0, u_new[i] - u_prev, alpha, beta, gamma)
    return out


#: populations at least this large are spread over threads
PARALLEL_MIN_POP = 64


def bouc_wen_h(u, alpha, beta, gamma):
    """Dispatch: the threaded kernel for large populations, the serial one otherwise → (N, P)."""
    import numba

    P = alpha.shape[0]
    threads = numba.get_num_threads()
    if P >= PARALLEL_MIN_POP and threads > 1:
        return bouc_wen_population_parallel(u, alpha, beta, gamma, min(threads, P // 32))
    return bouc_wen_population(u, alpha, beta, gamma)
