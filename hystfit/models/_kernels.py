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
from .._jit import fma, njit, numba_loaded, prange, readonly


#: below this many operator outputs (N · n) per call, play operators are computed with numpy (a few
#: ms) instead of loading numba (≈ 0.6 s of import and context the first time in a process)
NUMPY_PLAY_MAX = 250_000
#: … until the numpy route has done this many outputs in the process (≈ 0.3 s of work): from then
#: on numba pays off, and once numba is loaded for any kernel it is always used
NUMPY_PLAY_BUDGET = 2_500_000
_numpy_play_done = 0


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
    r = np.ascontiguousarray(r, dtype=np.float64)
    return play_matrix_from(u, r, np.zeros(r.shape[0]))


def play_matrix_from(u, r, state0):
    """Like :func:`play_matrix` but starting from given operator states ``state0`` (n,).

    Two routes give the same bits: the numba recurrence (:func:`_play_recurrence`), and for a small
    call in a process that has not loaded numba, :func:`_play_scan` (numpy), so that a command
    that only needs a few play operators (a PI fit of a short capture) never pays numba's start-up.
    """
    global _numpy_play_done
    u, r, state0 = readonly(u), readonly(r), readonly(state0)
    size = u.shape[0] * r.shape[0]
    if (not numba_loaded() and size <= NUMPY_PLAY_MAX and _numpy_play_done + size <= NUMPY_PLAY_BUDGET
            and np.isfinite(u).all()):
        _numpy_play_done += size
        return _play_scan(u, r, state0)
    return _play_recurrence(u, r, state0)


def _play_scan(u, r, state0):
    """Play operators as a prefix composition of clamps, in numpy (O(N log N · n), no time loop).

    Sample k maps the previous output y to clamp(y, u_k − r, u_k + r); two clamps compose into a
    clamp whose bounds are the first's clipped to the second's, so the composition of samples
    0 … k is found in ⌈log₂ N⌉ doubling passes and applied to ``state0``. Only min and max act on
    u_k ± r, so every output is bit-identical to the recurrence's.
    """
    lo = u[:, None] - r[None, :]
    hi = u[:, None] + r[None, :]
    step = 1
    while step < u.shape[0]:
        a, b = lo[step:], hi[step:]
        new_lo = np.minimum(np.maximum(lo[:-step], a), b)
        new_hi = np.minimum(np.maximum(hi[:-step], a), b)
        lo[step:], hi[step:] = new_lo, new_hi
        step *= 2
    return np.maximum(lo, np.minimum(hi, state0[None, :]))


@njit(cache=True)
def _play_recurrence(u, r, state0):
    """The play operators' recurrence, sample by sample (see :func:`play_matrix`)."""
    N = u.shape[0]
    n = r.shape[0]
    out = np.empty((N, n))
    if N == 0:
        return out
    for j in range(n):
        out[0, j] = max(u[0] - r[j], min(u[0] + r[j], state0[j]))
    for k in range(1, N):
        uk = u[k]
        for j in range(n):
            out[k, j] = max(uk - r[j], min(uk + r[j], out[k - 1, j]))
    return out


@njit(cache=True)
def _bw_segment(h, dv, a, c):
    """Exact solution of dh/dv = a − c·h over an interval dv ≥ 0 (c may be 0 or negative)."""
    x = c * dv
    if abs(x) < 1e-8:
        return h + (a - c * h) * dv
    e = np.exp(-x)
    return h * e + a * (1.0 - e) / c


@njit(cache=True)
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


#: |c·Δv| up to which the series of degree 7 in c·Δv is used (truncation error < 3e-14)
_BW_SERIES_MAX = 0.1

#: |c·Δv| up to which the series of degree 11 is used (truncation error < 6e-16); larger
#: arguments are halved until they fit and the result is squared back (see :func:`_bw_block`)
_BW_SERIES11_MAX = 0.35

