import math

import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.gwo import GWO, linear_convergence_factor, schedule_length
from hystfit.optimizers.igwo import IGWO, chaos_init, levy_steps, mantegna_sigma, nonlinear_convergence_factor


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


def _upper_face_fraction(F: float) -> float:
    """P(F r1 (1 − r2) ≥ 1) for independent uniforms: 1 − 1/F − ln(F)/F."""
    return 1.0 - 1.0 / F - math.log(F) / F


@pytest.mark.parametrize("F", [2.0, 3.0, 4.0])
def test_chaos_init_follows_paper_004_eq_10(F):
    """P = F r1 (1 − r2) on independent uniforms, X = lower + P (upper − lower), clipped."""
    lower, upper = np.array([-1.0, 0.0, 10.0]), np.array([1.0, 1e-3, 20.0])
    x = chaos_init(np.random.default_rng(5), 40_000, lower, upper, chaos_factor=F)
    assert x.shape == (40_000, 3) and np.all(x >= lower) and np.all(x <= upper)
    p = (x - lower) / (upper - lower)
    at_upper = np.mean(p == 1.0, axis=0)
    np.testing.assert_allclose(at_upper, _upper_face_fraction(F), atol=0.01)
    assert np.all(np.mean(p == 0.0, axis=0) == 0.0)
    # CDF of P below 1: P(F·XY ≤ p) = q − q ln q, q = p/F (product of two uniforms)
    for level in (0.1, 0.5, 0.9):
        q = level / F
        np.testing.assert_allclose(np.mean(p <= level, axis=0), q - q * math.log(q), atol=0.01)


def test_chaos_init_is_deterministic_by_seed_and_not_the_fixed_point_of_the_map():
    lower, upper = np.full(4, 0.1), np.full(4, 10.0)
    a = chaos_init(np.random.default_rng(5), 60, lower, upper)
    b = chaos_init(np.random.default_rng(5), 60, lower, upper)
    c = chaos_init(np.random.default_rng(6), 60, lower, upper)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # iterating the logistic map with F = 2 along the pack (the old code) put 93 % on the upper face
    assert np.mean(a == upper) < 0.3
    with pytest.raises(ConfigError):
        chaos_init(np.random.default_rng(5), 5, lower, upper, chaos_factor=0.0)


def test_igwo_starts_from_the_chaos_pack():
    lower, upper = np.full(3, 0.1), np.full(3, 10.0)
    seen = []

    def f(X):
        seen.append(X.copy())
        return np.sum(X ** 2, axis=1)

    IGWO(pop=30, iters=2, chaos_factor=3.0).minimize(f, lower, upper, rng=np.random.default_rng(9))
    np.testing.assert_array_equal(seen[0], chaos_init(np.random.default_rng(9), 30, lower, upper, 3.0))


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
    with pytest.raises(ConfigError, match="chaos_factor"):
        IGWO(chaos_factor=0.0)
    with pytest.raises(ConfigError, match="unknown option 'mu'"):
        IGWO.from_options({"mu": 4.0})  # the old logistic-map parameter is gone (eq. 10 has F)
    with pytest.raises(ConfigError, match="levy_scale"):
        IGWO(levy_scale=-0.1)
    assert IGWO.from_options({"levy_scale": 0.002, "chaos_factor": 4}).levy_scale == 0.002
    with pytest.raises(ConfigError):
        IGWO(levy_beta=2.0)
    with pytest.raises(ConfigError):
        IGWO(pop=2)
