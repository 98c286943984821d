"""NT softsign model (paper 002 eq. 2) and its discrete inverse (eq. 4–10)."""

import math

import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.models.nt import nt_inverse_causal
from hystfit.models.nt import NT
from hystfit.objective import Objective, Series
from hystfit.optimizers.lsq import LSQ
from hystfit.optimizers.pso import PSO
from hystfit.params import DataScale

FS = 10_000.0
DT = 1.0 / FS
# k0 µm/V, c0 µm·s/V, k1 µm, k2 1/V, y0 µm. c0 < 0: counter-clockwise loop, as a piezo stack
THETA_PIEZO = np.array([0.15, -2e-4, 3.0, 0.03, 0.3])
THETA_CW = np.array([0.15, 2e-6, 3.0, 0.03, 0.3])  # c0 > 0: 002's causal inverse is stable


def raised_cosine(amp, f=10.0, cycles=2, fs=FS):
    t = np.arange(int(round(cycles * fs / f))) / fs
    return 0.5 * amp * (1 - np.cos(2 * np.pi * f * t))


def reference_nt(u, dt, th):
    """Plain-Python 002 eq. 2 with the backward difference (u̇ = 0 at the first sample)."""
    k0, c0, k1, k2, y0 = th
    out = []
    for n in range(len(u)):
        v = (u[n] - u[n - 1]) / dt if n else 0.0
        out.append(k0 * u[n] + c0 * v + k1 * k2 * u[n] / (1 + abs(k2 * u[n])) + y0)
    return np.array(out)


def numpy_roots_inverse_step(A, k1, k2, B, u_prev):
    """002 eq. 8–10 solved with numpy.roots; admissible root on its branch closest to u_{n−1}."""
    cands = []
    for r in np.roots([A * k2, A + k1 * k2 - B * k2, -B]):
        if abs(r.imag) < 1e-12 and r.real >= 0:
            cands.append(r.real)
    for r in np.roots([A * k2, -(A + k1 * k2 + B * k2), B]):
        if abs(r.imag) < 1e-12 and r.real < 0:
            cands.append(r.real)
    cands = [r for r in cands
             if abs(A * r + k1 * k2 * r / (1 + k2 * abs(r)) - B) < 1e-8 * (abs(B) + abs(k1) + abs(A * r))]
    return min(cands, key=lambda r: abs(r - u_prev))


def test_kernel_matches_plain_python_reference(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), 20 * np.sin(np.linspace(0, 6 * np.pi, 300))]  # both signs of u
    m = NT()
    thetas = np.array([THETA_PIEZO, THETA_CW, [-0.1, 1e-4, -2.0, 0.5, -1.0]])
    Y = m.simulate(thetas, u, DT)
    for p in range(3):
        ref = reference_nt(u, DT, thetas[p])
        np.testing.assert_allclose(Y[p], ref, rtol=1e-9, atol=1e-9 * np.ptp(ref))


def test_linear_design_reproduces_output():
    u = raised_cosine(60.0, cycles=1)
    for m, th in ((NT(), THETA_PIEZO), (NT(offset=False), THETA_PIEZO[:4])):
        Phi = m.linear_design(u, DT, th[3])
        coef = np.r_[th[:3], th[4:]]
        np.testing.assert_allclose(Phi @ coef, m.simulate_one(th, u, DT), rtol=1e-12, atol=1e-12)
    assert NT().linear_design(u, DT, 0.1).shape == (u.size, 4)
    assert NT(offset=False).linear_design(u, DT, 0.1).shape == (u.size, 3)


def test_loop_orientation_follows_sign_of_c0():
    u = raised_cosine(60.0, cycles=1)
    i_up, i_down = 250, 750  # u = 30 V rising / falling
    y = NT().simulate_one(THETA_PIEZO, u, DT)
    assert y[i_down] > y[i_up]  # counter-clockwise
    y = NT().simulate_one(THETA_CW, u, DT)
    assert y[i_down] < y[i_up]


def test_step_agrees_with_simulate(rng):
    u = np.cumsum(rng.normal(size=60))
    m = NT()
    y = m.simulate_one(THETA_PIEZO, u, DT)
    ys = [m.step(THETA_PIEZO, m.initial_state(THETA_PIEZO, u[0], DT), u[0], np.array([u[0]]), DT)[0][0]]
    for k in range(1, len(u)):
        ys.append(m.step(THETA_PIEZO, np.zeros(0), u[k - 1], np.array([u[k]]), DT)[0][0])
    np.testing.assert_allclose(ys, y, rtol=1e-12, atol=1e-12)


