import math

import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.de import DE


def sphere(X):
    return np.sum((X - 0.3) ** 2, axis=1)


class Counter:
    def __init__(self):
        self.calls = []

    def __call__(self, X):
        self.calls.append(X.shape)
        return sphere(X)


@pytest.mark.parametrize("pop, d", [(40, 4), (30, 7)])
def test_nfev_and_history_are_consistent(pop, d):
    obj = Counter()
    r = DE(pop=pop, iters=25).minimize(obj, -np.ones(d), np.ones(d), rng=np.random.default_rng(0))
    members = math.ceil(pop / d) * d
    assert all(shape == (members, d) for shape in obj.calls)      # one (S, d) call per generation
    assert r.nit == 25 == len(obj.calls)                            # initial population = iteration 1
    assert r.nfev == 25 * members == sum(s[0] for s in obj.calls)
    assert len(r.history_best) == len(r.history_mean) == r.nit
    assert np.all(np.diff(r.history_best) <= 0)
    assert np.all(r.history_mean >= r.history_best)
    assert r.fun == r.history_best[-1] and r.status == 0


def test_eval_budget_and_stall_stop_after_a_generation():
    r = DE.from_options(dict(pop=20, iters=1000, max_evals=500)).minimize(sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(1))
    assert r.status == 0 and 500 <= r.nfev < 520 and r.nfev == 20 * r.nit
    r = DE.from_options(dict(pop=20, iters=10_000, stall_iter=10, stall_tol=1e-2)).minimize(
        sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(1))
    assert r.status == 1 and r.nit < 10_000


def test_single_iteration_evaluates_only_the_initial_population():
    obj = Counter()
    r = DE(pop=10, iters=1).minimize(obj, -np.ones(2), np.ones(2), rng=np.random.default_rng(1))
    assert r.nit == 1 and len(obj.calls) == 1 and r.status == 0


def test_scipy_convergence_is_status_5():
    r = DE(pop=20, iters=1000, tol=0.5).minimize(sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(1))
    assert r.status == 5 and r.nit < 1000 and r.message.startswith("scipy:")


def test_seeded_and_x0():
    a = DE(pop=12, iters=10).minimize(sphere, -np.ones(3), np.ones(3), rng=np.random.default_rng(3))
    b = DE(pop=12, iters=10).minimize(sphere, -np.ones(3), np.ones(3), rng=np.random.default_rng(3))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history_mean, b.history_mean)
    r = DE(pop=12, iters=1).minimize(sphere, -np.ones(3), np.ones(3), rng=np.random.default_rng(3),
                                     x0=np.array([0.3, 0.3, 0.3]))
    assert r.fun < 1e-25   # scipy scales x0 into the unit cube and back (round-off only)


def test_settings_validation():
    with pytest.raises(ConfigError):
        DE(strategy="nope")
    with pytest.raises(ConfigError):
        DE(mutation_min=1.0, mutation_max=0.5)
    with pytest.raises(ConfigError):
        DE(init="grid")
