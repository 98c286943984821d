"""Dahl hysteresis model (``shared/papers/README.md``; comparison model of paper 002)."""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np
from .._jit import njit, readonly

from ..params import DataScale, Param
from ..registry import models
from .base import Model
from .inverse import invert_from_rest
from .separable import Separable, separable_by_simulation


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (Dahl (exact solution along each input segment)). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

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
def dahl_moments(u, sigma, fc, a, y):
    """Σh, Σh², Σu·h, Σy·h per candidate (4, P) of the state h of :func:`dahl_population`, without
    the (N, P) states (samples summed in order; h(0) = 0 adds nothing)."""
    N = u.shape[0]
    P = sigma.shape[0]
    acc = np.zeros((4, P))
    h = np.zeros(P)
    for k in range(1, N):
        du = u[k] - u[k - 1]
        uk = u[k]
        yk = y[k]
        for p in range(P):
            hk = _dahl_advance(h[p], du, sigma[p], fc[p], a[p])
            h[p] = hk
            acc[0, p] += hk
            acc[1, p] += hk * hk
            acc[2, p] += uk * hk
            acc[3, p] += yk * hk
    return acc


@njit(cache=True, error_model="numpy")
def dahl_output(u, k, d0, h, group):
    """Outputs (P, N): y_p = k_p u + h_{p // group} + d0_p with the state h (N, P / group) of
    :func:`dahl_population` — the numbers of ``k[:, None] * u + h.T + d0[:, None]`` (the same
    operations in the same order) without the repeated state and the two temporaries."""
    N = u.shape[0]
    P = k.shape[0]
    out = np.empty((P, N))
    for p in range(P):
        g = p // group
        kp = k[p]
        dp = d0[p]
        for n in range(N):
            out[p, n] = kp * u[n] + h[n, g] + dp
    return out


@njit(cache=True, error_model="numpy")
def dahl_step(h0, u_prev, u_new, sigma, fc, a):
    """One Dahl sample from state h0 for candidate inputs u_new (C,) → new states (C,)."""
    C = u_new.shape[0]
    out = np.empty(C)
    for i in range(C):
        out[i] = _dahl_advance(h0, u_new[i] - u_prev, sigma, fc, a)
    return out


