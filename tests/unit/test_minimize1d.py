"""minimize_bounded: the same iterates and minimizer as scipy's bounded Brent search."""

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from hystfit.minimize1d import minimize_bounded

FUNCTIONS = [lambda x: (x - 0.3) ** 2, lambda x: math.sin(3 * x) + 0.1 * x, lambda x: abs(x - 0.77),
             lambda x: x ** 4 - x ** 2 + 0.1 * x, lambda x: math.cos(x) * math.exp(-x)]


@pytest.mark.parametrize("k", range(len(FUNCTIONS)))
def test_same_as_scipy_bounded(k):
    rng = np.random.default_rng(k)
    f = FUNCTIONS[k]
    for _ in range(100):
        lo = rng.uniform(-3, 1)
        hi = lo + rng.uniform(1e-6, 5)
        tol = 10 ** rng.uniform(-9, -2)
        ref = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": tol})
        got = minimize_bounded(f, lo, hi, xatol=tol)
        assert (got.x, got.fun, got.nfev, got.success) == (ref.x, ref.fun, ref.nfev, ref.success)


def test_budget_and_bad_bounds():
    got = minimize_bounded(lambda x: (x - 0.3) ** 2, 0.0, 1.0, xatol=1e-12, maxiter=3)
    assert got.nfev == 3 and not got.success
    with pytest.raises(ValueError):
        minimize_bounded(lambda x: x, 1.0, 0.0)
    with pytest.raises(ValueError):
        minimize_bounded(lambda x: x, 0.0, math.inf)