# The Bouc–Wen kernels write their multiply–adds as explicit fused operations (:data:`fma`) and
# use no fastmath flags: a compiler that fuses or reorders by itself does so differently in each
# context a helper is compiled in (alone, or inlined into each caller), and the last bits then
# depended on which compiled copy a process ran (see :class:`hystfit._jit._Fma`).
#
# Compile time (a first run after installing compiles them; the test suite on a clean checkout
# too). numba's IR-level inlining (``inline="always"``) deep-copies the callee's IR at every call
# site, block by block and each block with the whole variable scope, a cost that grows faster
# than the callee's size: with the whole time loop inlined into the block kernel once per mode,
# compiling that kernel took ≈ 45 s, and the serial and threaded callers each compiled their own
# (``_bw_serial`` passed p0 as a literal 0, another argument type).
# Now: the time loop is one kernel compiled once per ``mode`` (a constant at each call: numba
# types it as a literal and makes one specialisation per value, whose mode tests LLVM folds);
# the helpers called once per sample or less are plain kernels, which LLVM inlines or calls (the
# same IEEE operations, so the same bits); numba inlines only the helpers of the candidate loops
# (``_bw_candidate``, ``_bw_take``, ``_bw_next*``, ``_bw_neg``); and the serial variant is
# :func:`_bw_block` itself, called from Python. The candidate loops' helpers stay numba-inlined
# because a process runs a kernel as compiled alone when it compiled it, and the copy optimised
# again inside its caller when it loaded the caller from the cache: with ``_bw_next*`` and
# ``_bw_neg`` left to LLVM, the time loop compiled alone did not vectorize (measured; the likely
# cause: what LLVM leaves of numba's calling convention after one optimisation), and a first
# run's Bouc–Wen evaluations took 2.5–3× as long.


@njit(cache=True)
def _bw_phi11(x):
    """φ(x) = (1 − e^{−x})/x for |x| ≤ 0.35 by its series to x¹¹ (error < 6e-16)."""
    mx = -x
    r = fma(mx, 1.0 / 479001600, 1.0 / 39916800)  # Horner, one fused multiply–add per degree
    r = fma(mx, r, 1.0 / 3628800)
    r = fma(mx, r, 1.0 / 362880)
    r = fma(mx, r, 1.0 / 40320)
    r = fma(mx, r, 1.0 / 5040)
    r = fma(mx, r, 1.0 / 720)
    r = fma(mx, r, 1.0 / 120)
    r = fma(mx, r, 1.0 / 24)
    r = fma(mx, r, 1.0 / 6)
    r = fma(mx, r, 0.5)
    return fma(mx, r, 1.0)


@njit(cache=True)
def _bw_coefs7(dv):
    """q_j = dv^{j+1}/(j+1)!, j = 0..7: ψ(c) = dv·φ(c·dv) = Σ_j (−c)^j·q_j."""
    q0 = dv
    q1 = q0 * dv * (1.0 / 2)
    q2 = q1 * dv * (1.0 / 3)
    q3 = q2 * dv * (1.0 / 4)
    q4 = q3 * dv * (1.0 / 5)
    q5 = q4 * dv * (1.0 / 6)
    q6 = q5 * dv * (1.0 / 7)
    q7 = q6 * dv * (1.0 / 8)
    return (q0, q1, q2, q3, q4, q5, q6, q7)


@njit(cache=True)
def _bw_coefs11(q, dv):
    """q_j = dv^{j+1}/(j+1)!, j = 0..11, from those to j = 7 (``q``)."""
    q8 = q[7] * dv * (1.0 / 9)
    q9 = q8 * dv * (1.0 / 10)
    q10 = q9 * dv * (1.0 / 11)
    q11 = q10 * dv * (1.0 / 12)
    return (q[0], q[1], q[2], q[3], q[4], q[5], q[6], q[7], q8, q9, q10, q11)


@njit(cache=True, inline="always")
def _bw_neg(x):
    """Sign bit of x (set for −0.0): compiles to a bit test, not a floating-point comparison."""
    return math.copysign(1.0, x) < 0.0


@njit(cache=True, inline="always")
def _bw_next7(h, mcp, mcn, sa, q):
    """Exact Bouc–Wen update of one state h over one input segment, branch-free.

    With s = sgn(Δu), v = |Δu|, the equation along the segment is dh/dv = s·a − c·h with
    c = β + s·γ·sgn(h) (n = 1), solved exactly: h₁ = h + (s·a − c·h)·ψ, ψ = v·φ(c·v) =
    (1 − e^{−cv})/c. −c is ``mcp`` = −(β + sγ) for h ≥ +0 and ``mcn`` = −(β − sγ) for h ≤ −0
    (by the sign bit, as the exact redo reads the sign of a zero state); ``sa`` = s·a.
    ψ by its series Σ_j (−c)^j·q_j to degree 7 (q from :func:`_bw_coefs7`; :func:`_bw_next11`:
    degree 11, :func:`_bw_next0`: ψ computed beforehand). Valid while the sign bit of h does
    not change; the caller redoes the other candidates.
    """
    mc = mcn if _bw_neg(h) else mcp
    f = q[7]
    for j in (6, 5, 4, 3, 2, 1, 0):  # Horner, one fused multiply–add per degree
        f = fma(mc, f, q[j])
    return fma(fma(mc, h, sa), f, h)


