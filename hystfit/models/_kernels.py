"""Compiled recurrences (numba, ``cache=True``).

Layout rule (see ``../shared/PERFORMANCE.md``): the time loop is sequential and outermost,
the population dimension is innermost and contiguous, so LLVM vectorizes across candidates.
Population outputs are written as ``(N, P)`` arrays and handed back transposed as ``(P, N)`` views.
Each variant (serial / parallel) is its own function: numba's cache is keyed on the function,
not on the ``parallel=`` flag.
"""

from __future__ import annotations

import math

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


#: |c·Δv| up to which the series form of the exact Bouc–Wen update is used directly (larger
#: arguments are halved until they fit and the result is squared back, see :func:`_bw_sample`)
_BW_SERIES_MAX = 0.1

#: fastmath flags of the Bouc–Wen kernels: no ``nnan``/``ninf`` (a diverging candidate must stay inf/NaN)
_BW_FASTMATH = {"contract", "arcp", "nsz", "reassoc"}


@njit(cache=True, inline="always", fastmath=_BW_FASTMATH)
def _bw_phi(x):
    """φ(x) = (1 − e^{−x})/x for |x| ≤ 0.1 by its series to x⁷ (error < 3e-14; branch- and call-free)."""
    mx = -x
    return 1.0 + mx * (0.5 + mx * (1.0 / 6 + mx * (1.0 / 24 + mx * (1.0 / 120 + mx * (
        1.0 / 720 + mx * (1.0 / 5040 + mx * (1.0 / 40320)))))))


@njit(cache=True, inline="always", fastmath=_BW_FASTMATH)
def _bw_sample(h, hold, X, F, a, be, ga, du, cabs_max):
    """Advance the Bouc–Wen states ``h`` (m,) of a block of candidates exactly over one input
    segment ``du``, in place (``hold`` receives the previous states).

    In the driven direction s = sgn(Δu) and with g = s·h, v = |Δu|, the equation is
    dg/dv = a − c·g with c = β + γ·sgn(g) (n = 1), solved exactly:
    g₁ = g·e^{−cv} + a·v·φ(cv) = g + (a − c·g)·v·φ(cv),  φ(x) = (1 − e^{−x})/x.
    φ is evaluated branch-free for every candidate at once (contiguous arrays, so LLVM vectorizes
    the loops): by its series when |c·v| ≤ 0.1, otherwise by scaling and squaring — the argument
    is halved ``nsq`` times (one count for the whole block, from ``cabs_max`` = max |c|) and
    φ(2x) = φ(x)·(1 + e^{−x})/2 with e^{−x} = 1 − x·φ(x) is applied ``nsq`` times
    (relative error ≲ 2^nsq · 3e-14). The few candidates whose state changes sign inside the
    segment, or starts exactly at 0 (where the regime is set by the sign of a), are redone by
    :func:`_bw_advance`, which locates the zero crossing exactly. ``X``, ``F`` are scratch (m,).
    """
    m = h.shape[0]
    dv = abs(du)
    s = 1.0 if du > 0.0 else -1.0
    nsq = 0
    v = cabs_max * dv
    while v > _BW_SERIES_MAX and nsq < 64:
        v *= 0.5
        nsq += 1
    nbad = 0
    if nsq == 0:  # the common case near a fit: one pass
        for i in range(m):
            hi = h[i]
            g = s * hi
            c = be[i] + ga[i] * math.copysign(1.0, g)
            g1 = g + (a[i] - c * g) * dv * _bw_phi(c * dv)
            nbad += (g * g1 < 0.0) | (g == 0.0)
            hold[i] = hi
            h[i] = s * g1
    else:
        dvs = dv * 0.5 ** nsq
        for i in range(m):
            g = s * h[i]
            x = (be[i] + ga[i] * math.copysign(1.0, g)) * dvs
            X[i] = x
            F[i] = _bw_phi(x)
        for _ in range(nsq):
            for i in range(m):
                e = 1.0 - X[i] * F[i]
                F[i] = F[i] * (1.0 + e) * 0.5
                X[i] = 2.0 * X[i]
        for i in range(m):
            hi = h[i]
            g = s * hi
            c = be[i] + ga[i] * math.copysign(1.0, g)
            g1 = g + (a[i] - c * g) * dv * F[i]
            nbad += (g * g1 < 0.0) | (g == 0.0)
            hold[i] = hi
            h[i] = s * g1
    if nbad:
        for i in range(m):
            if (hold[i] * h[i] < 0.0) | (hold[i] == 0.0):
                h[i] = _bw_advance(hold[i], du, a[i], be[i], ga[i])


#: what a Bouc–Wen block kernel produces
_BW_STATES, _BW_SSE, _BW_MOMENTS = 0, 1, 2


