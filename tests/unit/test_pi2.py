"""Electromechanical model (paper 000): PI + second-order linear part, exact discrete solution."""

import math

import numpy as np
import pytest
from scipy import signal
from scipy.optimize import nnls

from hystfit.errors import ConfigError
from hystfit.models.pi import PI
from hystfit.models.pi2 import PI2, bilinear_biquad
from hystfit.objective import Objective, Series
from hystfit.optimizers.auto import Auto
from hystfit.params import DataScale
from hystfit.registry import models

FS = 10_000.0
DT = 1.0 / FS
W = np.r_[0.2, 0.05, 0.04, 0.03, 0.02, 0.015, 0.01, 0.008, 0.005, 0.003]  # µm/V, a P-721-like loop
TRUE = np.r_[W, 0.5, 1200.0, 0.15]  # weights, y0 (µm), fn (Hz), zeta


def raised_cosine(f_Hz, A=60.0, N=2000):
    t = np.arange(N) * DT
    return A * 0.5 * (1 - np.cos(2 * np.pi * f_Hz * t))


def adapted(us=None):
    us = us if us is not None else [raised_cosine(50)]
    return PI2().adapt(DataScale.from_arrays(us, us, [DT] * len(us)))


def reference_pi2(theta, u, r, dt):
    """Plain-Python loops: play operators (003 eq. 1–2), PI sum, then the difference equation of
    scipy's prewarped bilinear transform of ω²/(s² + 2ζωs + ω²), at rest at the first PI output."""
    n = len(r)
    w, y0, fn, zeta = theta[:n], theta[n], theta[n + 1], theta[n + 2]
    state = [0.0] * n
    v = []
    for uk in u:
        tot = 0.0
        for j in range(n):
            state[j] = max(uk - r[j], min(uk + r[j], state[j]))
            tot += w[j] * state[j]
        v.append(tot)
    wn = 2 * math.pi * fn
    k = wn / math.tan(wn * dt / 2)
    b, a = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=k / 2)
    b, a = b / a[0], a / a[0]
    xs = [v[0], v[0]]
    ys = [v[0], v[0]]
    out = []
    for x in v:
        yk = b[0] * x + b[1] * xs[-1] + b[2] * xs[-2] - a[1] * ys[-1] - a[2] * ys[-2]
        xs.append(x)
        ys.append(yk)
        out.append(yk + y0)
    return np.array(out)


def test_registered_and_parameter_table():
    assert models.get("pi2") is PI2
    us = [raised_cosine(80)]
    sc = DataScale.from_arrays(us, [0.3 * u for u in us], [DT])
    ps = PI2().adapt(sc).params(sc)
    assert [p.name for p in ps] == [f"w{j}" for j in range(10)] + ["y0", "fn_Hz", "zeta"]
    fn = ps[-2]
    assert fn.upper == pytest.approx(0.45 * FS)
    assert fn.lower == pytest.approx(5 * 80, rel=0.02)  # 5 × the excitation frequency recovered from the peak rate
    assert (ps[-1].lower, ps[-1].upper) == (0.01, 2.0)


def test_bilinear_coefficients_match_scipy_and_static_gain_is_one():
    for fn, zeta, dt in [(1200.0, 0.15, 1e-4), (30.0, 0.7, 1e-4), (4400.0, 0.01, 1e-4), (5.0, 2.0, 1e-3)]:
        b0, b1, b2, a1, a2 = (float(c[0]) for c in bilinear_biquad(fn, zeta, dt))
        wn = 2 * np.pi * fn
        k = wn / np.tan(wn * dt / 2)
        b, a = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=k / 2)
        np.testing.assert_allclose([b0, b1, b2], b / a[0], rtol=1e-9)
        np.testing.assert_allclose([a1, a2], (a / a[0])[1:], rtol=1e-9)
        assert (b0 + b1 + b2) / (1 + a1 + a2) == pytest.approx(1.0, abs=1e-13)
    # out of range: NaN coefficients, not an exception
    assert np.all(np.isnan(bilinear_biquad(np.array([6000.0, -1.0]), np.array([0.1, 0.1]), 1e-4)[3]))


def test_simulate_matches_python_reference(rng):
    u = raised_cosine(20, N=1500) * (1 - 0.3 * np.sin(np.arange(1500) * DT * 2 * np.pi * 7))
    m = adapted([u])
    P = 5
    theta = np.c_[rng.random((P, 10)) * 0.05, rng.random(P), 300 + rng.random(P) * 3000, 0.02 + rng.random(P)]
    theta[0] = TRUE
    y = m.simulate(theta, u, DT)
    assert y.shape == (P, 1500)
    for p in range(P):
        ref = reference_pi2(theta[p], u, m.pi.r, DT)
        np.testing.assert_allclose(y[p], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))