@njit(cache=True, inline="always")
def _bw_next11(h, mcp, mcn, sa, q):
    """:func:`_bw_next7` with the series of ψ to degree 11 (q from :func:`_bw_coefs11`)."""
    mc = mcn if _bw_neg(h) else mcp
    f = fma(mc, fma(mc, fma(mc, fma(mc, q[11], q[10]), q[9]), q[8]), q[7])
    for j in (6, 5, 4, 3, 2, 1, 0):
        f = fma(mc, f, q[j])
    return fma(fma(mc, h, sa), f, h)


@njit(cache=True, inline="always")
def _bw_next0(h, mcp, mcn, sa, psi):
    """:func:`_bw_next7` with ψ = ``psi`` computed beforehand (:func:`_bw_psi_halved`)."""
    mc = mcn if _bw_neg(h) else mcp
    return fma(fma(mc, h, sa), psi, h)


#: what a Bouc–Wen block kernel produces
_BW_STATES, _BW_SSE, _BW_MOMENTS = 0, 1, 2



@njit(cache=True, inline="always")
def _bw_regimes(alpha, beta, gamma, p0, p1):
    """Per-block constants of :func:`_bw_block` for the candidates p0:p1.

    Returns a, β, γ (copies), per input direction j (0: s = +1, 1: s = −1) s·a and −c for
    h ≥ +0 (``mcp``) / h ≤ −0 (``mcn``), and the largest |c| (1e300 when a candidate is NaN/inf:
    the squaring count saturates and that candidate's own output is NaN/inf).
    """
    m = p1 - p0
    a = alpha[p0:p1].copy()
    be = beta[p0:p1].copy()
    ga = gamma[p0:p1].copy()
    cabs_max = 0.0
    for i in range(m):
        cabs_max = max(cabs_max, abs(be[i] + ga[i]), abs(be[i] - ga[i]))
    if not np.isfinite(cabs_max):
        cabs_max = 1e300
    sa = np.empty((2, m))
    mcp = np.empty((2, m))
    mcn = np.empty((2, m))
    for i in range(m):
        sa[0, i] = a[i]
        sa[1, i] = -a[i]
        mcp[0, i] = -(be[i] + ga[i])
        mcn[0, i] = -(be[i] - ga[i])
        mcp[1, i] = -(be[i] - ga[i])
        mcn[1, i] = -(be[i] + ga[i])
    return a, be, ga, sa, mcp, mcn, cabs_max


@njit(cache=True)
def _bw_series_kind(xmax, dv):
    """Series of ψ for a sample whose largest argument is ``xmax`` = max|c|·Δv: 7, 11 or 0 (halving)."""
    kind = 7 if xmax <= _BW_SERIES_MAX else (11 if xmax <= _BW_SERIES11_MAX else 0)
    if dv > 1e20:
        kind = 0  # keep the powers of dv in the series coefficients finite
    return kind


@njit(cache=True)
def _bw_psi_halved(F, X, H, c, mcp, mcn, j, dv, xmax):
    """ψ = Δv·φ(c·Δv) per candidate into ``F`` for a large argument: c·Δv is halved ``nsq`` times
    to ≤ 0.35, φ by :func:`_bw_phi11`, then φ(2x) = φ(x)·(1 + e^{−x})/2 with e^{−x} = 1 − x·φ(x)
    is applied ``nsq`` times (relative error ≲ 2^nsq · 1e-16)."""
    m = F.shape[0]
    nsq = 0
    v = xmax
    while v > _BW_SERIES11_MAX and nsq < 64:
        v *= 0.5
        nsq += 1
    dvs = dv * 0.5 ** nsq
    for i in range(m):
        x = -(mcn[j, i] if _bw_neg(H[c, i]) else mcp[j, i]) * dvs
        X[i] = x
        F[i] = _bw_phi11(x)
    for _ in range(nsq):
        for i in range(m):
            e = fma(-X[i], F[i], 1.0)
            F[i] = F[i] * (1.0 + e) * 0.5
            X[i] = 2.0 * X[i]
    for i in range(m):
        F[i] *= dv


