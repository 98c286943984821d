"""Coleman–Hodgdon model (paper 001 eq. 1)."""

import math

import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.models.ch import ColemanHodgdon
from hystfit.objective import Objective, Series
from hystfit.optimizers.lsq import LSQ
from hystfit.optimizers.pso import PSO
from hystfit.params import DataScale

FS = 10_000.0
DT = 1.0 / FS
THETA = np.array([0.22, 0.05, 0.02, 0.6, 0.06, 0.3])  # A1..A6: µm/V, µm/V, 1/V, µm, 1/V, µm


def raised_cosine(amp, f=10.0, cycles=2, fs=FS):
    t = np.arange(int(round(cycles * fs / f))) / fs
    return 0.5 * amp * (1 - np.cos(2 * np.pi * f * t))


def reference_ch(u, theta, vm, vM):
    """Plain-Python 001 eq. 1, written literally (branch by the backward difference, u̇ = 0 keeps it)."""
    A1, A2, A3, A4, A5, A6 = theta
    K = A1 - A2 * math.exp(-A3 * (vM - vm))
    out, s = [], 1.0
    for k in range(len(u)):
        if k > 0 and u[k] != u[k - 1]:
            s = 1.0 if u[k] > u[k - 1] else -1.0
        x = u[k]
        if s > 0:
            out.append(K * x - A4 * (1 - 2 * math.exp(-A5 * x) / (math.exp(-A5 * vm) + math.exp(-A5 * vM))) + A6)
        else:
            out.append(K * x + A4 * (1 - 2 * math.exp(A5 * x) / (math.exp(A5 * vm) + math.exp(A5 * vM))) + A6)
    return np.array(out)


def _model(u, y=None):
    y = 0.2 * u if y is None else y
    return ColemanHodgdon().adapt(DataScale.from_arrays([u], [y], [DT]))


def test_kernel_matches_plain_python_reference(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), 30 + 10 * np.sin(np.linspace(0, 6 * np.pi, 300)), np.full(5, 12.0)]
    m = _model(u)
    assert (m.v_min, m.v_max) == (float(u.min()), float(u.max()))
    thetas = np.array([THETA, [0.1, 0.0, 0.0, -0.3, -0.05, 0.0], [0.3, 0.2, 0.1, 1.0, 0.15, -2.0]])
    Y = m.simulate(thetas, u, DT)
    for p in range(3):
        ref = reference_ch(u, thetas[p], m.v_min, m.v_max)
        np.testing.assert_allclose(Y[p], ref, rtol=1e-9, atol=1e-9 * np.ptp(ref))


def test_branches_close_at_extremes_and_orientation():
    u = raised_cosine(60.0, cycles=1)
    m = _model(u)
    asc = m.branch_value(THETA, np.array([0.0, 30.0, 60.0]), 1.0)
    desc = m.branch_value(THETA, np.array([0.0, 30.0, 60.0]), -1.0)
    np.testing.assert_allclose(asc[[0, 2]], desc[[0, 2]], rtol=1e-12)
    assert desc[1] > asc[1]  # A4 > 0: counter-clockwise, as a piezo stack


def test_zero_rate_keeps_branch_and_first_sample_ascending():
    m = ColemanHodgdon(0.0, 10.0)
    u = np.array([5.0, 5.0, 6.0, 6.0, 4.0, 4.0])
    y = m.simulate_one(THETA, u, DT)
    asc = m.branch_value(THETA, u, 1.0)
    desc = m.branch_value(THETA, u, -1.0)
    np.testing.assert_allclose(y, [asc[0], asc[1], asc[2], asc[3], desc[4], desc[5]])


def test_structure_required_and_validated():
    with pytest.raises(ConfigError, match="adapt"):
        ColemanHodgdon().simulate(THETA[None], np.zeros(3), DT)
    with pytest.raises(ConfigError):
        ColemanHodgdon(5.0, 1.0)
    with pytest.raises(ConfigError):
        ColemanHodgdon(0.0, None)
    m = ColemanHodgdon(0.0, 60.0)
    assert ColemanHodgdon.from_structure(m.structure()) == m


def test_step_agrees_with_simulate(rng):
    u = np.r_[0.0, np.cumsum(rng.normal(size=80))]
    u[10:13] = u[9]  # zero-rate samples
    m = _model(u)
    y = m.simulate_one(THETA, u, DT)
    state = m.initial_state(THETA, u[0], DT)
    ys = []
    for k in range(len(u)):
        yk, st = m.step(THETA, state, u[k - 1] if k else u[0], np.array([u[k]]), DT)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, rtol=1e-12, atol=1e-12)


def test_inverse_round_trip_on_raised_cosine_target():
    u = raised_cosine(60.0, cycles=1)
    m = _model(u)
    y_model = m.simulate_one(THETA, u, DT)
    # a realistic displacement target 0→A→0 (10 Hz, 10 kHz), inside the reachable range
    lo, hi = y_model.min() + 0.02 * np.ptp(y_model), y_model.max() - 0.05 * np.ptp(y_model)
    y_d = lo + (hi - lo) * raised_cosine(1.0, cycles=2)
    u_inv = m.invert(THETA, y_d, DT)
    # tolerance: bisection to machine precision → 1e-9 of the stroke
    np.testing.assert_allclose(m.simulate_one(THETA, u_inv, DT), y_d, rtol=0, atol=1e-9 * np.ptp(y_d))
    # the model's own output inverts to the original input
    np.testing.assert_allclose(m.invert(THETA, y_model, DT), u, rtol=0, atol=1e-9 * 60)


