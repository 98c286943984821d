"""Dahl model (exact per-segment solution)."""

import math

import numpy as np

from hystfit.models.dahl import dahl_population
from hystfit.models.dahl import Dahl
from hystfit.objective import Objective, Series
from hystfit.optimizers.lsq import LSQ
from hystfit.optimizers.pso import PSO
from hystfit.params import DataScale

FS = 10_000.0
DT = 1.0 / FS
THETA = np.array([0.2, -0.08, 1.0, 1.2, 0.3])  # k µm/V, σ µm/V, Fc µm, a, d0 µm


def raised_cosine(amp, f=10.0, cycles=2, fs=FS):
    t = np.arange(int(round(cycles * fs / f))) / fs
    return 0.5 * amp * (1 - np.cos(2 * np.pi * f * t))


def rk4_reference(u, sigma, fc, a, sub=200):
    """Plain-Python RK4 in u of the README's Dahl ODE, dh/du = σ φ_a(1 − (h/F) sgn Δu), F = sgn(σ) F_c."""
    F = fc if sigma > 0 else -fc

    def f(h, s):
        x = 1.0 - h / F * s
        return sigma * abs(x) ** a * (1.0 if x > 0 else -1.0 if x < 0 else 0.0)

    h, out = 0.0, [0.0]
    for k in range(1, len(u)):
        du = (u[k] - u[k - 1]) / sub
        s = 1.0 if du > 0 else -1.0
        for _ in range(sub):
            k1 = f(h, s)
            k2 = f(h + 0.5 * du * k1, s)
            k3 = f(h + 0.5 * du * k2, s)
            k4 = f(h + du * k3, s)
            h += du * (k1 + 2 * k2 + 2 * k3 + k4) / 6
        out.append(h)
    return np.array(out)


def test_exact_kernel_matches_rk4_reference():
    t = np.linspace(0, 1, 150)
    u = 40 * np.sin(2 * np.pi * 2 * t) * np.exp(-t)  # reversals inside the range: minor loops
    for sigma, fc, a in [(0.5, 2.0, 1.0), (-0.3, 1.5, 0.6), (0.2, 3.0, 2.5), (-1.0, 0.5, 1.0 + 1e-13)]:
        h = dahl_population(u, np.array([sigma]), np.array([fc]), np.array([a]))[:, 0]
        ref = rk4_reference(u, sigma, fc, a)
        # RK4 with 200 sub-steps per sample: ~1e-8 of F_c (a < 1 is non-Lipschitz at saturation)
        np.testing.assert_allclose(h, ref, rtol=0, atol=2e-7 * fc)


def test_orientation_symmetry_and_saturation():
    u = raised_cosine(60.0, cycles=1)
    args = (np.array([1.0]), np.array([0.7]))
    hp = dahl_population(u, np.array([0.5]), *args)[:, 0]
    hn = dahl_population(u, np.array([-0.5]), *args)[:, 0]
    np.testing.assert_array_equal(hn, -hp)
    assert abs(hp[len(u) // 2] - 1.0) < 1e-9  # saturated at +F_c at the top
    assert np.all(np.abs(hp) <= 1.0 + 1e-12)


def test_rate_independent_exactly():
    u = np.array([0, 10, 30, 5, 20, -10, 0], float)
    fine = np.interp(np.linspace(0, 6, 6 * 7 + 1), np.arange(7), u)
    for a in (0.5, 1.0, 2.0):
        args = (np.array([0.3]), np.array([2.0]), np.array([a]))
        np.testing.assert_allclose(dahl_population(u, *args)[:, 0], dahl_population(fine, *args)[::7, 0],
                                   rtol=0, atol=1e-12)


def test_step_agrees_with_simulate(rng):
    u = np.cumsum(rng.normal(size=80))
    m = Dahl()
    y = m.simulate_one(THETA, u, DT)
    state = m.initial_state(THETA, u[0], DT)
    ys = [THETA[0] * u[0] + THETA[4]]
    for k in range(1, len(u)):
        yk, st = m.step(THETA, state, u[k - 1], np.array([u[k]]), DT)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, rtol=0, atol=1e-12)


def test_numerical_inverse_round_trip_on_raised_cosine_target():
    m = Dahl()
    y_d = 0.3 + 10.0 * raised_cosine(1.0, cycles=2)  # 0→A→0 displacement (µm), 10 Hz, 10 kHz
    u_inv = m.invert(THETA, y_d, DT)
    # generic bracketing inverse: 17-point grid, 4 refinements, linear interpolation
    np.testing.assert_allclose(m.simulate_one(THETA, u_inv, DT), y_d, rtol=0, atol=1e-6 * 10.0)
    u = raised_cosine(60.0, cycles=1)
    np.testing.assert_allclose(m.invert(THETA, m.simulate_one(THETA, u, DT), DT), u, rtol=0, atol=1e-6 * 60)


def test_random_parameters_in_bounds_finite_and_divergent_nonfinite(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), raised_cosine(20.0, cycles=1) + 10]
    sc = DataScale.from_arrays([u], [0.2 * u], [DT])
    m = Dahl()
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((300, 5)) * (hi - lo)
    assert np.all(np.isfinite(m.simulate(theta, u, DT)))
    # outside the box (F_c < 0, a > 1): the state blows up → non-finite, never an exception
    y = m.simulate(np.array([[0.2, 0.5, -0.5, 2.0, 0.0]]), u, DT)
    assert y.shape == (1, u.size) and not np.all(np.isfinite(y))


