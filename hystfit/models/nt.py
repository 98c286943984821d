"""NT (softsign nonlinear transformation) model, paper 002 eq. 2, inverse eq. 4–10."""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Callable

import numpy as np
from .._jit import njit, readonly

from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from .base import Model, OptionalOffset
from .separable import Separable

INVERSE_METHODS = ("auto", "causal", "noncausal")


def backward_rate(u: np.ndarray, dt: float) -> np.ndarray:
    """u̇ by backward difference (u_n − u_{n−1})/Ts, zero at the first sample (rest)."""
    u = np.asarray(u, dtype=np.float64)
    v = np.zeros_like(u)
    if u.shape[0] > 1:
        v[1:] = np.diff(u) / float(dt)
    return v


def softsign(x: np.ndarray) -> np.ndarray:
    """x / (1 + |x|) (002 eq. 1)."""
    x = np.asarray(x, dtype=np.float64)
    return x / (1.0 + np.abs(x))


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (NT softsign model (paper 002 eq. 2, inverse eq. 4–10)). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

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


@models.register
@dataclass(frozen=True)
class NT(OptionalOffset, Model):
    r"""NT model: stiffness, damping and a softsign nonlinear transformation (paper 002 eq. 2).

    .. math::

        y = k_0\,u + c_0\,\dot u + k_1 \frac{k_2 u}{1 + |k_2 u|}\ (+\,y_0),\qquad
        \dot u_n = (u_n - u_{n-1})/T_s

    (``shared/papers/README.md``). The softsign term is memoryless; the loop opens only through
    c0 u̇, whose sign sets the orientation: c0 < 0 puts the rising branch below the falling one
    (the counter-clockwise loop of a piezo stack, which a PI-like plant produces), c0 > 0 the
    opposite. The first sample has u̇ = 0 (the stage starts at rest). Rate dependent.

    Offset (argued). 002's form has no offset; with a raised cosine from 0 V it predicts
    y(0) = 0, so any sensor offset in a real capture would be absorbed by distorting k0 and k1.
    ``offset=True`` (default, as for the other models of hystfit) adds y0; ``offset=False`` gives
    002's four parameters exactly.

    Parameters (θ)
    --------------
    k0 : out/V, linear stiffness gain.  c0 : out·s/V, damping (sign = orientation).
    k1 : out, softsign amplitude.  k2 : 1/V, softsign shape (> 0; the inverse needs k2 > 0).
    y0 : out, offset (only with ``offset=True``).

    For fixed k2 the output is linear in (k0, c0, k1, y0): :meth:`linear_design` gives the
    regressors so an optimizer can solve them exactly by least squares and search k2 alone.

    Bounds (g = output range / input range, Y = output range, R = max |u̇|, U = max |u|):
    k0 ∈ [−3, 3] g, c0 ∈ [−1, 1] Y/R, k1 ∈ [−2, 2] Y, k2 ∈ [0.01, 20]/U, y0 within one Y.

    Inverse (002 eq. 4–10). With A = k0 + c0/Ts and B_n = y_n − y0 + (c0/Ts) u_{n−1},
    A u + k1 k2 u/(1 + k2|u|) = B_n is solved in closed form per branch:
    u ≥ 0: A k2 u² + (A + k1 k2 − B_n k2) u − B_n = 0; u < 0: A k2 u² − (A + k1 k2 + B_n k2) u + B_n = 0;
    real roots on their branch that satisfy the equation on substitution are kept and the one
    closest to u_{n−1} is taken; the first sample (u̇ = 0) solves the static equation
    (A → k0, B → y_0 − y0), root closest to 0 V.

    Stability of that causal inverse (our finding, not in 002). Linearized, the recursion is
    u_n ≈ (y_n + c u_{n−1})/(K + c) with c = c0/Ts and K = k0 + k1 k2/(1 + k2|u|)² the local
    static slope: its pole c/(K + c) lies inside the unit circle iff c0 > 0 or |c0|/Ts < K/2.
    For the piezo orientation (c0 < 0) at usual sample rates |c0|/Ts ≫ K, so the causal
    recursion is unstable: the model then has a non-minimum-phase discrete zero and its exact
    causal inverse diverges (the forward map still reproduces the target, with a wildly wrong u).
    ``invert(method="auto")`` (default) therefore uses 002's causal recursion when it is stable
    for every slope K the parameters allow and otherwise the same discrete equation solved
    backwards in time, u_{n−1} = u_n + (k0 u_n + k1 softsign(k2 u_n) − y_n + y0)/c, from the
    static inverse of the last sample — the standard stable (non-causal, needs the whole
    target in advance) inversion of a non-minimum-phase model, fine for offline feedforward.
    """

    name = "nt"
    title = "NT (softsign nonlinear transformation)"
    reference = "paper 002 eq. 2 (model), eq. 4–10 (discrete inverse)"
    equation = "y = k0·u + c0·du/dt + k1·k2·u/(1 + |k2·u|) (+ y0),  du/dt by backward difference"
    rate_dependent = True
    n_params_without_offset = 4

    offset: bool = True

    def __post_init__(self) -> None:
        self.check_offset()

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, yr, R, U = scale.gain, scale.y_range, scale.rate_max, scale.u_abs_max
        c = yr / R
        ps = [
            Param("k0", "out/V", -3 * g, 3 * g, g, "linear stiffness gain k0"),
            Param("c0", "out*s/V", -c, c, 0.0, "damping c0 (sign = loop orientation)"),
            Param("k1", "out", -2 * yr, 2 * yr, 0.0, "softsign amplitude k1"),
            Param("k2", "1/V", 0.01 / U, 20.0 / U, 1.0 / U, "softsign shape k2"),
        ]
        if self.offset:
            ps.append(Param("y0", "out", *scale.offset_bounds(), 0.0, "output offset"))
        return tuple(ps)

    # ------------------------------------------------------------------ simulation
    def linear_design(self, u: np.ndarray, dt: float, k2: float) -> np.ndarray:
        """Regressors (N, 4) [u, u̇, softsign(k2 u), 1] (the last column only with ``offset``).

        y = Φ (k0, c0, k1, y0)ᵀ exactly for the given k2, so these four follow from linear
        least squares and only k2 needs a nonlinear search.
        """
        u = np.asarray(u, dtype=np.float64)
        cols = [u, backward_rate(u, dt), softsign(float(k2) * u)]
        if self.offset:
            cols.append(np.ones_like(u))
        return np.column_stack(cols)

    def separable(self):
        """k0, c0, k1 (and y0) enter linearly for fixed k2 (:meth:`linear_design`): only k2 is searched."""
        lin = (0, 1, 2, 4) if self.offset else (0, 1, 2)

        def factory(u, dt):
            u = readonly(u)
            v = backward_rate(u, dt)

            def basis(theta_nl):
                P = theta_nl.shape[0]
                B = np.empty((P, u.shape[0], len(lin)))
                B[:, :, 0] = u[None, :]
                B[:, :, 1] = v[None, :]
                z = theta_nl[:, 0:1] * u[None, :]
                B[:, :, 2] = z / (1.0 + np.abs(z))
                if self.offset:
                    B[:, :, 3] = 1.0
                return B

            return basis

        return Separable(lin, (3,), factory)

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return self.simulator(u, dt)(theta)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        u = readonly(u)
        v = np.ascontiguousarray(backward_rate(u, dt))
        d = self.n_params

        def sim(theta: np.ndarray) -> np.ndarray:
            theta = self.check_theta(theta, d)
            cols = [np.ascontiguousarray(theta[:, i]) for i in range(4)]
            y0 = np.ascontiguousarray(theta[:, 4]) if self.offset else np.zeros(theta.shape[0])
            return nt_population(u, v, *cols, y0).T

        return sim

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """No memory besides the previous input, which :meth:`step` receives: empty state."""
        return np.zeros(0)

    def step(self, theta, state, u_prev, u_new, dt):
        th = np.asarray(theta, float).ravel()
        k0, c0, k1, k2 = th[:4]
        y0 = th[4] if self.offset else 0.0
        u_new = np.asarray(u_new, dtype=np.float64)
        with np.errstate(all="ignore"):
            y = k0 * u_new + c0 * (u_new - float(u_prev)) / float(dt) + k1 * softsign(k2 * u_new) + y0
        return y, np.zeros((u_new.shape[0], 0))

    # ------------------------------------------------------------------ inverse
    def causal_inverse_is_stable(self, theta: np.ndarray, dt: float) -> bool:
        """Whether 002's causal recursion is stable for every local slope K the parameters allow.

        K = k0 + k1 k2/(1 + k2|u|)² lies between k0 and k0 + k1 k2; the linearized pole is
        c/(K + c), c = c0/Ts, and must have modulus < 1 over that whole interval.
        """
        th = np.asarray(theta, float).ravel()
        k0, c0, k1, k2 = (float(v) for v in th[:4])
        c = c0 / float(dt)
        if c == 0.0:
            return True
        for K in (k0, k0 + k1 * k2):
            if not abs(c) < abs(K + c):
                return False
        # |c| < |K + c| on an interval needs K + c not to change sign inside it
        return (k0 + c) * (k0 + k1 * k2 + c) > 0

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None, method: str = "auto") -> np.ndarray:
        """Input u (N,) whose simulated output is ``y_target``.

        Parameters
        ----------
        theta : (d,) parameters; k2 must be > 0.
        y_target : (N,) desired output.  dt : sample period Ts (s).
        u_range : optional (lo, hi); the result is clipped to it (saturation).
        method : ``"causal"`` 002's closed-form per-sample recursion (eq. 4–10);
            ``"noncausal"`` the backward recursion (stable when the causal one is not);
            ``"auto"`` the causal one when :meth:`causal_inverse_is_stable`, else the backward one.
        """
        if method not in INVERSE_METHODS:
            raise ConfigError(f"nt: inverse method must be one of {INVERSE_METHODS}, got {method!r}")
        th = np.asarray(theta, float).ravel()
        k0, c0, k1, k2 = (float(v) for v in th[:4])
        y0 = float(th[4]) if self.offset else 0.0
        if not k2 > 0:
            raise ConfigError(f"nt: the inverse needs k2 > 0 (got {k2:g})")
        yd = np.ascontiguousarray(np.asarray(y_target, float) - y0)
        N = yd.shape[0]
        if N == 0:
            return np.empty(0)
        c = c0 / float(dt)
        if method == "auto":
            method = "causal" if self.causal_inverse_is_stable(th, dt) else "noncausal"
        if method == "causal" or c == 0.0:
            u_first, _ = nt_root(k0, k1, k2, float(yd[0]), 0.0)
            u = nt_inverse_causal(yd, k0 + c, c, k1, k2, u_first)
        else:
            u_last, _ = nt_root(k0, k1, k2, float(yd[-1]), 0.0)
            u = nt_inverse_backward(yd, k0, c, k1, k2, u_last)
        if u_range is not None:
            u = np.clip(u, min(u_range), max(u_range))
        return u
