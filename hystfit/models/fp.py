"""Four-parameter fractional Zener model (Pritz 1996; ``shared/papers/README.md``, 002's "FP")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from .._jit import njit
from .._lazy import lazy_module
from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from .base import Model, OptionalOffset
from .separable import separable_by_simulation

sfft = lazy_module("scipy.fft")  # imported on first use: keeps start-up fast

#: Memory windows up to this many past samples use the direct recurrence; longer ones the FFT.
RECURRENCE_MAX_TERMS = 200
#: r^M of the z-transform circle used by the FFT evaluation (aliasing error ≈ this · N).
_FFT_ALIAS = 1e-14
#: complex spectrum elements per FFT block of candidates (≈ 64 MB per work array)
FFT_BLOCK_ELEMENTS = 4_000_000


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
        g, yr = scale.gain, scale.y_range
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
            ps.append(Param("y0", "out", scale.y_min - yr, scale.y_max + yr, 0.0, "output offset"))
        return tuple(ps)

    # ------------------------------------------------------------------ simulation
    def separable(self):
        """E0, E∞ (and y0) enter linearly for fixed (τ, a): the fractional operator is linear, so
        y = E0·L⁻¹[u] + E∞·L⁻¹[τ^a D^a u] + y0 with L = 1 + τ^a D^a. Only τ and a are searched."""
        return separable_by_simulation(self, (0, 1, 4) if self.offset else (0, 1), 5 if self.offset else 4)

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self.simulator(u, dt)(theta)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        u = np.ascontiguousarray(u, dtype=np.float64)
        N = u.shape[0]
        d = self.n_params
        dt = float(dt)
        u0 = float(u[0]) if N else 0.0
        x = np.ascontiguousarray(u - u0)
        L = min(self.memory_samples(dt), max(N - 1, 0))
        offset = self.offset

        def finish(theta: np.ndarray, ydev: np.ndarray) -> np.ndarray:
            y = ydev + (theta[:, 0] * u0)[:, None]
            if offset:
                y = y + theta[:, 4][:, None]
            return y

        if N == 0:
            return lambda theta: np.empty((self.check_theta(theta, d).shape[0], 0))

        if L <= RECURRENCE_MAX_TERMS:
            def sim(theta: np.ndarray) -> np.ndarray:
                theta = self.check_theta(theta, d)
                E0, Ei, tau, a = (np.ascontiguousarray(theta[:, i]) for i in range(4))
                with np.errstate(all="ignore"):
                    b = np.ascontiguousarray((tau / dt) ** a)
                    w = gl_weights(a, L)
                    ydev = gl_filter_population(x, w, np.ones_like(b), b, E0, np.ascontiguousarray(Ei * b)).T
                    return finish(theta, ydev)
            return sim

        M = sfft.next_fast_len(3 * N, real=True)
        r = _FFT_ALIAS ** (1.0 / M)
        rn = r ** np.arange(L + 1)
        X = sfft.rfft(x * r ** np.arange(N), M)
        inv_rn = r ** -np.arange(N, dtype=np.float64)

        # candidates per FFT block: bounds the complex work arrays (≈ 4 × 16 B × block × M/2) to
        # ~256 MB whatever the capture length (a 10⁶-sample capture goes one candidate at a time)
        block = max(1, FFT_BLOCK_ELEMENTS // (M // 2 + 1))

        def sim_fft(theta: np.ndarray) -> np.ndarray:
            theta = self.check_theta(theta, d)
            P = theta.shape[0]
            ydev = np.empty((P, N))
            with np.errstate(all="ignore"):
                for i in range(0, P, block):
                    E0, Ei, tau, a = (np.ascontiguousarray(theta[i:i + block, j]) for j in range(4))
                    b = (tau / dt) ** a
                    w = gl_weights(a, L).T * rn  # (p, L+1), damped onto |z| = r
                    Pz = sfft.rfft(w, M, axis=1)
                    del w
                    H = (E0[:, None] + (Ei * b)[:, None] * Pz) / (1.0 + b[:, None] * Pz)
                    del Pz
                    H *= X
                    ydev[i:i + block] = sfft.irfft(H, M, axis=1)[:, :N] * inv_rn
                    del H
                return finish(theta, ydev)

        return sim_fft

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
