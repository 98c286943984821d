import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.optimizers.ga import GA, make_children, polynomial_mutation, random_count, sbx_children


def test_sbx_children_straddle_the_parents_inside_the_box(rng):
    lo_all, hi_all = [], []
    for u in rng.random(2000):
        lo_c, hi_c = sbx_children(0.2, 0.6, 0.0, 1.0, 15.0, u)
        assert 0.0 <= lo_c <= 0.4 <= hi_c <= 1.0
        lo_all.append(lo_c)
        hi_all.append(hi_c)
    # η = 15 keeps most children near the parents
    assert np.median(np.abs(np.array(lo_all) - 0.2)) < 0.05
    assert np.median(np.abs(np.array(hi_all) - 0.6)) < 0.05
    # a parent on the face: the child beyond it is squeezed into the box by the bounded spread
    assert all(0.0 <= sbx_children(0.0, 0.5, 0.0, 1.0, 15.0, u)[0] for u in rng.random(200))


def test_polynomial_mutation_stays_in_the_box_and_is_local(rng):
    out = np.array([polynomial_mutation(0.9, 0.0, 1.0, 20.0, r) for r in rng.random(2000)])
    assert np.all((out >= 0.0) & (out <= 1.0))
    assert np.median(np.abs(out - 0.9)) < 0.05
    assert polynomial_mutation(0.3, 0.0, 1.0, 20.0, 0.5) == pytest.approx(0.3)   # r = ½: no move


def test_make_children_selection_and_mutation_rate(rng):
    P, d, n_child = 40, 6, 38
    lower, upper = np.zeros(d), np.ones(d)
    x = rng.random((P, d))
    f = np.arange(P, dtype=float)             # member 0 best
    out = np.empty((n_child, d))
    # no crossover, no mutation: children are tournament winners, which favour good members
    make_children(x, f, lower, upper, n_child, 3, 15.0, 0.0, 20.0, 0.0, rng.random(random_count(P, 2, d, 3)), out)
    rows = [int(np.flatnonzero(np.all(x == c, axis=1))[0]) for c in out]
    assert np.mean(rows) < P / 2 - 5
    # mutation only (p = 1/d) on identical members: about one gene per child changes
    same = np.full((P, d), 0.5)
    make_children(same, f, lower, upper, n_child, 3, 15.0, 0.9, 20.0, 1.0 / d, rng.random(random_count(P, 2, d, 3)),
                  out)
    n_mutated = int(np.sum(out != 0.5))
    assert 15 <= n_mutated <= 65          # expected n_child · d · (1/d) = 38
    assert np.all(out >= 0.0) and np.all(out <= 1.0)


def test_nfev_counts_children_only():
    r = GA(pop=20, iters=10, elite=2).minimize(lambda X: np.sum(X ** 2, axis=1), -np.ones(3), np.ones(3),
                                               rng=np.random.default_rng(0))
    assert r.nfev == 20 + 9 * 18 and r.nit == 10


def test_settings_validation():
    with pytest.raises(ConfigError):
        GA(elite=0)
    with pytest.raises(ConfigError):
        GA(pop=3, elite=2)
    with pytest.raises(ConfigError):
        GA(p_crossover=1.5)
