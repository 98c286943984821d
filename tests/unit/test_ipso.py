
import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.ipso import IPSO, rank_coefficients, social_attractors
from hystfit.factory import make_optimizer


def sphere(X):
    return np.sum((X - 0.3) ** 2, axis=1)


def test_rank_coefficients_on_a_tiny_swarm():
    # particle 1 is best, particle 2 second, particle 0 worst
    rank, w, c1, c2 = rank_coefficients(np.array([3.0, 1.0, 2.0]), 0.4, 0.9, 1.5, 2.5)
    np.testing.assert_array_equal(rank, [3, 1, 2])
    # w_i = w_min + (w_max − w_min)(s − rank_i)/(s − 1), s = 3
    np.testing.assert_allclose(w, [0.4, 0.9, 0.65])
    # λ = (w − w_min)/(w_max − w_min); c1 = c_min + (c_max − c_min)λ; c2 = c_max − (c_max − c_min)λ
    np.testing.assert_allclose(c1, [1.5, 2.5, 2.0])
    np.testing.assert_allclose(c2, [2.5, 1.5, 2.0])


def test_rank_coefficients_ties_are_broken_by_index():
    rank, w, _, _ = rank_coefficients(np.array([1.0, 1.0, np.inf, np.inf]))
    np.testing.assert_array_equal(rank, [1, 2, 3, 4])
    assert w[0] == pytest.approx(0.9) and w[3] == pytest.approx(0.4)


def test_social_attractors_are_better_ranked_and_cover_them(rng):
    rank = np.array([4, 1, 3, 2, 5])
    hits = np.zeros((5, 5), int)
    for _ in range(400):
        att = social_attractors(rank, rng)
        hits[np.arange(5), att] += 1
    best = 1
    assert hits[best, best] == 400                      # the best follows the global best (itself)
    for i in range(5):
        if i == best:
            continue
        followed = np.flatnonzero(hits[i])
        assert np.all(rank[followed] < rank[i])          # only better-ranked particles ...
        assert followed.size == rank[i] - 1              # ... and every one of them


def test_stops_on_stall_without_an_iteration_count():
    assert "iters" not in IPSO.option_names()
    r = IPSO.from_options(dict(pop=20, max_evals=None, stall_iter=15, stall_tol=1e-3)).minimize(
        sphere, -np.ones(3), np.ones(3), rng=np.random.default_rng(0))
    assert r.status == 1 and "no relative improvement" in r.message
    assert r.nfev == 20 * r.nit
    # the last stall_iter iterations improved the best by less than stall_tol (relative)
    h = r.history_best
    assert h[-1] >= h[-16] * (1 - 1e-3)


def test_evaluation_budget_stops_with_status_0():
    r = IPSO.from_options(dict(pop=10, max_evals=200, stall_iter=None)).minimize(sphere, -np.ones(2), np.ones(2),
                                                             rng=np.random.default_rng(0))
    assert r.status == 0 and r.nfev == 200 and r.nit == 20


def test_defaults_and_settings_validation():
    opt = IPSO()
    assert (opt.w_min, opt.w_max, opt.c_min, opt.c_max) == (0.4, 0.9, 1.5, 2.5)
    assert opt.stop.max_evals == 200 * 300 and opt.stop.stall_iter is not None
    with pytest.raises(ConfigError):
        IPSO.from_options(dict(max_evals=None, stall_iter=None))
    with pytest.raises(ConfigError):
        IPSO(w_min=0.9, w_max=0.4)
    # no iteration count: --iters is honoured as the evaluation budget pop·iters (issue 13)
    assert make_optimizer(IPSO, iters=100).stop.max_evals == IPSO().pop * 100
    assert make_optimizer(IPSO, pop=20, iters=100).stop.max_evals == 2000
    with pytest.raises(ConfigError, match="conflicts with max_evals"):
        make_optimizer(IPSO, {"max_evals": 500}, iters=100)
    assert make_optimizer(IPSO, pop=200).pop == 200
