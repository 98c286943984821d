"""Electromechanical model: PI hysteresis followed by a second-order linear subsystem (paper 000)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from .._jit import njit

from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import play_matrix
from .base import Model
from .pi import PI


@njit(cache=True)
def biquad_columns(x, b0, b1, b2, a1, a2):
    """Filter every column of x (N, M) with its own biquad, each starting at rest at x[0, m].

    y[k] = x[0] + e[k],  e[k] = b0 d[k] + b1 d[k−1] + b2 d[k−2] − a1 e[k−1] − a2 e[k−2],
    d[k] = x[k] − x[0], d[<0] = e[<0] = 0 (direct form I on deviations from the first sample).

    For a unit-DC-gain filter this is exactly the response from rest at x[0] (the filter has
    seen x[0] forever), computed without the cancellation of a large offset through poles near
    z = 1. Layout (``shared/PERFORMANCE.md``): time outermost, columns innermost and contiguous.
    A column with non-finite coefficients gives non-finite output (never an exception).

    Parameters
    ----------
    x : (N, M) float64 inputs.  b0, b1, b2, a1, a2 : (M,) coefficients (a0 = 1).

    Returns
    -------
    (N, M) float64 outputs.
    """
    N, M = x.shape
    out = np.empty((N, M))
    if N == 0:
        return out
    x0 = x[0].copy()
    d1 = np.zeros(M)
    d2 = np.zeros(M)
    e1 = np.zeros(M)
    e2 = np.zeros(M)
    for k in range(N):
        for m in range(M):
            d = x[k, m] - x0[m]
            e = b0[m] * d + b1[m] * d1[m] + b2[m] * d2[m] - a1[m] * e1[m] - a2[m] * e2[m]
            d2[m] = d1[m]
            d1[m] = d
            e2[m] = e1[m]
            e1[m] = e
            out[k, m] = e + x0[m]
    return out


def bilinear_biquad(fn_Hz, zeta, dt: float):
    """Prewarped bilinear (Tustin) discretization of ω_n²/(s² + 2ζω_n s + ω_n²), per candidate.

    s = K (1 − z⁻¹)/(1 + z⁻¹), K = ω_n / tan(ω_n Ts/2) (prewarping: the resonance ω_n maps
    exactly). Closed form, a0 = K² + 2ζω_n K + ω_n²:

        a1 = 2(ω_n² − K²)/a0,  a2 = (K² − 2ζω_n K + ω_n²)/a0,  b = g·[1, 2, 1],  g = (1 + a1 + a2)/4

    The numerator is built from the denominator so that the static gain H(1) = 4g/(1 + a1 + a2)
    is 1 to one rounding (analytically it is exactly 1). Candidates with f_n outside (0, f_s/2)
    or ζ < 0 get NaN coefficients (their simulation is non-finite, scored +inf by the objective).

    Returns
    -------
    b0, b1, b2, a1, a2 : (P,) float64 arrays.
    """
    fn = np.atleast_1d(np.asarray(fn_Hz, dtype=np.float64))
    z = np.atleast_1d(np.asarray(zeta, dtype=np.float64))
    with np.errstate(all="ignore"):
        wn = 2.0 * np.pi * fn
        ok = (fn > 0) & (fn * dt < 0.5) & (z >= 0) & np.isfinite(fn) & np.isfinite(z)
        K = wn / np.tan(0.5 * wn * dt)
        a0 = K * K + 2.0 * z * wn * K + wn * wn
        a1 = 2.0 * (wn * wn - K * K) / a0
        a2 = (K * K - 2.0 * z * wn * K + wn * wn) / a0
        g = 0.25 * (1.0 + a1 + a2)
    nan = np.full_like(g, np.nan)
    a1, a2, g = (np.where(ok, c, nan) for c in (a1, a2, g))
    return g, 2.0 * g, g.copy(), a1, a2


@models.register
@dataclass(frozen=True)
class PI2(Model):
    r"""Electromechanical model: classical PI hysteresis driving a second-order linear subsystem.

    .. math::

        \ddot y + 2\zeta\omega_n \dot y + \omega_n^2 y = \omega_n^2\, g\, H[u],\qquad
        H[u] = \sum_{j=0}^{n-1} w_j F_{r_j}[u],\qquad \omega_n = 2\pi f_n

        y_{\text{meas}} = y + y_0

    (paper 000, Fig. 3 and eq. 20–21: "a second-order linear subsystem preceded by a hysteresis
    nonlinearity"; formulation of ``shared/papers/README.md``, with the classical PI of paper
    003 eq. 1–3 as H, reused from :class:`hystfit.models.pi.PI`).

    Structure
    ---------
    n_operators, placement, thresholds_V, nonnegative : the PI part, as in :class:`PI`
    (thresholds filled from the identification data by :meth:`adapt`).

    Parameters (θ), in this order
    -----------------------------
    w0 … w{n−1} : PI weights including the static gain g (output unit per V). g is folded into
        the weights: g·w_j is all the data can determine (only products appear), so a separate
        g would be an exactly non-identifiable direction. Because the filter's static gain is 1,
        the weights keep the meaning they have in :class:`PI` (quasi-static loop).
    y0 : output offset (output unit), added after the filter (equivalent: unit static gain).
    fn_Hz : natural frequency f_n (Hz). Bounds from the data: lower min(max(5·f_exc, 0.002·f_s),
        0.05·f_s) with f_exc = rate_max/(π·input range) (the frequency of a sine with the
        captures' range and peak rate), upper 0.45·f_s. A resonance inside the excitation band
        would be an implausible explanation of a piezo loop (a low-pass with strong damping
        mimics the rate-dependent widening of the loop), hence the lower bound.
    zeta : damping ratio ζ (1), in [0.01, 2].

    Solution of the linear part. Paper 000 replaces RK4 by a fast exact solution ("symmetric
    solutions"); we discretize the transfer function once per candidate and filter exactly:
    prewarped bilinear (Tustin) transform (:func:`bilinear_biquad`), state at rest at the
    first sample. Bilinear rather than zero-order hold because (a) it is the trapezoidal rule:
    for the sampled, smooth PI output it is second-order accurate and adds no half-sample
    delay (ZOH would, i.e. a phase error of ω·Ts/2 — 0.75 µm on a 60 µm, 80 Hz loop at
    10 kHz), (b) prewarping places the resonance exactly, (c) it is unconditionally stable,
    and (d) it is what hystfit's virtual actuator uses (:mod:`hystfit.synth`), so the model
    can represent that plant exactly. The population is filtered by a numba biquad kernel,
    time outermost, candidates innermost (:func:`biquad_columns`).

    Exploited structure: for fixed (f_n, ζ) the output is linear in (w, y0) —
    :meth:`design_matrix` (filtered play outputs and ones), and :meth:`separable` for the
    ``auto`` optimizer (only f_n and ζ are searched).

    Inverse (:meth:`invert`): dynamic inversion of the linear part, then the analytic PI inverse
    (paper 003 eq. 17–20). The discrete filter's exact inverse is unusable: the bilinear
    numerator g(1 + z⁻¹)² has a double zero *on* the unit circle (z = −1), so the exact inverse
    carries an undamped, linearly growing alternating mode. We invert the continuous equation
    v = y + (2ζ/ω_n) ẏ + ÿ/ω_n² with derivatives consistent with the bilinear map,
    s ≈ (K/4)(q − q⁻¹), s² ≈ (K²/4)(q − 2 + q⁻¹) (q the one-sample advance; both equal the
    exact bilinear operator times cos²(θ/2) at normalized frequency θ), plus one correction
    step that removes the cos²(θ/2) factor to O(θ⁴). Limits: the target must be smooth
    (the inverse amplifies content above f_n by (f/f_n)²; noise or steps in y_d give large
    voltage spikes), the input uses one sample of preview (y_d[k+1]), and the signal is taken
    at rest before the first sample and held after the last.
    """

    name = "pi2"
    title = "PI hysteresis + second-order dynamics (electromechanical)"
    reference = "paper 000 (second-order linear subsystem preceded by hysteresis); PI of paper 003 eq. 1–3"
    equation = "y'' + 2ζω_n y' + ω_n² y = ω_n² Σ_j w_j F_{r_j}[u],  y_meas = y + y0,  ω_n = 2π f_n"
    rate_dependent = True

    n_operators: int = 10
    placement: str = "uniform"
    thresholds_V: tuple[float, ...] | None = None
    nonnegative: bool = True

    def __post_init__(self) -> None:
        try:
            self.pi
        except ConfigError as exc:
            raise ConfigError(f"pi2: {str(exc).removeprefix('pi: ')}") from None

    # ------------------------------------------------------------------ structure
    @property
    def pi(self) -> PI:
        """The hysteresis part as a classical :class:`PI` (same structure fields)."""
        return PI(self.n_operators, self.placement, self.thresholds_V, self.nonnegative)

    def adapt(self, scale: DataScale) -> "PI2":
        if self.thresholds_V is not None:
            return self
        return replace(self, thresholds_V=self.pi.adapt(scale).thresholds_V)

    @property
    def n_params(self) -> int:
        return self.n_operators + 3

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        fs = 1.0 / scale.dt
        f_exc = scale.rate_max / (math.pi * scale.u_range)
        f_lo = min(max(5.0 * f_exc, 0.002 * fs), 0.05 * fs)
        f_hi = 0.45 * fs
        return self.pi.params(scale) + (
            Param("fn_Hz", "Hz", f_lo, f_hi, math.sqrt(f_lo * f_hi), "natural frequency f_n of the linear subsystem"),
            Param("zeta", "1", 0.01, 2.0, 0.2, "damping ratio ζ of the linear subsystem"),
        )

    # ------------------------------------------------------------------ simulation
    def _filter(self, v: np.ndarray, fn: np.ndarray, zeta: np.ndarray, dt: float) -> np.ndarray:
        """Filter the columns of v (N, M) with per-column (f_n, ζ) (M,): (N, M)."""
        b0, b1, b2, a1, a2 = bilinear_biquad(fn, zeta, dt)
        return biquad_columns(np.ascontiguousarray(v), b0, b1, b2, a1, a2)

    def design_matrix(self, u: np.ndarray, dt: float, fn_Hz: float, zeta: float) -> np.ndarray:
        """Regressors (N, n + 1) for fixed (f_n, ζ): filtered play outputs and a column of ones.

        y = Φ·[w0 … w{n−1}, y0] exactly (the filter is linear and has unit static gain), so the
        weights follow from (non-negative) least squares for every candidate dynamics.
        """
        u = np.ascontiguousarray(u, dtype=np.float64)
        F = play_matrix(u, self.pi.r)
        n = self.n_operators
        Ff = self._filter(F, np.full(n, float(fn_Hz)), np.full(n, float(zeta)), dt)
        return np.hstack([Ff, np.ones((u.shape[0], 1))])

    def _simulate_from_plays(self, theta: np.ndarray, F: np.ndarray, dt: float) -> np.ndarray:
        n = self.n_operators
        theta = self.check_theta(theta, n + 3)
        v = np.ascontiguousarray(F @ theta[:, :n].T)  # (N, P) hysteresis outputs
        y = self._filter(v, theta[:, n + 1], theta[:, n + 2], dt)
        y += theta[:, n][None, :]
        return y.T

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        u = np.ascontiguousarray(u, dtype=np.float64)
        return self._simulate_from_plays(theta, play_matrix(u, self.pi.r), dt)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        F = play_matrix(np.ascontiguousarray(u, dtype=np.float64), self.pi.r)  # once per capture
        return lambda theta: self._simulate_from_plays(theta, F, dt)

    def separable(self):
        """Weights and y0 enter linearly; only (f_n, ζ) are searched (variable projection)."""
        from ..separable import Separable

        n = self.n_operators

        def factory(u, dt):
            F = play_matrix(np.ascontiguousarray(u, dtype=np.float64), self.pi.r)
            N = F.shape[0]

            def basis(theta_nl):
                theta_nl = np.atleast_2d(theta_nl)
                P = theta_nl.shape[0]
                X = np.tile(F, (1, P))  # (N, P·n): candidate-major blocks of the n plays
                fn = np.repeat(theta_nl[:, 0], n)
                ze = np.repeat(theta_nl[:, 1], n)
                Xf = self._filter(X, fn, ze, dt).reshape(N, P, n)
                B = np.empty((P, N, n + 1))
                B[:, :, :n] = Xf.transpose(1, 0, 2)
                B[:, :, n] = 1.0
                return B

            return basis

        return Separable(tuple(range(n + 1)), (n + 1, n + 2), factory)

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """[play states (n), d[k−1], d[k−2], e[k−1], e[k−2], v0] after the first sample u0.

        The filter memory is that of :func:`biquad_columns` (deviations from the first PI
        output v0, all zero at rest); stepping from here reproduces :meth:`simulate` from the
        second sample on.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        r = self.pi.r
        plays = np.maximum(u0 - r, np.minimum(u0 + r, 0.0))
        return np.r_[plays, 0.0, 0.0, 0.0, 0.0, plays @ t[: self.n_operators]]

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and states (C, n + 5)."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        state = np.asarray(state, dtype=np.float64)
        u_new = np.atleast_1d(np.asarray(u_new, dtype=np.float64))
        r = self.pi.r
        plays = np.maximum(u_new[:, None] - r[None, :], np.minimum(u_new[:, None] + r[None, :], state[None, :n]))
        d1, d2, e1, e2, v0 = state[n:n + 5]
        b0, b1, b2, a1, a2 = (float(c[0]) for c in bilinear_biquad(t[n + 1], t[n + 2], dt))
        d = plays @ t[:n] - v0
        e = b0 * d + b1 * d1 + b2 * d2 - a1 * e1 - a2 * e2
        C = u_new.shape[0]
        new = np.hstack([plays, d[:, None], np.full((C, 1), d1), e[:, None], np.full((C, 1), e1), np.full((C, 1), v0)])
        return e + v0 + t[n], new

    # ------------------------------------------------------------------ inverse
    def invert_dynamics(self, theta: np.ndarray, y_target: np.ndarray, dt: float) -> np.ndarray:
        """Hysteresis output v (N,) that drives the linear part along ``y_target`` (offset included).

        v = y + (2ζ/ω_n)·S y + S² y/ω_n² with the bilinear-consistent central differences
        S ≈ (K/4)(y[k+1] − y[k−1]), S² ≈ (K²/4)(y[k+1] − 2y[k] + y[k−1]), K = ω_n/tan(ω_n Ts/2),
        then the dynamic correction c = v − y is sharpened once, c ← 2c − M c with the 3-tap
        smoother M = [1, 2, 1]/4 (M is the cos²(θ/2) factor of the central differences; 2 − M
        inverts it to O(θ⁴)). y is held at y[0] before the first and at y[N−1] after the last sample.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        fn, zeta = float(t[n + 1]), float(t[n + 2])
        if not (0 < fn * dt < 0.5 and zeta >= 0):
            raise ConfigError(f"pi2: cannot invert with fn_Hz={fn:g} (must lie in (0, fs/2)) and zeta={zeta:g}")
        wn = 2.0 * math.pi * fn
        K = wn / math.tan(0.5 * wn * dt)
        y = np.asarray(y_target, dtype=np.float64)
        yp = np.concatenate([[y[0]], y, [y[-1]]])
        d1 = 0.25 * K * (yp[2:] - yp[:-2])
        d2 = 0.25 * K * K * (yp[2:] - 2.0 * y + yp[:-2])
        c = (2.0 * zeta / wn) * d1 + d2 / (wn * wn)
        cp = np.concatenate([[0.0], c, [c[-1]]])  # at rest before (c = 0), held after
        c = 2.0 * c - 0.25 * (cp[2:] + 2.0 * c + cp[:-2])
        c[0] = 0.0  # the filter starts at rest at its first input: y[0] = v[0] whatever comes next
        return y + c

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) for a smooth target ``y_target``: dynamic inversion, then the PI inverse.

        See the class docstring for the method and its limits (smooth target, one sample of
        preview). ``u_range`` is accepted for interface compatibility and ignored: both steps
        are analytic.
        """
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        if t.size != n + 3:
            raise ValueError(f"pi2: theta must have {n + 3} entries, got {t.size}")
        v = self.invert_dynamics(t, y_target, dt)
        return self.pi.invert(t[: n + 1], v, dt)