def test_static_limit_is_the_pi_and_constant_input_stays_at_rest():
    m = adapted()
    slow = raised_cosine(0.5, N=20000)  # 0.5 Hz, far below fn = 1200 Hz
    y = m.simulate_one(TRUE, slow, DT)
    y_pi = PI(10, thresholds_V=m.thresholds_V).simulate_one(TRUE[:11], slow, DT)
    assert np.max(np.abs(y - y_pi)) < 2e-4 * np.ptp(y_pi)  # quasi-static: only the tiny lag ≈ 2ζ/ωn·du/dt
    const = np.full(500, 42.0)
    y_c = m.simulate_one(TRUE, const, DT)
    np.testing.assert_allclose(y_c, y_c[0], atol=1e-12)


def test_design_matrix_is_exact_and_nnls_recovers_the_weights():
    us = [raised_cosine(50), raised_cosine(200)]
    m = adapted(us)
    fn, zeta = TRUE[-2], TRUE[-1]
    Phi = np.vstack([m.design_matrix(u, DT, fn, zeta) for u in us])
    y = np.concatenate([m.simulate_one(TRUE, u, DT) for u in us])
    np.testing.assert_allclose(Phi @ TRUE[:11], y, atol=1e-12)
    x, _ = nnls(Phi, y)
    np.testing.assert_allclose(x, TRUE[:11], atol=1e-6)


def test_separable_basis_reproduces_simulate(rng):
    u = raised_cosine(100, N=800)
    m = adapted([u])
    sep = m.separable()
    theta = np.vstack([TRUE, np.r_[rng.random(10) * 0.05, 0.2, 800.0, 0.4]])
    B = sep.basis_factory(u, DT)(theta[:, list(sep.nonlinear)])
    np.testing.assert_allclose(np.einsum("pnl,pl->pn", B, theta[:, list(sep.linear)]), m.simulate(theta, u, DT),
                               atol=1e-11)


@pytest.mark.parametrize("P", [7, 90])  # serial and threaded kernels (candidate blocks)
def test_fused_sse_and_normal_equations_equal_the_simulated_ones(rng, P):
    """The fused kernels (Σ(ŷ − y)² in the time loop; BᵀB, Bᵀy of the filtered plays and ones)
    equal the simulated sum and the stored basis to 1e-9 relative for random candidates inside
    the bounds; non-finite parameters give a non-finite result for that candidate only."""
    N = 2500
    u = raised_cosine(40, N=N) * (1 - 0.3 * np.sin(np.arange(N) * DT * 2 * np.pi * 13)) + 5.0  # starts off zero
    m = adapted([u])
    sc = DataScale.from_arrays([u], [0.3 * u], [DT])
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    theta = lo + rng.random((P, len(ps))) * (hi - lo)
    theta[0] = TRUE
    bad = {1: (3, np.nan), 2: (10, np.inf), 3: (11, np.nan), 4: (12, np.inf), 5: (11, 0.6 * FS)}  # row: (column, value)
    for row, (col, val) in bad.items():
        theta[row, col] = val
    y = m.simulate_one(TRUE, u, DT) + 0.01 * rng.standard_normal(N)

    with np.errstate(all="ignore"):
        ref = np.sum((m.simulate(theta, u, DT) - y) ** 2, axis=1)
    got = m.sse_evaluator(u, DT, y)(theta)
    finite = np.ones(P, bool)
    finite[list(bad)] = False
    np.testing.assert_array_equal(np.isfinite(ref), finite)
    np.testing.assert_array_equal(np.isfinite(got), finite)
    np.testing.assert_allclose(got[finite], ref[finite], rtol=1e-9)

    sep = m.separable()
    assert sep.gram_fused and sep.nonlinear == (11, 12)
    nl = list(sep.nonlinear)
    G, c, yy = sep.gram_factory(u, DT, y)(theta[:, nl])
    B = sep.basis_factory(u, DT)(theta[:, nl])
    assert G.shape == (P, 11, 11) and c.shape == (P, 11)
    with np.errstate(all="ignore"):
        G_ref = np.einsum("pnl,pnk->plk", B, B)
        c_ref = np.einsum("pnl,n->pl", B, y)
    ok = np.isfinite(G_ref.reshape(P, -1)).all(axis=1)
    np.testing.assert_array_equal(ok, ~np.isin(np.arange(P), [3, 4, 5]))  # non-finite or out-of-range dynamics
    np.testing.assert_array_equal(np.isfinite(G.reshape(P, -1)).all(axis=1), ok)
    np.testing.assert_allclose(G[ok], G_ref[ok], rtol=1e-9)
    np.testing.assert_allclose(c[ok], c_ref[ok], rtol=1e-9, atol=1e-12 * np.abs(c_ref[ok]).max())
    assert yy == pytest.approx(float(y @ y), rel=1e-14)
    # solving the normal equations at the true dynamics recovers (w, y0) to the noise level
    x = np.linalg.solve(G[0], c[0])
    np.testing.assert_allclose(x, TRUE[:11], atol=0.02)


