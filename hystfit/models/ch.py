"""Coleman–Hodgdon model in explicit branch form (paper 001 eq. 1)."""

from __future__ import annotations

import math

from dataclasses import dataclass
from typing import Callable

import numpy as np
from .._jit import njit, readonly

from ..errors import ConfigError
from ..params import DataScale, Param
from ..registry import models
from .base import Model
from .separable import Separable


# ----------------------------------------------------------------------------------------------
# Compiled recurrences of this model (Coleman–Hodgdon (paper 001 eq. 1)). numba, cache=True, error_model="numpy": a
# diverging candidate gives inf/nan (the objective scores it +inf), never an exception; the time
# loop is outermost and the population innermost (shared/PERFORMANCE.md).
# ----------------------------------------------------------------------------------------------

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


@models.register
@dataclass(frozen=True)
class ColemanHodgdon(Model):
    r"""Coleman–Hodgdon hysteresis, explicit branches (paper 001 eq. 1; ``shared/papers/README.md``).

    .. math::

        y = \begin{cases}
        K u - A_4\Bigl(1 - \dfrac{2 e^{-A_5 u}}{e^{-A_5 V_m} + e^{-A_5 V_M}}\Bigr) + A_6, & \dot u \ge 0\\[2ex]
        K u + A_4\Bigl(1 - \dfrac{2 e^{A_5 u}}{e^{A_5 V_m} + e^{A_5 V_M}}\Bigr) + A_6, & \dot u < 0
        \end{cases}
        \qquad K = A_1 - A_2 e^{-A_3 V_R}

    V_m, V_M are the minimum and maximum input of the identification data and V_R = V_M − V_m
    (001 §2). The two branches meet at V_m and V_M, so a cycle between the extremes of the data
    closes. The fraction is evaluated as 2/(e^{A5(u−V_m)} + e^{A5(u−V_M)}), which is the same
    number without exponents that grow with |u| (no overflow on offset inputs).

    Branch selection. The branch of sample k follows the sign of the backward difference
    u_k − u_{k−1}; a sample with u̇ = 0 keeps the previous branch, and the first sample is on the
    ascending branch (001's u̇ ≥ 0 case). Apart from that branch flag the model is
    **memoryless**: the output is a function of (u, sgn u̇) only, so it cannot produce minor loops
    — a reversal inside the range jumps to the other major branch. Captures with nested or
    partial loops therefore show systematic residuals at the reversals, which the diagnosis
    should reveal. Rate independent.

    Structure
    ---------
    v_min, v_max : V_m and V_M in V. Filled from the identification data by :meth:`adapt` and
        saved with the fit, so predictions on other captures use the same branch functions.

    Parameters (θ)
    --------------
    A1 : out/V, A2 : out/V, A3 : 1/V — they enter only through the slope K = A1 − A2 e^{−A3 V_R}.
        For one structure (fixed V_R) only K is identifiable; A2 and A3 are kept because 001
        reports them (its Table 1), and K is what a fit determines.
    A4 : out, loop amplitude; A4 > 0 puts the descending branch above the ascending one (the
        counter-clockwise loop of a piezo stack), A4 < 0 the opposite orientation.
    A5 : 1/V, loop shape (curvature of the branches); A5 → 0 closes the loop.
    A6 : out, output offset.

    Bounds scale with the data (gain g = output range / input range, ΔU = input range):
    A1 ∈ [−3, 3]·g, A2 ∈ [0, 3]·g, A3 ∈ [0, 10]/ΔU, A4 ∈ [−1, 1]·(output range),
    A5 ∈ [−20, 20]/ΔU, A6 within one output range of the data. (001's own A5 = −0.2 1/V on a
    3.3 V range is −0.66/ΔU.)

    Inverse: per branch. The branch of each target sample follows the sign of the target's
    derivative (times the orientation of the ascending branch; zero keeps the previous branch),
    and the input is the root of the active branch found by a scan from the previous input in the
    branch's direction plus bisection (:func:`hystfit.models.ch.ch_inverse`).
    """

    name = "ch"
    title = "Coleman–Hodgdon (explicit branches)"
    reference = "paper 001 eq. 1"
    equation = ("y = (A1 − A2·e^(−A3·V_R))·u ∓ A4·(1 − 2·e^(∓A5·u)/(e^(∓A5·V_m) + e^(∓A5·V_M))) + A6,"
                "  upper signs for du/dt ≥ 0")
    rate_dependent = False

    v_min: float | None = None
    v_max: float | None = None

    def __post_init__(self) -> None:
        if (self.v_min is None) != (self.v_max is None):
            raise ConfigError("ch: give both v_min and v_max (or neither; adapt() fills them from the data)")
        if self.v_min is not None:
            lo, hi = float(self.v_min), float(self.v_max)  # type: ignore[arg-type]
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise ConfigError(f"ch: need finite v_min < v_max, got v_min={self.v_min!r}, v_max={self.v_max!r}")

    # ------------------------------------------------------------------ structure
    def adapt(self, scale: DataScale) -> "ColemanHodgdon":
        if self.v_min is not None:
            return self
        lo, hi = float(scale.u_min), float(scale.u_max)
        if not hi > lo:
            hi = lo + scale.u_range
        return ColemanHodgdon(lo, hi)

    def _range(self) -> tuple[float, float]:
        if self.v_min is None or self.v_max is None:
            raise ConfigError("ch: V_m and V_M are not set; call adapt(scale) with the identification data first")
        return float(self.v_min), float(self.v_max)

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        g, du, yr = scale.gain, scale.u_range, scale.y_range
        mid = 0.5 * (scale.y_min + scale.y_max)
        return (
            Param("A1", "out/V", -3 * g, 3 * g, g, "slope term A1 (slope K = A1 − A2·e^(−A3·V_R))"),
            Param("A2", "out/V", 0.0, 3 * g, 0.0, "slope correction A2 (only K is identifiable)"),
            Param("A3", "1/V", 0.0, 10.0 / du, 1.0 / du, "slope correction rate A3 (only K is identifiable)"),
            Param("A4", "out", -yr, yr, 0.05 * yr, "loop amplitude A4 (> 0: counter-clockwise loop)"),
            Param("A5", "1/V", -20.0 / du, 20.0 / du, 2.0 / du, "loop shape A5"),
            Param("A6", "out", *scale.offset_bounds(), mid, "output offset A6"),
        )

    def slope(self, theta: np.ndarray) -> np.ndarray:
        """K = A1 − A2 e^{−A3 V_R} for θ (P, 6) → (P,) (the identifiable combination)."""
        theta = self.check_theta(theta, 6)
        lo, hi = self._range()
        with np.errstate(all="ignore"):
            return theta[:, 0] - theta[:, 1] * np.exp(-theta[:, 2] * (hi - lo))

    # ------------------------------------------------------------------ simulation
    def linear_design(self, u: np.ndarray, dt: float, A5: float) -> np.ndarray:
        """Regressors (N, 3) [u, −s·φ_s(u), 1] for (K, A4, A6) at a fixed A5.

        y = Φ (K, A4, A6)ᵀ exactly, with s the branch of each sample and
        φ_s(u) = 1 − 2/(e^{sA5(u−V_m)} + e^{sA5(u−V_M)}). For fixed A5 the fit is linear least
        squares; only A5 needs a nonlinear (1-D) search. The likelihood in the full 6-D box has
        a secondary minimum (large A4 with small A5 of the other sign mimics a parabolic loop),
        which this variable projection avoids.
        """
        vm, vM = self._range()
        u = readonly(u)
        s = ch_branches(u, 1.0)
        with np.errstate(all="ignore"):
            a = s * float(A5)
            phi = 1.0 - 2.0 / (np.exp(a * (u - vm)) + np.exp(a * (u - vM)))
        return np.column_stack([u, -s * phi, np.ones_like(u)])

    def separable(self):
        """A1, A4 and A6 enter linearly for fixed (A2, A3, A5) (:meth:`linear_design`, with the known
        part −A2·e^{−A3·V_R}·u): the search runs over (A2, A3, A5), of which only A5 shapes the fit."""
        def response(u, s_, theta_nl):
            """(−s·φ (P, N), κ (P, 1)): the basis column of A4 and the known part's slope."""
            vm, vM = self._range()
            A2, A3, A5 = theta_nl[:, 0:1], theta_nl[:, 1:2], theta_nl[:, 2:3]
            with np.errstate(all="ignore"):
                a = s_[None, :] * A5
                phi = 1.0 - 2.0 / (np.exp(a * (u[None, :] - vm)) + np.exp(a * (u[None, :] - vM)))
                return -s_[None, :] * phi, -(A2 * np.exp(-A3 * (vM - vm)))

        def factory(u, dt):
            u = readonly(u)
            s_ = ch_branches(u, 1.0)

            def basis(theta_nl):
                b1, kappa = response(u, s_, theta_nl)
                with np.errstate(all="ignore"):
                    C = kappa * u[None, :]
                B = np.empty((b1.shape[0], u.shape[0], 3))
                B[:, :, 0] = u[None, :]
                B[:, :, 1] = b1
                B[:, :, 2] = 1.0
                return B, C

            return basis

        def gram_factory(u, dt, y):
            """Normal equations of (A1, A4, A6) for the target y − κu from the sums of −s·φ (no basis)."""
            u = readonly(u)
            y = readonly(y)
            s_ = ch_branches(u, 1.0)
            n, su, sy = float(u.shape[0]), float(u.sum()), float(y.sum())
            uu, uy, yy = float(u @ u), float(u @ y), float(y @ y)

            def gram(theta_nl):
                b1, kappa = response(u, s_, theta_nl)
                k = kappa[:, 0]
                P = b1.shape[0]
                with np.errstate(all="ignore"):
                    bu, bb, sb, by = b1 @ u, np.einsum("pn,pn->p", b1, b1), b1.sum(axis=1), b1 @ y
                    G = np.empty((P, 3, 3))
                    G[:, 0, 0], G[:, 1, 1], G[:, 2, 2] = uu, bb, n
                    G[:, 0, 1] = G[:, 1, 0] = bu
                    G[:, 0, 2] = G[:, 2, 0] = su
                    G[:, 1, 2] = G[:, 2, 1] = sb
                    c = np.column_stack([uy - k * uu, by - k * bu, sy - k * su])
                    tt = yy - 2.0 * k * uy + k * k * uu
                return G, c, tt

            return gram

        return Separable((0, 3, 5), (1, 2, 4), factory, gram_factory, gram_fused=False)

    def _columns(self, theta: np.ndarray):
        K = np.ascontiguousarray(self.slope(theta))
        return (K,) + tuple(np.ascontiguousarray(theta[:, i]) for i in (3, 4, 5))

    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        theta = self.check_theta(theta, 6)
        u = readonly(u)
        return self.simulator(u, dt)(theta)

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        vm, vM = self._range()
        u = readonly(u)
        s = ch_branches(u, 1.0)  # depends on u only: computed once per capture

        def sim(theta: np.ndarray) -> np.ndarray:
            theta = self.check_theta(theta, 6)
            return ch_population(u, s, *self._columns(theta), vm, vM).T

        return sim

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """State: the active branch (+1 ascending), +1 before the first sample."""
        return np.ones(1)

    def step(self, theta, state, u_prev, u_new, dt):
        vm, vM = self._range()
        th = np.asarray(theta, float).reshape(1, 6)
        K, A4, A5, A6 = (float(c[0]) for c in self._columns(th))
        u_new = np.asarray(u_new, dtype=np.float64)
        du = u_new - float(u_prev)
        s = np.where(du > 0, 1.0, np.where(du < 0, -1.0, float(state[0])))
        with np.errstate(all="ignore"):
            a = s * A5
            phi = 1.0 - 2.0 / (np.exp(a * (u_new - vm)) + np.exp(a * (u_new - vM)))
            y = K * u_new - s * A4 * phi + A6
        return y, s[:, None]

    # ------------------------------------------------------------------ inverse
    def branch_value(self, theta: np.ndarray, u: np.ndarray, branch: float) -> np.ndarray:
        """Output of one branch (+1 ascending, −1 descending) at inputs ``u``."""
        vm, vM = self._range()
        u = readonly(np.atleast_1d(np.asarray(u, float)))
        s = np.full(u.shape[0], float(branch))  # writable, as ch_branches gives it
        return ch_population(u, s, *self._columns(np.asarray(theta, float).reshape(1, 6)), vm, vM)[:, 0]

    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) whose simulated output follows ``y_target``, branch by branch.

        ``u_range`` bounds the search (default: the data range widened by one V_R on each side).
        The first sample's root is the one nearest 0 V clipped into the range (the usual rest
        input); a target outside the reachable range saturates at the closest-output input.
        """
        vm, vM = self._range()
        th = np.asarray(theta, float).reshape(1, 6)
        y = readonly(y_target)
        if y.size == 0:
            return np.empty(0)
        lo, hi = u_range if u_range is not None else (vm - (vM - vm), vM + (vM - vm))
        K, A4, A5, A6 = (float(c[0]) for c in self._columns(th))
        rise = self.branch_value(th[0], np.array([vm, vM]), 1.0)
        orient = 1.0 if not rise[1] < rise[0] else -1.0
        # branch = orientation · sgn(Δy): ascending where the target moves the way the ascending
        # branch does; Δy = 0 keeps the branch; the first sample is ascending, as in simulate()
        s = ch_branches(readonly(orient * y), 1.0)
        return ch_inverse(y, s, K, A4, A5, A6, vm, vM, float(lo), float(hi),
                          float(min(max(0.0, lo), hi)), 2048)