@njit(cache=True, fastmath=_BW_FASTMATH)
def _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, p0, p1):
    """Bouc–Wen (n = 1, h(0) = 0) over the candidates p0:p1, time loop outside, candidates inside.

    ``mode`` selects the output (one kernel, so the three uses cannot drift apart):

    - ``_BW_STATES``: ``out`` (N, P) receives Kv·u + h + y0 (h alone when ``kv``, ``y0`` are zeros);
    - ``_BW_SSE``: ``out`` (P, 1) receives Σ_k (Kv·u_k + h_k + y0 − y_k)², without storing h;
    - ``_BW_MOMENTS``: ``out`` (P, 4) receives Σh², Σh·u, Σh, Σh·y (for the exact solve of the
      parameters that enter linearly, see :meth:`hystfit.models.bw.BoucWen.separable`).
    """
    N = u.shape[0]
    m = p1 - p0
    h = np.zeros(m)
    hn = np.zeros(m)  # previous states, for the few candidates redone exactly
    X = np.empty(m)
    F = np.empty(m)
    a = alpha[p0:p1].copy()
    be = beta[p0:p1].copy()
    ga = gamma[p0:p1].copy()
    cp = be + ga
    cn = be - ga
    cabs_max = 0.0
    for i in range(m):
        cabs_max = max(cabs_max, abs(cp[i]), abs(cn[i]))
    if not np.isfinite(cabs_max):
        cabs_max = 1e300  # a NaN/inf candidate: the squaring count saturates, its own output is NaN/inf
    acc0 = np.zeros(m)
    acc1 = np.zeros(m)
    acc2 = np.zeros(m)
    acc3 = np.zeros(m)
    if mode != _BW_MOMENTS:
        k_v = kv[p0:p1].copy()
        off = y0[p0:p1].copy()
    else:
        k_v = np.zeros(m)
        off = np.zeros(m)
    for k in range(N):
        if k > 0:
            du = u[k] - u[k - 1]
            if du != 0.0:
                _bw_sample(h, hn, X, F, a, be, ga, du, cabs_max)
        if mode == _BW_STATES:
            uk = u[k]
            for i in range(m):
                out[k, p0 + i] = k_v[i] * uk + h[i] + off[i]
        elif mode == _BW_SSE:
            uk = u[k]
            yk = y[k]
            for i in range(m):
                e = k_v[i] * uk + h[i] + off[i] - yk
                acc0[i] += e * e
        else:
            uk = u[k]
            yk = y[k]
            for i in range(m):
                hi = h[i]
                acc0[i] += hi * hi
                acc1[i] += hi * uk
                acc2[i] += hi
                acc3[i] += hi * yk
    if mode == _BW_SSE:
        for i in range(m):
            out[p0 + i, 0] = acc0[i]
    elif mode == _BW_MOMENTS:
        for i in range(m):
            out[p0 + i, 0] = acc0[i]
            out[p0 + i, 1] = acc1[i]
            out[p0 + i, 2] = acc2[i]
            out[p0 + i, 3] = acc3[i]


@njit(cache=True)
def _bw_serial(u, y, kv, alpha, beta, gamma, y0, mode, out):
    _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, 0, alpha.shape[0])


@njit(cache=True, parallel=True)
def _bw_parallel(u, y, kv, alpha, beta, gamma, y0, mode, out, n_blocks):
    """:func:`_bw_serial` with ``n_blocks`` candidate blocks spread over threads."""
    P = alpha.shape[0]
    size = (P + n_blocks - 1) // n_blocks
    for b in prange(n_blocks):
        p0 = b * size
        p1 = min(P, p0 + size)
        if p0 < p1:
            _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, p0, p1)


#: populations at least this large are spread over threads
PARALLEL_MIN_POP = 64


def _bw_run(u, y, kv, alpha, beta, gamma, y0, mode, out):
    """Run a Bouc–Wen block kernel over the population: threaded for large populations."""
    import numba

    P = alpha.shape[0]
    threads = numba.get_num_threads()
    if P >= PARALLEL_MIN_POP and threads > 1:
        _bw_parallel(u, y, kv, alpha, beta, gamma, y0, mode, out, min(threads, P // 32))
    else:
        _bw_serial(u, y, kv, alpha, beta, gamma, y0, mode, out)
    return out


def _f64(x):
    return np.ascontiguousarray(x, dtype=np.float64)


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
    u = _f64(u)
    alpha, beta, gamma = _f64(alpha), _f64(beta), _f64(gamma)
    out = np.empty((u.shape[0], alpha.shape[0]))
    zero = np.zeros(alpha.shape[0])
    return _bw_run(u, np.empty(0), zero, alpha, beta, gamma, zero, _BW_STATES, out)


def bouc_wen_output(u, kv, alpha, beta, gamma, y0):
    """Bouc–Wen output Kv·u + h + y0 of a population → (N, P) (the caller transposes)."""
    u = _f64(u)
    out = np.empty((u.shape[0], _f64(alpha).shape[0]))
    return _bw_run(u, np.empty(0), _f64(kv), _f64(alpha), _f64(beta), _f64(gamma), _f64(y0), _BW_STATES, out)


#: kept for callers of the former name: same as :func:`bouc_wen_population`
bouc_wen_h = bouc_wen_population


def bouc_wen_sse(u, y, kv, alpha, beta, gamma, y0):
    """Σ_k (Kv·u_k + h_k + y0 − y_k)² per candidate (P,), h from :func:`bouc_wen_population`,
    computed in the time loop without storing the (N, P) outputs."""
    u, y = _f64(u), _f64(y)
    out = np.empty((_f64(alpha).shape[0], 1))
    return _bw_run(u, y, _f64(kv), _f64(alpha), _f64(beta), _f64(gamma), _f64(y0), _BW_SSE, out)[:, 0]


def bouc_wen_moments(u, y, beta, gamma):
    """Per candidate (P, 4): Σg², Σg·u, Σg, Σg·y of the unit-gain state g (α = 1), without storing g."""
    u, y = _f64(u), _f64(y)
    beta, gamma = _f64(beta), _f64(gamma)
    out = np.empty((beta.shape[0], 4))
    z = np.empty(0)
    return _bw_run(u, y, z, np.ones(beta.shape[0]), beta, gamma, z, _BW_MOMENTS, out)


@njit(cache=True)
def bouc_wen_step(h0, u_prev, u_new, alpha, beta, gamma):
    """One Bouc–Wen sample from state h0 for candidate inputs u_new (C,) → new states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    for i in range(C):
        out[i] = _bw_advance(h0, u_new[i] - u_prev, alpha, beta, gamma)
    return out