def test_linear_design_reproduces_output():
    u = raised_cosine(60.0, cycles=1)
    m = _model(u)
    K = m.slope(THETA[None])[0]
    Phi = m.linear_design(u, DT, THETA[4])
    np.testing.assert_allclose(Phi @ np.array([K, THETA[3], THETA[5]]), m.simulate_one(THETA, u, DT),
                               rtol=1e-12, atol=1e-12)


def test_random_parameters_in_bounds_give_finite_output(rng):
    u = np.r_[raised_cosine(60.0, cycles=1), raised_cosine(20.0, cycles=1) + 40]
    sc = DataScale.from_arrays([u], [0.2 * u], [DT])
    m = ColemanHodgdon().adapt(sc)
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((200, 6)) * (hi - lo)
    assert np.all(np.isfinite(m.simulate(theta, u, DT)))
    # nm / mV scale: the bounds follow the data
    sc2 = DataScale.from_arrays([u / 1000], [200 * u], [DT])
    assert m.params(sc2)[0].upper / ps[0].upper > 1e5


def profile_start(m, u, y, A5_grid):
    """Variable projection: best A5 on a grid with (K, A4, A6) by linear least squares → θ0 (A2 = 0)."""
    best = (np.inf, None)
    for A5 in A5_grid:
        Phi = m.linear_design(u, DT, A5)
        c, *_ = np.linalg.lstsq(Phi, y, rcond=None)
        sse = float(np.sum((Phi @ c - y) ** 2))
        if sse < best[0]:
            best = (sse, np.array([c[0], 0.0, 0.0, c[1], A5, c[2]]))
    return best[1]


def test_recovery_pso_then_lsq(rng):
    """Only K = A1 − A2 e^{−A3 V_R}, A4, A5, A6 are identifiable (A1, A2, A3 enter through K alone).

    The 6-D box also has a secondary minimum (A4 large, A5 small of the other sign: a parabolic
    loop, RMSE ≈ 1.3σ here) that a plain PSO run reaches for ~40 % of noise realizations at any
    modest budget. PSO is therefore started from the A5 profile of :meth:`linear_design`
    (x0 = first particle), then polished by LSQ.
    """
    u = raised_cosine(60.0, cycles=2)
    m0 = ColemanHodgdon(0.0, 60.0)
    y_true = m0.simulate_one(THETA, u, DT)
    sigma = 0.005 * np.ptp(y_true)
    y = y_true + rng.normal(scale=sigma, size=u.size)
    sc = DataScale.from_arrays([u], [y], [DT])
    m = ColemanHodgdon().adapt(sc)
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    obj = Objective(m, [Series(u, y, DT)])
    x0 = profile_start(m, u, y, np.linspace(lo[4], hi[4], 41))
    res = PSO(pop=30, iters=60).minimize(obj, lo, hi, rng=rng, x0=x0)
    pol = LSQ().minimize(obj, lo, hi, rng=rng, x0=res.x)
    fun, x = min((pol.fun, pol.x), (res.fun, res.x), key=lambda t: t[0])
    assert math.sqrt(fun) <= 1.1 * sigma
    K_true = m0.slope(THETA[None])[0]
    assert abs(m.slope(x[None])[0] - K_true) < 0.01 * K_true
    np.testing.assert_allclose(x[3:6], THETA[3:6], rtol=0.08, atol=0.01)


def test_normal_equations_from_sums_equal_the_basis_ones():
    """(A1, A4, A6)'s normal equations from the sums of −s·φ equal BᵀB, Bᵀ(y − C), |y − C|² of the
    explicit basis (B, C), to rounding; a candidate with a NaN shape stays non-finite."""
    rng = np.random.default_rng(8)
    u = np.r_[raised_cosine(60.0, cycles=1), raised_cosine(30.0, f=40.0, cycles=2)]
    y = 0.25 * u + 2.0 * np.tanh(0.1 * (u - 30.0)) + 0.1 * rng.normal(size=u.size)
    sc = DataScale.from_arrays([u], [y], [DT])
    m = ColemanHodgdon().adapt(sc)
    lo, hi = np.array([p.lower for p in m.params(sc)]), np.array([p.upper for p in m.params(sc)])
    sep = m.separable()
    nl = (lo + (hi - lo) * rng.random((5, 6)))[:, list(sep.nonlinear)]
    nl[1, 2] = np.nan
    B, C = sep.basis_factory(u, DT)(nl)
    t = y[None, :] - C
    expected = (B.transpose(0, 2, 1) @ B, (B.transpose(0, 2, 1) @ t[:, :, None])[:, :, 0], np.einsum("pn,pn->p", t, t))
    got = sep.gram_factory(u, DT, y)(nl)
    ok = np.arange(5) != 1
    assert not np.all(np.isfinite(got[0][1]))
    for a, b in zip(got, expected):
        scale = np.max(np.abs(b[ok]), axis=tuple(range(1, b.ndim)), keepdims=True)
        assert np.all(np.abs(a[ok] - b[ok]) <= 1e-12 * scale)
