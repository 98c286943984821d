"""Four-parameter fractional Zener model (Grünwald–Letnikov recurrence, FFT evaluation)."""

import math

import numpy as np
import pytest
from scipy.special import binom

from hystfit.errors import ConfigError
from hystfit.models import fp as fp_module
from hystfit.models.fp import gl_filter_population, gl_weights
from hystfit.models.fp import FractionalZener
from hystfit.objective import Objective, Series
from hystfit.optimizers.lsq import LSQ
from hystfit.optimizers.pso import PSO
from hystfit.params import DataScale

FS = 10_000.0
DT = 1.0 / FS
THETA = np.array([0.22, 0.15, 0.004, 0.6, 0.3])  # E0 µm/V, E∞ µm/V, τ s, a, y0 µm


def raised_cosine(amp, f=10.0, cycles=2, fs=FS):
    t = np.arange(int(round(cycles * fs / f))) / fs
    return 0.5 * amp * (1 - np.cos(2 * np.pi * f * t))


def reference_fp(u, dt, theta, n_mem):
    """Plain-Python GL recurrence of y + τ^a D^a y = E0 u + E∞ τ^a D^a u in deviations from u_0."""
    E0, Ei, tau, a, y0 = theta
    w = [1.0]
    for j in range(1, n_mem + 1):
        w.append(w[-1] * (1 - (a + 1) / j))
    b = (tau / dt) ** a
    x = [v - u[0] for v in u]
    yd = []
    for k in range(len(u)):
        sx = sum(w[j] * x[k - j] for j in range(1, min(k, n_mem) + 1))
        sy = sum(w[j] * yd[k - j] for j in range(1, min(k, n_mem) + 1))
        yd.append((E0 * x[k] + Ei * b * (x[k] + sx) - b * sy) / (1 + b))
    return np.array(yd) + E0 * u[0] + y0


def test_gl_weights_are_signed_binomials():
    a = np.array([0.1, 0.5, 0.93])
    w = gl_weights(a, 30)
    j = np.arange(31)
    for p in range(3):
        np.testing.assert_allclose(w[:, p], (-1.0) ** j * binom(a[p], j), rtol=1e-12, atol=1e-15)
    assert np.all(w[1:] < 0) and np.all(np.sum(w, axis=0) > 0)  # Σ|w_j≥1| < 1: the recurrence is stable


@pytest.mark.parametrize("memory_s", [0.005, 0.05])  # 50 samples (recurrence) and 500 (FFT evaluation)
def test_simulate_matches_plain_python_reference(memory_s):
    u = np.r_[5.0, raised_cosine(60.0, cycles=1)[:600] + 5.0]  # starts away from 0 V
    m = FractionalZener(memory_s=memory_s)
    n_mem = m.memory_samples(DT)
    thetas = np.array([THETA, [0.3, 0.05, 0.02, 0.2, -1.0], [0.1, 0.25, 0.001, 0.95, 0.0]])
    Y = m.simulate(thetas, u, DT)
    for p in range(3):
        ref = reference_fp(u, DT, thetas[p], n_mem)
        np.testing.assert_allclose(Y[p], ref, rtol=1e-9, atol=1e-9 * np.max(np.abs(ref)))


def test_fft_evaluation_equals_recurrence_on_long_capture(rng):
    u = raised_cosine(60.0, cycles=5)  # N = 5000, full memory
    m = FractionalZener()
    P = 8
    theta = np.column_stack([rng.uniform(0.1, 0.3, P), rng.uniform(0.05, 0.3, P), rng.uniform(1e-4, 0.05, P),
                             rng.uniform(0.05, 0.95, P), rng.uniform(-1, 1, P)])
    y_fft = m.simulate(theta, u, DT)
    a, tau = theta[:, 3].copy(), theta[:, 2]
    b = (tau / DT) ** a
    w = gl_weights(a, u.size - 1)
    ydev = gl_filter_population(u - u[0], w, np.ones(P), b, theta[:, 0].copy(), theta[:, 1] * b).T
    y_rec = ydev + theta[:, 4][:, None]
    assert u.size - 1 > fp_module.RECURRENCE_MAX_TERMS
    np.testing.assert_allclose(y_fft, y_rec, rtol=0, atol=1e-9 * np.max(np.abs(y_rec)))


