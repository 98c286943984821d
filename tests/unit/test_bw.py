import numpy as np

from hystfit.models.bw import BoucWen
from hystfit.models._kernels import bouc_wen_population
from hystfit.params import DataScale


def euler_reference(u, a, b, g, sub=400):
    """Fine explicit Euler along a linearly interpolated input (the ODE of paper 004 eq. 2)."""
    h = 0.0
    out = [0.0]
    for k in range(1, len(u)):
        du = (u[k] - u[k - 1]) / sub
        for _ in range(sub):
            h += a * du - b * abs(du) * h - g * du * abs(h)
        out.append(h)
    return np.array(out)


def test_exact_kernel_matches_fine_euler():
    t = np.linspace(0, 1, 400)
    u = 40 * np.sin(2 * np.pi * 2 * t) * np.exp(-t)
    for a, b, g in [(0.5, 0.05, 0.01), (1.0, 0.02, -0.015), (-0.3, 0.1, 0.09), (0.2, 0.0, 0.0)]:
        h = bouc_wen_population(u, np.array([a]), np.array([b]), np.array([g]))[:, 0]
        ref = euler_reference(u, a, b, g)
        assert np.max(np.abs(h - ref)) < 2e-3 * max(np.max(np.abs(ref)), 1e-9)


def test_rate_independence():
    """Bouc-Wen is rate independent: inserting intermediate samples on the same straight input segments
    changes nothing at the original samples (exact integration)."""
    u = np.array([0, 10, 30, 5, 20, -10, 0], float)
    fine = np.interp(np.linspace(0, 6, 6 * 7 + 1), np.arange(7), u)
    args = (np.array([0.7]), np.array([0.04]), np.array([0.01]))
    h = bouc_wen_population(u, *args)[:, 0]
    hf = bouc_wen_population(fine, *args)[::7, 0]
    np.testing.assert_allclose(h, hf, atol=1e-10)


def test_population_columns_equal_single_runs(rng):
    u = np.cumsum(rng.normal(size=300))
    P = 6
    a, b, g = rng.random(P), rng.random(P) * 0.2, (rng.random(P) - 0.5) * 0.2
    H = bouc_wen_population(u, a, b, g)
    for p in range(P):
        np.testing.assert_allclose(H[:, p], bouc_wen_population(u, a[p:p + 1], b[p:p + 1], g[p:p + 1])[:, 0])


def test_simulate_shapes_and_bounds_scale_with_data():
    u = np.linspace(0, 100, 50)
    m = BoucWen()
    sc1 = DataScale.from_arrays([u], [0.3 * u], [1e-3])
    sc2 = DataScale.from_arrays([u / 1000], [300 * u], [1e-3])  # mV-scale input, nm-scale output
    p1, p2 = m.params(sc1), m.params(sc2)
    assert [p.name for p in p1] == ["Kv", "alpha", "beta", "gamma", "y0"]
    assert p2[0].upper / p1[0].upper > 1e5  # gain bound follows output/input range
    y = m.simulate(np.array([[p.default for p in p1]] * 3), u, 1e-3)
    assert y.shape == (3, 50) and np.all(np.isfinite(y))


def test_divergent_parameters_give_nonfinite_not_crash():
    u = np.r_[np.linspace(0, 1000, 200), np.linspace(1000, 0, 200)]
    y = BoucWen().simulate(np.array([[1.0, 1.0, 0.0, 5.0, 0.0]]), u, 1e-3)  # beta - gamma << 0: exponential growth
    assert y.shape == (1, 400)


def test_numerical_inverse_round_trip():
    t = np.arange(3000) * 1e-4
    u = 40 * (1 - np.cos(2 * np.pi * 3 * t))
    m = BoucWen()
    theta = np.array([0.25, 0.15, 0.03, 0.01, 0.2])
    y = m.simulate_one(theta, u, 1e-4)
    u_back = m.invert(theta, y, 1e-4, u_range=(-20.0, 100.0))
    assert np.max(np.abs(u_back - u)) < 1e-6 * 80
    np.testing.assert_allclose(m.simulate_one(theta, u_back, 1e-4), y, atol=1e-6)


def test_step_agrees_with_simulate(rng):
    u = np.cumsum(rng.normal(size=50))
    m = BoucWen()
    theta = np.array([0.3, 0.2, 0.05, -0.02, 0.1])
    y = m.simulate_one(theta, u, 1e-3)
    state = m.initial_state(theta, u[0], 1e-3)
    ys = [theta[0] * u[0] + theta[4]]
    for k in range(1, len(u)):
        yk, st = m.step(theta, state, u[k - 1], np.array([u[k]]), 1e-3)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, atol=1e-12)


def test_free_exponent_n1_matches_default_and_n2_differs():
    t = np.arange(2000) * 1e-4
    u = 30 * (1 - np.cos(2 * np.pi * 5 * t))
    sc = DataScale.from_arrays([u], [0.3 * u], [1e-4])
    m1 = BoucWen()
    mn = BoucWen(free_exponent=True).adapt(sc)
    assert mn.h_ref == sc.y_range and [p.name for p in mn.params(sc)][-1] == "n"
    th = np.array([0.25, 0.15, 0.03, 0.01, 0.2])
    y1 = m1.simulate_one(th, u, 1e-4)
    yn = mn.simulate_one(np.r_[th, 1.0], u, 1e-4)
    np.testing.assert_allclose(yn, y1, atol=1e-7 * np.ptp(y1))
    y2 = mn.simulate_one(np.r_[th, 2.0], u, 1e-4)
    assert np.all(np.isfinite(y2)) and np.max(np.abs(y2 - y1)) > 1e-3
    assert mn.separable() is None and m1.separable() is not None
    # structure round-trips through JSON
    assert BoucWen.from_structure(mn.structure()) == mn
