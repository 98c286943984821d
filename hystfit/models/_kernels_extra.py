"""Compiled recurrences of the Coleman–Hodgdon, Dahl, LuGre, fractional-Zener, NT and free-exponent
Bouc–Wen models (numba, ``cache=True``).

Layout rule (``../shared/PERFORMANCE.md``): the time loop is sequential and outermost, the
population dimension is innermost and contiguous, so LLVM vectorizes across candidates.
Population outputs are ``(N, P)`` arrays; the models hand them back transposed as ``(P, N)``.

Every kernel is compiled with ``error_model="numpy"``: a division by zero or an overflow gives
``inf``/``nan`` instead of raising, so a diverging parameter vector produces non-finite output
(which the objective maps to +inf) and never an exception. These are separate functions from
the ones in :mod:`hystfit.models._kernels`, so numba's on-disk cache cannot mix the two
error models.
"""

from __future__ import annotations

import math

import numpy as np
from .._jit import njit

#: Bouc–Wen free exponent: largest |Jacobian|·(sub-step length) of one RK4 sub-step.
BWN_STEP_RATIO = 0.05
#: Bouc–Wen free exponent: most RK4 sub-steps per sample (only diverging parameters reach it).
BWN_MAX_SUBSTEPS = 1000


# ============================================================================================
# Coleman–Hodgdon (paper 001 eq. 1)
# ============================================================================================
@njit(cache=True, error_model="numpy")
def ch_branches(u, s0):
    """Branch signs of an input: +1 where u̇ > 0, −1 where u̇ < 0, the previous branch where u̇ = 0.

    Parameters
    ----------
    u : (N,) float64 input (V).
    s0 : branch of the first sample (+1.0 ascending, −1.0 descending).

    Returns
    -------
    (N,) float64 of ±1.
    """
    N = u.shape[0]
    s = np.empty(N)
    cur = s0
    for k in range(N):
        if k > 0:
            du = u[k] - u[k - 1]
            if du > 0.0:
                cur = 1.0
            elif du < 0.0:
                cur = -1.0
        s[k] = cur
    return s


@njit(cache=True, error_model="numpy", inline="always")
def _ch_value(u, s, K, A4, A5, A6, vm, vM):
    """Coleman–Hodgdon output on branch s at input u (exponents written relative to V_m, V_M)."""
    a = s * A5
    phi = 1.0 - 2.0 / (math.exp(a * (u - vm)) + math.exp(a * (u - vM)))
    return K * u - s * A4 * phi + A6


@njit(cache=True, error_model="numpy")
def ch_population(u, s, K, A4, A5, A6, vm, vM):
    """Coleman–Hodgdon output for a population (paper 001 eq. 1).

    y = K u − s A4 (1 − 2 e^{−s A5 u}/(e^{−s A5 V_m} + e^{−s A5 V_M})) + A6,  K = A1 − A2 e^{−A3 V_R},

    evaluated as 1 − 2/(e^{sA5(u−V_m)} + e^{sA5(u−V_M)}) so that no exponent grows with |u|.

    Parameters
    ----------
    u : (N,) input (V).  s : (N,) branch signs from :func:`ch_branches`.
    K, A4, A5, A6 : (P,) slope (out/V), loop amplitude (out), loop shape (1/V), offset (out).
    vm, vM : input range of the identification data (V).

    Returns
    -------
    (N, P) output.
    """
    N = u.shape[0]
    P = K.shape[0]
    out = np.empty((N, P))
    for k in range(N):
        uk = u[k]
        sk = s[k]
        for p in range(P):
            out[k, p] = _ch_value(uk, sk, K[p], A4[p], A5[p], A6[p], vm, vM)
    return out


