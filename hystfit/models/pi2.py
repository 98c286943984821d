"""Electromechanical model of paper 000: generalized PI hysteresis driving a second-order stage."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .._jit import njit, prange, readonly
from .._lazy import lazy_module
from ..blocks.base import captures_at_one_rate
from ..blocks.dynamics import (Dynamics, bilinear_biquad, biquad_columns, fn_search_range_of,
                               invert_second_order)
from ..errors import ConfigError, InputError
from ..params import DataScale, Param
from ..registry import models
from ._kernels import PARALLEL_MIN_POP, candidate_block, play_matrix, store_sums, thread_blocks
from .base import Model
from .composite import Composite
from .pi import PI
from .separable import scaled_response
from .gpi import (ENVELOPE_CHUNK, GPI, TABLE_BLOCK_ELEMENTS, gpi_envelope_rows, gpi_envelopes_ahead, gpi_operators,
                  gpi_play,
                  copy_state, input_levels, input_period, same_state)

optimize = lazy_module("scipy.optimize")  # imported on first use: keeps start-up fast

#: kernel modes: the outputs (N, P), Σ(ŷ − y)² (P, 1), or the moments Σz_f², Σz_f, Σz_f·y (P, 3)
_OUTPUT, _SSE, _MOMENTS = 0, 1, 2
#: largest buffer (samples of one input period × candidates of a block) of the period repeat of
#: :func:`_gpi2_block`: 16 MB
REPEAT_MAX_ELEMENTS = 2_000_000
#: identification routes (structure option ``identification``)
IDENTIFICATIONS = ("two-step", "joint")


@njit(cache=True)
def _gpi2_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, f0, f1, f2, g1, g2, n,
                mode, out, p0, p1, period):
    """Generalized PI → second-order stage for candidates p0:p1, in one time loop.

    Per candidate (the recurrences of :func:`~hystfit.models.gpi.gpi_population` and
    :func:`~hystfit.blocks.dynamics.biquad_columns`, fused):

        s_j(k) = max(γ_l(u_k) − r_j, min(γ_r(u_k) + r_j, s_j(k−1))),  s_j(−1) = 0,  r_j = α j
        z(k)   = Σ_j e^{−τ r_j} s_j(k)                                  (unit-density gPI output)
        e(k)   = f0 d(k) + f1 d(k−1) + f2 d(k−2) − g1 e(k−1) − g2 e(k−2),  d(k) = z(k) − z(0)
        z_f(k) = z(0) + e(k)                                            (stage at rest at z(0))
        ŷ(k)   = ρ z_f(k) + y0

    ``mode`` :data:`_OUTPUT` writes ŷ into out (N, P); :data:`_SSE` accumulates Σ(ŷ − y)² into
    out[p, 0]; :data:`_MOMENTS` Σz_f², Σz_f, Σz_f·y into out[p, 0:3] (the normal equations of
    (ρ, y0), which enter linearly). Time outermost, candidates innermost and contiguous; memory
    O(n·P) in the SSE and moments modes (plus the envelope table: with ``index`` non-empty,
    u_k = levels[index[k]] and the envelopes are tabulated per level, bit-identical to computing
    them per sample, :func:`~hystfit.models.gpi.gpi_envelope_table`). Non-finite candidates give
    non-finite results.

    With ``period`` T > 0 (the tabulated input repeats every T samples,
    :func:`~hystfit.models.gpi.input_period`) the operator states are compared every T samples:
    once they equal those one period earlier, z repeats with period T and is taken from the last
    period (the same numbers, not computed again; the stage still runs on every sample). Only when
    the buffer of one period, T × candidates, stays within :data:`REPEAT_MAX_ELEMENTS`.
    """
    N = u.shape[0]
    m = p1 - p0
    s = np.zeros((n, m))
    r, q = gpi_operators(alpha, tau, n, p0, p1)
    z0 = np.zeros(m)
    d1 = np.zeros(m)
    d2 = np.zeros(m)
    e1 = np.zeros(m)
    e2 = np.zeros(m)
    acc0 = np.zeros(m)
    acc1 = np.zeros(m)
    acc2 = np.zeros(m)
    gl = np.empty(m)
    gr = np.empty(m)
    z = np.empty(m)
    zf = np.empty(m)
    tabulated = index.shape[0] > 0
    GL, GR = gpi_envelope_rows(index, levels, N, a1, a2, a3, a4, b1, b2, b3, b4, p0, p1)
    repeats = period > 0 and period * m <= REPEAT_MAX_ELEMENTS
    z_period = np.empty((period, m) if repeats else (0, 0))  # z of the last period, at k % period
    s_prev = np.empty((n, m) if repeats else (0, 0))
    copying = False
    for c0 in range(0, N, ENVELOPE_CHUNK):
        c1 = min(N, c0 + ENVELOPE_CHUNK)
        if not copying:
            gpi_envelopes_ahead(u, index, c0, c1, a1, a2, a3, a4, b1, b2, b3, b4, p0, GL, GR, gl, gr)
        for k in range(c0, c1):
            if repeats and not copying and k > 0 and k % period == 0:
                copying = k >= 2 * period and same_state(s, s_prev)
                copy_state(s_prev, s)
            if copying:
                for i in range(m):
                    z[i] = z_period[k % period, i]
            else:
                gpi_play(r, q, s, GL, GR, index[k] if tabulated else k - c0, z, n, m)
                if repeats:
                    for i in range(m):
                        z_period[k % period, i] = z[i]
            if k == 0:
                for i in range(m):
                    z0[i] = z[i]
            yk = y[k] if mode != _OUTPUT else 0.0
            for i in range(m):  # the stage, then each mode's use of z_f in its own loop (these vectorize)
                p = p0 + i
                d = z[i] - z0[i]
                e = f0[p] * d + f1[p] * d1[i] + f2[p] * d2[i] - g1[p] * e1[i] - g2[p] * e2[i]
                d2[i] = d1[i]
                d1[i] = d
                e2[i] = e1[i]
                e1[i] = e
                zf[i] = z0[i] + e
            if mode == _OUTPUT:
                for i in range(m):
                    out[k, p0 + i] = rho[p0 + i] * zf[i] + y0[p0 + i]
            elif mode == _SSE:
                for i in range(m):
                    res = rho[p0 + i] * zf[i] + y0[p0 + i] - yk
                    acc0[i] += res * res
            else:
                for i in range(m):
                    acc0[i] += zf[i] * zf[i]
                    acc1[i] += zf[i]
                    acc2[i] += zf[i] * yk
    if mode != _OUTPUT:
        store_sums(out, p0, (acc0, acc1, acc2), 1 if mode == _SSE else 3)


@njit(cache=True, parallel=True)
def _gpi2_parallel(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, f0, f1, f2, g1, g2, n,
                   mode, out, period, n_blocks):
    """:func:`_gpi2_block` over ``n_blocks`` candidate blocks spread over threads."""
    for b in prange(n_blocks):
        p0, p1 = candidate_block(b, n_blocks, a1.shape[0])
        if p0 < p1:
            _gpi2_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, f0, f1, f2, g1, g2,
                        n, mode, out, p0, p1, period)


def _gpi2_serial(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, f0, f1, f2, g1, g2, n,
                 mode, out, period, block):
    """:func:`_gpi2_block` over consecutive blocks of ``block`` candidates (bounds the envelope
    tables), in this thread; not a kernel of its own (see :func:`~hystfit.models.gpi._gpi_serial`)."""
    P = a1.shape[0]
    for p0 in range(0, P, block):
        _gpi2_block(u, levels, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, f0, f1, f2, g1, g2, n,
                    mode, out, p0, min(P, p0 + block), period)


#: the stage coefficients of the last few (f_n, ζ, dt, P): the two-step route calls the kernel
#: thousands of times with one stage, whose discretization cost 45 µs a call
_COEFFICIENTS: dict = {}
_COEFFICIENTS_KEPT = 8


def _stage_coefficients(fn_Hz, zeta, dt: float, P: int) -> tuple[np.ndarray, ...]:
    """:func:`bilinear_biquad` (b0, b1, b2, a1, a2), each (P,) and contiguous, remembered for the
    last :data:`_COEFFICIENTS_KEPT` arguments (the same arrays, computed once: read-only)."""
    fn = np.ascontiguousarray(fn_Hz, dtype=np.float64)
    z = np.ascontiguousarray(zeta, dtype=np.float64)
    key = (fn.tobytes(), z.tobytes(), float(dt), int(P))
    coef = _COEFFICIENTS.get(key)
    if coef is None:
        with np.errstate(all="ignore"):
            coef = [np.ascontiguousarray(c) for c in bilinear_biquad(fn, z, dt)]
        coef = tuple(np.broadcast_to(c, (P,)).copy() if c.shape[0] != P else c for c in coef)
        for c in coef:
            c.flags.writeable = False
        if len(_COEFFICIENTS) >= _COEFFICIENTS_KEPT:
            _COEFFICIENTS.pop(next(iter(_COEFFICIENTS)))
        _COEFFICIENTS[key] = coef
    return coef


def gpi2_run(u, y, gpi_theta, fn_Hz, zeta, dt: float, n: int, mode: int, levels=None, period: int = 0) -> np.ndarray:
    """Run :func:`_gpi2_block` for a population: ``gpi_theta`` (P, 12) in :class:`GPI`'s order,
    ``fn_Hz``, ``zeta`` (P,) the stage (discretized by :func:`bilinear_biquad`); ``levels`` the
    capture's :func:`~hystfit.models.gpi.input_levels` (envelope tables), if computed, and ``period``
    its :func:`~hystfit.models.gpi.input_period` (the gPI output is then copied a period on once the
    operator states repeat: the same numbers). Threaded over
    candidate blocks from :data:`~hystfit.models._kernels.PARALLEL_MIN_POP` candidates on."""
    u = readonly(u)
    lv, index = levels if levels is not None else (u, np.empty(0, dtype=np.int64))
    lv, index = readonly(lv), readonly(index, np.int64)  # one compiled form (see readonly)
    y = readonly(y if y is not None else np.empty(0))
    t = np.ascontiguousarray(gpi_theta, dtype=np.float64)
    P = t.shape[0]
    cols = [np.ascontiguousarray(t[:, i]) for i in range(12)]
    a1, a2, a3, a4, b1, b2, b3, b4, rho, tau, alpha, y0 = cols
    coef = _stage_coefficients(fn_Hz, zeta, dt, P)
    out = np.empty((u.shape[0], P)) if mode == _OUTPUT else np.empty((P, 1 if mode == _SSE else 3))
    args = (u, lv, index, y, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, rho, y0, *coef, int(n), int(mode), out,
            int(period))
    nb = thread_blocks(P, PARALLEL_MIN_POP, 8)
    block = max(1, TABLE_BLOCK_ELEMENTS // max(lv.shape[0], 1)) if index.shape[0] else P
    if nb:  # at least one block per thread, and blocks no larger than the table bound
        _gpi2_parallel(*args, max(nb, -(-P // block)))
    else:
        _gpi2_serial(*args, max(block, 1))
    return out


@njit(cache=True)
def _centred_stage_columns(x, b0, b1, b2, a1, a2):
    """:func:`biquad_columns` (x, …) minus its column means, in place: the numbers of
    ``F - F.mean(axis=0)`` (the rows summed in order from the first, then divided by N) without
    the two temporaries (step 1 of the two-step identification evaluates this ≈ 5000 times)."""
    out = biquad_columns(x, b0, b1, b2, a1, a2)
    N, M = out.shape
    if N == 0:
        return out
    mean = out[0].copy()
    for k in range(1, N):
        for m in range(M):
            mean[m] += out[k, m]
    for m in range(M):
        mean[m] = mean[m] / N
    for k in range(N):
        for m in range(M):
            out[k, m] -= mean[m]
    return out


def fit_stage_with_classical_pi(us, ys, dt: float, n_operators: int = 20,
                                fn_bounds_Hz: tuple[float, float] | None = None,
                                zeta_bounds: tuple[float, float] = (0.01, 2.0)) -> tuple[float, float, float]:
    """Step 1 of paper 000's two-step identification: the linear part first.

    The hysteresis is stood in for by a classical PI (20 operators, thresholds spread over the
    input range, weights free) plus static quadratic and cubic terms of the input (the
    envelopes' curvature), all entering linearly, so for a candidate (f_n, ζ) the best weights
    follow from one least-squares solve (pooled over the captures, one offset per capture):
    only (f_n, ζ) are searched — a log-spaced grid, then Nelder–Mead from the best grid point.
    Returns (f_n Hz, ζ, RMSE of that fit).

    The stand-in's misfit biases the stage: on a generalized-PI plant with a 1200 Hz, ζ 0.15
    stage seen through 50 and 200 Hz raised cosines (``tests/unit/test_pi2.py``) it finds
    1242 Hz and ζ 0.155 (10 operators without the cubic terms: 1513 Hz, ζ 0.195). The joint
    route (``identification=joint``) has no such bias but searches two more parameters.
    """
    us = [readonly(u) for u in us]
    ys = [readonly(y) for y in ys]
    u_all = np.concatenate(us)
    lo_u, hi_u = float(u_all.min()), float(u_all.max())
    if not hi_u > lo_u:
        raise InputError("pi2: the input is constant; the linear part needs an excitation")
    r = np.arange(n_operators) * (hi_u - lo_u) / n_operators
    c, h = 0.5 * (hi_u + lo_u), 0.5 * (hi_u - lo_u)
    # plays, plus static cubic terms for the envelopes' curvature (both enter linearly)
    plays = [readonly(np.hstack([play_matrix(u, r), ((u - c) / h)[:, None] ** 2, ((u - c) / h)[:, None] ** 3]))
             for u in us]
    n_cols = n_operators + 2
    if fn_bounds_Hz is None:  # no drive frequencies given: the captures' peak rate stands in
        fn_bounds_Hz = fn_search_range_of(DataScale.from_arrays(us, ys, [dt] * len(us)))
    lo_f, hi_f = fn_bounds_Hz
    N_total = sum(u.size for u in us)
    yc = [y - y.mean() for y in ys]  # one free offset per capture: solved by centring each capture

    def cost(x):
        fn, z = math.exp(x[0]), x[1]
        if not (lo_f <= fn <= hi_f and zeta_bounds[0] <= z <= zeta_bounds[1]):
            return math.inf
        coef = [np.full(n_cols, a[0]) for a in bilinear_biquad(fn, z, dt)]
        # the pooled least squares through its normal equations (K × K, K = n + 2): the stacked
        # (N_total × K) SVD solve cost 0.4 s per candidate on 24 captures, this a few ms
        cols = [_centred_stage_columns(F, *coef) for F in plays]
        G = sum(Fc.T @ Fc for Fc in cols)
        g = sum(Fc.T @ y for Fc, y in zip(cols, yc))
        scale = np.sqrt(np.maximum(np.diag(G), 1e-300))
        sol, *_ = np.linalg.lstsq(G / np.outer(scale, scale), g / scale, rcond=1e-12)
        sol = sol / scale
        sse = sum(float(r @ r) for r in (Fc @ sol - y for Fc, y in zip(cols, yc)))
        return sse / N_total

    grid = [(math.log(f), z) for f in np.geomspace(lo_f, hi_f, 10) for z in (0.05, 0.2, 0.5, 1.0)]
    start = min(grid, key=cost)
    sol = optimize.minimize(cost, np.array(start), method="Nelder-Mead",
                            options={"xatol": 1e-4, "fatol": 1e-12, "maxfev": 200})
    x = sol.x if sol.fun <= cost(start) else np.array(start)
    return math.exp(x[0]), float(x[1]), math.sqrt(cost(x))


@models.register
@dataclass(frozen=True)
class PI2(Model):
    r"""Electromechanical model (paper 000): generalized PI hysteresis driving a second-order stage.

    .. math::

        \ddot x + 2\zeta\omega_n \dot x + \omega_n^2 x = \omega_n^2\, H[u],\qquad
        y = x + y_0,\qquad \omega_n = 2\pi f_n

        H[u](k) = \rho \sum_{j=0}^{n-1} e^{-\tau r_j}\, s_{r_j}[u](k),\quad
        s_r = \max(\gamma_l(u) - r, \min(\gamma_r(u) + r, s_r(k-1))),\quad r_j = \alpha_r j

    with γ_l(u) = a1 tanh(a2 u + a3) + a4, γ_r(u) = b1 tanh(b2 u + b3) + b4: the generalized PI
    of :class:`~hystfit.models.gpi.GPI` (paper 000's hysteresis; Al Janaideh, Rakheja & Su 2009)
    as H, the static gain g of ``shared/papers/README.md`` folded into ρ (only ρ·g is
    identifiable), and the stage of the ``dynamics`` block (:mod:`hystfit.blocks.dynamics`:
    prewarped bilinear discretization, at rest at the first sample — paper 000's fast exact
    solution of the linear part instead of RK4). The classical-PI variant is the expression
    ``pi+dynamics``.

    Structure
    ---------
    n_operators : generalized play operators n (default 10).
    identification : "two-step" (default, paper 000: the linear part first, then the hysteresis)
        or "joint" (f_n and ζ searched with the hysteresis parameters).
    fn_Hz, zeta : the stage of the two-step route, identified once from all captures by
        :meth:`prepare` (:func:`fit_stage_with_classical_pi`: the stage with a classical PI
        standing in for the hysteresis, weights solved exactly); None before, and always None
        for "joint".

    Parameters (θ)
    --------------
    a1 … b4, rho, tau, alpha_r, y0 : as in :class:`~hystfit.models.gpi.GPI` (ρ in output unit
        per V includes the stage's static gain, which is 1).
    fn_Hz (Hz), zeta (1) : only with ``identification="joint"``; bounds of the ``dynamics`` block
        (f_n from twice the excitation frequency to 0.45·f_s, ζ in [0.01, 2]).

    Speed: one fused numba kernel (:func:`gpi2_run`) runs the generalized plays, the stage and
    the squared error (or the normal equations of ρ and y0, which enter linearly: the ``auto``
    optimizer searches the other ten or twelve) in one time loop, candidates innermost; the
    (P, N) outputs are never stored. Simulation reuses :func:`~hystfit.models.gpi.gpi_population` and
    :func:`biquad_columns` themselves.

    Inverse: the stage's inverse (:func:`~hystfit.blocks.dynamics.invert_second_order`, one
    sample of preview, smooth targets), then the generalized PI's inverse (:meth:`GPI.invert`:
    analytic for equal envelopes, per-sample numerical otherwise).
    """

    name = "pi2"
    title = "generalized PI hysteresis + second-order dynamics (electromechanical, paper 000)"
    reference = "paper 000 (generalized PI + second-order linear subsystem, two-step identification)"
    equation = ("x'' + 2ζω_n x' + ω_n² x = ω_n² ρ Σ_j e^{−τ r_j} s_{r_j}[u],  y = x + y0,  "
                "s_r = max(γ_l(u) − r, min(γ_r(u) + r, s_r(k−1))),  γ_l = a1 tanh(a2 u + a3) + a4,  "
                "γ_r = b1 tanh(b2 u + b3) + b4,  r_j = α_r j")
    rate_dependent = True
    resolution_option = "n_operators"

    n_operators: int = 10
    identification: str = "two-step"
    fn_Hz: float | None = None
    zeta: float | None = None

    def __post_init__(self) -> None:
        try:
            self.gpi
        except ConfigError as exc:
            raise ConfigError(f"pi2: {str(exc).removeprefix('gpi: ')}") from None
        if self.identification not in IDENTIFICATIONS:
            raise ConfigError(f"pi2: identification must be one of {', '.join(IDENTIFICATIONS)}, "
                              f"got {self.identification!r}")
        given = (self.fn_Hz is not None, self.zeta is not None)
        if self.identification == "joint" and any(given):
            raise ConfigError("pi2: fn_Hz and zeta are searched with identification=joint; do not set them")
        if given[0] != given[1]:
            raise ConfigError("pi2: give both fn_Hz and zeta (the stage of the two-step route) or neither")
        if all(given) and not (float(self.fn_Hz) > 0 and float(self.zeta) >= 0):
            raise ConfigError(f"pi2: the stage needs fn_Hz > 0 and zeta ≥ 0, got {self.fn_Hz!r}, {self.zeta!r}")

    # ------------------------------------------------------------------ structure
    @classmethod
    def from_structure(cls, data: dict) -> "Model":
        """Also reads the ``pi2`` of earlier hystfit versions (classical PI + stage; its structure
        has ``thresholds_V``): that model is now the expression ``pi+dynamics``, with the same θ
        order (w0 … w{n−1}, y0, f_n, ζ) and the same numbers, and is returned as such."""
        if "thresholds_V" in data or "placement" in data:

            legacy = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
            return Composite(PI(**legacy), (Dynamics(),))
        return super().from_structure(data)

    @property
    def gpi(self) -> GPI:
        """The hysteresis part as a :class:`GPI` (same operator count)."""
        return GPI(self.n_operators)

    @property
    def joint(self) -> bool:
        return self.identification == "joint"

    @property
    def d(self) -> int:
        return 14 if self.joint else 12

    @classmethod
    def example(cls, scale: DataScale, fn_Hz: float = 1200.0, zeta: float = 0.15) -> "PI2":
        """A two-step structure with a representative stage (P-721-like, capped at a tenth of the
        sample rate), for documentation and the contract suite; in use :meth:`prepare` identifies it."""
        return cls(fn_Hz=min(float(fn_Hz), 0.1 / scale.dt), zeta=float(zeta))

    def prepare(self, captures) -> "PI2":
        """Two-step route, step 1: identify the stage once from all captures (unless given)."""
        if self.joint or self.fn_Hz is not None:
            return self
        caps = captures_at_one_rate(captures, "pi2", ", or use --model-option identification=joint")
        us, ys = [c.u for c in caps], [c.y for c in caps]
        scale = DataScale.from_arrays(us, ys, [c.dt for c in caps], [c.frequency_Hz for c in caps])
        fn, z, _ = fit_stage_with_classical_pi(us, ys, caps[0].dt, fn_bounds_Hz=fn_search_range_of(scale))
        return replace(self, fn_Hz=float(fn), zeta=float(z))

    def structure_summary(self) -> str:
        if self.joint:
            return "Stage: f_n and ζ searched jointly with the hysteresis (identification=joint)."
        if self.fn_Hz is None:
            return "Stage: not identified yet (two-step: identified from the captures before the fit)."
        return (f"Stage: f_n {self.fn_Hz:.4g} Hz, ζ {self.zeta:.3g}, identified first with a classical PI standing "
                "in for the hysteresis (paper 000's two-step identification); the hysteresis is fitted through it.")

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        ps = self.gpi.params(scale)
        if self.joint:
            lo, hi = fn_search_range_of(scale)
            ps += (Param("fn_Hz", "Hz", lo, hi, math.sqrt(lo * hi), "natural frequency f_n of the linear subsystem"),
                   Param("zeta", "1", 0.01, 2.0, 0.2, "damping ratio ζ of the linear subsystem"))
        return ps

    def _stage(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f_n, ζ) per candidate (P,) from θ (joint) or the structure (two-step)."""
        P = theta.shape[0]
        if self.joint:
            return np.ascontiguousarray(theta[:, 12]), np.ascontiguousarray(theta[:, 13])
        if self.fn_Hz is None:
            raise ConfigError("pi2: the stage is not identified yet (two-step route): identify from captures, give "
                              "--model-option fn_Hz=… zeta=…, or use --model-option identification=joint")
        return np.full(P, float(self.fn_Hz)), np.full(P, float(self.zeta))

    def natural_frequency_Hz(self, theta: np.ndarray) -> float | None:
        """The linear subsystem's f_n: θ's (joint) or the structure's (two-step), None before it is identified."""
        if not self.joint and self.fn_Hz is None:
            return None
        return float(self._stage(np.atleast_2d(np.asarray(theta, dtype=np.float64)))[0][0])

    # ------------------------------------------------------------------ simulation
    def simulate(self, theta: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """gPI output (:func:`~hystfit.models.gpi.gpi_population`), stage (:func:`biquad_columns`), offset: (P, N)."""
        theta = self.check_theta(theta, self.d)
        u = readonly(u)
        fn, z = self._stage(theta)
        zg = self.gpi._z(theta[:, :12], u)  # (N, P) unit-density gPI output
        with np.errstate(all="ignore"):
            coef = bilinear_biquad(fn, z, dt)
        zf = biquad_columns(readonly(zg), *coef)
        return (zf * theta[:, 8][None, :] + theta[:, 11][None, :]).T

    def simulator(self, u: np.ndarray, dt: float) -> Callable[[np.ndarray], np.ndarray]:
        u = readonly(u)
        levels = input_levels(u)  # once per capture, shared by every call
        period = input_period(levels)

        def sim(theta):
            theta = self.check_theta(theta, self.d)
            fn, z = self._stage(theta)
            return gpi2_run(u, None, theta[:, :12], fn, z, dt, self.n_operators, _OUTPUT, levels, period).T

        return sim

    def sse_evaluator(self, u: np.ndarray, dt: float, y: np.ndarray):
        """Σ(ŷ − y)² per candidate from the fused kernel (:func:`gpi2_run`, SSE mode)."""
        u = readonly(u)
        y = readonly(y)
        levels = input_levels(u)
        period = input_period(levels)

        def sse(theta):
            theta = self.check_theta(theta, self.d)
            fn, z = self._stage(theta)
            return gpi2_run(u, y, theta[:, :12], fn, z, dt, self.n_operators, _SSE, levels, period)[:, 0]

        return sse

    def separable(self):
        """ρ and y0 enter linearly (y = ρ·z_f + y0); the normal equations come from the fused kernel."""
        lin = (8, 11)
        nl = tuple(i for i in range(self.d) if i not in lin)

        def full(theta_nl):
            theta_nl = np.atleast_2d(np.asarray(theta_nl, dtype=np.float64))
            th = np.zeros((theta_nl.shape[0], self.d))
            th[:, nl] = theta_nl
            th[:, 8] = 1.0  # unit density scale: the kernel's output is then z_f (y0 = 0)
            return th

        def response(u, dt):
            levels = input_levels(u)
            period = input_period(levels)

            def z_f(theta_nl):
                th = full(theta_nl)
                fn, z = self._stage(th)
                return gpi2_run(u, None, th[:, :12], fn, z, dt, self.n_operators, _OUTPUT, levels, period)  # (N, P)

            return z_f

        def moments(u, dt, y):
            levels = input_levels(u)
            period = input_period(levels)

            def sums(theta_nl):
                th = full(theta_nl)
                fn, z = self._stage(th)
                M = gpi2_run(u, y, th[:, :12], fn, z, dt, self.n_operators, _MOMENTS, levels, period)
                return M[:, 0], M[:, 1], M[:, 2]

            return sums

        return scaled_response(lin, nl, response, moments)

    # ------------------------------------------------------------------ stepping
    def initial_state(self, theta: np.ndarray, u0: float, dt: float) -> np.ndarray:
        """[gPI operator states (n), d[k−1], d[k−2], e[k−1], e[k−2], z0] after the first sample u0."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        s = self.gpi.initial_state(t[:12], u0, dt)
        _, q = self.gpi._operators(np.r_[t[:8], 1.0, t[9:12]])
        return np.r_[s, 0.0, 0.0, 0.0, 0.0, float(s @ q)]

    def step(self, theta, state, u_prev, u_new, dt):
        """One sample for candidate inputs u_new (C,): outputs (C,) and states (C, n + 5)."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        n = self.n_operators
        state = np.asarray(state, dtype=np.float64)
        u_new = np.atleast_1d(np.asarray(u_new, dtype=np.float64))
        unit = np.r_[t[:8], 1.0, t[9:11], 0.0]  # ρ = 1, y0 = 0: the gPI's unit-density output z
        z, s = self.gpi.step(unit, state[:n], u_prev, u_new, dt)
        d1, d2, e1, e2, z0 = state[n:n + 5]
        fn, zeta = self._stage(t[None, :])
        b0, b1, b2, a1, a2 = (float(c[0]) for c in bilinear_biquad(fn, zeta, dt))
        d = z - z0
        e = b0 * d + b1 * d1 + b2 * d2 - a1 * e1 - a2 * e2
        C = u_new.shape[0]
        new = np.hstack([s, d[:, None], np.full((C, 1), d1), e[:, None], np.full((C, 1), e1), np.full((C, 1), z0)])
        return t[8] * (z0 + e) + t[11], new

    # ------------------------------------------------------------------ inverse
    def invert(self, theta: np.ndarray, y_target: np.ndarray, dt: float,
               u_range: tuple[float, float] | None = None) -> np.ndarray:
        """Input u (N,) for a smooth target: the stage's inverse, then the generalized PI's inverse."""
        t = np.asarray(theta, dtype=np.float64).ravel()
        if t.size != self.d:
            raise ValueError(f"pi2: theta must have {self.d} entries, got {t.size}")
        fn, zeta = (float(a[0]) for a in self._stage(t[None, :]))
        try:
            x = invert_second_order(np.asarray(y_target, dtype=np.float64), fn, zeta, dt)
        except ConfigError as exc:
            raise ConfigError(f"pi2: {str(exc).removeprefix('dynamics: ')}") from None
        return self.gpi.invert(t[:12], x, dt, u_range=u_range)