@njit(cache=True, inline="always")
def _bw_take(mode, i, kvi, hn, offi, bad, uk, yk, acc, out, k, p0):
    """Add candidate i's contribution at sample k (state ``hn``, Kv ``kvi``, offset ``offi``) to
    the kernel's output (``mode``); a ``bad`` state (wrong regime, redone later) adds nothing
    to the sums (every multiply–add one fused operation: :data:`fma`)."""
    if mode == _BW_SSE:
        e = 0.0 if bad else fma(kvi, uk, hn) + offi - yk
        acc[0][i] = fma(e, e, acc[0][i])
    elif mode == _BW_MOMENTS:
        hm = 0.0 if bad else hn
        acc[0][i] = fma(hm, hm, acc[0][i])
        acc[1][i] = fma(hm, uk, acc[1][i])
        acc[2][i] += hm
        acc[3][i] = fma(hm, yk, acc[3][i])
    else:  # an unsigned column index: no test for a negative one in the candidate loop
        out[k, np.uint64(p0) + np.uint64(i)] = fma(kvi, uk, hn) + offi


@njit(cache=True, inline="always")
def _bw_candidate(mode, kind, i, H, c, sa, mcp, mcn, j, q, F, uk, yk, k_v, off, acc, out, k, p0):
    """Advance candidate i by one sample (:func:`_bw_next7`, :func:`_bw_next11` or
    :func:`_bw_next0` by the series ``kind``, a constant at each call) from row c of ``H`` into row 1 − c and add its contribution (:func:`_bw_take`); True when its state changed its
    sign bit (then it is left out of the sums and redone)."""
    hi = H[c, i]
    if kind == 7:
        hn = _bw_next7(hi, mcp[j, i], mcn[j, i], sa[j, i], q)
    elif kind == 11:
        hn = _bw_next11(hi, mcp[j, i], mcn[j, i], sa[j, i], q)
    else:
        hn = _bw_next0(hi, mcp[j, i], mcn[j, i], sa[j, i], F[i])
    H[1 - c, i] = hn
    bad = _bw_neg(hi) != _bw_neg(hn)
    _bw_take(mode, i, k_v[i], hn, off[i], bad, uk, yk, acc, out, k, p0)
    return bad


@njit(cache=True)
def _bw_time_loop(mode, u, y, H, X, F, a, be, ga, sa, mcp, mcn, cabs_max, k_v, off, acc, out, p0):
    """The time loop of :func:`_bw_block`, compiled once per ``mode``: the callers pass it as a
    constant, which numba types as a literal (one specialisation per value, in which the mode
    tests are constants), so every candidate loop is specialised. Arrays are handed to helpers
    only outside the time loop and inside the candidate loops (where numba prunes the reference
    counting); the one exception, :func:`_bw_psi_halved`, runs only for large input steps."""
    m = F.shape[0]
    c = np.int64(0)  # not a literal 0: helpers are compiled for one type of row index
    has_y = mode != _BW_STATES
    for k in range(u.shape[0]):
        uk = u[k]
        yk = y[k] if has_y else 0.0
        du = uk - u[k - 1] if k > 0 else 0.0
        if du == 0.0:  # no input change (or k = 0): the states stay
            for i in range(m):
                _bw_take(mode, i, k_v[i], H[c, i], off[i], False, uk, yk, acc, out, k, p0)
            continue
        dv = abs(du)
        j = 0 if du > 0.0 else 1
        xmax = cabs_max * dv
        kind = _bw_series_kind(xmax, dv)
        q7 = _bw_coefs7(dv if kind != 0 else 0.0)
        q11 = _bw_coefs11(q7, dv if kind == 11 else 0.0)
        nbad = False
        if kind == 7:
            for i in range(m):
                nbad |= _bw_candidate(mode, 7, i, H, c, sa, mcp, mcn, j, q7, F, uk, yk, k_v, off, acc, out, k, p0)
        elif kind == 11:
            for i in range(m):
                nbad |= _bw_candidate(mode, 11, i, H, c, sa, mcp, mcn, j, q11, F, uk, yk, k_v, off, acc, out, k, p0)
        else:
            _bw_psi_halved(F, X, H, c, mcp, mcn, j, dv, xmax)
            for i in range(m):
                nbad |= _bw_candidate(mode, 0, i, H, c, sa, mcp, mcn, j, q7, F, uk, yk, k_v, off, acc, out, k, p0)
        d = 1 - c
        if nbad:  # the few candidates whose state changed its sign bit: redo exactly
            for i in range(m):
                hi = H[c, i]
                if _bw_neg(hi) != _bw_neg(H[d, i]):
                    hn = _bw_advance(hi, du, a[i], be[i], ga[i])
                    H[d, i] = hn
                    _bw_take(mode, i, k_v[i], hn, off[i], False, uk, yk, acc, out, k, p0)
        c = d