@njit(cache=True, error_model="numpy")
def _ch_scan(target, s, x0, d, lo, hi, step, K, A4, A5, A6, vm, vM):
    """Walk from x0 in direction d (±1) in steps ``step`` until the branch crosses ``target``.

    Returns (found, root, best_x, best_abs_err); the root is refined by bisection.
    """
    x = min(max(x0, lo), hi)
    e = _ch_value(x, s, K, A4, A5, A6, vm, vM) - target
    best_x, best_e = x, abs(e)
    if e == 0.0:
        return True, x, x, 0.0
    while True:
        x1 = x + d * step
        at_bound = False
        if x1 >= hi:
            x1, at_bound = hi, True
        elif x1 <= lo:
            x1, at_bound = lo, True
        if x1 == x:
            break
        e1 = _ch_value(x1, s, K, A4, A5, A6, vm, vM) - target
        if abs(e1) < best_e:
            best_x, best_e = x1, abs(e1)
        if e * e1 <= 0.0:
            a, b, ea = x, x1, e
            for _ in range(200):
                m = 0.5 * (a + b)
                if m == a or m == b:
                    break
                em = _ch_value(m, s, K, A4, A5, A6, vm, vM) - target
                if em == 0.0:
                    a = b = m
                    break
                if (em > 0.0) == (ea > 0.0):
                    a, ea = m, em
                else:
                    b = m
            r = 0.5 * (a + b)
            return True, r, r, 0.0
        if at_bound or not np.isfinite(e1):
            break
        x, e = x1, e1
    return False, best_x, best_x, best_e


@njit(cache=True, error_model="numpy")
def ch_inverse(y, s, K, A4, A5, A6, vm, vM, lo, hi, u_start, n_grid):
    """Per-branch numerical inverse of Coleman–Hodgdon for one parameter vector.

    At sample k the branch s_k is given (it follows the sign of the target's derivative). The
    root of f_{s_k}(u) = y_k is searched from u_{k−1} in the branch's direction (u increases on
    the ascending branch), so the input's own derivative selects the same branch when the result
    is simulated; the first crossing is refined by bisection to machine precision. If there is
    none in that direction the other direction is tried; if the target is unreachable inside
    [lo, hi] the closest-output input is returned (saturation). The first sample searches both
    directions from ``u_start`` and takes the nearer root.

    Parameters
    ----------
    y : (N,) target output.  s : (N,) branch per sample (±1).
    K, A4, A5, A6, vm, vM : scalars as in :func:`ch_population`.
    lo, hi : search interval (V).  u_start : reference input for the first sample (V).
    n_grid : the scan step is (hi − lo)/n_grid.

    Returns
    -------
    (N,) input (V).
    """
    N = y.shape[0]
    out = np.empty(N)
    step = (hi - lo) / n_grid
    prev = min(max(u_start, lo), hi)
    for k in range(N):
        sk = s[k]
        if k == 0:
            f1, r1, b1, e1 = _ch_scan(y[k], sk, prev, 1.0, lo, hi, step, K, A4, A5, A6, vm, vM)
            f2, r2, b2, e2 = _ch_scan(y[k], sk, prev, -1.0, lo, hi, step, K, A4, A5, A6, vm, vM)
        else:
            f1, r1, b1, e1 = _ch_scan(y[k], sk, prev, sk, lo, hi, step, K, A4, A5, A6, vm, vM)
            f2, r2, b2, e2 = False, prev, prev, np.inf
            if not f1:
                f2, r2, b2, e2 = _ch_scan(y[k], sk, prev, -sk, lo, hi, step, K, A4, A5, A6, vm, vM)
        if f1 and f2:
            u = r1 if abs(r1 - prev) <= abs(r2 - prev) else r2
        elif f1:
            u = r1
        elif f2:
            u = r2
        else:
            u = b1 if e1 <= e2 else b2
        out[k] = u
        prev = u
    return out


