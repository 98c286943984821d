"""Four-parameter fractional Zener model (Pritz 1996; ``shared/papers/README.md``, 002's "FP")."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from .._jit import njit, prange, readonly
from .._lazy import lazy_module
from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import candidate_block, thread_blocks
from .base import Model, OptionalOffset
from .separable import Separable, separable_by_simulation

sfft = lazy_module("scipy.fft")  # imported on first use: keeps start-up fast

#: Memory windows up to this many past samples use the direct recurrence; longer ones the FFT.
RECURRENCE_MAX_TERMS = 200
#: r^M of the z-transform circle used by the FFT evaluation (aliasing error ≈ this · N).
_FFT_ALIAS = 1e-14
#: complex spectrum elements per FFT block of candidates (≈ 64 MB per work array)
FFT_BLOCK_ELEMENTS = 4_000_000
#: captures of at least this many samples whose window is longer than RECURRENCE_MAX_TERMS are
#: evaluated by the sum-of-exponentials (SOE) recursion, O(N·K) per candidate; shorter captures
#: (every capture of sample_data) keep the exact evaluation
SOE_MIN_SAMPLES = 20_000
#: trapezoid step and upper end in x = log s of the SOE quadrature; the lower end is −log L − 13
SOE_STEP = 0.45
SOE_X_MAX = math.log(40.0)
SOE_X_MIN_OFFSET = 13.0
#: tested bound of the SOE weights' ℓ1 error Σ_{j=2}^{L} |ŵ_j − w_j| for 0.01 ≤ a ≤ 0.99, any L
#: (tests/test_fp_soe.py; the quadrature's tail shrinks as L^{−a}, its step error is L-independent)
SOE_WEIGHT_L1 = 5e-8
#: kernel modes of the SOE recursion: the response v (N, P), or its moments (P, 7)
_SOE_OUTPUT, _SOE_MOMENTS = 0, 1


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (Fractional Zener: Grünwald–Letnikov recurrence). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

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


# ----------------------------------------------------------------------------------------------
# Long captures: the Grünwald–Letnikov memory as a sum of exponentials (diffusive representation).
#
# For j ≥ 1 and 0 < a < 1 the weights have the integral form (Beta function, Γ(1−a)Γ(1+a) = πa/sin πa)
#     w_j = −(sin πa / π) ∫_0^∞ e^{−s j} (1 − e^{−s})^a e^{a s} ds,
# and with s = e^x the trapezoid rule on x_n = x_min + n h (h = SOE_STEP) gives
#     ŵ_j = Σ_n c_n ρ_n^j,  ρ_n = e^{−s_n},  c_n = −(sin πa/π) h s_n (1 − e^{−s_n})^a e^{a s_n}.
# The nodes ρ_n do not depend on a (one grid for the whole population), only the c_n do. Each
# exponential is a one-term recursion, so the windowed sum Σ_{j=2}^{L} ŵ_j v_{k−j} costs O(K) per
# sample instead of O(L) (w_1 = −a is kept exact: the quadrature converges slowly at j = 1).
# ----------------------------------------------------------------------------------------------

def soe_nodes(L: int) -> tuple[np.ndarray, np.ndarray]:
    """Decay rates s_n (K,) and nodes ρ_n = e^{−s_n} of the SOE quadrature for a window of L samples."""
    x_min = -math.log(max(L, 1)) - SOE_X_MIN_OFFSET
    x = x_min + SOE_STEP * np.arange(int(math.floor((SOE_X_MAX - x_min) / SOE_STEP)) + 1)
    s = np.exp(x)
    return s, np.exp(-s)


def soe_coefficients(a: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Coefficients c (K, P) of the SOE weights ŵ_j = Σ_n c_n ρ_n^j for the orders a (P,)."""
    a = np.asarray(a, dtype=np.float64)[None, :]
    s = s[:, None]
    with np.errstate(all="ignore"):
        return -(np.sin(np.pi * a) / np.pi) * SOE_STEP * s * (-np.expm1(-s)) ** a * np.exp(a * s)