def test_causal_inverse_matches_numpy_roots_of_eq_8_to_10(rng):
    th = np.array([0.15, 2e-6, -1.5, 0.2, 0.0])  # k1 < 0: the quadratics have several real roots
    k0, c0, k1, k2 = th[:4]
    A, c = k0 + c0 / DT, c0 / DT
    y = 3.0 * np.sin(np.linspace(0, 4 * np.pi, 400)) + rng.normal(scale=0.05, size=400)  # crosses u = 0
    u = nt_inverse_causal(y, A, c, k1, k2, 0.0)
    for n in range(1, len(y)):
        B = y[n] + c * u[n - 1]
        assert abs(u[n] - numpy_roots_inverse_step(A, k1, k2, B, u[n - 1])) <= 1e-9 * (1 + abs(u[n]))


def test_causal_inverse_round_trip_on_raised_cosine_target():
    m = NT()
    assert m.causal_inverse_is_stable(THETA_CW, DT)
    y_d = 0.3 + 6.0 * raised_cosine(1.0, cycles=2)  # 0→A→0 displacement (µm), 10 Hz, 10 kHz
    u_inv = m.invert(THETA_CW, y_d, DT, method="causal")
    np.testing.assert_allclose(m.simulate_one(THETA_CW, u_inv, DT), y_d, rtol=0, atol=1e-9 * 6.0)
    u = raised_cosine(60.0, cycles=2)
    np.testing.assert_allclose(m.invert(THETA_CW, m.simulate_one(THETA_CW, u, DT), DT), u, rtol=0, atol=1e-9 * 60)


def test_piezo_orientation_needs_the_backward_inverse():
    """c0 < 0 with |c0|/Ts ≫ k0: 002's causal recursion is unstable; 'auto' solves backwards."""
    m = NT()
    assert not m.causal_inverse_is_stable(THETA_PIEZO, DT)
    u = raised_cosine(60.0, cycles=2)
    y = m.simulate_one(THETA_PIEZO, u, DT)
    with np.errstate(all="ignore"):
        u_causal = m.invert(THETA_PIEZO, y, DT, method="causal")
    assert not np.all(np.abs(u_causal - u) < 1.0)  # the causal recursion has run away
    u_auto = m.invert(THETA_PIEZO, y, DT)
    # exact except near the end, where the terminal condition assumes rest (u̇ ≈ 0 there)
    assert np.max(np.abs(u_auto - u)) < 1e-3 * 60
    np.testing.assert_allclose(u_auto[:-200], u[:-200], rtol=0, atol=1e-9 * 60)
    y_d = 0.3 + 6.0 * raised_cosine(1.0, cycles=2)
    u_inv = m.invert(THETA_PIEZO, y_d, DT)
    err = m.simulate_one(THETA_PIEZO, u_inv, DT) - y_d
    np.testing.assert_allclose(err[1:], 0.0, atol=1e-9 * 6.0)  # every sample's equation but the first
    # the first sample is at rest in simulate(); the bounded (non-minimum-phase) inverse would
    # need pre-actuation before it, so it is off by a fraction of the stroke
    assert abs(err[0]) < 2e-3 * 6.0
    with pytest.raises(ConfigError):
        m.invert(THETA_PIEZO, y_d, DT, method="magic")


def test_random_parameters_in_bounds_give_finite_output(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), raised_cosine(20.0, f=40.0, cycles=2) - 10]
    sc = DataScale.from_arrays([u], [0.2 * u], [DT])
    m = NT()
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((300, 5)) * (hi - lo)
    assert np.all(np.isfinite(m.simulate(theta, u, DT)))
    assert [p.name for p in NT(offset=False).params(sc)] == ["k0", "c0", "k1", "k2"]


def test_recovery_pso_then_lsq(rng):
    """All of k0, c0, k1, k2, y0 are identifiable from one raised cosine when k2·U_max ≈ 1–2
    (the softsign curvature separates k1 from k0); c0 is set by the loop width."""
    m = NT()
    u = raised_cosine(60.0, cycles=2)
    y_true = m.simulate_one(THETA_PIEZO, u, DT)
    sigma_n = 0.005 * np.ptp(y_true)
    y = y_true + rng.normal(scale=sigma_n, size=u.size)
    sc = DataScale.from_arrays([u], [y], [DT])
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    obj = Objective(m, [Series(u, y, DT)])
    res = PSO(pop=30, iters=80).minimize(obj, lo, hi, rng=rng)
    pol = LSQ().minimize(obj, lo, hi, rng=rng, x0=res.x)
    fun, x = min((pol.fun, pol.x), (res.fun, res.x), key=lambda t: t[0])
    assert math.sqrt(fun) <= 1.1 * sigma_n
    np.testing.assert_allclose(x[:4], THETA_PIEZO[:4], rtol=0.1)
    assert abs(x[4] - THETA_PIEZO[4]) < 0.05
