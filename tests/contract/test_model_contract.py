"""One contract, run over every registered model (scikit-learn style).

Shapes, determinism, population consistency, bounds, finite output for random parameters inside
the bounds, structure round trip through JSON, per-sample stepping agreeing with simulate, and the
inverse round trip simulate(invert(y_d)) ≈ y_d on a reachable target.
"""

import json
from pathlib import Path

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
    model = cls.example(scale)  # declared on Model; hammerstein/pi2 identify their structure from data
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
def test_head_simulator_gives_the_bits_of_simulate_one(name):
    """A diagnosis re-simulates every capture's fit part and whole capture with the model's
    head_simulator: it must be simulate_one of the first n samples, bit for bit."""
    model, params, u, _ = prepared(name)
    rng = np.random.default_rng(2)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    sim = model.head_simulator(u, DT)
    for theta in ([p.default for p in params], lo + rng.random(len(params)) * (hi - lo)):
        theta = np.asarray(theta, float)
        for n in (u.size, 1234, 7, 1):
            with np.errstate(all="ignore"):
                np.testing.assert_array_equal(sim(theta, n), model.simulate_one(theta, u[:n], DT))


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


@pytest.mark.parametrize("name", NAMES)
def test_sse_evaluator_equals_simulated_sum(name):
    """A model's fused sum of squared errors (if it has one) equals Σ(simulate − y)² to rounding,
    for random candidates inside the bounds; a diverging candidate scores non-finite in both."""
    model, params, u, _ = prepared(name)
    rng = np.random.default_rng(3)
    y_meas = 0.3 * u + 0.05 * rng.standard_normal(u.size)
    fn = model.sse_evaluator(u, DT, y_meas)
    if fn is None:
        pytest.skip(f"{name} has no fused sum of squares (the objective simulates)")
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((80, len(params))) * (hi - lo)  # ≥ 64: the threaded kernel path too
    theta[0] = [p.default for p in params]
    with np.errstate(all="ignore"):
        ref = np.sum((model.simulate(theta, u, DT) - y_meas) ** 2, axis=1)
        got = fn(theta)
    ok = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(got), ok)
    np.testing.assert_allclose(got[ok], ref[ok], rtol=1e-9, atol=1e-9 * np.sum(y_meas ** 2))


@pytest.mark.parametrize("name", NAMES)
def test_fused_normal_equations_equal_the_basis(name):
    """Where a separable model computes its normal equations directly (gram_factory), they equal
    BᵀB, Bᵀ(y − C) and the target's square sum computed from the stored basis."""
    model, params, u, _ = prepared(name)
    sep = model.separable()
    if sep is None or sep.gram_factory is None:
        pytest.skip(f"{name} has no fused normal equations")
    rng = np.random.default_rng(4)
    y_meas = 0.3 * u + 0.05 * rng.standard_normal(u.size)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((70, len(params))) * (hi - lo)
    nl = np.asarray(sep.nonlinear, dtype=int)
    G, c, yy = sep.gram_factory(u, DT, y_meas)(theta[:, nl])
    basis = sep.basis_factory(u, DT)(theta[:, nl])
    B, C = basis if isinstance(basis, tuple) else (basis, np.zeros((1, u.size)))
    target = y_meas[None, :] - C
    with np.errstate(all="ignore"):
        G_ref = np.einsum("pnl,pnk->plk", B, B)
        c_ref = np.einsum("pnl,pn->pl", B, np.broadcast_to(target, B.shape[:2]))
    ok = np.isfinite(G_ref.reshape(len(theta), -1)).all(axis=1)
    np.testing.assert_allclose(G[ok], G_ref[ok], rtol=1e-9, atol=1e-12 * np.abs(G_ref[ok]).max())
    np.testing.assert_allclose(c[ok], c_ref[ok], rtol=1e-9, atol=1e-12 * np.abs(c_ref[ok]).max())
    tt = np.sum(np.broadcast_to(target, B.shape[:2]) ** 2, axis=1)
    np.testing.assert_allclose(np.broadcast_to(yy, tt.shape)[ok], tt[ok], rtol=1e-12)


def _unit_exponents(unit: str) -> dict[str, int]:
    """Exponents of a parameter unit written as products and one quotient: "out*s/V" → {out: 1, s: 1, V: −1}."""
    num, _, den = unit.partition("/")
    exps: dict[str, int] = {}
    for part, sign in ((num, 1), (den, -1)):
        for tok in filter(None, (t.strip() for t in part.split("*"))):
            if tok != "1":
                exps[tok] = exps.get(tok, 0) + sign
    return exps


