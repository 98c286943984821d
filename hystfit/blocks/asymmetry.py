"""Static output nonlinearity: y = x + a₂(q² − 1) + a₃(q³ − q), q = (x − m)/h."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from ..effects import EffectParam
from ..params import DataScale, Param, output_span
from ..registry import blocks
from .base import Block

#: bound of |a₂|, |a₃| as a fraction of the half range h (the map stays monotone over the stroke
#: for |a₂| + |a₃| ≤ h/2)
MAX_COEF = 0.3


def bow(x: np.ndarray, a2, a3, center: float, half_range: float) -> np.ndarray:
    """x + a₂(q² − 1) + a₃(q³ − q), q = (x − center)/half_range (a₂, a₃ broadcast against x)."""
    q = (x - center) / half_range
    q2 = q * q
    return x + a2 * (q2 - 1.0) + a3 * (q2 - 1.0) * q


@blocks.register
@dataclass(frozen=True)
class Asymmetry(Block):
    r"""Static output nonlinearity after the hysteresis: a polynomial bow that keeps the stroke ends.

    .. math:: y = x + a_2\,(q^2 - 1) + a_3\,(q^3 - q),\qquad q = (x - m)/h

    m and h the middle and half-range of the span the block's input covers (structure, set from the
    data: :func:`hystfit.params.output_span`), so a₂ and a₃ are in output units and both terms
    vanish at the stroke ends q = ±1: the map bends the curve between fixed end points. −a₂ is the
    bow at mid-stroke (a₂ < 0: the middle bulges up, saturation), a₃ a skew (stiffening at one end).

    Why this form: the classical PI model's loops are point-symmetric (ascending and descending
    branches are the same curve rotated by 180°). A static map after the hysteresis — the form
    a Wiener–Hammerstein or generalized-PI model adds — breaks that symmetry: the two branches
    bend differently, and the error grows faster than the stroke. Linear in a₂, a₃ (solved
    exactly when x is held); the first two terms of any smooth monotone output map (linear and
    constant terms belong to the base model, hence the fixed end points). The virtual
    actuator's asymmetry z + a·z(z − s)/s is this block with m = h = s/2, a₂ = a·s/4, a₃ = 0.

    Parameters (θ)
    --------------
    a2, a3 : bow and skew (output unit), in ±0.3·h.

    Structure
    ---------
    center, half_range : m and h (output unit); by default (None) the middle and half of the
        identification data's output span (:attr:`hystfit.params.DataScale.y_span`; diagnose: of
        the fit part, by the same rule): the output range of the smoothly driven captures, widened
        to the output's settled levels where the input is at its extremes. Not the output's range:
        a stage after the hysteresis overshoots after a step and rings on a PRBS, and h taken from
        those excursions spread the bow over inputs the block never sees and made the coefficient
        box (∝ h, while the coefficients needed grow ∝ h²) bind — seed 9090 at strength 2: h
        36.6 µm instead of 10.5 µm, a₂ at its bound −10.99 µm. A params.json's stored m, h are
        kept (files written before this rule load with the numbers they were fitted with).

    Inverse: monotone static inverse, per sample (Newton steps safeguarded by bisection on the
    bracket of the output range).
    """

    name: ClassVar[str] = "asymmetry"
    title: ClassVar[str] = "asymmetry / saturation (static output bow)"
    equation: ClassVar[str] = "y = x + a2·(q² − 1) + a3·(q³ − q), q = (x − m)/h"
    reference: ClassVar[str] = "static output nonlinearity (Wiener form), as the envelope of a generalized PI"

    center: float | None = None
    half_range: float | None = None

    def __post_init__(self) -> None:
        if self.center is not None and not np.isfinite(self.center):
            raise ValueError(f"center must be finite, got {self.center!r}")
        if self.half_range is not None and not (np.isfinite(self.half_range) and self.half_range > 0):
            raise ValueError(f"half_range must be > 0, got {self.half_range!r}")

    @property
    def m(self) -> float:
        return 0.0 if self.center is None else float(self.center)

    @property
    def h(self) -> float:
        return 1.0 if self.half_range is None else float(self.half_range)

    # ------------------------------------------------------------------ structure
    def spanning(self, lo: float, hi: float) -> "Asymmetry":
        """The block with m, h spanning the levels ``lo``…``hi`` where they are not set (the
        structure given — an option, or a params.json's — wins)."""
        return replace(self, center=0.5 * (lo + hi) if self.center is None else self.center,
                       half_range=max(0.5 * (hi - lo), 1e-12) if self.half_range is None else self.half_range)

    def configure(self, views, yhats):
        """m, h from the fit part of the captures, by the rule :meth:`adapt` applies to the
        identification data (:func:`hystfit.params.output_span`); views without their input (callers
        that build them so) give the range of the fit part's output."""
        if all(v.u is not None for v in views):
            return self.spanning(*output_span([v.u for v in views], [v.y for v in views], [v.dt for v in views],
                                              [v.frequency_Hz for v in views], [v.fit for v in views]))
        ys = np.concatenate([v.y[v.fit] for v in views])
        return self.spanning(float(ys.min()), float(ys.max()))

    def adapt(self, scale: DataScale) -> "Asymmetry":
        return self.spanning(*scale.y_span)

    def params(self, scale: DataScale) -> tuple[Param, ...]:
        b = MAX_COEF * self.h
        return (Param("a2", "out", -b, b, 0.0, "quadratic bow: −a2 is the bow at mid-stroke"),
                Param("a3", "out", -b, b, 0.0, "cubic skew"))

    # ------------------------------------------------------------------ diagnose interface
    def param_table(self):
        return (EffectParam("a2", "out", "linear", "quadratic bow: −a2 is the bow at mid-stroke"),
                EffectParam("a3", "out", "linear", "cubic skew"),
                EffectParam("center", "out", "fixed", "middle of the output's span (hysteresis, without ringing)"),
                EffectParam("half_range", "out", "fixed", "half the output's span (hysteresis, without ringing)"))

    def layout(self):
        return 2, 0

    def coefficient_bounds(self):
        b = MAX_COEF * self.h
        return np.full(2, -b), np.full(2, b), np.empty(0), np.empty(0)

    def _q(self, x):
        return (np.asarray(x, float) - self.m) / self.h

    def regressors(self, yhat, view, phi):
        q = self._q(yhat)
        q2 = q * q
        return np.column_stack([q2 - 1.0, (q2 - 1.0) * q]), np.zeros((q.shape[0], 0))

    def tangent(self, x, yhat, view, phi, shared, local):
        q = self._q(yhat)
        slope = 1.0 + (2.0 * shared[0] * q + shared[1] * (3.0 * q * q - 1.0)) / self.h
        return x * slope[:, None]

    def describe(self, phi, shared, local, views, sources=None):
        a2, a3 = float(shared[0]), float(shared[1])
        return {"a2_out": a2, "a3_out": a3, "center_out": self.m, "half_range_out": self.h,
                "mid_stroke_bow_out": -a2,
                "bow_pct_of_stroke": 100.0 * abs(a2) / (2.0 * self.h)}

    # ------------------------------------------------------------------ composite interface
    def apply_population(self, x, theta, dt):
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        th = self.population(theta, 2, x.shape[0])
        return bow(x, th[:, 0:1], th[:, 1:2], self.m, self.h)

    def invert(self, theta, y, dt):
        a2, a3 = (float(v) for v in np.ravel(theta)[:2])
        y = np.asarray(y, dtype=np.float64)
        h, m = self.h, self.m
        # bracket: the map is monotone over the stroke; widen until it brackets every target
        lo = np.full_like(y, m - 2.0 * h)
        hi = np.full_like(y, m + 2.0 * h)
        for _ in range(60):
            flo = bow(lo, a2, a3, m, h) - y
            fhi = bow(hi, a2, a3, m, h) - y
            bad = (flo > 0) | (fhi < 0)
            if not bad.any():
                break
            lo = np.where(flo > 0, lo - (hi - lo), lo)
            hi = np.where(fhi < 0, hi + (hi - lo), hi)
        x = y.copy()
        for _ in range(60):  # Newton, safeguarded by the bracket
            q = (x - m) / h
            f = bow(x, a2, a3, m, h) - y
            lo = np.where(f < 0, x, lo)
            hi = np.where(f > 0, x, hi)
            d = 1.0 + (2.0 * a2 * q + a3 * (3.0 * q * q - 1.0)) / h
            with np.errstate(all="ignore"):
                xn = x - f / d
            outside = ~((xn > lo) & (xn < hi)) | ~np.isfinite(xn)
            xn = np.where(outside, 0.5 * (lo + hi), xn)
            if np.max(np.abs(xn - x)) <= 1e-13 * max(h, 1e-300):
                x = xn
                break
            x = xn
        return x

    def step(self, theta, state, x_new, dt):
        t = np.ravel(theta)
        x_new = np.atleast_1d(np.asarray(x_new, dtype=np.float64))
        return bow(x_new, t[0], t[1], self.m, self.h), np.zeros((x_new.size, 0))