# ============================================================================================
# Dahl (exact solution along each input segment)
# ============================================================================================
@njit(cache=True, error_model="numpy", inline="always")
def _dahl_x(x0, cv, a):
    """Exact solution of dx/dv = −c |x|^a sgn(x) after c·v = ``cv`` (x never changes sign).

    |x|^{1−a} = |x0|^{1−a} − (1−a) c v  (a ≠ 1; for a < 1 x reaches 0 in finite v and stays),
    |x| = |x0| e^{−cv}  (a = 1). Written with expm1/log1p so that a → 1 stays accurate.
    """
    if x0 == 0.0 or cv == 0.0:
        return x0
    ax = abs(x0)
    eps = 1.0 - a
    if abs(eps) < 1e-12:
        ax1 = ax * math.exp(-cv)
    else:
        qm1 = math.expm1(eps * math.log(ax)) - eps * cv  # |x1|^eps − 1
        if qm1 <= -1.0:
            ax1 = 0.0 if eps > 0.0 else math.inf
        else:
            ax1 = math.exp(math.log1p(qm1) / eps)
    return ax1 if x0 > 0.0 else -ax1


@njit(cache=True, error_model="numpy", inline="always")
def _dahl_advance(h, du, sigma, fc, a):
    """Advance the Dahl state h exactly over one straight input segment du.

    ḣ = σ u̇ φ_a(1 − (h/F) sgn u̇), φ_a(x) = |x|^a sgn x, F = sgn(σ)·F_c. With s = sgn(du),
    v = |du| and x = 1 − s h/F: dx/dv = −(σ/F) φ_a(x), solved by :func:`_dahl_x`.
    """
    if du == 0.0 or sigma == 0.0:
        return h
    s = 1.0 if du > 0.0 else -1.0
    F = fc if sigma > 0.0 else -fc
    c = sigma / F
    x1 = _dahl_x(1.0 - s * h / F, c * abs(du), a)
    return s * F * (1.0 - x1)


@njit(cache=True, error_model="numpy")
def dahl_population(u, sigma, fc, a):
    """Dahl hysteretic state h for a population, exact per sample, h(0) = 0.

    Parameters
    ----------
    u : (N,) input (V).
    sigma : (P,) initial slope σ (out/V); its sign sets the loop orientation.
    fc : (P,) saturation level F_c > 0 (out).  a : (P,) exponent a > 0.

    Returns
    -------
    (N, P) h (output units); the caller transposes.
    """
    N = u.shape[0]
    P = sigma.shape[0]
    out = np.empty((N, P))
    for p in range(P):
        out[0, p] = 0.0
    for k in range(1, N):
        du = u[k] - u[k - 1]
        for p in range(P):
            out[k, p] = _dahl_advance(out[k - 1, p], du, sigma[p], fc[p], a[p])
    return out