def test_play_matrix_is_shared_per_capture_and_never_stale():
    """Simulator, fused SSE and normal equations of one capture share one read-only play matrix;
    an input changed in place gets its own (content-keyed), never the stale one."""
    from hystfit.models._kernels import play_matrix
    from hystfit.models.pi2 import shared_play_matrix

    u = raised_cosine(30, N=600)
    r = adapted([u]).pi.r
    F = shared_play_matrix(u, r)
    assert shared_play_matrix(u.copy(), r) is F and not F.flags.writeable
    np.testing.assert_array_equal(F, play_matrix(u, r))
    u2 = u.copy()
    u2[100] += 1.0
    assert shared_play_matrix(u2, r) is not F
    np.testing.assert_array_equal(shared_play_matrix(u2, r), play_matrix(u2, r))


def test_step_agrees_with_simulate(rng):
    u = 30 + np.cumsum(rng.normal(size=400))
    m = adapted([u])
    y = m.simulate_one(TRUE, u, DT)
    state = m.initial_state(TRUE, u[0], DT)
    ys = [m.step(TRUE, state, u[0], np.array([u[0]]), DT)[0][0]]
    for k in range(1, len(u)):
        yk, st = m.step(TRUE, state, u[k - 1], np.array([u[k], u[k] - 3.0]), DT)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, atol=1e-11)


def test_inverse_round_trip_on_raised_cosine_target():
    """Dynamic inversion (bilinear-consistent central differences) + analytic PI inverse.

    Tolerances: the target's acceleration steps at t = 0 (raised cosine from rest); the discrete
    model cannot follow that step exactly, leaving a decaying transient of ≈ (f/f_n)² × stroke at the
    start; afterwards the inversion is accurate to O((ωTs)⁴) (< 1e-7 of the stroke at 10 Hz).
    """
    m = adapted()
    N = 4000
    t = np.arange(N) * DT
    stroke = 10.0
    y_d = 2.0 + stroke * 0.5 * (1 - np.cos(2 * np.pi * 10 * t))
    u = m.invert(TRUE, y_d, DT)
    e = np.abs(m.simulate_one(TRUE, u, DT) - y_d)
    assert e.max() < 2e-5 * stroke
    assert e[200:-2].max() < 1e-7 * stroke  # the last sample lacks its preview y_d[N] (held)
    # the quasi-static part is the classical PI inverse
    v = m.invert_dynamics(TRUE, y_d, DT)
    np.testing.assert_allclose(u, PI(10, thresholds_V=m.thresholds_V).invert(TRUE[:11], v, DT))


def test_inverse_rejects_bad_dynamics():
    m = adapted()
    bad = TRUE.copy()
    bad[-2] = 0.6 * FS
    with pytest.raises(ConfigError, match="fn_Hz"):
        m.invert(bad, np.ones(10), DT)


def test_structure_validation_and_round_trip():
    m = adapted()
    assert PI2.from_structure(m.structure()) == m
    with pytest.raises(ConfigError, match="pi2"):
        PI2(0)


def test_recovery_with_noise():
    """Two noisy captures (50 and 200 Hz raised cosines, 60 V) of a known pi2; auto = PSO over (fn, ζ)
    with the weights and y0 solved exactly (bounded least squares) + least-squares polish.

    Identifiable: fn, ζ (the 200 Hz capture shows the lag), y0, the low-threshold weights and the
    total gain Σw. The high-threshold weights w7…w9 are not individually identifiable to better than
    ~50 %: the play-operator matrix is ill-conditioned (``shared/PERFORMANCE.md``).
    """
    us = [raised_cosine(50), raised_cosine(200)]
    m = adapted(us)
    sigma = 0.008  # µm, the virtual actuator's sensor noise
    ys = [m.simulate_one(TRUE, u, DT) + sigma * np.random.default_rng(11 + i).standard_normal(u.size)
          for i, u in enumerate(us)]
    sc = DataScale.from_arrays(us, ys, [DT, DT])
    ps = m.params(sc)
    lo, hi = np.array([p.lower for p in ps]), np.array([p.upper for p in ps])
    obj = Objective(m, [Series(u, y, DT) for u, y in zip(us, ys)])
    res = Auto(pop=20, iters=40).minimize(obj, lo, hi, rng=np.random.default_rng(5))
    assert math.sqrt(res.fun) <= 1.1 * sigma
    x = res.x
    assert x[-2] == pytest.approx(1200.0, rel=0.01)
    assert x[-1] == pytest.approx(0.15, rel=0.03)
    assert x[10] == pytest.approx(0.5, abs=0.01)
    np.testing.assert_allclose(x[:5], W[:5], rtol=0.02)
    assert x[:10].sum() == pytest.approx(W.sum(), rel=0.005)
