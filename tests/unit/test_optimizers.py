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
    r = PSO.from_options(dict(pop=10, iters=10_000, stall_iter=20, stall_tol=1e-3)).minimize(sphere, -np.ones(2), np.ones(2),
                                                                          rng=np.random.default_rng(0))
    assert r.status == 1 and r.nit < 10_000
    r = PSO.from_options(dict(pop=10, iters=10_000, target=1e-2)).minimize(sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(0))
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
    capped = Auto.from_options(dict(restarts=3, max_evals=60)).minimize(Objective(model, [Series(u, y, 1 / fs)]), lo, hi,
                                                     rng=np.random.default_rng(0))
    search_evals = len(capped.history_best) - 1  # iterations of the searches (the last entry is the polish)
    assert capped.nfev < free.nfev
    assert search_evals * Auto().pop <= 60 + Auto().pop


def _dahl_problem():
    """A Dahl identification objective (three nonlinear parameters: the m > 2 search), box, truth."""
    from hystfit.models.dahl import Dahl
    from hystfit.objective import Objective, Series
    from hystfit.params import DataScale

    fs = 2000.0
    t = np.arange(1200) / fs
    u = 30.0 * (1 - np.cos(2 * np.pi * 3 * t)) * (1 - 0.3 * np.cos(2 * np.pi * 1 * t))
    model = Dahl()
    ps = model.params(DataScale.from_arrays([u], [0.3 * u], [1 / fs]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    truth = np.array([p.default for p in ps])
    y = model.simulate_one(truth, u, 1 / fs) + 0.01 * np.random.default_rng(5).standard_normal(u.size)
    return Objective(model, [Series(u, y, 1 / fs)]), lo, hi


def _spy_polishes(monkeypatch):
    """Record every polish ``auto`` runs: (start value, end value, end point)."""
    from hystfit.optimizers import auto as auto_module

    polishes = []
    real_min = LSQ.minimize

    def spy(self, objective, lower, upper, **kw):
        out = real_min(self, objective, lower, upper, **kw)
        polishes.append((float(objective(kw["x0"][None, :])[0]), float(out.fun), out.x.copy()))
        return out

    monkeypatch.setattr(LSQ, "minimize", spy)
    return auto_module, polishes


def test_auto_polishes_the_best_point_of_every_search_and_keeps_the_best_polished_fit(monkeypatch):
    """With restarts > 1 each search's best point is polished (and nothing after): the result is the
    best polished fit (which one is chosen when they differ: the stand-in test below)."""
    from hystfit.optimizers.auto import Auto

    obj, lo, hi = _dahl_problem()
    searches = []
    real_pso = PSO.minimize

    def pso_spy(self, objective, lower, upper, **kw):
        out = real_pso(self, objective, lower, upper, **kw)
        searches.append(out)
        return out

    monkeypatch.setattr(PSO, "minimize", pso_spy)
    _, polishes = _spy_polishes(monkeypatch)
    res = Auto(restarts=3).minimize(obj, lo, hi, rng=np.random.default_rng(0))
    assert len(searches) == 3 and len(polishes) == 3  # one polish per search, none after
    best = min(range(3), key=lambda i: polishes[i][1])
    np.testing.assert_array_equal(res.x, polishes[best][2])
    assert res.fun == pytest.approx(min(p[1] for p in polishes), rel=1e-12)
    assert all(p[1] <= p[0] for p in polishes)
    # the polishes start from the searches' best points (ρ-like linear parameters solved exactly)
    starts = sorted(p[0] for p in polishes)
    assert starts == pytest.approx(sorted(s.fun for s in searches), rel=1e-9)
    again = Auto(restarts=3).minimize(obj, lo, hi, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(res.x, again.x)  # deterministic


def test_auto_keeps_the_polish_with_the_lowest_cost_not_the_best_or_last_search(monkeypatch):
    """The choice among the polished fits is by the polished cost alone: here the polishes are
    stand-ins that leave each start where it is and report costs 3, 1, 2 — the second is kept,
    whatever the searches' own values and order."""
    from hystfit.optimizers import auto as auto_module
    from hystfit.optimizers.auto import Auto
    from hystfit.optimizers.base import OptimizeResult

    obj, lo, hi = _dahl_problem()
    starts = []

    class StandIn:
        def minimize(self, objective, lower, upper, *, rng, x0):
            starts.append(np.array(x0))
            return OptimizeResult(x=np.array(x0), fun=(3.0, 1.0, 2.0)[len(starts) - 1], nfev=7, nit=1, success=True,
                                  history_best=[1.0], history_mean=[1.0], status=5, message="stand-in",
                                  optimizer="lsq")

    monkeypatch.setattr(auto_module, "polisher", StandIn)
    res = Auto(restarts=3).minimize(obj, lo, hi, rng=np.random.default_rng(0))
    assert len(starts) == 3
    np.testing.assert_array_equal(res.x, starts[1])
    assert res.fun == pytest.approx(float(obj(starts[1][None, :])[0]), rel=1e-12)


def test_auto_runs_one_search_and_one_polish_by_default(monkeypatch):
    """Three nonlinear parameters: one (larger) search, one polish — a second search kept only for
    its better search value bought no measurable RMSE at 31–42 % of the fit's CPU (CHANGELOG;
    benchmarks/restarts.py measures what more searches, each polished, buy)."""
    from hystfit.optimizers.auto import Auto

    obj, lo, hi = _dahl_problem()
    searches = []
    real_pso = PSO.minimize
    monkeypatch.setattr(PSO, "minimize", lambda self, *a, **kw: searches.append(self) or real_pso(self, *a, **kw))
    _, polishes = _spy_polishes(monkeypatch)
    res = Auto().minimize(obj, lo, hi, rng=np.random.default_rng(0))
    assert len(searches) == 1 and len(polishes) == 1
    assert searches[0].pop == 16 and searches[0].iters == 30  # the defaults: the search is scaled by m only for m > 4
    assert res.fun == pytest.approx(polishes[0][1], rel=1e-12)


def test_auto_sizes_the_search_by_the_nonlinear_parameters_beyond_the_defaults(monkeypatch):
    """gpi's ten nonlinear parameters: 5m particles, 15m iterations, a 3m stall window (the
    defaults 16, 30 and 6 are smaller; a 3m × 7.5m search gave pi2 a worse inverse: auto.py)."""
    from hystfit.models.gpi import GPI
    from hystfit.objective import Objective, Series
    from hystfit.optimizers.auto import Auto
    from hystfit.params import DataScale

    fs = 2000.0
    u = 30.0 * (1 - np.cos(2 * np.pi * 5 * np.arange(400) / fs))
    model = GPI()
    ps = model.params(DataScale.from_arrays([u], [0.3 * u], [1 / fs]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    y = model.simulate_one(np.array([p.default for p in ps]), u, 1 / fs)
    searches = []
    real_pso = PSO.minimize
    monkeypatch.setattr(PSO, "minimize", lambda self, *a, **kw: searches.append(self) or real_pso(self, *a, **kw))
    Auto().minimize(Objective(model, [Series(u, y, 1 / fs)]), lo, hi, rng=np.random.default_rng(0))
    assert len(model.separable().nonlinear) == 10
    assert [(s.pop, s.iters, s.stop.stall_iter) for s in searches] == [(50, 150, 30)]


# ------------------------------------------------------------------ LSQ: the normal-equation route
BW_TRUTH = np.array([0.25, 0.12, 0.03, 0.01, 0.3])
FS_BW = 10_000.0


def _bw_problem(rng, n_captures=1):
    """A Bouc–Wen identification objective (loops of two amplitudes, σ = 0.01 µm noise), its box
    and its default start."""
    from hystfit.models.bw import BoucWen
    from hystfit.objective import Series
    from hystfit.params import DataScale

    def raised_cosine(amplitude, cycles):
        t = np.arange(int(cycles * FS_BW / 10.0) + 1) / FS_BW
        return 0.5 * amplitude * (1 - np.cos(2 * np.pi * 10.0 * t))

    model = BoucWen()
    u = np.r_[raised_cosine(60, 2), raised_cosine(30, 2)[1:]]
    series = [Series(u, model.simulate_one(BW_TRUTH, u, 1 / FS_BW) + rng.normal(0, 0.01, u.size), 1 / FS_BW)
              for _ in range(n_captures)]
    scale = DataScale.from_arrays([s.u for s in series], [s.y for s in series], [s.dt for s in series])
    ps = model.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    return model, series, lo, hi, np.array([p.default for p in ps])


def _recording_objective(model, series):
    """An identification objective that records every parameter vector it is asked about."""
    from hystfit.objective import Objective

    class Recording(Objective):
        seen: list

        def __call__(self, theta):
            self.seen.append(np.atleast_2d(theta).copy())
            return super().__call__(theta)

        def normal_equations(self, theta, rel_step=1e-6, upper=None, lower=None):
            h, pop = self._fd_population(theta, rel_step, upper, lower)
            self.seen.append(pop)
            return super().normal_equations(theta, rel_step, upper, lower)

    obj = Recording(model, series)
    obj.seen = []
    return obj


@pytest.mark.parametrize("box", ["free", "kv_upper", "beta_lower"])
def test_lsq_normal_equation_route_reaches_the_scipy_optimum(box, rng, monkeypatch):
    """Forced onto a mid-size Bouc–Wen problem (4001 residuals × 5 parameters), the memory-bounded
    Levenberg–Marquardt on the normal equations lands on scipy's optimum — also when it lies on a
    bound (Kv ≤ 0.24 < 0.25 true; β ≥ 0.04 > 0.03 true) — and never leaves the box."""
    import hystfit.optimizers.lsq as lsq_module
    from hystfit.objective import Objective

    model, series, lo, hi, x0 = _bw_problem(rng)
    if box == "kv_upper":
        hi = np.r_[0.24, hi[1:]]
    elif box == "beta_lower":
        lo = np.r_[lo[:2], 0.04, lo[3:]]
    m, d = series[0].y.size, lo.size
    assert m * d < lsq_module.NORMAL_EQUATIONS_ABOVE  # small: scipy by default
    ref = LSQ().minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    assert ref.message.startswith("scipy least_squares")

    monkeypatch.setattr(lsq_module, "NORMAL_EQUATIONS_ABOVE", 0)
    obj = _recording_objective(model, series)
    ne = LSQ().minimize(obj, lo, hi, rng=np.random.default_rng(0), x0=x0)
    assert "normal-equation" in ne.message and ne.status == 5, ne.message
    assert isinstance(ne, type(ref)) and ne.optimizer == "lsq"
    width = hi - lo
    assert np.all(np.abs(ne.x - ref.x) <= 1e-5 * np.abs(ref.x) + 1e-7 * width), (ne.x, ref.x)
    assert ne.fun == pytest.approx(ref.fun, rel=1e-9)
    assert ne.fun == pytest.approx(float(Objective(model, series)(ne.x[None, :])[0]), rel=1e-12)
    if box == "free":
        np.testing.assert_allclose(ne.x[:4], BW_TRUTH[:4], rtol=0.02)  # the truth, to the noise
    # bounds: every candidate evaluated (costs and finite-difference populations) is inside the box
    seen = np.vstack(obj.seen)
    assert np.all(seen >= lo) and np.all(seen <= hi)
    if box == "kv_upper":
        assert ne.x[0] == pytest.approx(0.24, abs=1e-12)
    if box == "beta_lower":
        assert ne.x[2] == pytest.approx(0.04, abs=1e-12)
    # evaluations counted like the scipy route: every Jacobian is d + 1, every cost 1
    assert ne.nfev == obj.nfev
    assert ne.nit == len(ne.history_best) and np.all(np.diff(ne.history_best) <= 0)


def test_lsq_normal_equation_route_stop_rules(rng, monkeypatch):
    """max_evals bounds the cost evaluations (status 0); a loose ftol stops early (status 5)."""
    import hystfit.optimizers.lsq as lsq_module
    from hystfit.objective import Objective

    model, series, lo, hi, x0 = _bw_problem(rng)
    monkeypatch.setattr(lsq_module, "NORMAL_EQUATIONS_ABOVE", 0)
    capped = LSQ.from_options(dict(max_evals=4)).minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    assert capped.status == 0 and "max_evals" in capped.message
    assert capped.nit == 4  # the start and three trial steps
    full = LSQ().minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    loose = LSQ(ftol=1e-2, xtol=1e-2, gtol=1e-2).minimize(Objective(model, series), lo, hi,
                                                           rng=np.random.default_rng(0), x0=x0)
    assert loose.status == 5 and loose.nfev < full.nfev and loose.fun >= full.fun
    assert capped.fun >= full.fun


def test_normal_equations_equal_the_dense_products(rng):
    """(JᵀJ, Jᵀr, rᵀr, M) from the chunked one-pass computation equal the products of the dense
    ``jacobian`` and ``residuals`` (two pooled captures, away from the optimum, with and without
    backward steps at the upper bounds); ``normal_matrix`` returns its first, third and fourth."""
    from hystfit.objective import Objective

    model, series, lo, hi, _ = _bw_problem(rng, n_captures=2)
    obj = Objective(model, series)
    theta = BW_TRUTH * np.array([1.1, 0.9, 1.2, 0.8, 1.5])
    for upper in (None, np.r_[theta[0], hi[1:]]):  # Kv at its upper bound: its step is taken backwards
        J = obj.jacobian(theta, upper=upper)
        r = obj.residuals(theta)
        n0 = obj.nfev
        JtJ, Jtr, rr, m = obj.normal_equations(theta, upper=upper)
        assert obj.nfev - n0 == theta.size + 1
        assert m == r.size == J.shape[0] == sum(s.y.size for s in series)
        np.testing.assert_allclose(JtJ, J.T @ J, rtol=1e-10, atol=1e-10 * np.max(np.abs(J.T @ J)))
        scale = np.linalg.norm(J, axis=0) * np.linalg.norm(r)
        assert np.all(np.abs(Jtr - J.T @ r) <= 1e-10 * scale)
        assert np.all(np.abs(J.T @ r) > 1e-6 * scale)  # a non-trivial gradient is being compared
        assert rr == pytest.approx(float(r @ r), rel=1e-10)
        JtJ2, rr2, m2 = obj.normal_matrix(theta, upper=upper)
        np.testing.assert_array_equal(JtJ2, JtJ)
        assert (rr2, m2) == (rr, m)


# ------------------------------------------------------------------ issue 12: one StopRules value
def test_stop_rules_are_one_frozen_validated_value():
    import dataclasses

    from hystfit.errors import ConfigError
    from hystfit.optimizers.base import StopRules

    rules = StopRules(max_evals=100, stall_iter=5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rules.max_evals = 3  # type: ignore[misc]
    with pytest.raises(ConfigError, match=r"stop rule max_evals .* got -5; set e\.g\. --opt-option max_evals="):
        StopRules(max_evals=-5)
    with pytest.raises(ConfigError, match="time_limit_s"):
        StopRules(time_limit_s=0.0)
    # every optimizer holds it, and the flat options build it
    opt = PSO.from_options({"max_evals": 100, "stall_iter": 5})
    assert opt.stop == rules and opt.settings()["max_evals"] == 100


def test_identify_with_a_negative_budget_exits_2_in_one_line(tmp_path):
    """Issue 12's reproduction: this used to exit 0 and record "evaluation budget -5 reached"."""
    from pathlib import Path

    from typer.testing import CliRunner

    from hystfit.cli import app

    data = Path(__file__).resolve().parents[2] / "sample_data" / "a40V_f10Hz.csv"
    for opt in ("pso", "ipso", "gwo", "igwo", "ga", "de", "auto", "lsq", "pso-cf"):
        r = CliRunner().invoke(app, ["identify", str(data), "--opt", opt, "--opt-option", "max_evals=-5",
                                     "--out", str(tmp_path / opt), "--no-plots", "--quiet"])
        assert r.exit_code == 2, (opt, r.output)
        assert "max_evals" in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
        assert not (tmp_path / opt).exists()


# ------------------------------------------------------------------ shared loop and shared docstring text
def test_fill_doc_puts_the_shared_paragraphs_in_once():
    import re

    from hystfit.optimizers.base import DOC_SECTIONS, fill_doc
    from hystfit.registry import optimizers

    doc = "Head.\n\n    Notes\n    -----\n    {iterated_stop_rules}\n\n    Tail {not a marker}.\n"
    filled = fill_doc(doc, DOC_SECTIONS, "generations")
    assert filled.startswith("Head.\n\n    Notes\n    -----\n    Stop rules: ``iters`` generations,")
    assert "\n    ``stall_tol`` for ``stall_iter`` generations, ``target`` reached" in filled
    assert filled.endswith("\n\n    Tail {not a marker}.\n")
    assert fill_doc("  {a}\n", {"a": "one\n\ntwo"}) == "  one\n\n  two\n"
    with pytest.raises(KeyError):
        fill_doc("    {no_such_section}\n")
    # every registered optimizer's docstring is filled in (a mixin's sections too): no marker is left
    for name in optimizers.names():
        assert not re.search(r"^ *\{\w+\}$", optimizers.get(name).__doc__, re.M), name


def test_settings_declare_the_values_they_accept():
    from dataclasses import dataclass

    from hystfit.optimizers.base import Accepts, check_fields, setting
    from hystfit.optimizers.ga import GA
    from hystfit.optimizers.igwo import IGWO

    rule = Accepts(above=0, below=2)
    assert 1.5 in rule and 2 not in rule and 0 not in rule and float("nan") not in rule and None not in rule
    assert True not in Accepts() and "1" not in Accepts() and np.float32(3) in Accepts(at_least=3)
    assert 2.0 not in Accepts(whole=True) and np.int64(2) in Accepts(whole=True, at_most=2)
    assert rule.describe() == "a finite number in (0, 2)"
    assert Accepts(whole=True, at_least=1, nullable=True).describe() == "a whole number ≥ 1 or null"
    assert Accepts(at_least=0, at_most=1).describe() == "a finite number in [0, 1]"

    @dataclass
    class Toy:
        step: float = setting(0.5, above=0, what="step size")
        cap: int | None = setting(None, whole=True, at_least=1, nullable=True, example=9, null_means="have none")

    check_fields(Toy())
    with pytest.raises(ConfigError, match=r"^toy: step \(step size\) must be a finite number > 0, got -1; "
                                          r"set e\.g\. --opt-option step=0\.5$"):
        check_fields(Toy(step=-1), "toy: ")
    with pytest.raises(ConfigError, match=r"cap=9, or cap=null to have none$"):
        check_fields(Toy(cap=0))
    # the optimizers check their declared settings when built
    with pytest.raises(ConfigError, match="levy_beta must be a finite number in \\(0, 2\\)"):
        IGWO(levy_beta=2.0)
    with pytest.raises(ConfigError, match="tournament must be a whole number ≥ 1"):
        GA(tournament=0)


def test_required_stop_rules_cannot_be_switched_off():
    from hystfit.optimizers.auto import Auto

    assert LSQ.required_stop_rules and Auto.required_stop_rules
    with pytest.raises(ConfigError, match=r"^lsq: max_evals \(a local solve needs a budget\) must be a whole "
                                          r"number ≥ 1, got None; set e\.g\. --opt-option max_evals=2000$"):
        LSQ.from_options({"max_evals": None})
    with pytest.raises(ConfigError, match="auto: stall_iter"):
        Auto.from_options({"stall_iter": None})
    assert LSQ.from_options({"max_evals": 10}).stop.max_evals == 10


def test_swarm_loop_is_shared_and_a_velocity_rule_is_all_a_swarm_adds():
    from dataclasses import dataclass

    from hystfit.optimizers.base import IteratedSearch
    from hystfit.optimizers.ipso import IPSO
    from hystfit.optimizers.pso import Swarm
    from hystfit.optimizers.pso_cf import ConstrictionPSO

    assert all(issubclass(c, Swarm) for c in (PSO, ConstrictionPSO, IPSO))

    @dataclass
    class Still(Swarm, IteratedSearch):
        """A swarm whose particles never move."""
        name = "still"
        vmax_frac: float = 0.5

        def velocity(self, nit, x, v, pbest, pbest_f, rng):
            return np.zeros_like(v)

    seen = []

    def f(X):
        seen.append(X.copy())
        return sphere(X)

    lo, hi = -np.ones(3), np.ones(3)
    r = Still(pop=6, iters=4).minimize(f, lo, hi, rng=np.random.default_rng(0))
    assert r.nit == 4 and r.nfev == 24 and r.status == 0
    assert all(np.array_equal(X, seen[0]) for X in seen)
    assert r.fun == sphere(seen[0]).min()


def test_lsq_takes_the_normal_equation_route_from_many_parameters(rng, monkeypatch):
    """From NORMAL_EQUATIONS_FROM_PARAMS parameters the polish forms JᵀJ instead of an SVD of J per
    iteration, whatever the residual count: a PI model with 40 operators (41 parameters) on a
    2001-sample capture (M·d ≈ 8·10⁴, far below the size rule) takes it and lands on scipy's optimum;
    with the rule lifted, scipy's route is taken."""
    import hystfit.optimizers.lsq as lsq_module
    from hystfit.factory import make_model
    from hystfit.objective import Objective, Series
    from hystfit.params import DataScale

    t = np.arange(2001) / 2000.0
    u = 30.0 * (1 - np.cos(2 * np.pi * 2.0 * t)) * (0.6 + 0.4 * t)
    scale = DataScale.from_arrays([u], [u], [t[1]])
    model = make_model("pi", {"n_operators": 40}).adapt(scale)
    ps = model.params(scale)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    truth = np.array([p.default for p in ps]) * (1 + 0.2 * rng.random(len(ps)))
    y = model.simulate_one(np.clip(truth, lo, hi), u, t[1]) + rng.normal(0, 0.01, u.size)
    series = [Series(u, y, t[1])]
    assert len(ps) >= lsq_module.NORMAL_EQUATIONS_FROM_PARAMS
    assert u.size * len(ps) < lsq_module.NORMAL_EQUATIONS_ABOVE
    x0 = np.array([p.default for p in ps])
    ne = LSQ().minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    assert "normal-equation" in ne.message, ne.message
    monkeypatch.setattr(lsq_module, "NORMAL_EQUATIONS_FROM_PARAMS", 10**9)
    ref = LSQ().minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    assert ref.message.startswith("scipy least_squares")
    assert ne.fun == pytest.approx(ref.fun, rel=1e-6)
    assert np.sqrt(ne.fun) < 0.0105  # the noise floor (σ = 0.01 µm)


def test_lsq_normal_equation_route_stops_when_nothing_is_left_to_gain(monkeypatch):
    """MINPACK's ftol test on the normal-equation route. A linear least-squares problem whose cost
    is known to a quantum of ≈ ftol × cost only (as a long simulation's rounded sums are): near the
    optimum a step's actual reduction is 0 or one quantum, ρ = actual / predicted is meaningless,
    and the ρ > 0.25 test never fires (without MINPACK's test λ grows until the step falls below
    xtol). The polish stops once a step's actual and predicted reductions are both below
    ftol × cost, at the optimum."""
    import hystfit.optimizers.lsq as lsq_module
    from hystfit.objective import ObjectiveFunction

    rng = np.random.default_rng(3)
    m, d = 400, 40
    A = rng.normal(size=(m, d)) * np.logspace(0, -3, d)  # ill-conditioned columns
    b = A @ rng.normal(size=d) + rng.normal(0, 0.1, m)
    QUANTUM = 1e-11  # ≈ ftol × cost: a step's gain below the tolerance shows as 0 or one quantum

    class Noisy(ObjectiveFunction):
        n_total = m

        def __call__(self, theta):
            theta = np.atleast_2d(theta)
            r = theta @ A.T - b
            f = np.einsum("ij,ij->i", r, r) / m
            return np.round(f / QUANTUM) * QUANTUM  # a cost known to QUANTUM only, as rounding does

        def normal_equations(self, theta, upper=None, lower=None):
            r = A @ theta - b
            return A.T @ A, A.T @ r, float(r @ r), m

    lo, hi = np.full(d, -1e3), np.full(d, 1e3)
    exact = np.linalg.lstsq(A, b, rcond=None)[0]
    res = lsq_module.polisher().minimize(Noisy(), lo, hi, rng=np.random.default_rng(0), x0=np.zeros(d))
    assert "normal-equation" in res.message
    assert res.fun == pytest.approx(float(np.mean((A @ exact - b) ** 2)), rel=1e-9)
    assert "actual and predicted relative reductions below ftol" in res.message, res.message
    assert res.nfev < 200


def test_lsq_first_damping_from_a_close_start_saves_iterations_not_accuracy(monkeypatch):
    """``damping0``: from a start close to the optimum (each parameter moved by 2 % of its box) of a
    40-operator PI fit (41 parameters, their scaled JᵀJ ill-conditioned as every fine PI base's),
    the normal-equation route with λ₀ = 10⁻⁶ (:data:`CLOSE_START_DAMPING`, diagnose's hand-over)
    needs fewer evaluations than with the default 10⁻³ (measured: 302 against 603), and lands on the
    same optimum."""
    import hystfit.optimizers.lsq as lsq_module
    from hystfit.factory import make_model
    from hystfit.objective import Objective, Series
    from hystfit.params import DataScale

    monkeypatch.setattr(lsq_module, "NORMAL_EQUATIONS_ABOVE", 0)
    rng = np.random.default_rng(0)
    fs = 10_000.0
    t = np.arange(4001) / fs
    u = np.r_[30 * (1 - np.cos(2 * np.pi * 10 * t)), 15 * (1 - np.cos(2 * np.pi * 10 * t[1:]))]
    model = make_model("pi", {"n_operators": 40}).adapt(DataScale.from_arrays([u], [0.3 * u], [1 / fs]))
    ps = model.params(DataScale.from_arrays([u], [0.3 * u], [1 / fs]))
    lo, hi, x0 = (np.array([getattr(p, k) for p in ps]) for k in ("lower", "upper", "default"))
    truth = np.clip(x0 * (1 + 0.3 * rng.standard_normal(x0.size)), lo, hi)
    series = [Series(u, model.simulate_one(truth, u, 1 / fs) + rng.normal(0, 0.01, u.size), 1 / fs)]
    best = LSQ().minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=x0)
    close = np.clip(best.x + 0.02 * (hi - lo) * rng.choice([-1.0, 1.0], x0.size), lo, hi)
    runs = {lam: LSQ(damping0=lam).minimize(Objective(model, series), lo, hi, rng=np.random.default_rng(0), x0=close)
            for lam in (1e-3, lsq_module.CLOSE_START_DAMPING)}
    default, damped_less = runs[1e-3], runs[lsq_module.CLOSE_START_DAMPING]
    assert "normal-equation" in default.message and default.status == damped_less.status == 5
    assert damped_less.nfev < 0.75 * default.nfev, (damped_less.nfev, default.nfev)
    assert damped_less.fun == pytest.approx(default.fun, rel=1e-9)
    assert np.max(np.abs(damped_less.x - default.x) / (hi - lo)) < 1e-5
    assert lsq_module.polisher(close_start=True).damping0 == lsq_module.CLOSE_START_DAMPING
    assert lsq_module.polisher().damping0 == 1e-3