@njit(cache=True)
def _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, p0, p1):
    """Bouc–Wen (n = 1, h(0) = 0) over the candidates p0:p1, time loop outside, candidates inside.

    ``mode`` selects the output (one kernel, so the three uses cannot drift apart):

    - ``_BW_STATES``: ``out`` (N, P) receives Kv·u + h + y0 (h alone when ``kv``, ``y0`` are zeros);
    - ``_BW_SSE``: ``out`` (P, 1) receives Σ_k (Kv·u_k + h_k + y0 − y_k)², without storing h;
    - ``_BW_MOMENTS``: ``out`` (P, 4) receives Σh², Σh·u, Σh, Σh·y (for the exact solve of the
      parameters that enter linearly, see :meth:`hystfit.models.bw.BoucWen.separable`).

    Per sample (:func:`_bw_time_loop`), every candidate's state is advanced exactly by
    :func:`_bw_next7` (or its degree-11 and halved-ψ variants) and its contribution to the output is added in the same loop
    (:func:`_bw_candidate`; contiguous arrays, branch-free: the loops vectorize across
    candidates). ψ comes from one series chosen for the whole block by the largest argument
    max|c|·|Δu|: degree 7 up to 0.1, degree 11 up to 0.35; beyond, :func:`_bw_psi_halved`. A
    candidate whose state changes its sign bit in the segment has used the wrong regime (or, from
    a zero state, the regime that the sign of a excludes): its contribution is left out of the
    loop and it is redone by :func:`_bw_advance`, which locates the zero crossing exactly. The
    states alternate between the two rows of ``H``, so the previous ones stay available for that.

    What makes the loops fast (measured; see ``../shared/PERFORMANCE.md`` for the layout rule):
    the regime and the sign-change test use sign bits only (a masked load and an integer xor, no
    floating-point work); the coefficients of ψ as a polynomial in c are computed once per sample;
    the mode and the series kind are constants of each candidate loop; and no array is handed to
    a helper per sample (numba's atomic reference counting of array arguments cost 14–35 % of the
    kernel's time — also for ``inline="always"`` helpers that contain a loop).
    """
    m = p1 - p0
    H = np.zeros((2, m))  # states before (row c) and after (row 1 − c) the sample
    X = np.empty(m)
    F = np.empty(m)
    a, be, ga, sa, mcp, mcn, cabs_max = _bw_regimes(alpha, beta, gamma, p0, p1)
    acc = (np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m))
    if mode != _BW_MOMENTS:
        k_v = kv[p0:p1].copy()
        off = y0[p0:p1].copy()
    else:
        k_v = np.zeros(m)
        off = np.zeros(m)
    if mode == _BW_SSE:
        _bw_time_loop(_BW_SSE, u, y, H, X, F, a, be, ga, sa, mcp, mcn, cabs_max, k_v, off, acc, out, p0)
        store_sums(out, p0, acc, 1)
    elif mode == _BW_MOMENTS:
        _bw_time_loop(_BW_MOMENTS, u, y, H, X, F, a, be, ga, sa, mcp, mcn, cabs_max, k_v, off, acc, out, p0)
        store_sums(out, p0, acc, 4)
    else:
        _bw_time_loop(_BW_STATES, u, y, H, X, F, a, be, ga, sa, mcp, mcn, cabs_max, k_v, off, acc, out, p0)


@njit(cache=True, inline="always")
def store_sums(out, p0, acc, ncols):
    """Write the first ``ncols`` per-candidate sums ``acc`` (a tuple of (m,) arrays) of a block
    kernel into columns 0..ncols−1 of rows p0.. of ``out`` (P, ≥ ncols)."""
    for col in range(ncols):
        a = acc[col]
        for i in range(a.shape[0]):
            out[p0 + i, col] = a[i]


@njit(cache=True, inline="always")
def candidate_block(b, n_blocks, P):
    """Candidates p0:p1 of block b when P candidates are split into ``n_blocks`` equal blocks
    (the last ones may be shorter or empty: p0 ≥ p1) — the split of every threaded kernel."""
    size = (P + n_blocks - 1) // n_blocks
    p0 = b * size
    return p0, min(P, p0 + size)