def soe_weights(a: np.ndarray, L: int) -> np.ndarray:
    """The weights (L+1, P) the SOE recursion applies: ŵ_0 = 1, ŵ_1 = −a (exact), ŵ_j = Σ_n c_n ρ_n^j
    for 2 ≤ j ≤ L — to compare with :func:`gl_weights` (the error bound :data:`SOE_WEIGHT_L1`)."""
    a = np.atleast_1d(np.asarray(a, dtype=np.float64))
    s, _ = soe_nodes(L)
    c = soe_coefficients(a, s)
    w = np.empty((L + 1, a.shape[0]))
    w[0] = 1.0
    w[1:2] = -a[None, :]
    j = np.arange(2, L + 1, dtype=np.float64)
    w[2:] = np.exp(-j[:, None] * s[None, :]) @ c
    return w


@njit(cache=True, error_model="numpy")
def _soe_block(x, y, a, b, c, r1, r2, rL1, L, mode, out, p0, p1):
    """v = (1 + b W)⁻¹ x for candidates p0:p1, W the windowed GL sum with the SOE weights.

    Per sample k: A_k = −a v_{k−1} + Σ_n c_n S_n(k),  v_k = (x_k − b A_k)/(1 + b), then
    S_n(k+1) = ρ_n S_n(k) + ρ_n² v_{k−1} − ρ_n^{L+1} v_{k−L}  (S_n(k) = Σ_{j=2}^{min(k,L)} ρ_n^j v_{k−j};
    the last L outputs in a ring buffer). ``mode`` :data:`_SOE_OUTPUT` writes v into out (N, P);
    :data:`_SOE_MOMENTS` accumulates, with d = x − v, Σv², Σv·d, Σd², Σv, Σd, Σv·y, Σd·y into
    out[p, 0:7] (memory O(L·P)). Time outermost, candidates innermost.
    """
    N = x.shape[0]
    K = r1.shape[0]
    m = p1 - p0
    R = L + 1
    S = np.zeros((K, m))
    cb = np.ascontiguousarray(c[:, p0:p1])
    hist = np.zeros((R, m))
    vprev = np.zeros(m)
    acc = np.empty(m)
    sums = np.zeros((7, m))
    na = np.empty(m)
    bb = np.empty(m)
    for i in range(m):
        na[i] = -a[p0 + i]
        bb[i] = b[p0 + i]
    for k in range(N):
        for i in range(m):
            acc[i] = na[i] * vprev[i]
        old = (k + 1) % R  # v_{k−L} (still zero while k < L)
        for n in range(K):  # one pass: A_k from S_n(k), then S_n(k+1)
            q1 = r1[n]
            q2 = r2[n]
            q3 = rL1[n]
            for i in range(m):
                sn = S[n, i]
                acc[i] += cb[n, i] * sn
                S[n, i] = q1 * sn + q2 * vprev[i] - q3 * hist[old, i]
        xk = x[k]
        slot = k % R
        for i in range(m):
            v = (xk - bb[i] * acc[i]) / (1.0 + bb[i])
            hist[slot, i] = v
            vprev[i] = v
        if mode == _SOE_OUTPUT:
            for i in range(m):
                out[k, p0 + i] = vprev[i]
        else:
            yk = y[k]
            for i in range(m):
                v = vprev[i]
                d = xk - v
                sums[0, i] += v * v
                sums[1, i] += v * d
                sums[2, i] += d * d
                sums[3, i] += v
                sums[4, i] += d
                sums[5, i] += v * yk
                sums[6, i] += d * yk
    if mode == _SOE_MOMENTS:
        for col in range(7):
            for i in range(m):
                out[p0 + i, col] = sums[col, i]


@njit(cache=True, parallel=True, error_model="numpy")
def _soe_parallel(x, y, a, b, c, r1, r2, rL1, L, mode, out, n_blocks):
    """:func:`_soe_block` over ``n_blocks`` candidate blocks spread over threads."""
    for blk in prange(n_blocks):
        p0, p1 = candidate_block(blk, n_blocks, a.shape[0])
        if p0 < p1:
            _soe_block(x, y, a, b, c, r1, r2, rL1, L, mode, out, p0, p1)