@models.register
@dataclass(frozen=True)
class Dahl(Model):
    r"""Dahl model: a linear term plus a Dahl friction-type hysteretic state.

    .. math::

        y = k\,u + h + d_0,\qquad
        \dot h = \sigma\,\dot u\,\bigl|1 - \tfrac{h}{F}\,\mathrm{sgn}\,\dot u\bigr|^{a}
                 \,\mathrm{sgn}\bigl(1 - \tfrac{h}{F}\,\mathrm{sgn}\,\dot u\bigr),
        \qquad F = \mathrm{sgn}(\sigma)\,F_c,\qquad h(0) = 0

    Five parameters (k, σ, F_c, a, d0) as counted in paper 002 Table 3; the equation is the one
    ``shared/papers/README.md`` adopts.

    Orientation (our convention, argued). The Dahl equation is invariant under
    (σ, F_c, h) → (−σ, −F_c, −h). We take F_c > 0 as the *magnitude* of the saturation level
    and let σ carry the sign (F = sgn(σ) F_c). With σ > 0 this is exactly the README's equation
    (clockwise loop in (u, y): the state saturates at +F_c while u rises); σ < 0 gives the
    counter-clockwise loop of piezo stacks (h → −F_c while u rises). Written the README's way,
    the counter-clockwise case needs σ and F_c both negative, a box containing that would also
    contain the unstable quadrants (σ F_c < 0) and the singular F_c = 0; ours has neither.

    Integration. The model is rate independent: along each sample's straight input segment
    (s = sgn Δu, v = |u| travelled), x = 1 − s h/F obeys dx/dv = −(σ/F) |x|^a sgn x, which has
    the closed-form solution |x|^{1−a} = |x_0|^{1−a} − (1 − a)(σ/F) v (|x| = |x_0| e^{−(σ/F)v}
    for a = 1; for a < 1, x reaches 0 in finite v and stays). The kernel uses it, so the state
    is exact for piecewise-linear inputs at any sample rate and any a — no sub-steps
    (:func:`hystfit.models.dahl.dahl_population`).

    Parameters (θ)
    --------------
    k : out/V, linear gain.
    sigma : out/V, slope of h right after a reversal from h = 0; sign = loop orientation.
    Fc : out, saturation level of h (> 0); the loop's half-height about the linear term.
    a : 1, shape exponent (a = 1 exponential approach; a < 1 reaches saturation in finite travel).
    d0 : out, output offset.

    Identifiability. σ/F_c is a rate per volt: when σ ΔU/F_c ≫ 1 the state saturates right
    after each reversal and only F_c (and k) are determined, σ and a trading against each other
    near the reversals; when σ ΔU/F_c ≪ 1 the state never saturates, h ≈ σ·(travel) and σ merges
    with k while F_c is poorly determined. Between (σΔU/F_c of a few) all five are identifiable,
    a the least precisely.

    Inverse: the generic per-sample numerical inverse on :meth:`step`, started at rest at
    u_0 = (y_0 − d0)/k as :meth:`simulate` starts (h = 0 there). It needs the one-step map to
    increase with u_k: right after a reversal from saturation the slope is k + σ·2^a, so a
    counter-clockwise loop (σ < 0) needs |σ| 2^a < k — true of any physical loop, whose
    slope stays positive.

    Bounds (data-scaled; g = output range / input range): k ∈ [−3, 3] g, σ ∈ [−30, 30] g,
    F_c ∈ [10⁻³, 1]·(output range), a ∈ [0.25, 4], d0 within one output range of the data.
    """

    name = "dahl"
    title = "Dahl"
    reference = "shared/papers/README.md (Dahl); paper 002 §4 comparison model, 5 parameters"
    equation = "y = k·u + h + d0,  dh/dt = σ·du/dt·|1 − (h/F)·sgn(du/dt)|^a·sgn(1 − (h/F)·sgn(du/dt)),  F = sgn(σ)·Fc"
    rate_dependent = False

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, yr = scale.gain, scale.y_range
        return (
            Param("k", "out/V", -3 * g, 3 * g, g, "linear gain"),
            Param("sigma", "out/V", -30 * g, 30 * g, -0.2 * g,
                  "initial slope σ of h after a reversal (sign = orientation)"),
            Param("Fc", "out", 1e-3 * yr, yr, 0.05 * yr, "saturation level F_c of h"),
            Param("a", "1", 0.25, 4.0, 1.0, "shape exponent a"),
            Param("d0", "out", *scale.offset_bounds(), 0.0, "output offset"),
        )

    def separable(self):
        """k and d0 enter linearly; σ, Fc and a (the friction state's shape) are searched. The basis
        [u, 1] with the known part h: the basis is simulated with h once per candidate
        (:meth:`_simulate`), the normal equations come from h's sums (:func:`dahl_moments`: one
        pass, O(P) memory, no (P, N) outputs)."""
        exact = separable_by_simulation(self, (0, 4), 5,
                                        grouped=lambda u, dt: lambda th, g: self._simulate(th, u, g))
        return Separable(exact.linear, exact.nonlinear, exact.basis_factory, self._gram, gram_fused=True)

    def _gram(self, u: np.ndarray, dt: float, y: np.ndarray):
        """theta_nl (P, 3) = (σ, Fc, a) → normal equations (G, c, tᵀt) of (k, d0) for the target t = y − h."""
        u = readonly(u)
        y = readonly(y)
        n, su, sy = float(u.shape[0]), float(u.sum()), float(y.sum())
        uu, uy, yy = float(u @ u), float(u @ y), float(y @ y)

        def gram(theta_nl):
            sig, fc, a = (np.ascontiguousarray(theta_nl[:, i]) for i in range(3))
            with np.errstate(all="ignore"):
                sh, hh, uh, yh = dahl_moments(u, sig, fc, a, y)
                P = sig.shape[0]
                G = np.empty((P, 2, 2))
                G[:, 0, 0] = uu
                G[:, 0, 1] = G[:, 1, 0] = su
                G[:, 1, 1] = n
                c = np.empty((P, 2))
                c[:, 0] = uy - uh
                c[:, 1] = sy - sh
                tt = yy - 2.0 * yh + hh
            return G, c, tt

        return gram

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self._simulate(theta, readonly(u), 1)

    def _simulate(self, theta: np.ndarray, u: np.ndarray, group: int) -> np.ndarray:
        """Outputs (P, N); consecutive groups of ``group`` rows of θ share σ, Fc and a, so the
        state h (the costly part) is simulated for the first row of each group only."""
        theta = self.check_theta(theta, 5)
        k, sig, fc, a, d0 = (np.ascontiguousarray(theta[:, i]) for i in range(5))
        h = dahl_population(u, sig[::group].copy(), fc[::group].copy(), a[::group].copy())
        return dahl_output(u, k, d0, h, group)

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """State: h, zero before the first sample."""
        return np.zeros(1)

    def step(self, theta, state, u_prev, u_new, dt):
        k, sig, fc, a, d0 = (float(v) for v in np.asarray(theta, float).ravel())
        u_new = np.ascontiguousarray(u_new, dtype=np.float64)
        h = dahl_step(float(state[0]), float(u_prev), u_new, sig, fc, a)
        with np.errstate(all="ignore"):
            return k * u_new + h + d0, h[:, None]

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Generic per-sample numerical inverse, started where :meth:`simulate` starts.

        :meth:`simulate` puts the stage at rest at the first input (zero state, no rate), so the
        first sample is the static inverse u_0 = (y_0 − d0)/k and the per-sample search
        (:func:`hystfit.models.inverse.invert_by_stepping`) continues from there.
        """
        th = np.asarray(theta, float).ravel()
        return invert_from_rest(self, th, y_target, dt, th[0], th[4], u_range)

    def _inverse_range(self, theta: np.ndarray, y_target: np.ndarray) -> tuple[float, float]:
        """Search window of the numerical inverse: the static inverse ± the hysteresis, widened."""
        k, sig, fc, a, d0 = (float(v) for v in np.asarray(theta, float).ravel())
        yt = np.asarray(y_target, float)
        kk = abs(k) if k != 0 else 1e-12
        c = [(float(yt.min()) - d0) / kk, (float(yt.max()) - d0) / kk]
        lo, hi = min(c), max(c)
        pad = 0.5 * (hi - lo) + 2.0 * fc / kk
        return lo - pad, hi + pad