def _bw_serial(u, y, kv, alpha, beta, gamma, y0, mode, out):
    """:func:`_bw_block` over the whole population, in this thread. Not a kernel of its own: a
    compiled caller would optimise and generate the machine code of the whole Bouc–Wen kernel
    once more (numba links a kernel's callees into it), ≈ 3 s of a first run."""
    _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, 0, alpha.shape[0])


@njit(cache=True, parallel=True)
def _bw_parallel(u, y, kv, alpha, beta, gamma, y0, mode, out, n_blocks):
    """:func:`_bw_serial` with ``n_blocks`` candidate blocks spread over threads."""
    for b in prange(n_blocks):
        p0, p1 = candidate_block(b, n_blocks, alpha.shape[0])
        if p0 < p1:
            _bw_block(u, y, kv, alpha, beta, gamma, y0, mode, out, p0, p1)


#: populations at least this large are spread over threads
PARALLEL_MIN_POP = 64


def thread_blocks(P: int, min_pop: int = PARALLEL_MIN_POP, min_block: int = 32) -> int:
    """Candidate blocks for a kernel's threaded variant: one per numba thread, each of at least
    ``min_block`` candidates, from a population of ``min_pop`` on (0: run the serial variant —
    a small population or a single thread). The one threading policy of every population kernel."""
    import numba

    threads = numba.get_num_threads()
    if P >= min_pop and threads > 1:
        return min(threads, P // min_block)
    return 0


def _bw_run(u, y, kv, alpha, beta, gamma, y0, mode, out):
    """Run a Bouc–Wen block kernel over the population: threaded for large populations."""
    nb = thread_blocks(alpha.shape[0])
    if nb:
        _bw_parallel(u, y, kv, alpha, beta, gamma, y0, mode, out, nb)
    else:
        _bw_serial(u, y, kv, alpha, beta, gamma, y0, mode, out)
    return out


#: the Bouc–Wen kernels' stand-in for "no array" (read-only, as every input)
_NONE = readonly(np.empty(0))


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
    u = readonly(u)
    alpha, beta, gamma = readonly(alpha), readonly(beta), readonly(gamma)
    out = np.empty((u.shape[0], alpha.shape[0]))
    zero = readonly(np.zeros(alpha.shape[0]))
    return _bw_run(u, _NONE, zero, alpha, beta, gamma, zero, _BW_STATES, out)


def bouc_wen_output(u, kv, alpha, beta, gamma, y0):
    """Bouc–Wen output Kv·u + h + y0 of a population → (N, P) (the caller transposes)."""
    u = readonly(u)
    out = np.empty((u.shape[0], readonly(alpha).shape[0]))
    return _bw_run(u, _NONE, readonly(kv), readonly(alpha), readonly(beta), readonly(gamma), readonly(y0), _BW_STATES, out)


#: kept for callers of the former name: same as :func:`bouc_wen_population`
bouc_wen_h = bouc_wen_population


def bouc_wen_sse(u, y, kv, alpha, beta, gamma, y0):
    """Σ_k (Kv·u_k + h_k + y0 − y_k)² per candidate (P,), h from :func:`bouc_wen_population`,
    computed in the time loop without storing the (N, P) outputs."""
    u, y = readonly(u), readonly(y)
    out = np.empty((readonly(alpha).shape[0], 1))
    return _bw_run(u, y, readonly(kv), readonly(alpha), readonly(beta), readonly(gamma), readonly(y0), _BW_SSE, out)[:, 0]


def bouc_wen_moments(u, y, beta, gamma):
    """Per candidate (P, 4): Σg², Σg·u, Σg, Σg·y of the unit-gain state g (α = 1), without storing g."""
    u, y = readonly(u), readonly(y)
    beta, gamma = readonly(beta), readonly(gamma)
    out = np.empty((beta.shape[0], 4))
    return _bw_run(u, y, _NONE, readonly(np.ones(beta.shape[0])), beta, gamma, _NONE, _BW_MOMENTS, out)


@njit(cache=True)
def bouc_wen_step(h0, u_prev, u_new, alpha, beta, gamma):
    """One Bouc–Wen sample from state h0 for candidate inputs u_new (C,) → new states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    for i in range(C):
        out[i] = _bw_advance(h0, u_new[i] - u_prev, alpha, beta, gamma)
    return out
