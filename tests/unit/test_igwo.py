import math

import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.gwo import GWO, linear_convergence_factor, schedule_length
from hystfit.optimizers.igwo import (IGWO, levy_steps, logistic_init, mantegna_sigma,
                                     nonlinear_convergence_factor)


def hill_tail_index(x: np.ndarray, k: int) -> float:
    """Hill estimator of the tail index α of |x| from the k largest values."""
    a = np.sort(np.abs(x))[-(k + 1):]
    return 1.0 / float(np.mean(np.log(a[1:] / a[0])))


def test_mantegna_sigma_value():
    assert mantegna_sigma(1.5) == pytest.approx(0.696574, rel=1e-5)
    assert mantegna_sigma(1.0) == pytest.approx(1.0)


@pytest.mark.parametrize("n_sum", [1, 3])
def test_levy_steps_have_the_mantegna_power_law_tail(n_sum):
    s = levy_steps(np.random.default_rng(11), 1_000_000, beta=1.5, n_sum=n_sum)
    assert s.shape == (1_000_000,) and np.all(np.isfinite(s))
    # P(|s| > x) ~ x^{−β}: the tail index from the top 0.2 % is β
    assert hill_tail_index(s, 2000) == pytest.approx(1.5, abs=0.1)
    # the same from the survival function: slope of log P(|s| > x) between two far quantiles
    x1, x2 = np.quantile(np.abs(s), [0.99, 0.9999])
    slope = math.log(1e-2 / 1e-4) / math.log(x2 / x1)
    assert slope == pytest.approx(1.5, abs=0.15)
    assert np.median(s) == pytest.approx(0.0, abs=0.01 * n_sum)   # symmetric


def test_levy_sum_matches_three_explicit_steps_in_distribution():
    from scipy.stats import ks_2samp

    rng = np.random.default_rng(3)
    direct = levy_steps(rng, (3, 200_000)).sum(axis=0)
    summed = levy_steps(rng, 200_000, n_sum=3)
    assert ks_2samp(direct, summed).pvalue > 1e-3


def test_levy_steps_shape_and_beta_check(rng):
    assert levy_steps(rng, (3, 4, 5)).shape == (3, 4, 5)
    with pytest.raises(ConfigError):
        levy_steps(rng, 10, beta=2.5)


def test_logistic_init_in_bounds_deterministic_and_chaotic():
    lower, upper = np.array([-1.0, 0.0, 10.0]), np.array([1.0, 1e-3, 20.0])
    a = logistic_init(np.random.default_rng(5), 200, lower, upper)
    b = logistic_init(np.random.default_rng(5), 200, lower, upper)
    c = logistic_init(np.random.default_rng(6), 200, lower, upper)
    assert a.shape == (200, 3)
    assert np.all(a >= lower) and np.all(a <= upper)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    z = (a - lower) / (upper - lower)
    np.testing.assert_allclose(z[1:], 4.0 * z[:-1] * (1.0 - z[:-1]), atol=1e-9)   # x ← μx(1−x)
    # μ < 4: the map's range [0, μ/4] is stretched onto the box
    d = logistic_init(np.random.default_rng(5), 50, lower, upper, mu=3.2)
    assert np.all(d >= lower) and np.all(d <= upper)
    with pytest.raises(ConfigError):
        logistic_init(np.random.default_rng(5), 5, lower, upper, mu=4.5)


def test_convergence_factor_endpoints():
    T = 300
    assert nonlinear_convergence_factor(0, T) == pytest.approx(2.0)
    assert nonlinear_convergence_factor(T, T) == pytest.approx(0.0, abs=1e-15)
    assert nonlinear_convergence_factor(T / 2, T) == pytest.approx(2 * (1 - (math.sqrt(math.e) - 1) / (math.e - 1)))
    a = [nonlinear_convergence_factor(t, T) for t in range(T + 1)]
    assert np.all(np.diff(a) < 0)
    assert linear_convergence_factor(0, T) == 2.0 and linear_convergence_factor(T, T) == 0.0
    assert linear_convergence_factor(T / 2, T) == pytest.approx(1.0)
    # the nonlinear factor stays above the linear one: slow early, fast late
    assert all(nonlinear_convergence_factor(t, T) >= linear_convergence_factor(t, T) for t in range(T + 1))


def test_schedule_follows_the_effective_budget():
    assert schedule_length(300, 200, None) == 299
    assert schedule_length(300, 200, 20_000) == 99     # max_evals ends the run at iteration 100
    assert schedule_length(1, 10, None) == 1


def test_igwo_runs_reproducibly_and_converges_on_sphere():
    def f(X):
        return np.sum((X - 0.3) ** 2, axis=1)

    r1 = IGWO(pop=20, iters=80).minimize(f, -np.ones(4), np.ones(4), rng=np.random.default_rng(2))
    r2 = IGWO(pop=20, iters=80).minimize(f, -np.ones(4), np.ones(4), rng=np.random.default_rng(2))
    np.testing.assert_array_equal(r1.x, r2.x)
    assert r1.nfev == 20 * 80 and r1.fun < 1e-3
    g = GWO(pop=20, iters=80).minimize(f, -np.ones(4), np.ones(4), rng=np.random.default_rng(2))
    assert g.nfev == 20 * 80 and g.fun < 1e-3


def test_settings_validation():
    with pytest.raises(ConfigError):
        IGWO(mu=0.0)
    with pytest.raises(ConfigError):
        IGWO(levy_beta=2.0)
    with pytest.raises(ConfigError):
        IGWO(pop=2)