@njit(cache=True, error_model="numpy")
def dahl_step(h0, u_prev, u_new, sigma, fc, a):
    """One Dahl sample from state h0 for candidate inputs u_new (C,) → new states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    for i in range(C):
        out[i] = _dahl_advance(h0, u_new[i] - u_prev, sigma, fc, a)
    return out


# ============================================================================================
# LuGre (exact per sample for the sample's constant rate)
# ============================================================================================
@njit(cache=True, error_model="numpy", inline="always")
def _lugre_advance(z, v, dt, s0abs, fc, fs, vs):
    """Advance z over one sample with constant rate v: ż = v − λ z, λ = |σ0| |v| / g(v).

    Exact: z1 = z e^{−λdt} + v dt (1 − e^{−λdt})/(λdt). Returns (z1, ż at the sample's end).
    """
    if v == 0.0:
        return z, 0.0
    r = v / vs
    g = fc + (fs - fc) * math.exp(-r * r)
    lam = s0abs * abs(v) / g
    x = lam * dt
    if abs(x) < 1e-5:
        phi = 1.0 - x * (0.5 - x / 6.0)
    else:
        phi = -math.expm1(-x) / x
    z1 = z * math.exp(-x) + v * dt * phi
    return z1, v - lam * z1


@njit(cache=True, error_model="numpy")
def lugre_population(u, dt, k, s0, s1, s2, fc, fs, vs):
    """LuGre output y = k u + σ0 z + σ1 ż + σ2 u̇ for a population (without offset), z(0) = 0.

    u̇ is the backward difference (u_k − u_{k−1})/dt (0 at the first sample) and is constant
    over each sample, so the linear z equation is integrated exactly: stable at any rate.
    g(u̇) = F_c + (F_s − F_c) e^{−(u̇/v_s)²} with F_c, F_s > 0; the sign of σ0 sets the loop
    orientation (λ uses |σ0|).

    Parameters
    ----------
    u : (N,) input (V).  dt : sample period (s).
    k, s0, s1, s2, fc, fs, vs : (P,) parameters (see :class:`hystfit.models.lugre.LuGre`).

    Returns
    -------
    (N, P) output.
    """
    N = u.shape[0]
    P = k.shape[0]
    out = np.empty((N, P))
    z = np.zeros(P)
    if N == 0:
        return out
    for p in range(P):
        out[0, p] = k[p] * u[0]
    for n in range(1, N):
        un = u[n]
        v = (un - u[n - 1]) / dt
        for p in range(P):
            z1, zd = _lugre_advance(z[p], v, dt, abs(s0[p]), fc[p], fs[p], vs[p])
            z[p] = z1
            out[n, p] = k[p] * un + s0[p] * z1 + s1[p] * zd + s2[p] * v
    return out


@njit(cache=True, error_model="numpy")
def lugre_step(z0, u_prev, u_new, dt, k, s0, s1, s2, fc, fs, vs):
    """One LuGre sample from state z0 for candidate inputs u_new (C,) → (outputs (C,), states (C,))."""
    C = u_new.shape[0]
    y = np.empty(C)
    z = np.empty(C)
    for i in range(C):
        v = (u_new[i] - u_prev) / dt
        z1, zd = _lugre_advance(z0, v, dt, abs(s0), fc, fs, vs)
        z[i] = z1
        y[i] = k * u_new[i] + s0 * z1 + s1 * zd + s2 * v
    return y, z


# ============================================================================================
# Fractional Zener: Grünwald–Letnikov recurrence
# ============================================================================================
@njit(cache=True, error_model="numpy")
def gl_weights(a, L):
    """Grünwald–Letnikov weights w_j = (−1)^j C(a, j), j = 0..L, for each order a[p].

    Recurrence w_0 = 1, w_j = w_{j−1} (1 − (a+1)/j). Returns (L+1, P).
    """
    P = a.shape[0]
    w = np.empty((L + 1, P))
    for p in range(P):
        w[0, p] = 1.0
    for j in range(1, L + 1):
        f = 1.0 / j
        for p in range(P):
            w[j, p] = w[j - 1, p] * (1.0 - (a[p] + 1.0) * f)
    return w


@njit(cache=True, error_model="numpy")
def gl_filter_population(x, w, c0, c1, d0, d1):
    """Solve (c0 + c1 W) y = (d0 + d1 W) x sample by sample for a population.

    W is the windowed Grünwald–Letnikov sum (W x)_k = Σ_{j=0}^{min(k, L)} w_j x_{k−j}
    (zero history before the first sample, w_0 = 1)::

        y_k = [d0 x_k + d1 (x_k + Σ_{j≥1} w_j x_{k−j}) − c1 Σ_{j≥1} w_j y_{k−j}] / (c0 + c1)

    With c0 = 1, c1 = b = (τ/dt)^a, d0 = E0, d1 = E∞ b this is the fractional Zener model in
    deviation variables; swapping the roles gives its exact inverse.

    Parameters
    ----------
    x : (N,) input (shared by the population).  w : (L+1, P) weights from :func:`gl_weights`.
    c0, c1, d0, d1 : (P,) coefficients.

    Returns
    -------
    (N, P) output. Cost O(N · L · P): time outer, memory middle, population inner.
    """
    N = x.shape[0]
    L = w.shape[0] - 1
    P = w.shape[1]
    y = np.empty((N, P))
    acc_x = np.empty(P)
    acc_y = np.empty(P)
    for k in range(N):
        J = min(k, L)
        for p in range(P):
            acc_x[p] = 0.0
            acc_y[p] = 0.0
        for j in range(1, J + 1):
            xj = x[k - j]
            for p in range(P):
                wj = w[j, p]
                acc_x[p] += wj * xj
                acc_y[p] += wj * y[k - j, p]
        xk = x[k]
        for p in range(P):
            y[k, p] = (d0[p] * xk + d1[p] * (xk + acc_x[p]) - c1[p] * acc_y[p]) / (c0[p] + c1[p])
    return y


# ============================================================================================
# NT softsign model (paper 002 eq. 2, inverse eq. 4–10)
# ============================================================================================
@njit(cache=True, error_model="numpy")
def nt_population(u, v, k0, c0, k1, k2, y0):
    """NT output y = k0 u + c0 u̇ + k1 k2 u/(1 + |k2 u|) + y0 for a population.

    Parameters
    ----------
    u, v : (N,) input (V) and its backward difference rate (V/s).
    k0, c0, k1, k2, y0 : (P,) parameters.

    Returns
    -------
    (N, P) output.
    """
    N = u.shape[0]
    P = k0.shape[0]
    out = np.empty((N, P))
    for n in range(N):
        un = u[n]
        vn = v[n]
        for p in range(P):
            q = k2[p] * un
            out[n, p] = k0[p] * un + c0[p] * vn + k1[p] * q / (1.0 + abs(q)) + y0[p]
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _quad_roots(a2, a1, a0):
    """Real roots of a2 x² + a1 x + a0 (stable formula). Returns (n, r1, r2), n ∈ {0, 1, 2}."""
    if a2 == 0.0:
        if a1 == 0.0:
            return 0, 0.0, 0.0
        return 1, -a0 / a1, 0.0
    disc = a1 * a1 - 4.0 * a2 * a0
    if disc < 0.0:
        if disc > -1e-14 * a1 * a1:
            disc = 0.0
        else:
            return 0, 0.0, 0.0
    sq = math.sqrt(disc)
    q = -0.5 * (a1 + sq) if a1 >= 0.0 else -0.5 * (a1 - sq)
    if q == 0.0:
        return 1, 0.0, 0.0
    return 2, q / a2, a0 / q


@njit(cache=True, error_model="numpy", inline="always")
def _nt_resid(u, A, k1, k2, B):
    q = k2 * u
    return A * u + k1 * q / (1.0 + abs(q)) - B


@njit(cache=True, error_model="numpy")
def nt_root(A, k1, k2, B, u_ref):
    """Solve A u + k1 k2 u/(1 + k2|u|) = B by 002's piecewise quadratics (eq. 8–10), k2 > 0.

    u ≥ 0:  A k2 u² + (A + k1 k2 − B k2) u − B = 0;
    u < 0:  A k2 u² − (A + k1 k2 + B k2) u + B = 0.

    Roots are kept when they lie on their branch and satisfy the original equation on
    substitution (relative residual ≤ 1e-8); among those the one closest to ``u_ref`` wins.
    Returns (u, ok); when no admissible root exists (A = 0 and |B| ≥ |k1|), (u_ref, False).
    """
    best = u_ref
    best_d = math.inf
    scale = abs(B) + abs(k1) + 1e-300
    for br in range(2):
        if br == 0:
            n, r1, r2 = _quad_roots(A * k2, A + k1 * k2 - B * k2, -B)
        else:
            n, r1, r2 = _quad_roots(A * k2, -(A + k1 * k2 + B * k2), B)
        for i in range(n):
            r = r1 if i == 0 else r2
            if (br == 0 and r < 0.0) or (br == 1 and r >= 0.0):
                continue
            if abs(_nt_resid(r, A, k1, k2, B)) > 1e-8 * (scale + abs(A * r)):
                continue
            d = abs(r - u_ref)
            if d < best_d:
                best, best_d = r, d
    return best, best_d < math.inf


@njit(cache=True, error_model="numpy")
def nt_inverse_causal(yd, A, c, k1, k2, u_first):
    """Causal discrete NT inverse (paper 002 eq. 4–10): u_n from B_n = y_n + c u_{n−1}.

    Parameters
    ----------
    yd : (N,) target output minus the offset y0.
    A : k0 + c0/Ts.  c : c0/Ts.  k1, k2 : softsign parameters (k2 > 0).
    u_first : input at the first sample (the static inverse of yd[0]).

    Returns
    -------
    (N,) input; samples without an admissible root hold the previous input.
    """
    N = yd.shape[0]
    out = np.empty(N)
    if N == 0:
        return out
    out[0] = u_first
    for n in range(1, N):
        B = yd[n] + c * out[n - 1]
        out[n], _ = nt_root(A, k1, k2, B, out[n - 1])
    return out


@njit(cache=True, error_model="numpy")
def nt_inverse_backward(yd, k0, c, k1, k2, u_last):
    """Anti-causal NT inverse: u_{n−1} = u_n + (k0 u_n + k1 softsign(k2 u_n) − y_n)/c, backwards.

    The same discrete model equation as :func:`nt_inverse_causal` solved for u_{n−1}: stable
    exactly when the causal recursion is not (c0 < 0 with |c0|/Ts above half the local slope).
    ``u_last`` is the terminal input (static inverse of the last target sample).
    """
    N = yd.shape[0]
    out = np.empty(N)
    if N == 0:
        return out
    out[N - 1] = u_last
    for n in range(N - 1, 0, -1):
        un = out[n]
        q = k2 * un
        out[n - 1] = un + (k0 * un + k1 * q / (1.0 + abs(q)) - yd[n]) / c
    return out


# ============================================================================================
# Bouc–Wen with a free exponent n ≥ 1 (sub-stepped RK4 in the input)
# ============================================================================================
@njit(cache=True, error_model="numpy", inline="always")
def _bwn_rk4(g, dv, alpha, c, n):
    """One RK4 step of dg/dv = α − c g |g|^{n−1} (the right-hand side on one side of g = 0)."""
    k1 = alpha - c * g * abs(g) ** (n - 1.0)
    gg = g + 0.5 * dv * k1
    k2 = alpha - c * gg * abs(gg) ** (n - 1.0)
    gg = g + 0.5 * dv * k2
    k3 = alpha - c * gg * abs(gg) ** (n - 1.0)
    gg = g + dv * k3
    k4 = alpha - c * gg * abs(gg) ** (n - 1.0)
    return g + dv * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0


@njit(cache=True, error_model="numpy", inline="always")
def _bwn_bound(alpha, beta, gamma, n):
    """(G_s, J_s): largest saturation level (|α|/(β ± γ))^{1/n} and n(|β|+|γ|) G_s^{n−1}."""
    G = 0.0
    inv_n = 1.0 / n
    bp = beta + gamma
    bm = beta - gamma
    if bp > 0.0:
        G = max(G, (abs(alpha) / bp) ** inv_n)
    if bm > 0.0:
        G = max(G, (abs(alpha) / bm) ** inv_n)
    return G, n * (abs(beta) + abs(gamma)) * G ** (n - 1.0)


@njit(cache=True, error_model="numpy", inline="always")
def _bwn_advance(h, du, alpha, beta, gamma, n, Gs, Js):
    """Advance the Bouc–Wen state over one straight input segment du with RK4 sub-steps.

    In g = sgn(du)·h the equation is dg/dv = α − (β + σγ) g |g|^{n−1} with σ = sgn g: smooth on
    each side of g = 0 and kinked at 0 (for n = 1 it is linear on each side). Each RK4 sub-step
    uses the smooth right-hand side of the side it starts on; a sub-step that crosses 0 is split
    at the crossing (linear estimate refined by one Newton correction) and finished with the
    other side's right-hand side, so the kink costs no order of accuracy.

    The sub-step count makes |J|·Δv ≤ :data:`BWN_STEP_RATIO`, with |J| = n(|β| + |γ|) G^{n−1}
    bounding the Jacobian for |g| ≤ G, G = max(|g|, G_s) and G_s the largest saturation level
    (``Gs``, ``Js`` from :func:`_bwn_bound`, precomputed per candidate): the state moves toward a
    saturation level or down from a larger |g|, so G bounds it along the segment for stable
    parameters. Diverging parameters hit :data:`BWN_MAX_SUBSTEPS` and overflow to non-finite
    values.
    """
    if du == 0.0:
        return h
    s = 1.0 if du > 0.0 else -1.0
    v = abs(du)
    g = s * h
    if not np.isfinite(g):
        return h
    ag = abs(g)
    J = Js if ag <= Gs else n * (abs(beta) + abs(gamma)) * ag ** (n - 1.0)
    x = v * J / BWN_STEP_RATIO
    if x < 1.0:
        m = 1
    elif x < BWN_MAX_SUBSTEPS:
        m = int(math.ceil(x))
    else:
        m = BWN_MAX_SUBSTEPS
    dv = v / m
    for _ in range(m):
        if g > 0.0 or (g == 0.0 and alpha >= 0.0):
            sg = 1.0
        else:
            sg = -1.0
        c = beta + sg * gamma
        g1 = _bwn_rk4(g, dv, alpha, c, n)
        if g != 0.0 and g1 * sg < 0.0:
            # crossed zero inside the sub-step: stop at the crossing, continue on the other side
            th = g / (g - g1)
            gm = _bwn_rk4(g, th * dv, alpha, c, n)
            f = alpha - c * gm * abs(gm) ** (n - 1.0)
            if f != 0.0:
                th = min(max(th - gm / (f * dv), 0.0), 1.0)
                gm = _bwn_rk4(g, th * dv, alpha, c, n)
            g1 = _bwn_rk4(gm, (1.0 - th) * dv, alpha, beta - sg * gamma, n)
        g = g1
    return s * g


@njit(cache=True, error_model="numpy")
def bouc_wen_n_population(u, alpha, beta, gamma, n):
    """Bouc–Wen state h for a population with a free exponent n ≥ 1, h(0) = 0.

    ḣ = α u̇ − β |u̇| |h|^{n−1} h − γ u̇ |h|^n  (paper 004 eq. 2). Rate independent, so h is
    integrated in the input along each sample's straight segment: with g = sgn(Δu) h and v the
    distance travelled, dg/dv = α − β |g|^{n−1} g − γ |g|^n, by classical RK4 with a per-sample,
    per-candidate sub-step count chosen for stability (see :func:`_bwn_advance`). For n = 1 it
    agrees with the exact :func:`hystfit.models._kernels.bouc_wen_population` to ~1e-8.

    Parameters
    ----------
    u : (N,) input (V).
    alpha : (P,) out/V.  beta, gamma : (P,) in V⁻¹·out^{1−n}.  n : (P,) exponent ≥ 1.

    Returns
    -------
    (N, P) h (output units); the caller transposes.
    """
    N = u.shape[0]
    P = alpha.shape[0]
    out = np.empty((N, P))
    Gs = np.empty(P)
    Js = np.empty(P)
    for p in range(P):
        out[0, p] = 0.0
        Gs[p], Js[p] = _bwn_bound(alpha[p], beta[p], gamma[p], n[p])
    for k in range(1, N):
        du = u[k] - u[k - 1]
        for p in range(P):
            out[k, p] = _bwn_advance(out[k - 1, p], du, alpha[p], beta[p], gamma[p], n[p], Gs[p], Js[p])
    return out


@njit(cache=True, error_model="numpy")
def bouc_wen_n_step(h0, u_prev, u_new, alpha, beta, gamma, n):
    """One free-exponent Bouc–Wen sample from state h0 for candidate inputs u_new (C,) → states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    Gs, Js = _bwn_bound(alpha, beta, gamma, n)
    for i in range(C):
        out[i] = _bwn_advance(h0, u_new[i] - u_prev, alpha, beta, gamma, n, Gs, Js)
    return out
