"""LuGre hysteresis model (``shared/papers/README.md``; comparison model of paper 002)."""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np
from .._jit import njit, readonly

from ..params import DataScale, Param
from ..registry import models
from .base import Model, OptionalOffset
from .inverse import invert_from_rest, refine_inverse
from .separable import Separable, separable_by_simulation


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (LuGre (exact per sample for the sample's constant rate)). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

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
def lugre_population(u, dt, k, s0, s1, s2, fc, fs, vs, group=1):
    """LuGre output y = k u + σ0 z + σ1 ż + σ2 u̇ for a population (without offset), z(0) = 0.

    u̇ is the backward difference (u_k − u_{k−1})/dt (0 at the first sample) and is constant
    over each sample, so the linear z equation is integrated exactly: stable at any rate.
    g(u̇) = F_c + (F_s − F_c) e^{−(u̇/v_s)²} with F_c, F_s > 0; the sign of σ0 sets the loop
    orientation (λ uses |σ0|).

    Parameters
    ----------
    u : (N,) input (V).  dt : sample period (s).
    k, s0, s1, s2, fc, fs, vs : (P,) parameters (see :class:`hystfit.models.lugre.LuGre`).
    group : consecutive groups of ``group`` candidates share σ0, Fc, Fs and vs (they differ in
        k, σ1, σ2 only): the bristle state is advanced once per group (default 1: every candidate).

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
        for g in range(0, P, group):  # the state once per group (no integer modulo per candidate)
            z1, zd = _lugre_advance(z[g], v, dt, abs(s0[g]), fc[g], fs[g], vs[g])
            z[g] = z1
            for p in range(g, min(g + group, P)):
                out[n, p] = k[p] * un + s0[p] * z1 + s1[p] * zd + s2[p] * v
    return out


@njit(cache=True, error_model="numpy")
def lugre_moments(u, dt, s0, fc, fs, vs, y):
    """Sums over the capture of the bristle state z, its rate ż (as :func:`lugre_population`
    advances them, z(0) = 0) and their products with u, u̇ and y, per candidate: rows Σz, Σz²,
    Σz·u, Σz·u̇, Σz·y, Σż, Σż², Σż·u, Σż·u̇, Σż·y, Σż·z of the (11, P) result — the normal
    equations of LuGre's linear parameters without the (N, P) outputs. Samples summed in order."""
    N = u.shape[0]
    P = s0.shape[0]
    acc = np.zeros((11, P))
    z = np.zeros(P)
    for n in range(1, N):  # the first sample has z = ż = u̇ = 0: it adds nothing
        un = u[n]
        v = (un - u[n - 1]) / dt
        yn = y[n]
        for p in range(P):
            z1, zd = _lugre_advance(z[p], v, dt, abs(s0[p]), fc[p], fs[p], vs[p])
            z[p] = z1
            acc[0, p] += z1
            acc[1, p] += z1 * z1
            acc[2, p] += z1 * un
            acc[3, p] += z1 * v
            acc[4, p] += z1 * yn
            acc[5, p] += zd
            acc[6, p] += zd * zd
            acc[7, p] += zd * un
            acc[8, p] += zd * v
            acc[9, p] += zd * yn
            acc[10, p] += zd * z1
    return acc


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


@models.register
@dataclass(frozen=True)
class LuGre(OptionalOffset, Model):
    r"""LuGre model: linear gain plus a LuGre bristle state with Stribeck-type level.

    .. math::

        y = k\,u + \sigma_0 z + \sigma_1 \dot z + \sigma_2 \dot u\ (+\,y_0),\qquad
        \dot z = \dot u - \frac{|\sigma_0|\,|\dot u|}{g(\dot u)}\,z,\qquad
        g(\dot u) = F_c + (F_s - F_c)\,e^{-(\dot u/v_s)^2},\qquad z(0) = 0

    (``shared/papers/README.md``). 002 counts 6 parameters; we add the gain k (7) because a
    piezo loop sits on a large linear slope. u̇ is the backward difference (u_k − u_{k−1})/Ts
    (zero at the first sample).

    Orientation (our convention, argued). The textbook form uses σ0 in the decay term. The
    equations are invariant under (σ0, F_c, F_s) → −(σ0, F_c, F_s) (z unchanged), so we take
    F_c, F_s > 0 as magnitudes and let σ0 carry the sign (|σ0| in the decay term). σ0 > 0 is the
    textbook model (clockwise loop in (u, y)); σ0 < 0 gives the counter-clockwise loop of piezo
    stacks, and the box contains no unstable region (σ0/g < 0) and no singular g = 0.

    Rate scaling. v_s is in V/s and its bounds are [10⁻³, 2]·(max |u̇| of the data), so the
    Stribeck transition lies inside the capture's rate range whatever the units or speed.

    Integration. Over one sample u̇ is constant, so ż = u̇ − λ z with λ = |σ0||u̇|/g is linear
    and is solved exactly: z_k = z_{k−1} e^{−λTs} + u̇ Ts (1 − e^{−λTs})/(λTs); ż_k = u̇ − λ z_k
    (the rate at the end of the sample). Stable at any sample rate, no sub-steps
    (:func:`hystfit.models.lugre.lugre_population`). The model is rate dependent: g, σ1
    and σ2 see u̇.

    Structure
    ---------
    offset : add an output offset y0 as an 8th parameter (default False, the 7 parameters of the
        brief). A capture with a sensor offset needs it; y(0) = k u(0) otherwise.

    Parameters (θ)
    --------------
    k : out/V, linear gain.
    sigma0 : out/V, bristle stiffness; the loop half-height is ≈ g(u̇) and z saturates over
        ≈ g/|σ0| volts of travel; sign = orientation.
    sigma1 : out·s/V, bristle damping (acts while z is in transit, ż ≠ 0).
    sigma2 : out·s/V, viscous term on u̇.
    Fc : out, Coulomb level (g at high rate).  Fs : out, static level (g at u̇ = 0).
    vs : V/s, Stribeck rate.
    y0 : out, output offset (only with ``offset=True``).

    Identifiability. k, σ0 and the levels F_c/F_s are well determined when z saturates within a
    fraction of the stroke. F_s versus F_c and v_s need captures whose rates span v_s (several
    frequencies or amplitudes); from one raised cosine they trade against each other. σ1 only
    acts while z is in transit and is correlated with σ2 (both multiply rates).

    Bounds (g = output range / input range, Y = output range, R = max |u̇|): k ∈ [−3, 3] g,
    σ0 ∈ [−10, 10] g (z then saturates over ≥ 10⁻⁴ of the stroke), σ1, σ2 ∈ [−0.2, 0.2] Y/R (a
    rate term alone opens a loop of up to 20 % of the stroke), F_c, F_s ∈ [10⁻³, 1] Y,
    v_s ∈ [10⁻³, 2] R. Wider boxes for σ0, σ1, σ2 leave PSO in spurious minima where large
    σ0 z, σ1 ż and σ2 u̇ cancel.

    Inverse: the generic per-sample numerical inverse on :meth:`step`, started at rest at
    u_0 = (y_0 − y0)/k as :meth:`simulate` starts. It needs a one-step map that increases with
    u_k: after a reversal the slope is about k + 2σ0 (z swings from one level to the other), so
    σ0 < 0 needs |σ0| < k/2, as any physical loop has. As for NT, a negative rate coefficient
    (σ2, or σ1 while z is in transit) larger than about half the static slope times Ts makes the
    exact causal inverse unstable (a non-minimum-phase discrete zero).
    """

    name = "lugre"
    title = "LuGre"
    reference = "shared/papers/README.md (LuGre); paper 002 §4 comparison model, 6 parameters + gain k"
    equation = ("y = k·u + σ0·z + σ1·dz/dt + σ2·du/dt,  dz/dt = du/dt − |σ0|·|du/dt|·z/g(du/dt),"
                "  g = Fc + (Fs − Fc)·exp(−(du/dt / vs)²)")
    rate_dependent = True
    n_params_without_offset = 7

    offset: bool = False

    def __post_init__(self) -> None:
        self.check_offset()

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, yr, R = scale.gain, scale.y_range, scale.rate_max
        c = 0.2 * yr / R
        ps = [
            Param("k", "out/V", -3 * g, 3 * g, g, "linear gain"),
            Param("sigma0", "out/V", -10 * g, 10 * g, -g, "bristle stiffness σ0 (sign = orientation)"),
            Param("sigma1", "out*s/V", -c, c, 0.0, "bristle damping σ1"),
            Param("sigma2", "out*s/V", -c, c, 0.0, "viscous coefficient σ2"),
            Param("Fc", "out", 1e-3 * yr, yr, 0.05 * yr, "Coulomb level F_c"),
            Param("Fs", "out", 1e-3 * yr, yr, 0.05 * yr, "static level F_s"),
            Param("vs", "V/s", 1e-3 * R, 2.0 * R, 0.3 * R, "Stribeck rate v_s"),
        ]
        if self.offset:
            ps.append(Param("y0", "out", *scale.offset_bounds(), 0.0, "output offset"))
        return tuple(ps)

    def _cols(self, theta: np.ndarray):
        return tuple(np.ascontiguousarray(theta[:, i]) for i in range(7))

    def separable(self):
        """k, σ1, σ2 (and y0) enter linearly for a fixed bristle state z(σ0, Fc, Fs, vs): only those four are
        searched. The basis [u, ż, u̇(, 1)] with the known part σ0·z; the basis is simulated with the
        state advanced once per candidate, and the normal equations come from the state's moments
        (:func:`lugre_moments`: one pass, O(P) memory, no (P, N) outputs)."""
        exact = separable_by_simulation(self, (0, 2, 3, 7) if self.offset else (0, 2, 3), 8 if self.offset else 7,
                                        grouped=lambda u, dt: lambda th, g: self._simulate(th, u, dt, g))
        return Separable(exact.linear, exact.nonlinear, exact.basis_factory, self._gram, gram_fused=True)

    def _gram(self, u: np.ndarray, dt: float, y: np.ndarray):
        """theta_nl (P, 4) = (σ0, Fc, Fs, vs) → normal equations (G, c, tᵀt) of (k, σ1, σ2[, y0]) for the
        target t = y − σ0·z, from the sums of :func:`lugre_moments` and of the data."""
        u = readonly(u)
        y = readonly(y)
        dt = float(dt)
        v = np.zeros_like(u)
        v[1:] = (u[1:] - u[:-1]) / dt  # u̇, as the kernel computes it (0 at the first sample)
        n, su, sv, sy = float(u.shape[0]), float(u.sum()), float(v.sum()), float(y.sum())
        uu, uv, vv, uy, vy, yy = (float(a @ b) for a, b in ((u, u), (u, v), (v, v), (u, y), (v, y), (y, y)))
        L = 4 if self.offset else 3

        def gram(theta_nl):
            s0, fc, fs, vs = (np.ascontiguousarray(theta_nl[:, i]) for i in range(4))
            with np.errstate(all="ignore"):
                z, zz, zu, zv, zy, d, dd, du, dv, dy, dz = lugre_moments(u, dt, s0, fc, fs, vs, y)
                P = s0.shape[0]
                G = np.empty((P, L, L))
                G[:, 0, 0], G[:, 1, 1], G[:, 2, 2] = uu, dd, vv
                G[:, 0, 1] = G[:, 1, 0] = du
                G[:, 0, 2] = G[:, 2, 0] = uv
                G[:, 1, 2] = G[:, 2, 1] = dv
                c = np.empty((P, L))
                c[:, 0] = uy - s0 * zu
                c[:, 1] = dy - s0 * dz
                c[:, 2] = vy - s0 * zv
                if L == 4:
                    G[:, 0, 3] = G[:, 3, 0] = su
                    G[:, 1, 3] = G[:, 3, 1] = d
                    G[:, 2, 3] = G[:, 3, 2] = sv
                    G[:, 3, 3] = n
                    c[:, 3] = sy - s0 * z
                tt = yy - 2.0 * s0 * zy + s0 * s0 * zz
            return G, c, tt

        return gram

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self._simulate(theta, readonly(u), dt, 1)

    def _simulate(self, theta: np.ndarray, u: np.ndarray, dt: float, group: int) -> np.ndarray:
        """Outputs (P, N); consecutive groups of ``group`` rows of θ share σ0, Fc, Fs and vs."""
        theta = self.check_theta(theta, self.n_params)
        y = lugre_population(u, float(dt), *self._cols(theta), group).T
        if self.offset:
            with np.errstate(all="ignore"):
                y = y + theta[:, 7][:, None]
        return y

    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """State: the bristle deflection z (V), zero before the first sample."""
        return np.zeros(1)

    def step(self, theta, state, u_prev, u_new, dt):
        th = np.asarray(theta, float).ravel()
        u_new = np.ascontiguousarray(u_new, dtype=np.float64)
        y, z = lugre_step(float(state[0]), float(u_prev), u_new, float(dt), *(float(v) for v in th[:7]))
        if self.offset:
            y = y + th[7]
        return y, z[:, None]

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Generic per-sample numerical inverse, started where :meth:`simulate` starts, checked by simulation.

        When the per-sample recursion is unstable (a rate term of the "wrong" sign: σ2 < 0 makes
        the one-step map decrease in u_k) the result is refined over the whole trajectory by
        :func:`hystfit.models.inverse.refine_inverse` (iterative learning on the model itself).

        :meth:`simulate` puts the stage at rest at the first input (zero state, no rate), so the
        first sample is the static inverse u_0 = (y_0 − y0)/k and the per-sample search
        (:func:`hystfit.models.inverse.invert_by_stepping`) continues from there.
        """
        th = np.asarray(theta, float).ravel()
        y = np.asarray(y_target, float)
        if y.size == 0:
            return np.empty(0)
        u = invert_from_rest(self, th, y, dt, th[0], th[7] if self.offset else 0.0, u_range)
        # safeguard: with σ2 < 0 (or σ1 ż acting like it) the per-sample recursion can be unstable;
        # check by simulation and, if it misses, refine over the whole trajectory
        with np.errstate(all="ignore"):
            miss = y - self.simulate_one(th, u, dt)
        if not np.all(np.isfinite(miss)) or np.sqrt(np.mean(miss ** 2)) > 1e-3 * max(float(np.ptp(y)), 1e-300):
            start = np.where(np.isfinite(u), u, (y - (th[7] if self.offset else 0.0)) / th[0])
            static = (y - (th[7] if self.offset else 0.0)) / th[0]
            cand = [refine_inverse(self, th, y, dt, s0, gain=th[0], u_range=u_range) for s0 in (start, static)]
            errs = [np.sqrt(np.mean((y - self.simulate_one(th, c, dt)) ** 2)) for c in cand]
            u = cand[int(np.nanargmin(errs))]
        return u

    def _inverse_range(self, theta: np.ndarray, y_target: np.ndarray) -> tuple[float, float]:
        """Search window of the numerical inverse: the static inverse ± the loop, widened."""
        th = np.asarray(theta, float).ravel()
        k = abs(th[0]) if th[0] != 0 else 1e-12
        y0 = th[7] if self.offset else 0.0
        yt = np.asarray(y_target, float)
        c = [(float(yt.min()) - y0) / k, (float(yt.max()) - y0) / k]
        lo, hi = min(c), max(c)
        pad = 0.5 * (hi - lo) + 2.0 * max(abs(th[4]), abs(th[5])) / k
        return lo - pad, hi + pad