def test_static_and_instantaneous_gain():
    u = np.r_[0.0, np.full(9999, 10.0)]  # 10 V step at the second sample, 1 s long
    E0, Ei, tau, a = 0.2, 0.1, 1e-3, 0.7
    y = FractionalZener(offset=False).simulate_one(np.array([E0, Ei, tau, a]), u, DT)
    b = (tau / DT) ** a
    assert abs(y[1] - 10 * (E0 + Ei * b) / (1 + b)) < 1e-12  # first sample after the step
    assert abs(y[-1] - 10 * E0) < 0.01 * 10 * E0  # relaxed to the static gain (power-law tail)


def test_step_agrees_with_simulate():
    u = np.r_[2.0, raised_cosine(60.0, cycles=1)[:300] + 2.0]
    for m in (FractionalZener(memory_s=0.004), FractionalZener()):
        y = m.simulate_one(THETA, u, DT)
        state = m.initial_state(THETA, u[0], DT)
        ys = []
        for k in range(len(u)):
            yk, st = m.step(THETA, state, u[k - 1] if k else u[0], np.array([u[k], u[k] + 1.0]), DT)
            ys.append(yk[0])
            state = st[0]
        np.testing.assert_allclose(ys, y, rtol=0, atol=1e-9 * np.max(np.abs(y)))


def test_exact_inverse_round_trip_on_raised_cosine_target():
    m = FractionalZener()
    y_d = 0.3 + 10.0 * raised_cosine(1.0, cycles=2)  # 0→A→0 displacement (µm), 10 Hz, 10 kHz
    u_inv = m.invert(THETA, y_d, DT)
    np.testing.assert_allclose(m.simulate_one(THETA, u_inv, DT), y_d, rtol=0, atol=1e-9 * 10.0)
    u = raised_cosine(60.0, cycles=2)
    np.testing.assert_allclose(m.invert(THETA, m.simulate_one(THETA, u, DT), DT), u, rtol=0, atol=1e-9 * 60)
    with pytest.raises(ConfigError, match="E0 ≠ 0"):
        m.invert(np.array([0.0, 0.1, 0.01, 0.5, 0.0]), y_d, DT)
    # a falling output (both gains negative, DataScale.sign = −1) inverts as exactly
    neg = THETA * np.array([-1.0, -1.0, 1.0, 1.0, -1.0])
    y_neg = 100.0 - y_d
    np.testing.assert_allclose(m.simulate_one(neg, m.invert(neg, y_neg, DT), DT), y_neg, rtol=0, atol=1e-9 * 100)
    with pytest.raises(ConfigError, match="Einf of E0's sign"):
        m.invert(np.array([0.3, -0.1, 0.01, 0.5, 0.0]), y_d, DT)


def test_structure_validation_and_memory_is_a_time_span():
    with pytest.raises(ConfigError):
        FractionalZener(memory_s=0)
    with pytest.raises(ConfigError):
        FractionalZener(offset=1)
    m = FractionalZener(memory_s=0.2)
    assert m.memory_samples(1e-4) == 2000 and m.memory_samples(1e-3) == 200
    assert FractionalZener.from_structure(m.structure()) == m
    assert len(FractionalZener(offset=False).params(DataScale(0, 1, 0, 1, 1e-3, 10.0))) == 4


def test_random_parameters_in_bounds_finite_and_invalid_nonfinite(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), raised_cosine(20.0, f=40.0, cycles=2) + 10]
    sc = DataScale.from_arrays([u], [0.2 * u], [DT])
    m = FractionalZener()
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((200, 5)) * (hi - lo)
    assert np.all(np.isfinite(m.simulate(theta, u, DT)))
    y = m.simulate(np.array([[0.2, 0.1, -0.01, 0.5, 0.0]]), u, DT)  # τ < 0: (τ/Ts)^a is NaN
    assert not np.any(np.isfinite(y[0, 1:]))


