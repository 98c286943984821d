"""Viscoelastic creep: y = x + Σ c_i (LP_τi[x] − x), a Kelvin–Voigt chain driven by the displacement."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from .._jit import njit, readonly
from .._lazy import lazy_module
from ..effects import EffectParam, fmt_list
from ..params import DataScale, Param
from ..registry import blocks
from .base import Block

signal = lazy_module("scipy.signal")

#: upper bound of every creep gain c_i (a creep share above 50 % of a step is not a piezo stage)
MAX_GAIN = 0.5


def lowpass_at_rest(x: np.ndarray, tau_s: float, dt: float, axis: int = 0) -> np.ndarray:
    """First-order low-pass τ ẋ_f = x − x_f, exact for piecewise-constant input (ZOH), started at
    rest at x(0): x_f[k] = p x_f[k−1] + (1 − p) x[k], p = e^{−dt/τ}, x_f[0] = x[0].

    ``x`` is filtered along ``axis``; the same shape is returned.
    """
    x = np.asarray(x, dtype=np.float64)
    p = math.exp(-dt / tau_s)
    first = np.take(x, [0], axis=axis)
    out, _ = signal.lfilter([1.0 - p], [1.0, -p], x, axis=axis, zi=p * first)
    return out


def time_constants(longest_s: float, dt: float) -> tuple[float, ...]:
    """One τ per decade from 0.01 s to the first decade at or above the longest capture (at least
    0.1 s, at most 100 s), keeping only τ ≥ 5 samples.

    Time constants below 10 ms are excluded on purpose: they would make creep a second way to
    fit stage dynamics. The top one can exceed the capture length by up to 10×: over a capture of
    length L a relaxation 1 − e^(−t/τ) bends by ≈ L/(2τ) relative to its tangent, so the top one is
    only weakly determined and partly acts as a ramp (set ``tau_s`` to bound it). A tighter bound
    (the last decade at or below 3 L) was measured and rejected: the slow tail of a true 10 s creep
    on 3 s captures then reappeared as a spurious drift in the withheld-effect suite.
    """
    top = min(max(10.0 ** math.ceil(math.log10(max(longest_s, 1e-3)) - 1e-9), 0.1), 100.0)
    taus = tuple(float(x) for x in 10.0 ** np.arange(-2, round(math.log10(top)) + 1))
    return tuple(t for t in taus if t >= 5.0 * dt) or (float(top),)


@njit(cache=True)
def lowpass_bank(x, p):
    """LP_τi[x] − x for every column of x (N, M) and every p_i = e^{−dt/τ_i}: (K, N, M).

    The recursion of :func:`lowpass_at_rest` (x_f[k] = p x_f[k−1] + (1 − p) x[k], x_f[−1] = x[0]),
    the same operations, hence the same numbers, for all the time constants in one call.
    """
    N, M = x.shape
    K = p.shape[0]
    out = np.empty((K, N, M))
    if N == 0:
        return out
    prev = np.empty(M)
    for i in range(K):
        pi = p[i]
        b = 1.0 - pi
        for m in range(M):
            prev[m] = x[0, m]
        for k in range(N):
            for m in range(M):
                v = pi * prev[m] + b * x[k, m]
                prev[m] = v
                out[i, k, m] = v - x[k, m]
    return out


#: rows of a population that :func:`creep_rows` runs side by side (independent recursions:
#: 1.4× the row-by-row loop at 85 rows, 1.1–1.4× at 200; ``python benchmarks/creep_lanes.py``)
CREEP_LANES = 8


@njit(cache=True)
def creep_rows_one_by_one(x, p, c, out, first):
    """:func:`creep_rows` for rows ``first``, ``first`` + 1, … of x, one row's recursion after the
    other, added into ``out`` (which holds x): the last few rows of :func:`creep_rows`, and all of
    them before it ran rows side by side (``benchmarks/creep_lanes.py`` compares the two)."""
    P, N = x.shape
    K = p.shape[0]
    for r in range(first, P):
        for i in range(K):
            pi = p[i]
            b = 1.0 - pi
            cr = c[r, i]
            pv = x[r, 0]
            for k in range(N):
                v = pi * pv + b * x[r, k]
                pv = v
                out[r, k] += cr * (v - x[r, k])


@njit(cache=True)
def creep_rows(x, p, c):
    """Row r of x (P, N) plus Σ_i c[r, i]·(LP_τi[x_r] − x_r), p_i = e^{−dt/τ_i}: (P, N).

    The low-pass recursion of :func:`lowpass_bank` and the sum in the order of
    ``out = x; out += c_i·(LP_τi[x] − x)`` for i = 0, 1, … (the same operations, hence the same
    numbers), with no (K, P, N) bank in memory. Each row's recursion depends on its previous
    sample, so one row alone waits on every multiply and add: :data:`CREEP_LANES` rows at a time
    are copied time-major and advanced together (independent lanes), the last few rows one at a
    time. Every row gets exactly the operations it would alone.
    """
    P, N = x.shape
    K = p.shape[0]
    out = x.copy()
    if N == 0:
        return out
    B = CREEP_LANES
    xt = np.empty((N, B))
    ot = np.empty((N, B))
    prev = np.empty(B)
    ci = np.empty(B)
    r0 = 0
    while r0 < P:
        nb = min(B, P - r0)
        if nb < 4:  # too few rows to interleave: one at a time
            creep_rows_one_by_one(x, p, c, out, r0)
            break
        for k in range(N):
            for m in range(nb):
                xt[k, m] = x[r0 + m, k]
                ot[k, m] = xt[k, m]
        for i in range(K):
            pi = p[i]
            b = 1.0 - pi
            for m in range(nb):
                prev[m] = xt[0, m]
                ci[m] = c[r0 + m, i]
            for k in range(N):
                for m in range(nb):
                    xv = xt[k, m]
                    v = pi * prev[m] + b * xv
                    prev[m] = v
                    ot[k, m] += ci[m] * (v - xv)
        for m in range(nb):
            for k in range(N):
                out[r0 + m, k] = ot[k, m]
        r0 += nb
    return out


@njit(cache=True)
def _creep_inverse(y, p, c):
    """x with y = x + Σ c_i (s_i − x), s_i[k] = p_i s_i[k−1] + (1 − p_i) x[k], s_i[0] = x[0]."""
    N = y.shape[0]
    K = p.shape[0]
    x = np.empty(N)
    s = np.empty(K)
    x[0] = y[0]  # at rest: s_i = x, so y = x
    for i in range(K):
        s[i] = y[0]
    csum = 0.0
    lead = 0.0
    for i in range(K):
        csum += c[i]
        lead += c[i] * (1.0 - p[i])
    den = 1.0 - csum + lead
    for k in range(1, N):
        acc = y[k]
        for i in range(K):
            acc -= c[i] * p[i] * s[i]
        xk = acc / den
        x[k] = xk
        for i in range(K):
            s[i] = p[i] * s[i] + (1.0 - p[i]) * xk
    return x


@blocks.register
@dataclass(frozen=True)
class Creep(Block):
    r"""Slow viscoelastic creep driven by the displacement (a Kelvin–Voigt chain).

    .. math:: y = x + \sum_i c_i\,(\mathrm{LP}_{\tau_i}[x] - x),\qquad \tau_i \dot s_i = x - s_i

    LP_τ a first-order low-pass (exact for a piecewise-constant input) started at rest at x(0).
    After a step Δx the output jumps by (1 − Σc_i)Δx and keeps moving to Δx as
    Δx·Σ c_i(1 − e^{−t/τ_i}); with one τ per decade and equal gains that is ≈ c per decade of
    time, the logarithmic creep of piezo stacks. The DC gain is 1: the quasi-static gain belongs
    to the base model.

    Why this form: creep is slow and follows the displacement history, not the input alone; a
    fixed log-spaced bank of time constants spans 0.01 s … the capture length without a
    nonlinear search, and the gains c_i enter linearly when the signal before the block is held
    (solved exactly by diagnose and by the ``auto`` optimizer's staged start; c_i ≥ 0: creep
    follows the motion).

    Parameters (θ)
    --------------
    c0 … c{k−1} : gain with time constant τ_i (1), in [0, 0.5].

    Structure
    ---------
    tau_s : the time constants τ_i (s); by default (None) one per decade from 0.01 s to the first
        decade at or above the longest capture (at least 0.1 s, at most 100 s), set from the data
        (:func:`time_constants`); ``--model-option creep.tau_s=[0.02,0.3]`` fixes them.

    Inverse: exact and causal (:func:`_creep_inverse`): with s_i the filter states,
    x[k] = (y[k] − Σ c_i p_i s_i[k−1]) / (1 − Σc_i + Σc_i(1 − p_i)), p_i = e^{−dt/τ_i}.
    The virtual actuator's creep y = z + Σ g_i LP_τi[z] is this block with x = (1 + Σg)z and
    c_i = g_i/(1 + Σg) (:mod:`hystfit.synth`).
    """

    name: ClassVar[str] = "creep"
    title: ClassVar[str] = "viscoelastic creep"
    equation: ClassVar[str] = "y = x + Σ c_i (LP_τi[x] − x)"
    reference: ClassVar[str] = "Kelvin–Voigt creep chain (logarithmic creep of piezo stacks)"

    tau_s: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.tau_s is None:
            return
        taus = tuple(float(t) for t in np.ravel(self.tau_s))
        if not taus or not all(math.isfinite(t) and t > 0 for t in taus):
            raise ValueError(f"tau_s must be positive time constants in s, got {self.tau_s!r}")
        object.__setattr__(self, "tau_s", taus)

    @property
    def taus(self) -> tuple[float, ...]:
        """The time constants (s): ``tau_s``, or 0.01 … 10 s before they are set from the data."""
        return (0.01, 0.1, 1.0, 10.0) if self.tau_s is None else self.tau_s

    # ------------------------------------------------------------------ structure
    def configure(self, views, yhats):
        longest = max(v.t[-1] - v.t[0] + v.dt for v in views)
        return replace(self, tau_s=time_constants(longest, max(v.dt for v in views)))

    def adapt(self, scale: DataScale) -> "Creep":
        if self.tau_s is not None or scale.duration_s is None:
            return self
        return replace(self, tau_s=time_constants(scale.duration_s, scale.dt))

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        return tuple(Param(f"c{i}", "1", 0.0, MAX_GAIN, 0.01, f"creep gain with time constant {t:g} s")
                     for i, t in enumerate(self.taus))

    # ------------------------------------------------------------------ diagnose interface
    def param_table(self):
        return tuple(EffectParam(f"c{i}", "1", "linear", f"creep gain with time constant {t:g} s")
                     for i, t in enumerate(self.taus))

    def layout(self):
        return len(self.taus), 0

    def coefficient_bounds(self):
        k = len(self.taus)
        return np.zeros(k), np.full(k, MAX_GAIN), np.empty(0), np.empty(0)

    def _bank(self, x: np.ndarray, dt: float, axis: int = 0) -> list[np.ndarray]:
        """LP_τi[x] − x for every τ_i, each of the shape of ``x`` (filtered along ``axis``, 0 or 1)."""
        x = np.asarray(x, dtype=np.float64)
        cols = x[:, None] if x.ndim == 1 else (x.T if axis == 1 else x)
        p = np.array([math.exp(-dt / tau) for tau in self.taus])
        bank = lowpass_bank(readonly(cols), p)
        return [b[:, 0] if x.ndim == 1 else (b.T if axis == 1 else b) for b in bank]

    def regressors(self, yhat, view, phi):
        cols = self._bank(yhat, view.dt)
        return np.column_stack(cols), np.zeros((yhat.shape[0], 0))

    def tangent(self, x, yhat, view, phi, shared, local):
        out = np.array(x, dtype=float, copy=True)
        for c, term in zip(shared, self._bank(x, view.dt)):
            if c != 0.0:
                out += c * term
        return out

    def describe(self, phi, shared, local, views, sources=None):
        c = fmt_list(shared)
        return {"tau_s": list(self.taus), "gain": c, "total_gain": float(np.sum(c)),
                "gain_per_decade": float(np.sum(c)) / max(len(c), 1)}

    # ------------------------------------------------------------------ composite interface
    def apply_population(self, x, theta, dt):
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        k = len(self.taus)
        th = self.population(theta, k, x.shape[0])
        p = np.array([math.exp(-dt / tau) for tau in self.taus])
        return creep_rows(readonly(x), p, readonly(th))

    def invert(self, theta, y, dt):
        c = np.asarray(np.ravel(theta), dtype=np.float64)
        p = np.exp(-dt / np.asarray(self.taus))
        return _creep_inverse(readonly(y), p, readonly(c))

    def step_init(self, theta, x0, dt):
        return np.full(len(self.taus), float(x0))

    def step(self, theta, state, x_new, dt):
        c = np.ravel(theta)
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        p = np.exp(-dt / np.asarray(self.taus))
        s = p[None, :] * np.asarray(state)[None, :] + (1.0 - p)[None, :] * x_new[:, None]  # (C, K)
        y = x_new + (s - x_new[:, None]) @ c
        return y, s
