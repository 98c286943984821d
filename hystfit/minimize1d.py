"""Bounded minimization of a function of one variable (Brent's method), without scipy.

:func:`minimize_bounded` follows ``scipy.optimize.minimize_scalar(method="bounded")`` (scipy's
``_minimize_scalar_bounded``, itself Brent's ``fmin``: golden-section steps, parabolic steps when
they are acceptable) step for step, so it visits the same points and returns the same minimizer
to the last bit. It exists so that condition detection, which runs in every command that loads a
capture, does not import :mod:`scipy.optimize` (≈ 0.5–1.0 s of start-up) for one small search.
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

__all__ = ["BoundedResult", "minimize_bounded"]

_SQRT_EPS = math.sqrt(2.2e-16)
_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))


class BoundedResult(NamedTuple):
    """Outcome of :func:`minimize_bounded`: minimizer ``x``, ``fun`` = f(x), evaluations ``nfev``,
    ``success`` (False when the evaluation budget ran out or a value was NaN)."""

    x: float
    fun: float
    nfev: int
    success: bool


def _sign(v: float) -> float:
    """numpy's ``sign(v) + (v == 0)``: +1 for v >= 0, -1 below (NaN stays NaN)."""
    if v != v:
        return v
    return 1.0 if v >= 0 else -1.0


def _parabolic_step(a: float, b: float, xf: float, fx: float, nfc: float, fnfc: float, fulc: float,
                    ffulc: float, e: float, rat: float, xm: float, tol1: float) -> tuple[float, float] | None:
    """Brent's parabolic step through the three best points, or None when it is not acceptable.

    Returns ``(rat, e)``: the step from ``xf`` and the previous step, kept for the next test.
    """
    r = (xf - nfc) * (fx - ffulc)
    q = (xf - fulc) * (fx - fnfc)
    p = (xf - fulc) * q - (xf - nfc) * r
    q = 2.0 * (q - r)
    if q > 0.0:
        p = -p
    q = abs(q)
    r, e = e, rat
    if not (abs(p) < abs(0.5 * q * r) and p > q * (a - xf) and p < q * (b - xf)):
        return None
    rat = (p + 0.0) / q
    x = xf + rat
    if (x - a) < 2.0 * tol1 or (b - x) < 2.0 * tol1:
        rat = tol1 * _sign(xm - xf)
    return rat, e


def minimize_bounded(func: Callable[[float], float], lower: float, upper: float, *, xatol: float = 1e-5,
                     maxiter: int = 500) -> BoundedResult:
    """Minimize ``func`` on ``[lower, upper]`` (finite, ``lower <= upper``) to absolute tolerance ``xatol``.

    Same iterates and result as ``scipy.optimize.minimize_scalar(func, bounds=(lower, upper),
    method="bounded", options={"xatol": xatol, "maxiter": maxiter})``.
    """
    if not (math.isfinite(lower) and math.isfinite(upper)) or lower > upper:
        raise ValueError(f"minimize_bounded: needs finite bounds with lower <= upper, got ({lower}, {upper})")
    a, b = float(lower), float(upper)
    xf = nfc = fulc = a + _GOLDEN * (b - a)
    fx = fnfc = ffulc = float(func(xf))
    fu = math.inf
    rat = e = 0.0
    num = 1
    xm = 0.5 * (a + b)
    tol1 = _SQRT_EPS * abs(xf) + xatol / 3.0
    ok = True
    while abs(xf - xm) > (2.0 * tol1 - 0.5 * (b - a)):
        step = _parabolic_step(a, b, xf, fx, nfc, fnfc, fulc, ffulc, e, rat, xm, tol1) if abs(e) > tol1 else None
        if step is None:  # golden-section step into the larger part
            e = (a - xf) if xf >= xm else (b - xf)
            rat = _GOLDEN * e
        else:
            rat, e = step
        x = xf + _sign(rat) * max(abs(rat), tol1)
        fu = float(func(x))
        num += 1
        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc, nfc, fnfc, xf, fx = nfc, fnfc, xf, fx, x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if fu <= fnfc or nfc == xf:
                fulc, ffulc, nfc, fnfc = nfc, fnfc, x, fu
            elif fu <= ffulc or fulc == xf or fulc == nfc:
                fulc, ffulc = x, fu
        xm = 0.5 * (a + b)
        tol1 = _SQRT_EPS * abs(xf) + xatol / 3.0
        if num >= maxiter:
            ok = False
            break
    if math.isnan(xf) or math.isnan(fx) or math.isnan(fu):
        ok = False
    return BoundedResult(xf, fx, num, ok)
