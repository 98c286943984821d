"""One contract, run over every registered model (scikit-learn style).

Shapes, determinism, population consistency, bounds, finite output for random parameters inside
the bounds, structure round trip through JSON, per-sample stepping agreeing with simulate, and the
inverse round trip simulate(invert(y_d)) ≈ y_d on a reachable target.
"""

import json

import numpy as np
import pytest

from hystfit.params import DataScale
from hystfit.registry import models

FS = 10_000.0
DT = 1 / FS
NAMES = models.names()


def reference_input(n_cycles=2, f=10.0, amplitude=40.0):
    t = np.arange(int(n_cycles * FS / f) + 1) / FS
    return 0.5 * amplitude * (1 - np.cos(2 * np.pi * f * t))


def prepared(name):
    u = reference_input()
    y_like = 0.3 * u + 0.02 * np.sin(2 * np.pi * 10 * np.arange(u.size) / FS)
    scale = DataScale.from_arrays([u], [y_like], [DT])
    cls = models.get(name)
    if hasattr(cls, "example"):  # models whose structure is identified from data (e.g. hammerstein)
        model = cls.example(scale)
    else:
        model = cls().adapt(scale)
    return model, model.params(scale), u, scale


@pytest.mark.parametrize("name", NAMES)
def test_metadata_and_bounds(name):
    cls = models.get(name)
    assert cls.name == name and cls.title and cls.reference and cls.equation
    assert cls.__doc__ and len(cls.__doc__) > 200, "docstring must state the equation, units and paper"
    _, params, _, _ = prepared(name)
    names = [p.name for p in params]
    assert len(set(names)) == len(names)
    for p in params:
        assert p.lower < p.upper and p.lower <= p.default <= p.upper and p.unit


@pytest.mark.parametrize("name", NAMES)
def test_shapes_determinism_and_population_consistency(name):
    model, params, u, _ = prepared(name)
    rng = np.random.default_rng(0)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((6, len(params))) * (hi - lo)
    theta[0] = [p.default for p in params]
    y = model.simulate(theta, u, DT)
    assert y.shape == (6, u.size)
    np.testing.assert_array_equal(y, model.simulate(theta, u, DT))
    for i in (0, 3):
        np.testing.assert_allclose(model.simulate(theta[i:i + 1], u, DT)[0], y[i], rtol=1e-12, atol=1e-12,
                                   equal_nan=True)
    np.testing.assert_allclose(model.simulator(u, DT)(theta), y, rtol=1e-12, atol=1e-12, equal_nan=True)


@pytest.mark.parametrize("name", NAMES)
def test_random_parameters_inside_bounds_give_finite_output(name):
    model, params, u, _ = prepared(name)
    rng = np.random.default_rng(1)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((32, len(params))) * (hi - lo)
    with np.errstate(all="ignore"):
        y = model.simulate(theta, u, DT)
    assert np.isfinite(y).all(axis=1).mean() >= 0.9, "most of the box must give finite output"


@pytest.mark.parametrize("name", NAMES)
def test_structure_round_trips_through_json(name):
    model, _, _, _ = prepared(name)
    again = type(model).from_structure(json.loads(json.dumps(model.structure())))
    assert again == model


@pytest.mark.parametrize("name", NAMES)
def test_step_agrees_with_simulate(name):
    model, params, u, _ = prepared(name)
    theta = np.array([p.default for p in params])
    try:
        state = model.initial_state(theta, float(u[0]), DT)
    except Exception:
        pytest.skip(f"{name} has a model-specific inverse and no per-sample stepping")
    y = model.simulate_one(theta, u, DT)
    out = []
    prev = float(u[0])
    for k in range(1, 200):
        yk, st = model.step(theta, state, prev, np.array([u[k]]), DT)
        out.append(yk[0])
        state, prev = st[0], float(u[k])
    np.testing.assert_allclose(out, y[1:200], rtol=1e-7, atol=1e-9 * np.ptp(y))


@pytest.mark.parametrize("name", NAMES)
def test_inverse_round_trip(name):
    """simulate(invert(y_d)) ≈ y_d for a reachable target (the model's own output): within 0.5 % of the stroke."""
    model, params, u, scale = prepared(name)
    theta = np.array([p.default for p in params])
    y_d = model.simulate_one(theta, u, DT)
    u_inv = model.invert(theta, y_d, DT)
    assert u_inv.shape == y_d.shape and np.all(np.isfinite(u_inv))
    y_back = model.simulate_one(theta, u_inv, DT)
    err = np.abs(y_back - y_d)
    assert np.sqrt(np.mean(err ** 2)) <= 5e-3 * np.ptp(y_d), f"{name}: round-trip RMSE {np.sqrt(np.mean(err**2)):.3g}"


@pytest.mark.parametrize("name", NAMES)
def test_declared_separable_structure_is_exact(name):
    """Where a model declares parameters that enter linearly, C + B·θ_lin reproduces simulate exactly."""
    model, params, u, _ = prepared(name)
    sep = model.separable()
    if sep is None:
        pytest.skip(f"{name} declares no separable structure")
    assert sorted(sep.linear + sep.nonlinear) == list(range(len(params)))
    rng = np.random.default_rng(2)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((4, len(params))) * (hi - lo)
    theta[0] = [p.default for p in params]
    nl = np.asarray(sep.nonlinear, dtype=int)
    basis = sep.basis_factory(u, DT)(theta[:, nl] if nl.size else np.empty((4, 0)))
    B, C = basis if isinstance(basis, tuple) else (basis, 0.0)
    B = np.broadcast_to(B, (4,) + B.shape[1:])
    y_sep = C + np.einsum("pnl,pl->pn", B, theta[:, list(sep.linear)])
    with np.errstate(all="ignore"):
        y = model.simulate(theta, u, DT)
    ok = np.isfinite(y).all(axis=1)
    np.testing.assert_allclose(y_sep[ok], y[ok], rtol=1e-8, atol=1e-9 * np.nanmax(np.abs(y[ok])))