def test_recovery_pso_then_lsq(rng):
    """Three pooled raised cosines (10, 40, 80 Hz): the phase lag at several frequencies plus the
    mean level determine all of E0, E∞, τ, a (from one frequency (E∞, τ, a) would trade)."""
    m = FractionalZener()
    us = [raised_cosine(60.0, f=f, cycles=c) for f, c in ((10.0, 1), (40.0, 2), (80.0, 4))]
    ys = [m.simulate_one(THETA, u, DT) for u in us]
    sigma_n = 0.005 * np.ptp(ys[0])
    ys = [y + rng.normal(scale=sigma_n, size=y.size) for y in ys]
    sc = DataScale.from_arrays(us, ys, [DT] * 3)
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    obj = Objective(m, [Series(u, y, DT) for u, y in zip(us, ys)])
    res = PSO(pop=30, iters=60).minimize(obj, lo, hi, rng=rng)
    pol = LSQ().minimize(obj, lo, hi, rng=rng, x0=res.x)
    fun, x = min((pol.fun, pol.x), (res.fun, res.x), key=lambda t: t[0])
    assert math.sqrt(fun) <= 1.1 * sigma_n
    np.testing.assert_allclose(x[:2], THETA[:2], rtol=0.05)
    np.testing.assert_allclose(x[2:4], THETA[2:4], rtol=0.25)
    assert abs(x[4] - THETA[4]) < 0.05


def _fft_reference(theta, u, memory_samples):
    """The FFT evaluation written out per row, H = (E0 + E∞bP)/(1 + bP) for every row (the
    straightforward form the grouped evaluation must reproduce bit for bit)."""
    from scipy import fft as sfft

    x = u - u[0]
    N = u.size
    L = min(memory_samples, N - 1)
    M = sfft.next_fast_len(3 * N, real=True)
    r = fp_module._FFT_ALIAS ** (1.0 / M)
    X = sfft.rfft(x * r ** np.arange(N), M)
    E0, Ei, tau, a, y0 = (theta[:, i].copy() for i in range(5))
    with np.errstate(all="ignore"):
        b = (tau / DT) ** a
        Pz = sfft.rfft(gl_weights(a, L).T * r ** np.arange(L + 1), M, axis=1)
        H = (E0[:, None] + (Ei * b)[:, None] * Pz) / (1.0 + b[:, None] * Pz)
        ydev = sfft.irfft(H * X, M, axis=1)[:, :N] * r ** -np.arange(N, dtype=np.float64)
        zero = (E0 == 0.0) & (Ei == 0.0)
        ydev[zero] = np.where(np.any(np.isnan(H[zero]), axis=1), np.nan, 0.0)[:, None]
        return ydev + (E0 * u[0])[:, None] + y0[:, None]


@pytest.mark.parametrize("group", [1, 4])
def test_grouped_fft_evaluation_is_the_per_row_formula_bit_for_bit(rng, group):
    """The FFT route computes 1 + bP once per group of rows sharing (τ, a) and skips the rows with
    E0 = E∞ = 0 (the separable basis' zero and offset columns): the same numbers as the per-row
    formula, including the NaN of a zero row whose spectrum is not finite."""
    u = raised_cosine(60.0, cycles=1)[:900] + 1.0
    m = FractionalZener(memory_s=0.05)  # 500 samples: the FFT route
    assert m.memory_samples(DT) > fp_module.RECURRENCE_MAX_TERMS
    nl = np.column_stack([rng.uniform(1e-4, 0.05, 5), rng.uniform(0.05, 0.95, 5)])
    nl[2, 0] = np.nan  # a non-finite τ: every row of its group is NaN, the zero rows too
    theta = np.zeros((5 * group, 5))
    theta[:, 2:4] = np.repeat(nl, group, axis=0)
    theta[:, :2] = rng.uniform(0.05, 0.3, (5 * group, 2))
    theta[:, 4] = rng.uniform(-1, 1, 5 * group)
    if group == 4:  # the separable basis' pattern: θ_lin = 0, E0 = 1, E∞ = 1, y0 = 1
        theta[:, [0, 1, 4]] = np.tile(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), (5, 1))
    else:
        theta[1, :2] = 0.0
    got = m.simulator(u, DT)(theta, group)
    ref = _fft_reference(theta, u, m.memory_samples(DT))
    assert np.isnan(got).any() and np.isfinite(got).any()
    assert np.array_equal(got, ref, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(ref))
