"""gpi's search subsample (search_indices, GPI.search_samples) and optimizer auto's use of it on long
captures: exact outputs at the kept samples, the search on the subsample, the polish on every sample."""

import numpy as np
import pytest

from hystfit.errors import ConfigError

import hystfit.models.gpi as gpi_module
import hystfit.optimizers.auto as auto_module
from hystfit.models.gpi import GPI, search_indices
from hystfit.models.pi import PI
from hystfit.objective import Objective, Series
from hystfit.optimizers.auto import Auto, _search_series
from hystfit.optimizers.lsq import LSQ
from hystfit.params import DataScale

TRUE = np.array([30.0, 0.05, -1.4, 30.0, 28.0, 0.055, -1.6, 31.0, 0.2, 0.1, 2.5, 1.0])


def _input(N=3000, rng=None):
    t = np.arange(N) / N
    u = 30 * (1 - np.cos(2 * np.pi * 7 * t)) * (0.6 + 0.4 * np.cos(2 * np.pi * t))  # loops of several amplitudes
    if rng is not None:  # minor loops: many turning points
        u = u + rng.normal(scale=0.5, size=N)
    return u


def _thetas(model, u, rng, P=40):
    ps = model.params(DataScale.from_arrays([u], [0.3 * u], [1e-4]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    th = lo + rng.random((P, 12)) * (hi - lo)
    th[0] = TRUE
    return th


@pytest.mark.parametrize("noisy", [False, True])
@pytest.mark.parametrize("step", [3, 17])
def test_outputs_at_kept_samples_are_exact(rng, noisy, step):
    u = _input(rng=rng if noisy else None)
    m = GPI(8)
    th = _thetas(m, u, rng)
    idx = search_indices(u, step)
    assert idx[0] == 0 and idx[-1] == u.size - 1 and np.all(np.diff(idx) > 0)
    assert np.all(np.diff(idx) < 2 * step)
    np.testing.assert_array_equal(m.simulate(th, u[idx], 1e-4), m.simulate(th, u, 1e-4)[:, idx])


def test_turning_points_are_what_makes_it_exact(rng):
    """Every k-th sample alone misses the extremes and changes the operator states."""
    u = _input()
    m = GPI(8)
    th = _thetas(m, u, rng)
    idx = np.arange(0, u.size, 17)
    assert not np.array_equal(m.simulate(th, u[idx], 1e-4), m.simulate(th, u, 1e-4)[:, idx])
    kept = search_indices(u, 17)
    turns = np.flatnonzero(np.diff(np.sign(np.diff(u))) != 0) + 1
    assert set(turns) <= set(kept)


def test_search_samples_only_on_long_captures(monkeypatch):
    m = GPI()
    assert m.search_samples(np.zeros(gpi_module.SEARCH_MAX_SAMPLES)) is None
    u = _input(5 * gpi_module.SEARCH_MAX_SAMPLES + 1)
    idx = m.search_samples(u)
    assert idx is not None and idx.size < 0.25 * u.size
    assert np.array_equal(idx, search_indices(u, 6))  # k = ⌈N / SEARCH_MAX_SAMPLES⌉
    assert GPI(search_max_samples=0).search_samples(u) is None  # 0: the search sees every sample
    with pytest.raises(ConfigError, match="search_max_samples"):
        GPI(search_max_samples=-1)


def test_search_series_keeps_other_models_and_maps_the_warm_up(monkeypatch):
    u = _input()
    s = Series(u, 0.3 * u, 1e-4, 100)
    assert _search_series(PI(), [s])[0] is s  # no search_samples: every sample
    (sub,) = _search_series(GPI(search_max_samples=500), [s])
    idx = GPI(search_max_samples=500).search_samples(u)
    np.testing.assert_array_equal(sub.u, u[idx])
    np.testing.assert_array_equal(sub.y, 0.3 * u[idx])
    assert sub.skip == np.count_nonzero(idx < 100)  # the warm-up covers the same samples


@pytest.mark.parametrize("restarts", [1, 2])
def test_auto_searches_the_subsample_and_polishes_on_all_samples(monkeypatch, rng, restarts):
    u = _input(3000)
    m = GPI(6, search_max_samples=600)
    y = m.simulate(TRUE[None, :], u, 1e-4)[0] + rng.normal(scale=0.01, size=u.size)
    obj = Objective(m, [Series(u, y, 1e-4)])
    ps = m.params(DataScale.from_arrays([u], [y], [1e-4]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    x0 = np.array([p.default for p in ps])
    seen = []
    real = auto_module.ProjectedObjective

    def spy(sep, series, lower, upper):
        seen.append([s.u.size for s in series])
        return real(sep, series, lower, upper)

    monkeypatch.setattr(auto_module, "ProjectedObjective", spy)
    polishes = []
    real_min = LSQ.minimize

    def polish_spy(self, objective, lower, upper, **kw):
        out = real_min(self, objective, lower, upper, **kw)
        polishes.append((objective.n_total, self.stop.max_evals, float(objective(kw["x0"][None, :])[0]),
                         float(obj(out.x[None, :])[0]), float(out.fun)))
        return out

    monkeypatch.setattr(LSQ, "minimize", polish_spy)
    res = Auto(pop=10, iters=8, restarts=restarts).minimize(obj, lo, hi, rng=np.random.default_rng(3), x0=x0)
    n_sub = m.search_samples(u).size
    assert seen == [[n_sub]] and n_sub < u.size
    # a polish on the subsample per search, then a short one on every sample from the best of them
    assert [p[:2] for p in polishes] == [(n_sub, 300)] * restarts + [(u.size, auto_module.POLISH_EVALS_AFTER_SUBSAMPLE)]
    best = min(polishes[:-1], key=lambda p: p[4])  # the best on the subsample (what the search sees)
    assert polishes[-1][2] == best[3]  # the full polish starts where the best subsample polish ended
    assert res.fun == pytest.approx(float(obj(res.x[None, :])[0]), rel=1e-12)  # scored on every sample
    assert res.fun <= polishes[-1][2]
    again = Auto(pop=10, iters=8, restarts=restarts).minimize(obj, lo, hi, rng=np.random.default_rng(3), x0=x0)
    np.testing.assert_array_equal(res.x, again.x)  # deterministic


def test_input_period():
    from hystfit.models.gpi import input_levels, input_period

    cycle = np.r_[np.linspace(0, 10, 30), np.linspace(10, 0, 30)[1:-1]]
    assert input_period(input_levels(np.tile(cycle, 6))) == cycle.size
    assert input_period(input_levels(np.r_[np.tile(cycle, 6), 3.0])) == 0  # breaks the repetition at the end
    assert input_period(input_levels(np.linspace(0, 1, 500))) == 0  # distinct values: no table, no period
    assert input_period(input_levels(np.array([1.0]))) == 0


@pytest.mark.parametrize("n_cycles", [6, 9])
def test_periodic_input_copies_exactly_what_it_would_compute(rng, n_cycles):
    """z copied a period on once the states repeat equals z computed sample by sample, bit for bit —
    also for candidates whose states never repeat (NaN) or repeat late (large thresholds)."""
    from hystfit.models.gpi import gpi_population, input_levels, input_period

    cycle = 30 * (1 - np.cos(2 * np.pi * np.arange(100) / 100))
    u = np.tile(cycle, n_cycles)
    levels = input_levels(u)
    assert input_period(levels) == 100
    th = _thetas(GPI(8), u, rng, P=30)
    th[1, 9] = np.nan
    cols = [np.ascontiguousarray(th[:, i]) for i in range(11)]
    a1, a2, a3, a4, b1, b2, b3, b4, _, tau, alpha = cols
    computed = gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, 8, levels)
    copied = gpi_population(u, a1, a2, a3, a4, b1, b2, b3, b4, tau, alpha, 8, levels, period=100)
    np.testing.assert_array_equal(copied, computed)
    ok = np.delete(np.arange(30), 1)  # without the NaN candidate the states repeat and rows are copied
    args = [np.ascontiguousarray(c[ok]) for c in cols]
    z = gpi_population(u, *args[:8], args[9], args[10], 8, levels, period=100)
    np.testing.assert_array_equal(z, gpi_population(u, *args[:8], args[9], args[10], 8, levels))
    np.testing.assert_array_equal(GPI(8).simulator(u, 1e-4)(th), GPI(8).simulate(th, u, 1e-4))


def test_the_subsample_sees_every_phase_of_a_periodic_capture():
    """A 10 Hz cosine at 10 kHz with step 50: every 50th sample would keep 20 phases of the
    1000-sample cycle (plus the 2 turning points); the kept samples spread over the cycle."""
    t = np.arange(200_001) * 1e-4
    u = 30.0 * (1.0 - np.cos(2 * np.pi * 10.0 * t))
    idx = search_indices(u, 50)
    phases = np.unique(idx % 1000)
    assert phases.size > 500
    assert idx.size < 200_001 / 50 + 2 * 200 + 3  # one per block, the turning points, the ends
