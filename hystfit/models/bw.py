"""Bouc–Wen hysteresis model (paper 004 eq. 1–2)."""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np
from .._jit import njit, readonly

from ..params import DataScale, Param
from ..registry import models
from ._kernels import bouc_wen_moments, bouc_wen_output, bouc_wen_population, bouc_wen_sse, bouc_wen_step
from .base import Model
from .separable import Separable


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (Bouc–Wen with a free exponent n ≥ 1 (sub-stepped RK4 in the input)). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

#: Bouc–Wen free exponent: largest |Jacobian|·(sub-step length) of one RK4 sub-step.
BWN_STEP_RATIO = 0.05
#: Bouc–Wen free exponent: most RK4 sub-steps per sample (only diverging parameters reach it).
BWN_MAX_SUBSTEPS = 1000


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


@models.register
@dataclass(frozen=True)
class BoucWen(Model):
    r"""Bouc–Wen model with exponent n = 1.

    .. math::

        y = K_v\,u + h + y_0,\qquad
        \dot h = \alpha\,\dot u - \beta\,|\dot u|\,h - \gamma\,\mathrm{sgn}(\alpha)\,\dot u\,|h|,
        \qquad h(0) = 0

    (paper 004 eq. 1–2 with n = 1, as ``shared/papers/README.md`` adopts, with paper 004's γ
    written γ·sgn(α): see "Sign convention" below). The output offset y0 is ours: real captures
    carry a sensor offset. This is the equation simulated *and* the one printed in ``params.json``
    (:attr:`equation`) for the stored values: ``tests/unit/test_bw_printed_equation.py`` integrates
    the printed equation with the printed values independently and matches hystfit.

    Parameters (θ)
    --------------
    Kv : linear gain, output unit per V.
    alpha : hysteresis input gain, output unit per V.
    beta, gamma : shape parameters, 1/V; β + γ sets how fast h saturates along the input,
        β − γ the other branch; h saturates at α/(β+γ).
    y0 : output offset, output unit.

    Integration. Bouc–Wen is rate independent, so h is integrated in the input along each
    sample's straight input segment. For n = 1 and fixed signs of u̇ and h the equation is
    linear in h and is solved exactly (with the zero crossing of h located exactly), see
    :func:`hystfit.models._kernels.bouc_wen_population`: no sub-steps, stable at any sample
    rate, exact for piecewise-linear inputs.

    Sign convention of γ. θ stores γ such that paper 004's γ is γ·sgn(α) (identical for α ≥ 0,
    the case paper 004 bounds to; on real captures α often comes out negative, and then the
    textbook γ is −γ). Then h = α·g exactly, with g the solution of
    ġ = u̇ − β|u̇|g − γu̇|g| for *either* sign of α: the output is linear in (Kv, α, y0) and the
    ``auto`` optimizer solves them exactly, searching only (β, γ). Without this convention the
    split would be wrong for α < 0 (|h| = |α||g|), and loops of both orientations (clockwise and
    counter-clockwise) must be representable.

    Free exponent (structure ``free_exponent=True``, paper 004 eq. 2 with n free):
    ḣ = α u̇ − β |u̇| |h|^{n−1} h − γ u̇ |h|^n, integrated with stable sub-steps
    (:func:`hystfit.models.bw.bouc_wen_n_population`); θ gains ``n`` ∈ [1, 4]. Since
    the units of β, γ depend on n, they are searched normalised: β_phys = β·h_ref^{1−n} with
    h_ref = the output range of the identification data (saved in the structure), so at n = 1
    they mean exactly what they mean in the default model.

    Bounds scale with the data: Kv, α in [−3, 3]·gain (gain = output range / input range),
    β in [0, 50]/ΔU, γ in [−50, 50]/ΔU with ΔU the input range; paper 004 uses [0.1, 10] on
    its own scale.
    """

    name = "bw"
    title = "Bouc–Wen"
    reference = "paper 004 eq. 1–2"
    #: the equation simulated, in the stored θ (γ multiplies sgn(α): paper 004's γ is γ·sgn(α));
    #: with ``free_exponent`` h becomes |h|^(n−1)·h and |h|^n, β and γ scaled by h_ref^(1−n)
    equation = "y = Kv·u + h + y0,  dh/dt = α·du/dt − β·|du/dt|·h − γ·sgn(α)·du/dt·|h|"
    rate_dependent = False

    free_exponent: bool = False
    h_ref: float | None = None

    def adapt(self, scale: DataScale) -> "BoucWen":
        if self.free_exponent and self.h_ref is None:
            return BoucWen(free_exponent=True, h_ref=float(scale.y_range))
        return self

    @property
    def d(self) -> int:
        return 6 if self.free_exponent else 5

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, du = scale.gain, scale.u_range
        ps = (
            Param("Kv", "out/V", -3 * g, 3 * g, g, "linear gain"),
            Param("alpha", "out/V", -3 * g, 3 * g, 0.1 * g, "hysteresis input gain α"),
            Param("beta", "1/V", 0.0, 50.0 / du, 2.0 / du, "shape parameter β (normalised by h_ref^(1−n) when n is free)"),
            Param("gamma", "1/V", -50.0 / du, 50.0 / du, 0.0, "shape parameter γ, multiplies sgn(α)·u̇·|h| (paper 004's γ = γ·sgn(α); normalised by h_ref^(1−n) when n is free)"),
            Param("y0", "out", *scale.offset_bounds(), 0.0, "output offset"),
        )
        if self.free_exponent:
            ps += (Param("n", "1", 1.0, 4.0, 1.0, "Bouc–Wen exponent n"),)
        return ps

    def _physical(self, theta: np.ndarray):
        """(Kv, α, β, γ, y0, n) of paper 004's equation: γ_paper = γ·sgn(α), and with a free
        exponent β, γ de-normalised by h_ref^(1−n)."""
        kv, a, b, g, y0 = (np.ascontiguousarray(theta[:, i]) for i in range(5))
        g = np.ascontiguousarray(g * np.where(a < 0, -1.0, 1.0))  # γ_paper = γ·sgn(α), see the class docstring
        if not self.free_exponent:
            return kv, a, b, g, y0, None
        n = np.ascontiguousarray(theta[:, 5])
        f = float(self.h_ref or 1.0) ** (1.0 - n)
        return kv, a, np.ascontiguousarray(b * f), np.ascontiguousarray(g * f), y0, n

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, self.d)
        u = readonly(u)
        kv, a, b, g, y0, n = self._physical(theta)
        if n is None:
            return bouc_wen_output(u, kv, a, b, g, y0).T  # (P, N) view of the kernel's (N, P); exact for n = 1
        h = bouc_wen_n_population(u, a, b, g, n).T
        return kv[:, None] * u[None, :] + h + y0[:, None]

    def sse_evaluator(self, u, dt, y):
        """Σ(ŷ − y)² from the fused kernel :func:`~hystfit.models._kernels.bouc_wen_sse` (n = 1):
        the (P, N) outputs are never stored. With a free exponent: None (simulate)."""
        if self.free_exponent:
            return None
        u = readonly(u)
        y = readonly(y)

        def sse(theta):
            theta = self.check_theta(theta, self.d)
            kv, a, b, g, y0, _ = self._physical(theta)
            return bouc_wen_sse(u, y, kv, a, b, g, y0)

        return sse

    def separable(self):
        """Kv, α and y0 enter linearly (n = 1): with h = α·g, g solves the same equation with α = 1
        (ġ = u̇ − β|u̇|g − γu̇|g|), so y = Kv·u + α·g(β, γ) + y0. Only β and γ are searched.

        The normal equations of (Kv, α, y0) come straight from the fused kernel
        :func:`~hystfit.models._kernels.bouc_wen_moments` (Σg², Σg·u, Σg, Σg·y per candidate),
        so a search never stores g."""
        if self.free_exponent:
            return None  # with a free n, α no longer scales h: no exact split

        def gram_factory(u, dt, y):
            u = readonly(u)
            y = readonly(y)
            su, suu, suy, sy, yy, n = u.sum(), u @ u, u @ y, y.sum(), float(y @ y), float(u.shape[0])

            def gram(theta_nl):
                M = bouc_wen_moments(u, y, theta_nl[:, 0], theta_nl[:, 1])  # Σg², Σgu, Σg, Σgy
                P = M.shape[0]
                G = np.empty((P, 3, 3))
                G[:, 0, 0] = suu
                G[:, 0, 1] = G[:, 1, 0] = M[:, 1]
                G[:, 0, 2] = G[:, 2, 0] = su
                G[:, 1, 1] = M[:, 0]
                G[:, 1, 2] = G[:, 2, 1] = M[:, 2]
                G[:, 2, 2] = n
                c = np.empty((P, 3))
                c[:, 0] = suy
                c[:, 1] = M[:, 3]
                c[:, 2] = sy
                return G, c, yy

            return gram

        def factory(u, dt):
            u = readonly(u)

            def basis(theta_nl):
                P = theta_nl.shape[0]
                g = bouc_wen_population(u, np.ones(P), np.ascontiguousarray(theta_nl[:, 0]),
                                        np.ascontiguousarray(theta_nl[:, 1])).T
                B = np.empty((P, u.shape[0], 3))
                B[:, :, 0] = u[None, :]
                B[:, :, 1] = g
                B[:, :, 2] = 1.0
                return B

            return basis

        return Separable((0, 1, 4), (2, 3), factory, gram_factory, gram_fused=True)

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        return np.zeros(1)

    def step(self, theta, state, u_prev, u_new, dt):
        kv, a, b, g, y0, n = (float(v[0]) if v is not None else None
                              for v in self._physical(np.atleast_2d(np.asarray(theta, float))))
        u_new = np.ascontiguousarray(u_new, dtype=np.float64)
        if n is None:
            h = bouc_wen_step(float(state[0]), float(u_prev), u_new, a, b, g)
        else:
            h = bouc_wen_n_step(float(state[0]), float(u_prev), u_new, a, b, g, n)
        return kv * u_new + h + y0, h[:, None]