def test_recovery_pso_then_lsq(rng):
    """All five parameters are identifiable here: σΔU/F_c ≈ 5 (the state saturates over about a
    fifth of the stroke). a is the least precise (it trades with σ near the reversals)."""
    u = raised_cosine(60.0, cycles=2)
    y_true = Dahl().simulate_one(THETA, u, DT)
    sigma_n = 0.005 * np.ptp(y_true)
    y = y_true + rng.normal(scale=sigma_n, size=u.size)
    sc = DataScale.from_arrays([u], [y], [DT])
    m = Dahl()
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    obj = Objective(m, [Series(u, y, DT)])
    res = PSO(pop=40, iters=100).minimize(obj, lo, hi, rng=rng)
    pol = LSQ().minimize(obj, lo, hi, rng=rng, x0=res.x)
    fun, x = min((pol.fun, pol.x), (res.fun, res.x), key=lambda t: t[0])
    assert math.sqrt(fun) <= 1.1 * sigma_n
    np.testing.assert_allclose(x[[0, 1, 2]], THETA[[0, 1, 2]], rtol=0.05)
    assert abs(x[3] - THETA[3]) < 0.15 * THETA[3]
    assert abs(x[4] - THETA[4]) < 0.05


def test_output_kernel_is_the_numpy_formula_bit_for_bit():
    """y = k·u + h + d0 from the grouped state (h once per group of rows): the numbers of the numpy
    expression on the repeated state, non-finite entries included."""
    from hystfit.models.dahl import dahl_output

    rng = np.random.default_rng(2)
    u = rng.normal(size=300)
    h = rng.normal(size=(300, 3))
    h[5, 1] = np.nan
    k, d0 = rng.normal(size=12), rng.normal(size=12)
    k[4] = np.inf
    with np.errstate(all="ignore"):
        expected = k[:, None] * u[None, :] + np.repeat(h.T, 4, axis=0) + d0[:, None]
    got = dahl_output(u, k, d0, h, 4)
    assert np.array_equal(got, expected, equal_nan=True)
    assert np.array_equal(dahl_output(u, k[:3], d0[:3], h, 1), k[:3, None] * u + h.T + d0[:3, None], equal_nan=True)


def test_fused_normal_equations_equal_the_simulated_basis_ones():
    """(k, d0)'s normal equations from the state's sums (dahl_moments) are those of the simulated
    basis [u, 1] with target y − h, to rounding; a candidate whose state is NaN is not solvable."""
    from hystfit.models.dahl import Dahl
    from hystfit.models.separable import separable_by_simulation
    from hystfit.params import DataScale

    rng = np.random.default_rng(7)
    u = 30.0 * (1.0 - np.cos(2 * np.pi * np.arange(1500) / 500.0)) + rng.normal(0.0, 0.1, 1500)
    y = 0.2 * u + 0.3 * np.tanh(np.gradient(u)) - 0.4
    m = Dahl()
    ps = m.params(DataScale.from_arrays([u], [y], [1e-4]))
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + (hi - lo) * rng.random((6, len(ps)))
    sep = m.separable()
    plain = separable_by_simulation(m, sep.linear, len(ps))
    nl = theta[:, list(sep.nonlinear)]
    nl[2, 1] = np.nan
    G, c, tt = sep.gram_factory(u, 1e-4, y)(nl)
    Gp, cp, ttp = plain.gram_factory(u, 1e-4, y)(nl)
    ok = np.arange(6) != 2
    assert not np.all(np.isfinite(c[2]))
    for a, b in ((G, Gp), (c, cp), (np.broadcast_to(tt, ttp.shape), ttp)):
        scale = np.max(np.abs(b[ok]), axis=tuple(range(1, b.ndim)), keepdims=True)
        assert np.all(np.abs(a[ok] - b[ok]) <= 1e-12 * scale)