@pytest.mark.parametrize("name", NAMES)
def test_default_bounds_and_output_follow_the_data_units(name):
    """The same command works on µm/V stages and on nm/mV ones: with the input scaled by k_u and the
    output by k_y, every default bound scales as its unit says (out^a·V^b → k_y^a·k_u^b) and the model
    maps the scaled parameters to exactly the scaled output."""
    k_u, k_y = 1e-2, 1e3  # e.g. a stage driven at 0…0.4 V, measured in nm instead of µm
    model, params, u, scale = prepared(name)
    y_like = 0.3 * u + 0.02 * np.sin(2 * np.pi * 10 * np.arange(u.size) / FS)
    scale2 = DataScale.from_arrays([k_u * u], [k_y * y_like], [DT])
    cls = models.get(name)
    model2 = cls.example(scale2)
    params2 = model2.params(scale2)
    factors = []
    for p, q in zip(params, params2):
        e = _unit_exponents(p.unit)
        assert set(e) <= {"out", "V", "s", "Hz"}, f"{name}.{p.name}: unexpected unit {p.unit!r}"
        f = k_y ** e.get("out", 0) * k_u ** e.get("V", 0)
        factors.append(f)
        for a, b in ((p.lower, q.lower), (p.upper, q.upper), (p.default, q.default)):
            assert b == pytest.approx(f * a, rel=1e-9, abs=1e-12 * f), f"{name}.{p.name} [{p.unit}]"
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + np.random.default_rng(3).random((4, len(params))) * (hi - lo)
    theta[0] = [p.default for p in params]
    with np.errstate(all="ignore"):
        y1 = model.simulate(theta, u, DT)
        y2 = model2.simulate(theta * np.array(factors), k_u * u, DT)
    ok = np.isfinite(y1).all(axis=1)
    assert ok[0]
    np.testing.assert_allclose(y2[ok], k_y * y1[ok], rtol=1e-9, atol=1e-9 * k_y * np.abs(y1[ok]).max())


@pytest.mark.parametrize("name", NAMES)
def test_diverging_parameters_score_infinite_not_crash(name):
    """Issue 3: a parameter vector that makes the model diverge or produce NaN gets an infinite
    objective, never an exception (nor a RuntimeWarning: hystfit's warnings are errors here)."""
    from hystfit.objective import Objective, Series

    model, params, u, _ = prepared(name)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    width = hi - lo
    y = model.simulate_one(np.array([p.default for p in params]), u, DT)
    extreme = np.vstack([lo - 1e6 * width, hi + 1e6 * width, np.where(np.arange(lo.size) % 2, lo, hi) * 1e12,
                         np.full(lo.size, np.nan), np.full(lo.size, np.inf),
                         [p.default for p in params]])
    f = Objective(model, [Series(u, y, DT)])(extreme)
    assert f.shape == (extreme.shape[0],)
    assert not np.any(np.isnan(f)) and np.all(f >= 0)
    assert f[-1] == pytest.approx(0.0, abs=1e-20)  # the defaults reproduce their own output


@pytest.mark.parametrize("name", models.names())
def test_every_model_has_the_one_invert_signature(name):
    """invert(theta, y_target, dt, u_range=None) for every model: orchestration never inspects signatures."""
    import inspect

    params = list(inspect.signature(models.get(name).invert).parameters)
    assert params[:5] == ["self", "theta", "y_target", "dt", "u_range"]


@pytest.mark.parametrize("name", models.names())
def test_refined_doubles_the_declared_resolution(name):
    cls = models.get(name)
    model = cls()
    fine = model.refined()
    if cls.resolution_option is None:
        assert fine is None
        return
    assert type(fine) is cls
    assert getattr(fine, cls.resolution_option) == 2 * getattr(model, cls.resolution_option)
    assert fine.refined() is not None  # 20 → 40 is still below the cap



def _read_only(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def exercise_kernels(name: str) -> None:
    """Model ``name``'s kernels with writable data (the virtual actuator's) and read-only data (a
    capture read from CSV): simulation (serial and threaded), the fused sum of squares and the
    separable basis and normal equations."""
    model, params, u, _ = prepared(name)
    rng = np.random.default_rng(5)
    y_meas = 0.3 * u + 0.05 * rng.standard_normal(u.size)
    lo, hi = np.array([p.lower for p in params]), np.array([p.upper for p in params])
    theta = lo + rng.random((80, len(params))) * (hi - lo)  # ≥ 64: the threaded kernels too
    sep = model.separable()
    nl = np.asarray(sep.nonlinear, dtype=int) if sep is not None else None
    with np.errstate(all="ignore"):
        for uu, yy in ((u, y_meas), (_read_only(u), _read_only(y_meas))):
            for th in (theta[:3], theta):
                model.simulate(th, uu, DT)
                fn = model.sse_evaluator(uu, DT, yy)
                if fn is not None:
                    fn(th)
                if sep is not None:
                    sep.basis_factory(uu, DT)(th[:, nl])
                    if sep.gram_factory is not None:
                        sep.gram_factory(uu, DT, yy)(th[:, nl])


def test_kernels_are_compiled_once_for_read_only_and_writable_data(kernel_twins):
    """A capture read from CSV holds read-only arrays, one from the virtual actuator writable ones:
    every model's kernels take both without a second compilation (the Bouc–Wen kernel took ≈ 45 s
    a time in the first run after installing). In a fresh process, so that no other test's direct
    kernel calls count."""
    code = (f"import sys\nsys.path.insert(0, {str(Path(__file__).parent)!r})\n"
            "from test_model_contract import NAMES, exercise_kernels\n"
            "for name in NAMES:\n    exercise_kernels(name)\n")
    assert kernel_twins(code) == []
