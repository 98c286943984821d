import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.base import reflect
from hystfit.optimizers.lsq import LSQ
from hystfit.optimizers.pso import PSO


def sphere(X):
    return np.sum((X - 0.3) ** 2, axis=1)


def test_reflect_keeps_points_inside_and_mirrors():
    lo, hi = np.array([0.0, -1.0]), np.array([1.0, 1.0])
    x = np.array([[1.2, -1.5], [-0.3, 3.5], [0.5, 0.0]])
    y = reflect(x, lo, hi)
    np.testing.assert_allclose(y, [[0.8, -0.5], [0.3, -0.5], [0.5, 0.0]])


def test_pso_respects_bounds_and_is_reproducible():
    seen = []

    def f(X):
        seen.append(X.copy())
        return sphere(X)

    lo, hi = -np.ones(4), np.ones(4)
    r1 = PSO(pop=20, iters=50).minimize(f, lo, hi, rng=np.random.default_rng(3))
    allx = np.vstack(seen)
    assert np.all(allx >= lo) and np.all(allx <= hi)
    r2 = PSO(pop=20, iters=50).minimize(sphere, lo, hi, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(r1.x, r2.x)
    assert r1.nfev == 20 * 50 and r1.nit == 50  # iters counts population evaluations, the initial one included
    assert r1.fun < 1e-4
    assert np.all(np.diff(r1.history_best) <= 0)


def test_pso_stall_and_target_stop():
    r = PSO(pop=10, iters=10_000, stall_iter=20, stall_tol=1e-3).minimize(sphere, -np.ones(2), np.ones(2),
                                                                          rng=np.random.default_rng(0))
    assert r.status == 1 and r.nit < 10_000
    r = PSO(pop=10, iters=10_000, target=1e-2).minimize(sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(0))
    assert r.status == 2 and r.fun <= 1e-2


def test_bad_box_is_a_config_error():
    with pytest.raises(ConfigError):
        PSO().minimize(sphere, np.ones(2), np.zeros(2), rng=np.random.default_rng(0))


def test_nonfinite_objective_values_are_infinite_not_fatal():
    def f(X):
        out = sphere(X)
        out[X[:, 0] > 0.5] = np.nan
        return out

    r = PSO(pop=10, iters=30).minimize(f, -np.ones(2), np.ones(2), rng=np.random.default_rng(1))
    assert np.isfinite(r.fun)


def test_lsq_uses_residuals_and_converges():
    class Obj:
        def __call__(self, X):
            return np.sum((X - [2.0, -1.0]) ** 2, axis=1)

        def residuals(self, x):
            return np.asarray(x) - [2.0, -1.0]

    r = LSQ().minimize(Obj(), np.array([0.0, -5.0]), np.array([5.0, 5.0]), rng=np.random.default_rng(0))
    np.testing.assert_allclose(r.x, [2.0, -1.0], atol=1e-8)
    assert r.status == 5


def test_auto_budget_bounds_all_searches_together():
    """``auto``'s max_evals is a budget for all its searches together, not per search."""
    from hystfit.models.bw import BoucWen
    from hystfit.objective import Objective, Series
    from hystfit.optimizers.auto import Auto
    from hystfit.params import DataScale

    fs = 2000.0
    t = np.arange(2000) / fs
    u = 30.0 * (1 - np.cos(2 * np.pi * 2 * t))
    model = BoucWen()
    scale = DataScale.from_arrays([u], [0.3 * u], [1 / fs])
    ps = model.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    y = model.simulate_one(np.array([0.25, 0.08, 0.05, 0.01, 0.1]), u, 1 / fs)
    free = Auto(restarts=3).minimize(Objective(model, [Series(u, y, 1 / fs)]), lo, hi, rng=np.random.default_rng(0))
    capped = Auto(restarts=3, max_evals=60).minimize(Objective(model, [Series(u, y, 1 / fs)]), lo, hi,
                                                     rng=np.random.default_rng(0))
    search_evals = len(capped.history_best) - 1  # iterations of the searches (the last entry is the polish)
    assert capped.nfev < free.nfev
    assert search_evals * Auto().pop <= 60 + Auto().pop
