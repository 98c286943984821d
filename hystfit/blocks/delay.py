"""Pure time delay: y(t) = x(t − T_d)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from .._jit import njit, readonly
from ..effects import EffectParam
from ..params import DataScale, Param
from ..registry import blocks
from .base import Block, frequency_of_excitation, scale_of_views


@njit(cache=True)
def _delay_rows(x, n, f):
    """Row k of x (N, M) read at k − n − f: (1 − f)·x[max(k − n, 0)] + f·x[max(k − n − 1, 0)] (the
    first row held before the start); for f = 0 the row x[max(k − n, 0)] itself. One pass, no
    temporaries (the arithmetic of the former slice form, hence the same numbers)."""
    N, M = x.shape
    out = np.empty((N, M))
    g = 1.0 - f
    for k in range(N):
        i0 = max(k - n, 0)
        if f == 0.0:
            for m in range(M):
                out[k, m] = x[i0, m]
        else:
            i1 = max(k - n - 1, 0)
            for m in range(M):
                out[k, m] = g * x[i0, m] + f * x[i1, m]
    return out


def shift_rows(x: np.ndarray, n: int, f: float = 0.0) -> np.ndarray:
    """x delayed along axis 0 by n + f samples, f in [0, 1) (:func:`_delay_rows`); any shape."""
    x = np.asarray(x, dtype=np.float64)
    cols = readonly(x.reshape(x.shape[0], math.prod(x.shape[1:])))
    return _delay_rows(cols, int(n), float(f)).reshape(x.shape)


def fractional_delay(x: np.ndarray, delay_s: float, dt: float) -> np.ndarray:
    """x(t − T) along axis 0 by linear interpolation between samples; x(t < T) = x(0) (held)."""
    d = max(float(delay_s) / dt, 0.0)
    n = int(math.floor(d))
    return shift_rows(x, n, d - n)


def delay_population(x: np.ndarray, delay_s: np.ndarray, dt: float) -> np.ndarray:
    """Row p of x (P, N) delayed by delay_s[p] (s): linear interpolation, first value held."""
    x = np.asarray(x, dtype=np.float64)
    P, N = x.shape
    d = np.maximum(np.nan_to_num(np.asarray(delay_s, dtype=np.float64), nan=0.0) / dt, 0.0)
    n = np.floor(d).astype(np.int64)
    f = d - n
    values = np.unique(d)
    if P > 1 and values.size <= 4 and np.all(np.isfinite(np.asarray(delay_s, dtype=np.float64))):
        # few distinct delays (a finite-difference Jacobian perturbs the delay in one row at most):
        # the rows of each in one pass, the same products and sum per sample as below (same numbers)
        out = np.empty((P, N))
        xr = readonly(x)
        for v in values:
            rows = np.flatnonzero(d == v) if values.size > 1 else np.arange(P)
            _shift_rows_into(xr, readonly(rows, np.int64), int(n[rows[0]]), float(f[rows[0]]), out)
        return out
    idx = np.arange(N)[None, :] - n[:, None]
    x0 = np.take_along_axis(x, np.clip(idx, 0, N - 1), axis=1)
    x1 = np.take_along_axis(x, np.clip(idx - 1, 0, N - 1), axis=1)
    out = (1.0 - f)[:, None] * x0 + f[:, None] * x1
    bad = ~np.isfinite(np.asarray(delay_s, dtype=np.float64))
    if bad.any():
        out[bad] = np.nan
    return out


@njit(cache=True)
def _shift_rows_into(x, rows, n, f, out):
    """Rows ``rows`` of x (P, N) delayed by n + f samples into the same rows of ``out``:
    (1 − f)·x[k − n] + f·x[k − n − 1], indices clamped at 0 (as :func:`delay_population`'s gather,
    the same two products and sum per sample, hence the same numbers). One pass over each row, no
    temporaries and no copy of the rows (0.07 s against 0.27 s for the finite-difference Jacobians
    of diagnose's recommended fit on sample_data, ``pi+creep+delay``)."""
    N = x.shape[1]
    g = 1.0 - f
    for r in range(rows.shape[0]):
        p = rows[r]
        for k in range(N):
            i0 = max(k - n, 0)
            i1 = max(k - n - 1, 0)
            out[p, k] = g * x[p, i0] + f * x[p, i1]


def max_delay_s(dt: float, fmax_Hz: float) -> float:
    """Search range of T_d: min(50 samples, 10 % of the shortest excitation period), ≥ 2 samples.
    (It was 5 % of the period, against this description: a blind test's 0.45 ms delay under a
    120 Hz drive, 5.4 % of its period, was clipped at the bound.)"""
    hi = 50.0 * dt
    if np.isfinite(fmax_Hz) and fmax_Hz > 0:
        hi = min(hi, 0.1 / fmax_Hz)
    return float(max(hi, 2.0 * dt))


@blocks.register
@dataclass(frozen=True)
class Delay(Block):
    r"""Pure time delay between input and output: y(t) = x(t − T_d).

    Fractional samples by linear interpolation, x(0) held for t < T_d (as an amplifier or a
    sensor filter with a constant group delay would look from the data). Applied to the signal
    before it; after a rate-independent base model this equals delaying the input.

    Why this form: DAQ pipelines, amplifiers and digital sensor filters delay the signal by a
    few samples; it shows as a phase lag 2πfT_d that grows linearly with frequency, with no gain
    change and no ringing (which separates it from the ``dynamics`` block). One searched parameter.

    Parameters (θ)
    --------------
    delay_s : T_d (s), in [0, max_delay_s].

    Structure
    ---------
    max_delay_s : the upper bound (s); by default (None) min(50 samples, 10 % of the shortest
        excitation period), ≥ 2 samples, set from the data.

    Inverse: a time advance x(t) = y(t + T_d) (the feedforward target is known in advance), the
    last value held.
    """

    name: ClassVar[str] = "delay"
    title: ClassVar[str] = "pure time delay"
    equation: ClassVar[str] = "y(t) = x(t − T_d)"
    reference: ClassVar[str] = "transport delay of amplifier and sensor electronics"

    max_delay_s: float | None = None
    n_grid: int = 41

    @property
    def delay_max(self) -> float:
        """The upper bound of T_d (s): ``max_delay_s``, or 5 ms before it is set from the data."""
        return 0.005 if self.max_delay_s is None else float(self.max_delay_s)

    # ------------------------------------------------------------------ structure
    def configure(self, views, yhats):
        return replace(self, max_delay_s=None).adapt(scale_of_views(views))  # as identify sets it

    def adapt(self, scale: DataScale) -> "Delay":
        if self.max_delay_s is not None:
            return self
        return replace(self, max_delay_s=max_delay_s(scale.dt, frequency_of_excitation(scale)))

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        return (Param("delay_s", "s", 0.0, self.delay_max, min(scale.dt, 0.5 * self.delay_max),
                      "delay T_d between the signal before the block and after it"),)

    # ------------------------------------------------------------------ diagnose interface
    def param_table(self):
        return (EffectParam("delay_s", "s", "searched", "delay between input and output"),)

    def searched_bounds(self):
        return np.array([0.0]), np.array([self.delay_max])

    def search_grid(self):
        return np.linspace(0.0, self.delay_max, self.n_grid)[:, None]

    def operator(self, x, view, phi):
        return fractional_delay(x, float(phi[0]), view.dt)

    def operator_knots(self, phi, view):
        """A fractional delay interpolates between the whole-sample delays around it (knots: samples)."""
        d = max(float(phi[0]) / view.dt, 0.0)
        n = int(math.floor(d))
        return n, n + 1, d - n

    def knot_operator(self, x, view, key):
        return shift_rows(x, key)

    def knot_shift(self, key) -> int:
        """The knot ``key`` as a whole-sample delay: :meth:`knot_operator` is ``shift_rows(x, key)``, whose
        Gram products :class:`hystfit.effects._ShiftedRuns` takes from one Gram of the fit rows."""
        return int(key)

    def signature(self, yhat, view):
        """One sample of delay, ŷ(t − dt) − ŷ(t): first order in T_d for smooth inputs, and the
        right shape at steps (a derivative would be a spike there)."""
        x = np.asarray(yhat, float)
        back = np.empty_like(x)
        back[0] = 0.0
        back[1:] = x[:-1] - x[1:]
        return back[:, None], np.zeros((x.shape[0], 0))

    def describe(self, phi, shared, local, views, sources=None):
        d = float(phi[0])
        dt = min(v.dt for v in views)
        out = {"delay_s": d, "delay_ms": 1e3 * d, "delay_samples": d / dt, "search_max_ms": 1e3 * self.delay_max}
        fmax = frequency_of_excitation(scale_of_views(views))
        if np.isfinite(fmax):
            out["phase_lag_at_highest_excitation_deg"] = 360.0 * fmax * d
        return out

    # ------------------------------------------------------------------ composite interface
    def apply_population(self, x, theta, dt):
        x = np.atleast_2d(x)
        th = self.population(theta, 1, x.shape[0])
        return delay_population(x, th[:, 0], dt)

    def invert(self, theta, y, dt):
        """x(t) = y(t + T_d) by linear interpolation; the last value is held."""
        y = np.asarray(y, dtype=np.float64)
        d = max(float(np.ravel(theta)[0]) / dt, 0.0)
        N = y.shape[0]
        pos = np.arange(N) + d
        return np.interp(pos, np.arange(N), y)

    def _length(self, theta, dt) -> int:
        return int(math.floor(max(float(np.ravel(theta)[0]) / dt, 0.0))) + 2

    def step_init(self, theta, x0, dt):
        return np.full(self._length(theta, dt), float(x0))  # the last inputs, newest first

    def step(self, theta, state, x_new, dt):
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        d = max(float(np.ravel(theta)[0]) / dt, 0.0)
        n = int(math.floor(d))
        f = d - n
        hist = np.asarray(state, dtype=np.float64)
        new = np.empty((x_new.size, hist.size))
        new[:, 0] = x_new
        new[:, 1:] = hist[None, :-1]
        y = (1.0 - f) * new[:, n] + f * new[:, n + 1]
        return y, new