def soe_run(x: np.ndarray, y: np.ndarray | None, a: np.ndarray, b: np.ndarray, L: int, mode: int) -> np.ndarray:
    """Run the SOE recursion (:func:`_soe_block`) for orders a (P,) and b = (τ/dt)^a (P,): the
    response v (N, P) or its moments (P, 7). Threaded over candidates from two candidates on
    (each candidate is O(N·K) work on a long capture)."""
    x = readonly(x)
    y = readonly(y if y is not None else np.empty(0))
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    s, rho = soe_nodes(L)
    c = np.ascontiguousarray(soe_coefficients(a, s))
    r2 = rho * rho
    rL1 = np.exp(-(L + 1) * s)
    P = a.shape[0]
    out = np.empty((x.shape[0], P)) if mode == _SOE_OUTPUT else np.empty((P, 7))
    args = (x, y, a, b, c, rho, r2, rL1, int(L), int(mode), out)
    nb = thread_blocks(P, 2, 1)
    if nb:
        _soe_parallel(*args, nb)
    else:
        _soe_block(*args, 0, P)
    return out


@models.register
@dataclass(frozen=True)
class FractionalZener(OptionalOffset, Model):
    r"""Four-parameter fractional derivative (fractional Zener) model of Pritz (1996).

    .. math::

        y + \tau^{a} D^{a} y = E_0\,u + E_\infty\,\tau^{a} D^{a} u\ (+\,y_0),\qquad 0 < a < 1

    (``shared/papers/README.md``; paper 002 compares against an "FP" model without defining
    it, this is our choice). Linear and causal: the "hysteresis" is the phase lag of a
    power-law creep/relaxation, E0 the static gain and E∞ the instantaneous gain; no nonlinear
    equation, as 002 describes FP.

    Discretization: Grünwald–Letnikov with a bounded memory window,
    D^a x(t_k) ≈ Ts^{−a} Σ_{j=0}^{min(k, L)} w_j x_{k−j}, w_j = (−1)^j C(a, j), L = round(memory_s/Ts).
    With b = (τ/Ts)^a each sample solves
    y_k (1 + b) = E0 u_k + E∞ b Σ_j w_j u_{k−j} − b Σ_{j≥1} w_j y_{k−j}
    (:func:`hystfit.models.fp.gl_filter_population`). The recurrence is written in
    deviations from the first sample (u − u_0, y − E0 u_0): the stage is taken to rest at u_0
    before the capture (Caputo-type start), so a capture that starts at a non-zero input does
    not see a spurious step.

    Memory window (argued). ``memory_s`` is a *time span*, not a sample count, so the model
    means the same on captures at different sample rates (a sample-count window would shrink
    the physics with the rate). Default 1 s: longer than every capture of 002's campaign (five
    periods at ≥ 10 Hz = 0.5 s), so there the recurrence is the exact GL scheme; on longer
    captures the short-memory principle applies (the truncated operator forgets excitation
    older than memory_s, which at the truncation error ~ (memory_s)^{−a} matters for slow creep
    only). The window also bounds the stepping state.

    Evaluation (deviation from a plain time loop, argued). The windowed recurrence is a linear
    time-invariant filter with transfer function (E0 + E∞ b P_L(z))/(1 + b P_L(z)), P_L the
    truncated GL polynomial. Re P_L > 0 on the closed unit disk (Σ_{j≥1}|w_j| < 1 for 0 < a < 1),
    so the filter is stable. For windows longer than :data:`RECURRENCE_MAX_TERMS` samples the
    population is evaluated by FFT on the circle |z| = r < 1 (r^M = 1e-14, M ≈ 3N), which gives
    the *same* outputs as the recurrence to ~1e-11 relative at O(N log N) instead of O(N·L) per
    candidate (measured 10× faster at N = L = 5000); shorter windows use the numba recurrence.
    Captures of :data:`SOE_MIN_SAMPLES` samples or more (none in sample_data) take the
    sum-of-exponentials route instead (:func:`soe_run`, O(N·K) per candidate, K ≈ 60): the GL
    weights w_j, 2 ≤ j ≤ L, are replaced by a trapezoid quadrature of their diffusive integral
    representation with a tested ℓ1 error ε ≤ :data:`SOE_WEIGHT_L1` = 5e-8, which bounds the output
    error by ‖ŷ − y‖∞ ≤ |E0 − E∞|·b·ε/(1 + b·s_L)·‖v‖∞ (v = L⁻¹[u − u_0], s_L = Σ_{j≤L} w_j > 0;
    tests/unit/test_fp_soe.py checks both against the exact recurrence).

    Structure
    ---------
    memory_s : GL memory window in s (> 0).
    offset : add the output offset y0 (default True): real captures carry a sensor offset that
        the linear model cannot otherwise produce (y = E0 u_0 at rest). ``offset=False`` gives
        Pritz's four parameters exactly.

    Parameters (θ)
    --------------
    E0 : out/V, static (relaxed) gain.  Einf : out/V, instantaneous gain.
    tau : s, relaxation time.  a : 1, fractional order (0 < a < 1).  y0 : out, offset.

    Identifiability. From one sinusoid only the gain and phase at that frequency plus the mean
    level are seen: E0 (from the mean) is determined, (E∞, τ, a) trade against each other. Pooled
    captures at several frequencies (or a broadband input) determine all four.

    Bounds (g = output range / input range, t_c = input range / max |u̇|, ≈ 1/(πf) for a sine):
    E0, E∞ ∈ [0, 3] g, τ ∈ [0, 20 t_c], a ∈ [0.01, 0.99], y0 within one output range.

    Inverse: exact and analytic — the inverse filter (1 + bW)/(E0 + E∞ bW) by the same GL
    recurrence (stable for E0 > 0, E∞ ≥ 0); u_0 = (y_0 − y0)/E0.
    """

    name = "fp"
    title = "Fractional Zener (four-parameter, Pritz)"
    reference = "Pritz 1996 (four-parameter fractional derivative model); shared/papers/README.md; paper 002 'FP'"
    equation = "y + τ^a·D^a y = E0·u + E∞·τ^a·D^a u (+ y0),  D^a by Grünwald–Letnikov over memory_s"
    rate_dependent = True
    n_params_without_offset = 4

    memory_s: float = 1.0
    offset: bool = True

    def __post_init__(self) -> None:
        m = self.memory_s
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not np.isfinite(m) or m <= 0:
            raise ConfigError(f"fp: memory_s must be a positive number of seconds, got {m!r}")
        self.check_offset()

    def memory_samples(self, dt: float) -> int:
        """Number of past samples in the GL window at sample period ``dt``."""
        return max(0, int(round(float(self.memory_s) / float(dt))))

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g = scale.gain
        sg = -1.0 if scale.sign < 0 else 1.0
        tc = scale.u_range / scale.rate_max
        ps = [
            # gains of the data's sign (an output that falls with the input: E0, E∞ ≤ 0)
            Param("E0", "out/V", *sorted((0.0, 3 * sg * g)), sg * g, "static gain E0"),
            Param("Einf", "out/V", *sorted((0.0, 3 * sg * g)), 0.8 * sg * g, "instantaneous gain E∞"),
            Param("tau", "s", 0.0, 20.0 * tc, tc, "relaxation time τ"),
            Param("a", "1", 0.01, 0.99, 0.5, "fractional order a"),
        ]
        if self.offset:
            ps.append(Param("y0", "out", *scale.offset_bounds(), 0.0, "output offset"))
        return tuple(ps)

    # ------------------------------------------------------------------ simulation
    def separable(self):
        """E0, E∞ (and y0) enter linearly for fixed (τ, a): the fractional operator is linear, so
        y = E0·L⁻¹[u] + E∞·L⁻¹[τ^a D^a u] + y0 with L = 1 + τ^a D^a. Only τ and a are searched.

        One response per candidate, v = L⁻¹[u − u_0], gives the whole basis — L⁻¹[τ^a D^a x] =
        L⁻¹[(L − 1) x] = x − v, so y = E0 (v + u_0) + E∞ (x − v) + y0 — on the captures evaluated by
        FFT or by the SOE recursion (:meth:`_response`); the normal equations then come from the
        moments of v and x − v (long captures, :meth:`soe_route`: from the fused SOE kernel, O(L·P)
        memory). Captures of the direct recurrence (windows up to :data:`RECURRENCE_MAX_TERMS`):
        the basis from the model's simulator (:func:`separable_by_simulation`)."""
        linear = (0, 1, 4) if self.offset else (0, 1)
        exact = separable_by_simulation(self, linear, self.n_params, grouped=self.simulator)

        def factory(u, dt):
            response = self._response(u, dt)
            if response is None:
                return exact.basis_factory(u, dt)
            u = readonly(u)
            x = u - u[0]

            def basis(theta_nl):
                with np.errstate(all="ignore"):
                    v = response(theta_nl)  # (P, N)
                    B = np.ones((v.shape[0], v.shape[1], len(linear)))
                    B[:, :, 0] = v + u[0]
                    B[:, :, 1] = x[None, :] - v
                return B

            return basis

        def gram_factory(u, dt, y):
            if self.soe_route(len(u), dt):
                return self._gram(u, dt, y, None)
            response = self._response(u, dt)
            if response is None:
                return exact.gram_factory(u, dt, y)
            return self._gram(u, dt, y, response)

        return Separable(linear, exact.nonlinear, factory, gram_factory, fused_for=self.soe_route)

    def _response(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray] | None:
        """θ_nl (P, 2) = (τ, a) → v = L⁻¹[u − u_0] (P, N): by the SOE recursion (:meth:`soe_route`)
        or the FFT evaluation (windows longer than :data:`RECURRENCE_MAX_TERMS`, one transform per
        candidate); None for the direct recurrence."""
        u = readonly(u)
        N = u.shape[0]
        x = np.ascontiguousarray(u - u[0]) if N else u
        L = min(self.memory_samples(dt), max(N - 1, 0))
        if self.soe_route(N, dt):
            def v_soe(theta_nl):
                tau, a = (np.ascontiguousarray(theta_nl[:, i]) for i in range(2))
                with np.errstate(all="ignore"):
                    return soe_run(x, None, a, (tau / float(dt)) ** a, L, _SOE_OUTPUT).T

            return v_soe
        if N == 0 or L <= RECURRENCE_MAX_TERMS:
            return None
        deviation = self._fft_deviation(x, dt, L)

        def v_fft(theta_nl):
            th = np.zeros((theta_nl.shape[0], 4))
            th[:, 0] = 1.0  # E0 = 1, E∞ = 0: the deviation is v
            th[:, 2:4] = theta_nl[:, :2]
            return deviation(th)

        return v_fft

    def soe_route(self, n_samples: int, dt: float) -> bool:
        """True when a capture of ``n_samples`` at period ``dt`` is evaluated by the SOE recursion
        (at least :data:`SOE_MIN_SAMPLES` samples and a window longer than :data:`RECURRENCE_MAX_TERMS`)."""
        return n_samples >= SOE_MIN_SAMPLES and min(self.memory_samples(dt), n_samples - 1) > RECURRENCE_MAX_TERMS

    def _gram(self, u: np.ndarray, dt: float, y: np.ndarray, response=None):
        """theta_nl (P, 2) = (τ, a) → normal equations (G (P, l, l), c (P, l), yᵀy) of the linear
        parameters (E0, E∞[, y0]) from the moments of v and d = x − v (basis [v + u_0, d, 1]): those
        of the SOE kernel, or with ``response`` (:meth:`_response`) summed from v."""
        u = readonly(u)
        y = readonly(y)
        u0 = float(u[0])
        x = u - u0
        L = min(self.memory_samples(dt), u.shape[0] - 1)
        n, sy, yy = float(u.shape[0]), float(y.sum()), float(y @ y)
        l = 3 if self.offset else 2

        def gram(theta_nl):
            tau, a = (np.ascontiguousarray(theta_nl[:, i]) for i in range(2))
            with np.errstate(all="ignore"):
                if response is None:
                    vv, vd, dd, sv, sd, vy, dy = soe_run(x, y, a, (tau / float(dt)) ** a, L, _SOE_MOMENTS).T
                else:
                    v = response(theta_nl)
                    dv = x[None, :] - v
                    vv, vd, dd = (np.einsum("pn,pn->p", p, q) for p, q in ((v, v), (v, dv), (dv, dv)))
                    sv, sd, vy, dy = v.sum(axis=1), dv.sum(axis=1), v @ y, dv @ y
                G = np.empty((tau.shape[0], l, l))
                G[:, 0, 0] = vv + 2.0 * u0 * sv + n * u0 * u0
                G[:, 0, 1] = G[:, 1, 0] = vd + u0 * sd
                G[:, 1, 1] = dd
                c = np.empty((tau.shape[0], l))
                c[:, 0] = vy + u0 * sy
                c[:, 1] = dy
                if l == 3:
                    G[:, 0, 2] = G[:, 2, 0] = sv + n * u0
                    G[:, 1, 2] = G[:, 2, 1] = sd
                    G[:, 2, 2] = n
                    c[:, 2] = sy
            return G, c, yy

        return gram

    def sse_evaluator(self, u: np.ndarray, dt: float, y: np.ndarray):
        """Long captures (:meth:`soe_route`): Σ(ŷ − y)² = θ_linᵀGθ_lin − 2cᵀθ_lin + yᵀy from the fused
        SOE normal equations (no (P, N) outputs). Short captures: the simulated sum (so that a
        warm-up prefix of a long capture, which is short, is subtracted as well)."""
        if not self.soe_route(len(u), dt):
            sim = self.simulator(u, dt)
            y_short = np.asarray(y, dtype=np.float64)

            def simulated(theta: np.ndarray) -> np.ndarray:
                e = sim(theta) - y_short[None, :]
                return np.einsum("ij,ij->i", e, e)

            return simulated
        gram = self._gram(u, dt, y)
        lin = [0, 1, 4] if self.offset else [0, 1]

        def sse(theta: np.ndarray) -> np.ndarray:
            theta = self.check_theta(theta, self.n_params)
            G, c, yy = gram(theta[:, [2, 3]])
            t = theta[:, lin]
            return yy - 2.0 * np.einsum("pl,pl->p", c, t) + np.einsum("pl,plk,pk->p", t, G, t)

        return sse

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self.simulator(u, dt)(theta)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[..., np.ndarray]:
        """θ (P, d) → outputs (P, N), optionally ``group``: consecutive groups of that many rows share
        τ and a (what :func:`separable_by_simulation` simulates; the FFT route then transforms the
        GL spectrum once per group — the same numbers)."""
        u = readonly(u)
        N = u.shape[0]
        d = self.n_params
        dt = float(dt)
        u0 = float(u[0]) if N else 0.0
        x = np.ascontiguousarray(u - u0)
        L = min(self.memory_samples(dt), max(N - 1, 0))
        offset = self.offset

        def finish(theta: np.ndarray, ydev: np.ndarray) -> np.ndarray:
            """y = ydev + E0·u_0 (+ y0), in place (``ydev`` is each route's own fresh array)."""
            ydev += (theta[:, 0] * u0)[:, None]
            if offset:
                ydev += theta[:, 4][:, None]
            return ydev

        if N == 0:
            return lambda theta, group=1: np.empty((self.check_theta(theta, d).shape[0], 0))

        if self.soe_route(N, dt):
            def sim_soe(theta: np.ndarray, group: int = 1) -> np.ndarray:
                theta = self.check_theta(theta, d)
                E0, Ei, tau, a = (np.ascontiguousarray(theta[:, i]) for i in range(4))
                with np.errstate(all="ignore"):
                    v = soe_run(x, None, a, (tau / dt) ** a, L, _SOE_OUTPUT).T  # (P, N)
                    ydev = E0[:, None] * v + Ei[:, None] * (x[None, :] - v)
                    return finish(theta, ydev)
            return sim_soe

        if L <= RECURRENCE_MAX_TERMS:
            def sim(theta: np.ndarray, group: int = 1) -> np.ndarray:
                theta = self.check_theta(theta, d)
                E0, Ei, tau, a = (np.ascontiguousarray(theta[:, i]) for i in range(4))
                with np.errstate(all="ignore"):
                    b = np.ascontiguousarray((tau / dt) ** a)
                    w = gl_weights(a, L)
                    ydev = gl_filter_population(x, w, np.ones_like(b), b, E0, np.ascontiguousarray(Ei * b)).T
                    return finish(theta, ydev)
            return sim

        deviation = self._fft_deviation(x, dt, L)

        def sim_fft(theta: np.ndarray, group: int = 1) -> np.ndarray:
            """Outputs (P, N); consecutive groups of ``group`` rows share τ and a (the separable basis)."""
            theta = self.check_theta(theta, d)
            return finish(theta, deviation(theta, group))

        return sim_fft

    def _fft_deviation(self, x: np.ndarray, dt: float, L: int) -> Callable[..., np.ndarray]:
        """The FFT evaluation (windows longer than :data:`RECURRENCE_MAX_TERMS`) of the deviation
        ydev (P, N) = H[x] for the input deviation x = u − u_0: θ (P, ≥ 4) → ydev, optionally
        ``group`` (consecutive groups of that many rows share τ and a)."""
        N = x.shape[0]
        dt = float(dt)
        M = sfft.next_fast_len(3 * N, real=True)
        r = _FFT_ALIAS ** (1.0 / M)
        rn = r ** np.arange(L + 1)
        X = sfft.rfft(x * r ** np.arange(N), M)
        inv_rn = r ** -np.arange(N, dtype=np.float64)

        # candidates per FFT block: bounds the complex work arrays (≈ 4 × 16 B × block × M/2) to
        # ~256 MB whatever the capture length (a 10⁶-sample capture goes one candidate at a time)
        block = max(1, FFT_BLOCK_ELEMENTS // (M // 2 + 1))

        def deviation(theta: np.ndarray, group: int = 1) -> np.ndarray:
            """ydev (P, N); the GL spectrum P_L(z) and the denominator 1 + bP_L(z) are computed once per
            group of rows, and only rows with a non-zero gain are transformed back."""
            P = theta.shape[0]
            ydev = np.empty((P, N))
            blk = max(group, block // group * group)
            with np.errstate(all="ignore"):
                for i in range(0, P, blk):
                    E0, Ei, tau, a = (np.ascontiguousarray(theta[i:i + blk, j]) for j in range(4))
                    b = (tau / dt) ** a
                    w = gl_weights(np.ascontiguousarray(a[::group]), L).T * rn  # (p, L+1), damped onto |z| = r
                    Pz = sfft.rfft(w, M, axis=1)
                    del w
                    ydev[i:i + blk] = self._inverse_fft(Pz, b, group, X, E0, Ei, M, N, inv_rn)
                    del Pz
            return ydev

        return deviation

    @staticmethod
    def _inverse_fft(Pz: np.ndarray, b: np.ndarray, group: int, X: np.ndarray, E0: np.ndarray, Ei: np.ndarray,
                     M: int, N: int, inv_rn: np.ndarray) -> np.ndarray:
        """ydev (p, N) = undamped irfft(H·X), H = (E0 + E∞bP)/(1 + bP) per row, P = Pz[row // group]
        (the rows of a group share b). Rows with E0 = E∞ = 0 (the θ_lin = 0 and offset columns of
        the separable basis) have H = 0/(1 + bP) = ±0 unless something is NaN: their output is 0
        (NaN if H has a NaN, as the transform would give) without a transform; H is computed for
        them only when their group's 1 + bP or b is not finite and non-zero (otherwise no NaN can
        arise). The same numbers, bit for bit, as H computed for every row."""
        den = 1.0 + b[::group, None] * Pz  # (p / group, K): each row's denominator, once per group
        zero = (E0 == 0.0) & (Ei == 0.0)
        keep = np.flatnonzero(~zero)
        out = np.empty((E0.shape[0], N))
        if keep.size < E0.shape[0]:
            rows = np.flatnonzero(zero)
            g = rows // group
            safe = (np.isfinite(b[::group]) & np.all(np.isfinite(Pz), axis=1) & np.all(np.isfinite(den), axis=1)
                    & (np.max(np.maximum(np.abs(den.real), np.abs(den.imag)), axis=1) > 1e-300))
            nan = np.zeros(rows.size, dtype=bool)
            risky = ~safe[g]
            if np.any(risky):
                r, gr = rows[risky], g[risky]
                H0 = (E0[r, None] + (Ei[r] * b[r])[:, None] * Pz[gr]) / den[gr]
                nan[risky] = np.any(np.isnan(H0), axis=1)
            out[rows] = np.where(nan, np.nan, 0.0)[:, None]
        if keep.size:
            g = keep // group
            H = (E0[keep, None] + (Ei[keep] * b[keep])[:, None] * Pz[g]) / den[g]
            H *= X
            out[keep] = sfft.irfft(H, M, axis=1)[:, :N] * inv_rn
        return out

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """State: [u_ref, (u − u_ref) history (newest first), (y − E0 u_ref) history], zero history."""
        n = self.memory_samples(dt)
        s = np.zeros(1 + 2 * n)
        s[0] = float(u0)
        return s

    def step(self, theta, state, u_prev, u_new, dt):
        th = np.asarray(theta, float).ravel()
        E0, Ei, tau, a = (float(v) for v in th[:4])
        y0 = float(th[4]) if self.offset else 0.0
        state = np.asarray(state, float)
        n = (state.shape[0] - 1) // 2
        u_ref = state[0]
        xh, yh = state[1:1 + n], state[1 + n:]
        u_new = np.asarray(u_new, dtype=np.float64)
        with np.errstate(all="ignore"):
            b = (tau / float(dt)) ** a
            w = gl_weights(np.array([a]), n)[1:, 0]
            Sx = float(w @ xh)
            Sy = float(w @ yh)
            xc = u_new - u_ref
            ydev = (E0 * xc + Ei * b * (xc + Sx) - b * Sy) / (1.0 + b)
            y = ydev + E0 * u_ref + y0
        C = u_new.shape[0]
        new = np.empty((C, state.shape[0]))
        new[:, 0] = u_ref
        if n:
            new[:, 1] = xc
            new[:, 2:1 + n] = xh[:-1]
            new[:, 1 + n] = ydev
            new[:, 2 + n:] = yh[:-1]
        return y, new

    # ------------------------------------------------------------------ inverse
    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Exact inverse: (E0 + E∞ b W) ũ = (1 + b W) ỹ with ỹ = y − y_target[0], u = u_0 + ũ.

        u_0 = (y_target[0] − y0)/E0 puts the stage at rest at the first target sample, as
        :meth:`simulate` assumes. ``u_range``, if given, clips the result (saturation).
        Needs E0 ≠ 0, E∞ of E0's sign or 0, τ ≥ 0 and 0 < a < 1 (then the inverse filter is stable:
        with both gains negative it is the positive case applied to −ỹ).
        """
        th = np.asarray(theta, float).ravel()
        E0, Ei, tau, a = (float(v) for v in th[:4])
        y0 = float(th[4]) if self.offset else 0.0
        if not (E0 != 0 and E0 * Ei >= 0 and tau >= 0 and 0 < a < 1):
            raise ConfigError(f"fp: the inverse needs E0 ≠ 0, Einf of E0's sign (or 0), tau ≥ 0 and 0 < a < 1 "
                              f"(got E0={E0:g}, Einf={Ei:g}, tau={tau:g}, a={a:g})")
        y = np.asarray(y_target, dtype=np.float64)
        N = y.shape[0]
        if N == 0:
            return np.empty(0)
        u0 = (y[0] - y0) / E0
        L = min(self.memory_samples(dt), N - 1)
        b = (tau / float(dt)) ** a
        w = gl_weights(np.array([a]), L)
        xdev = gl_filter_population(np.ascontiguousarray(y - y[0]), w, np.array([E0]), np.array([Ei * b]),
                                    np.array([1.0]), np.array([b]))[:, 0]
        u = u0 + xdev
        if u_range is not None:
            u = np.clip(u, min(u_range), max(u_range))
        return u
