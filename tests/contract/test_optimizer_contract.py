"""Contract suite run over every registered population optimizer.

Every name from ``hystfit.registry.optimizers`` that is a population search searching the box
from its own initialisation (``PopulationSearch`` without ``uses_start_point``; not ``lsq`` nor
``auto``) is tested. Budgets are set through the common options (``pop``, ``iters`` where the
optimizer has one, else ``max_evals``) with the stall rule off,
so each optimizer spends its whole budget; random search gets exactly the same number of
evaluations. Test functions are shifted so that the optimum is neither the box centre nor
the origin (GWO-type updates are biased towards the origin).
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

importlib.import_module("hystfit.optimizers")  # registers the built-in optimizers
from hystfit.errors import ConfigError  # noqa: E402
from hystfit.optimizers.base import STOP_RULE_NAMES, PopulationSearch, StopRules  # noqa: E402
from hystfit.registry import optimizers as registry  # noqa: E402
from hystfit.factory import make_optimizer  # noqa: E402


def _population_names() -> list[str]:
    return [name for name in registry.names()
            if issubclass(registry.get(name), PopulationSearch) and not registry.get(name).uses_start_point]


NAMES = _population_names()
SEEDS = (0, 1, 2)


def make(name: str, pop: int, iters: int, **extra):
    """The optimizer with ``pop`` × ``iters`` (or ``max_evals = pop·iters``), stall rule off."""
    cls = registry.get(name)
    kw = {"pop": pop, "iters": iters, "max_evals": pop * iters, "stall_iter": None}
    kw.update(extra)
    return cls.from_options({k: v for k, v in kw.items() if k in cls.option_names()})


# ------------------------------------------------------------------ test problems
def _shift(d: int, lower: float, upper: float) -> np.ndarray:
    return lower + (upper - lower) * np.linspace(0.62, 0.81, d)


def sphere(X):
    Z = X - _shift(X.shape[1], -5.0, 5.0)
    return np.einsum("ij,ij->i", Z, Z)


def rosenbrock(X):
    return np.sum(100.0 * (X[:, 1:] - X[:, :-1] ** 2) ** 2 + (1.0 - X[:, :-1]) ** 2, axis=1)


def rastrigin(X):
    Z = X - _shift(X.shape[1], -5.12, 5.12)
    return 10.0 * X.shape[1] + np.sum(Z * Z - 10.0 * np.cos(2.0 * np.pi * Z), axis=1)


FUNCTIONS = {"sphere": (sphere, 5.0), "rosenbrock": (rosenbrock, 2.0), "rastrigin": (rastrigin, 5.12)}
BUDGET = {2: (20, 40), 5: (30, 60), 10: (40, 80)}  # d → (pop, iters)


def random_search(f, lower, upper, n: int, rng) -> float:
    return float(np.min(f(lower + rng.random((n, lower.size)) * (upper - lower))))


class Recorder:
    """Wraps an objective and keeps a copy of every candidate and value it saw."""

    def __init__(self, f):
        self.f = f
        self.X: list[np.ndarray] = []
        self.F: list[np.ndarray] = []

    def __call__(self, X):
        assert X.ndim == 2
        self.X.append(np.array(X, copy=True))
        out = np.asarray(self.f(X), float)
        self.F.append(out.copy())
        return out

    @property
    def all_x(self) -> np.ndarray:
        return np.vstack(self.X)

    @property
    def all_f(self) -> np.ndarray:
        return np.concatenate(self.F)


@pytest.fixture(scope="module")
def hysteresis_problem():
    """Bouc–Wen with known θ on a short raised-cosine input (a major and a minor loop)."""
    from hystfit.models.bw import BoucWen
    from hystfit.objective import Objective, Series
    from hystfit.params import DataScale

    dt = 1e-3
    t = np.arange(300) * dt
    amplitude = np.where(t < 0.2, 1.0, 0.6)
    u = 50.0 * amplitude * (1.0 - np.cos(2.0 * np.pi * 10.0 * t))   # 0 … 100 V, then 0 … 60 V
    model = BoucWen()
    theta = np.array([0.12, 0.05, 0.02, 0.004, 0.3])
    y = model.simulate(theta[None, :], u, dt)[0]
    params = model.params(DataScale.from_arrays([u], [y], [dt]))
    lower = np.array([p.lower for p in params])
    upper = np.array([p.upper for p in params])
    return Objective(model, [Series(u, y, dt)]), lower, upper, theta


def test_registry_lists_the_population_optimizers():
    for name in ("pso", "pso-cf", "ipso", "ga", "gwo", "igwo", "de"):
        assert name in NAMES


# ------------------------------------------------------------------ contract
@pytest.mark.parametrize("name", NAMES)
def test_respects_bounds_and_reports_consistently(name):
    lower, upper = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 0.5, 7.0])

    def corner(X):  # optimum at a corner: pushes candidates out of the box
        return np.sum(X * np.array([1.0, -1.0, 1.0]), axis=1)

    rec = Recorder(corner)
    res = make(name, 12, 15).minimize(rec, lower, upper, rng=np.random.default_rng(4))
    X = rec.all_x
    assert np.all(X >= lower) and np.all(X <= upper)
    assert res.nfev == X.shape[0]
    assert len(res.history_best) == len(res.history_mean) == res.nit
    assert np.all(np.diff(res.history_best) <= 0)
    assert res.fun == pytest.approx(float(np.min(rec.all_f)))
    assert np.all(res.x >= lower) and np.all(res.x <= upper)
    assert res.fun == pytest.approx(float(corner(res.x[None, :])[0]))
    assert res.optimizer == name and res.success


@pytest.mark.parametrize("name", NAMES)
def test_x0_replaces_an_initial_candidate(name):
    lower, upper = -np.ones(4), np.ones(4)
    x0 = np.array([0.25, -0.5, 0.125, 0.75])
    rec = Recorder(sphere)
    make(name, 10, 3).minimize(rec, lower, upper, rng=np.random.default_rng(0), x0=x0)
    assert np.any(np.all(rec.X[0] == x0, axis=1))


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_run_different_seed_different_run(name):
    lower, upper = -5.0 * np.ones(3), 5.0 * np.ones(3)
    opt = make(name, 16, 20)
    a = opt.minimize(rastrigin, lower, upper, rng=np.random.default_rng(7))
    b = opt.minimize(rastrigin, lower, upper, rng=np.random.default_rng(7))
    c = opt.minimize(rastrigin, lower, upper, rng=np.random.default_rng(8))
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history_best, b.history_best)
    np.testing.assert_array_equal(a.history_mean, b.history_mean)
    assert (a.nfev, a.nit, a.fun) == (b.nfev, b.nit, b.fun)
    assert not np.array_equal(a.x, c.x)
    assert not np.array_equal(a.history_mean, c.history_mean)


@pytest.mark.parametrize("name", NAMES)
def test_target_and_callback_stop(name):
    lower, upper = -5.0 * np.ones(2), 5.0 * np.ones(2)
    res = make(name, 20, 500, target=1e-2).minimize(sphere, lower, upper, rng=np.random.default_rng(1))
    assert res.status == 2 and res.fun <= 1e-2

    seen = []

    def stop_at_3(it, best, mean):
        seen.append((it, best, mean))
        return it >= 3

    res = make(name, 20, 500).minimize(sphere, lower, upper, rng=np.random.default_rng(1), callback=stop_at_3)
    assert res.status == 4 and res.nit == 3
    assert [s[0] for s in seen] == [1, 2, 3]
    assert seen[-1][1] == res.fun


@pytest.mark.parametrize("name", NAMES)
def test_nonfinite_values_are_infinite_not_fatal(name):
    def half_nan(X):
        out = sphere(X)
        out[X[:, 0] < 0.0] = np.nan
        return out

    res = make(name, 12, 10).minimize(half_nan, -5.0 * np.ones(2), 5.0 * np.ones(2), rng=np.random.default_rng(2))
    assert np.isfinite(res.fun) and res.x[0] >= 0.0


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("fname", sorted(FUNCTIONS))
@pytest.mark.parametrize("d", sorted(BUDGET))
def test_beats_random_search_at_equal_budget(name, fname, d):
    f, half_width = FUNCTIONS[fname]
    lower, upper = -half_width * np.ones(d), half_width * np.ones(d)
    pop, iters = BUDGET[d]
    opt, rnd = [], []
    for seed in SEEDS:
        res = make(name, pop, iters).minimize(f, lower, upper, rng=np.random.default_rng(seed))
        opt.append(res.fun)
        rnd.append(random_search(f, lower, upper, res.nfev, np.random.default_rng(1000 + seed)))
    assert np.median(opt) < np.median(rnd), (opt, rnd)


@pytest.mark.parametrize("name", NAMES)
def test_identifies_bouc_wen_better_than_random_search(name, hysteresis_problem):
    objective, lower, upper, theta = hysteresis_problem
    opt, rnd = [], []
    for seed in SEEDS:
        res = make(name, 30, 60).minimize(objective, lower, upper, rng=np.random.default_rng(seed))
        opt.append(res.fun)
        rnd.append(random_search(objective, lower, upper, res.nfev, np.random.default_rng(1000 + seed)))
    assert np.median(opt) < 0.5 * np.median(rnd), (opt, rnd)


# ------------------------------------------------------------------ documentation
#: docstrings with a known gap, in files another change owns this sprint (strict: remove the
#: entry once the docstring is complete, or this test fails)
DOC_GAPS: dict[str, str] = {}


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(reason=DOC_GAPS[n], strict=True)) if n in DOC_GAPS else n
    for n in registry.names()])
def test_docstring_documents_every_setting_stop_rule_and_bounds_handling(name):
    """Issue 4: each optimizer documents its parameters and defaults, its stop rules and its
    bounds handling; ``hystfit optimizers`` shows the 'Stop rules:' and 'Bounds:' paragraphs."""
    cls = registry.get(name)
    doc = cls.__doc__ or ""
    missing = [k for k in cls.option_names() if k not in doc]
    assert not missing, f"{name}: settings not described in the docstring: {missing}"
    assert "Stop rules:" in doc and "Bounds:" in doc


# ------------------------------------------------------------------ stop rules and budgets (issues 12, 13)
BAD_RULES = [("max_evals", -5), ("max_evals", 0), ("max_evals", 2.5), ("max_evals", "many"), ("max_evals", True),
             ("stall_iter", 0), ("stall_tol", -1e-3), ("stall_tol", None), ("target", float("nan")),
             ("time_limit_s", 0), ("time_limit_s", -1.0)]


@pytest.mark.parametrize("name", registry.names())
def test_holds_one_validated_stop_rule_value(name):
    cls = registry.get(name)
    opt = cls()
    assert isinstance(opt.stop, StopRules)
    assert set(cls.applied_stop_rules) <= set(STOP_RULE_NAMES) and "max_evals" in cls.applied_stop_rules
    # the flat settings (as params.json records them) rebuild the same optimizer
    assert cls.from_options(opt.settings()) == opt
    assert list(opt.settings())[-len(cls.applied_stop_rules):] == list(cls.applied_stop_rules)


@pytest.mark.parametrize("name", registry.names())
@pytest.mark.parametrize("key,value", BAD_RULES)
def test_invalid_stop_rule_is_a_one_line_config_error(name, key, value):
    cls = registry.get(name)
    if key not in cls.applied_stop_rules:
        with pytest.raises(ConfigError, match="does not apply"):
            cls.from_options({key: value})
        return
    with pytest.raises(ConfigError) as info:
        cls.from_options({key: value})
    msg = str(info.value)
    assert "\n" not in msg and key in msg and "--opt-option" in msg


@pytest.mark.parametrize("name", NAMES)
def test_pop_and_iters_give_every_population_search_the_same_budget(name):
    """``--pop 10 --iters 7`` bounds every population search by 70 evaluations (GA, which does
    not re-evaluate its elite, uses fewer; DE rounds its population up to a multiple of d)."""
    cls = registry.get(name)
    opt = make_optimizer(cls, {"stall_iter": None}, pop=10, iters=7)
    res = opt.minimize(sphere, -np.ones(2), np.ones(2), rng=np.random.default_rng(0))
    assert res.nfev <= 70 and res.status == 0
    assert res.nfev >= 70 - 6 * opt.elite if name == "ga" else res.nfev == 70


@pytest.mark.parametrize("name", registry.names())
def test_libraries_imported_on_first_use_are_declared_and_load(name):
    """An optimizer whose code imports scipy.optimize on first use (or that solves through variable
    projection, which does) declares it in ``libraries``, so that a run's clock (runtime_s) starts
    after the one-time import; load_libraries imports what is declared."""
    import inspect
    import sys

    cls = registry.get(name)
    source = inspect.getsource(importlib.import_module(cls.__module__))
    if "from scipy.optimize import" in source or cls.uses_separable_structure:
        assert "scipy.optimize" in cls.libraries, name
    cls().load_libraries()
    assert all(m in sys.modules for m in cls.libraries)
