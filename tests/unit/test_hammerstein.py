"""Hammerstein model (paper 003): PI + linear state space identified by correlation/Hankel SVD (ERA)."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import signal

from hystfit.errors import ConfigError, InputError
from hystfit.models.hammerstein import (Hammerstein, LinearSS, fit_linear_to_sine, identify_linear_era,
                                        is_broadband)
from hystfit.models.pi import PI
from hystfit.params import DataScale
from hystfit.registry import models
from hystfit.synth import multisine, multisine_frequencies, prbs, raised_cosine, sine, triangle

FS = 10_000.0
DT = 1.0 / FS
W = np.r_[0.2, 0.05, 0.04, 0.03, 0.02, 0.015, 0.01, 0.008, 0.005, 0.003]  # µm/V
THETA = np.r_[W, 0.5]  # weights, y0 (µm)
THRESHOLDS = tuple(6.0 * np.arange(10))  # 0 … 54 V


def paper_003_eq16(dt=DT) -> LinearSS:
    """Paper 003 eq. 16, read from the text (it is legible and consistent: static gain 0.990,
    poles −2001, −628.4, ω = 1868 rad/s (ζ 0.50), ω = 3155 rad/s = 502 Hz (ζ 0.022); zeros −3.03e4,
    a lightly damped pair at 286 Hz and a right-half-plane pair at 1.70 kHz, as the text describes):

        G(s) = 3.8608 (s + 3.03e4)(s² + 213 s + 3.24e6)(s² − 1.383e4 s + 1.141e8)
               / [(s + 2001)(s + 628.4)(s² + 1884 s + 3.489e6)(s² + 138.8 s + 9.957e6)]

    discretized with a zero-order hold (exact for a sample-and-hold drive such as the PRBS)."""
    num = 3.8608 * np.polymul(np.polymul([1, 3.03e4], [1, 213, 3.24e6]), [1, -1.383e4, 1.141e8])
    den = np.polymul(np.polymul(np.polymul([1, 2001], [1, 628.4]), [1, 1884, 3.489e6]), [1, 138.8, 9.957e6])
    A, B, C, D, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, "zoh")
    return LinearSS(A, B.ravel(), C.ravel(), dt, 6, method="given", D=float(D.ravel()[0]))


def second_order_zoh(fn=800.0, zeta=0.3, dt=DT) -> LinearSS:
    wn = 2 * np.pi * fn
    b, a, _ = signal.cont2discrete(([wn * wn], [1.0, 2 * zeta * wn, wn * wn]), dt, "zoh")
    return LinearSS.from_tf(b.ravel(), a.ravel(), dt)


def model_with(lin: LinearSS) -> Hammerstein:
    return Hammerstein(10, thresholds_V=THRESHOLDS).with_linear(lin)


def pi_output(u, w=W):
    return PI(10, thresholds_V=THRESHOLDS).design_matrix(u, DT)[:, :10] @ w


def reference_state_space(lin: LinearSS, v):
    """Plain-Python loops: x_{k+1} = A x_k + B v_k, y_k = C x_k + D v_k from the equilibrium of v_0."""
    r = lin.order
    x0 = np.linalg.solve(np.eye(r) - lin.A, lin.B * v[0])
    x = [float(a) for a in x0]
    out = []
    for vk in v:
        out.append(sum(lin.C[i] * x[i] for i in range(r)) + lin.D * vk)
        x = [sum(lin.A[i, j] * x[j] for j in range(r)) + lin.B[i] * vk for i in range(r)]
    return np.array(out)


def reference_play(u, r):
    out, s = [], 0.0
    for uk in u:
        s = max(uk - r, min(uk + r, s))
        out.append(s)
    return np.array(out)


def test_registered_default_is_the_static_pi():
    assert models.get("hammerstein") is Hammerstein
    u = raised_cosine(60, 20, fs_Hz=FS)[1]
    m = Hammerstein(10, thresholds_V=THRESHOLDS)
    assert m.order == 0 and m.linear_method == "none"
    np.testing.assert_allclose(m.simulate_one(THETA, u, DT), PI(10, thresholds_V=THRESHOLDS).simulate_one(THETA, u, DT))


def test_filter_matches_python_state_space_loop(rng):
    lin = replace_d(paper_003_eq16(), 0.07)  # exercise D too
    v = 5 + np.cumsum(rng.normal(size=600))
    ref = reference_state_space(lin, v)
    np.testing.assert_allclose(lin.filter(v), ref, rtol=0, atol=1e-11 * np.max(np.abs(ref)))
    V = np.stack([v, 2 * v - 3], axis=1)
    np.testing.assert_allclose(lin.filter(V)[:, 1], reference_state_space(lin, V[:, 1]), atol=1e-10)


def replace_d(lin, D):
    from dataclasses import replace

    return replace(lin, D=D)


def test_simulate_matches_python_reference(rng):
    lin = paper_003_eq16().normalized()
    m = model_with(lin)
    u = raised_cosine(60, 40, fs_Hz=FS, cycles=3)[1] + rng.normal(scale=0.5, size=751)
    theta = np.vstack([THETA, np.r_[rng.random(10) * 0.05, -1.0]])
    y = m.simulate(theta, u, DT)
    for p in range(2):
        v = sum(theta[p, j] * reference_play(u, THRESHOLDS[j]) for j in range(10))
        ref = reference_state_space(lin, v) + theta[p, 10]
        np.testing.assert_allclose(y[p], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))
    assert abs(lin.dc_gain() - 1.0) < 1e-12
    np.testing.assert_allclose(m.simulate_one(THETA, np.full(300, 33.0), DT), m.simulate_one(THETA, np.full(300, 33.0), DT)[0])


def test_structure_json_round_trip_and_adapt_keeps_linear_part():
    m = Hammerstein(10).with_linear(paper_003_eq16().normalized())
    sc = DataScale.from_arrays([np.linspace(0, 60, 10)], [np.linspace(0, 18, 10)], [DT])
    m = m.adapt(sc)
    assert m.thresholds_V == PI(10).adapt(sc).thresholds_V
    assert m.order == 6 and len(m.A) == 36
    back = Hammerstein.from_structure(json.loads(json.dumps(m.structure())))
    assert back == m
    assert back.adapt(DataScale.from_arrays([np.linspace(0, 10, 5)], [np.linspace(0, 1, 5)], [DT])) == m
    u = raised_cosine(60, 20, fs_Hz=FS)[1]
    np.testing.assert_array_equal(back.simulate_one(THETA, u, DT), m.simulate_one(THETA, u, DT))


def test_invalid_structure():
    with pytest.raises(ConfigError, match="entries"):
        Hammerstein(order=2, A=(1.0, 0.0), B=(1.0, 0.0), C=(1.0, 0.0), dt_s=DT)
    with pytest.raises(ConfigError, match="dt_s"):
        Hammerstein(order=1, A=(0.5,), B=(1.0,), C=(0.5,))
    for bad in ({"feedthrough": "yes"}, {"correlation": "fft"}, {"max_order": 0}, {"n_markov": 2},
                {"era_order": -1}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            Hammerstein(**bad)


@pytest.mark.parametrize("method", ["zoh", "bilinear"])
def test_linear_part_identified_at_5kHz_simulates_and_inverts_at_10kHz(method):
    """Exact re-discretization: the 5 kHz part resampled to 10 kHz equals the same continuous stage
    discretized at 10 kHz (zero-order hold for D = 0, bilinear with a feedthrough)."""
    wn = 2 * np.pi * 800.0
    sysc = signal.tf2ss([wn * wn], [1.0, 2 * 0.1 * wn, wn * wn])

    def at(dt):
        A, B, C, D, _ = signal.cont2discrete(sysc, dt, method=method)
        return LinearSS(A, B.ravel(), C.ravel(), dt, 2, D=float(D.ravel()[0]))

    assert (at(2 * DT).D == 0.0) == (method == "zoh")  # "auto" picks the method from D
    m5, m10 = model_with(at(2 * DT)), model_with(at(DT))
    u = raised_cosine(60, 20, fs_Hz=FS)[1]
    u = u + 5 * np.sin(2 * np.pi * 700 * np.arange(u.size) * DT)
    np.testing.assert_allclose(m5.simulate_one(THETA, u, DT), m10.simulate_one(THETA, u, DT), atol=1e-9)
    y_d = 2 + 5 * (1 - np.cos(2 * np.pi * 10 * np.arange(2000) * DT))
    np.testing.assert_allclose(m5.invert(THETA, y_d, DT), m10.invert(THETA, y_d, DT), atol=1e-8)
    with pytest.raises(ConfigError, match="negative real axis|z = −1"):
        LinearSS(np.array([[-0.5 if method == "zoh" else -1.0]]), np.array([1.0]), np.array([1.5]), DT, 1,
                 D=0.0 if method == "zoh" else 0.1).resampled(2 * DT, method)


def test_step_agrees_with_simulate(rng):
    m = model_with(replace_d(paper_003_eq16(), 0.05).normalized())
    u = 30 + np.cumsum(rng.normal(size=300))
    y = m.simulate_one(THETA, u, DT)
    state = m.initial_state(THETA, u[0], DT)
    ys = [m.step(THETA, state, u[0], np.array([u[0]]), DT)[0][0]]
    for k in range(1, len(u)):
        yk, st = m.step(THETA, state, u[k - 1], np.array([u[k], u[k] + 2.0]), DT)
        ys.append(yk[0])
        state = st[0]
    np.testing.assert_allclose(ys, y, atol=1e-11)


def test_broadband_detection():
    assert is_broadband(prbs(10, FS, 1.0, 2500, seed=1)[1])
    assert is_broadband(multisine(10, multisine_frequencies(1000, 1.0), FS, 1.0)[1])
    for u in (sine(10, 20, fs_Hz=FS)[1], raised_cosine(10, 20, fs_Hz=FS)[1], triangle(10, 20, fs_Hz=FS)[1]):
        assert not is_broadband(u)


def _compare_response(lin, true, f_max=1000.0):
    f = np.linspace(2.0, f_max, 400)
    ratio = lin.freqresp(f) / true.freqresp(f)
    return np.max(np.abs(np.abs(ratio) - 1)), np.max(np.abs(np.angle(ratio, deg=True)))


def test_era_identifies_paper_003_eq16_from_a_prbs_capture():
    """Full-stroke PRBS (0/60 V, new bit every sample: energy over the whole band) → PI → eq. 16 →
    + sensor noise; ERA from the PI output v. The order-6 gap is found and the frequency response
    matches up to 1 kHz. (With a 10 V PRBS at this noise the weak 6th mode, σ₆/σ₁ ≈ 1.6 %, is no
    longer above the noise floor and the gap rule picks order 5.)"""
    true = paper_003_eq16()
    u = prbs(60.0, FS, 1.0, FS, seed=1)[1]
    sigma = 0.008
    v = pi_output(u)
    y = true.filter(v) + 0.3 + sigma * np.random.default_rng(2).standard_normal(u.size)
    lin = identify_linear_era(v, y, DT, n_markov=800)  # 800 samples ≈ 5.5 time constants of the 502 Hz mode
    assert lin.method == "era" and lin.order == 6
    s = lin.singular_values
    assert s[5] / s[6] > 5 and s[5] / s[6] == max(s[:8] / s[1:9])  # the gap
    mag, ph = _compare_response(lin, true)
    assert mag < 0.02 and ph < 2.0
    assert lin.D == 0.0  # feedthrough "auto": a zero-order-hold plant does not demand D
    # the estimated feedthrough of a strictly proper plant is ≈ 0, and gives the same model
    lin_d = identify_linear_era(v, y, DT, n_markov=800, feedthrough=True)
    assert lin_d.order == 6 and abs(lin_d.D) < 1e-3
    mag_d, ph_d = _compare_response(lin_d, true)
    assert mag_d < 0.02 and ph_d < 2.0


def bilinear_second_order(fn=1200.0, zeta=0.15, dt=DT) -> LinearSS:
    """The virtual actuator's kind of stage: a bilinear (Tustin) biquad, double zero at z = −1, D ≠ 0."""
    wn = 2 * np.pi * fn
    b, a = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=1.0 / dt)
    return LinearSS.from_tf(b, a, dt)


def test_feedthrough_auto_keeps_d_when_the_data_demand_it():
    """A bilinear stage has D = b0 ≈ 8 % of its static gain: D = 0 cannot represent it (the
    simulation error more than halves with D), so "auto" keeps D; a ZOH stage keeps D = 0 (above)."""
    true = bilinear_second_order()
    u = prbs(60.0, FS, 1.0, 2500.0, seed=3)[1]
    y = true.filter(u) + 0.004 * np.random.default_rng(4).standard_normal(u.size)
    lin = identify_linear_era(u, y, DT, n_markov=400)
    assert lin.D == pytest.approx(true.D, rel=0.05)
    assert identify_linear_era(u, y, DT, n_markov=400, feedthrough=False).D == 0.0
    with pytest.raises(ConfigError, match="feedthrough"):
        identify_linear_era(u, y, DT, n_markov=400, feedthrough="maybe")


def sign_alternations(x):
    """Longest run of consecutive sample-to-sample differences that alternate in sign."""
    d = np.sign(np.diff(x))
    d = d[d != 0]
    run = best = 0
    for a, b in zip(d[:-1], d[1:]):
        run = run + 1 if a != b else 0
        best = max(best, run)
    return best


def test_step_feedforward_through_zeros_at_minus_one_does_not_oscillate():
    """The bilinear stage's zeros sit at z = −1: an exact (or radius-pulled) inverse alternates sign
    every sample and grows to kilovolts. ZPETC: a 10 µm step needs about its static voltage, reached
    within a few samples, no alternation."""
    m = model_with(bilinear_second_order().normalized())
    assert m.linear.inverse_plan().kinds == ("zero-phase", "zero-phase")
    y_d = np.full(600, THETA[-1])
    y_d[200:] += 10.0
    u = m.invert(THETA, y_d, DT)
    u_static = m.pi.invert(np.r_[W, 0.0], np.array([0.0, 10.0]), DT)[1]  # the static inverse of 10 µm
    assert np.all(np.isfinite(u)) and u.min() > -1.0 and u.max() < 1.5 * u_static
    assert sign_alternations(u) <= 2
    assert np.allclose(u[210:], u_static, rtol=1e-6)
    y = m.simulate_one(THETA, u, DT)
    assert np.abs(y - y_d)[210:].max() < 1e-6  # settled on the target


def test_era_toeplitz_route_on_a_simple_plant():
    """The paper's eq. 4 correlations + Levinson solve (biased by (impulse length)/N) on a fast plant."""
    true = second_order_zoh(1500.0, 0.5)
    u = prbs(10.0, FS, 2.0, FS, seed=4)[1]
    y = true.filter(u)
    lin = identify_linear_era(u, y, DT, n_markov=100, correlation="toeplitz")
    assert lin.order == 2
    mag, ph = _compare_response(lin, true)
    assert mag < 0.02 and ph < 2.0


def test_from_data_era_path_and_weight_recovery():
    """PRBS for the dynamics + a raised cosine for the loop shape, through PI + eq. 16 (unit gain) + noise.

    The PI output is not measured: from_data identifies the linear part from v = u, solves the
    weights, re-identifies from v = PI output. Then θ is the exact least-squares solve.
    Identifiable: the response up to 1 kHz, y0, the low-threshold weights and Σw; the high-threshold
    weights only to ~50 % (ill-conditioned play-operator matrix).
    """
    true = paper_003_eq16().normalized()
    u1 = prbs(60.0, FS, 1.0, FS, seed=1)[1]
    u2 = raised_cosine(60, 20, fs_Hz=FS, cycles=4)[1]
    sigma = 0.008
    rng = np.random.default_rng(3)
    ys = [true.filter(pi_output(u)) + 0.5 + sigma * rng.standard_normal(u.size) for u in (u1, u2)]
    m = Hammerstein.from_data([u1, u2], ys, DT, n_markov=800)
    assert m.linear_method == "era" and m.order == 6
    assert m.linear.dc_gain() == pytest.approx(1.0, abs=1e-12)
    mag, ph = _compare_response(m.linear, true)
    assert mag < 0.02 and ph < 2.0
    m = Hammerstein(10, thresholds_V=THRESHOLDS).with_linear(m.linear)  # compare weights on the true thresholds
    theta = m.fit_weights([u1, u2], ys, DT)
    res = np.concatenate([m.simulate_one(theta, u, DT) - y for u, y in zip((u1, u2), ys)])
    assert math.sqrt(np.mean(res ** 2)) <= 1.1 * sigma
    assert theta[10] == pytest.approx(0.5, abs=5 * sigma)
    np.testing.assert_allclose(theta[:3], W[:3], rtol=0.03)
    assert theta[:10].sum() == pytest.approx(W.sum(), rel=0.01)


def test_sine_only_data_fits_gain_and_phase():
    """Raised cosines at 20, 100 and 300 Hz through PI + a 2nd-order plant: no broadband capture, so
    from_data fits the 2nd-order model to the gain/phase measured per frequency (method recorded)."""
    true = second_order_zoh(800.0, 0.3).normalized()
    us = [30 * (1 - np.cos(2 * np.pi * f * np.arange(3000) * DT)) for f in (20.0, 100.0, 300.0)]
    sigma = 0.008
    rng = np.random.default_rng(5)
    ys = [true.filter(pi_output(u)) + 0.5 + sigma * rng.standard_normal(u.size) for u in us]
    m = Hammerstein.from_data(us, ys, DT)
    assert m.linear_method == "sine-gain-phase" and m.order == 2
    f = np.array([20.0, 100.0, 300.0])
    ratio = m.linear.freqresp(f) / true.freqresp(f)
    assert np.max(np.abs(np.abs(ratio) - 1)) < 1e-3 and np.max(np.abs(np.angle(ratio, deg=True))) < 0.05
    m = Hammerstein(10, thresholds_V=THRESHOLDS).with_linear(m.linear)
    theta = m.fit_weights(us, ys, DT)
    res = np.concatenate([m.simulate_one(theta, u, DT) - y for u, y in zip(us, ys)])
    assert math.sqrt(np.mean(res ** 2)) <= 1.1 * sigma
    # the direct function, from the known PI output
    lin = fit_linear_to_sine([pi_output(u) for u in us], ys, DT)
    assert lin.method == "sine-gain-phase" and len(lin.fit_points) == 3
    with pytest.raises(InputError, match="same drive frequency"):
        fit_linear_to_sine([pi_output(us[0])] * 2, [ys[0]] * 2, DT)


def test_the_linear_part_s_errors_name_the_captures_and_no_function():
    """A blind test's find: a step pattern gave `fit_linear_to_sine: all sine captures have the same
    frequency`: a function's name, no file, and nothing on why steps did not count as broadband."""
    from hystfit import synth
    from hystfit.capture import Capture

    t, u = synth.step_pattern(60.0, 2.0, 5_000)
    cap = Capture(source="/data/steps.csv", t=t, u=u, y=pi_output(u), dt=t[1] - t[0])
    with pytest.raises(InputError) as got:
        Hammerstein(10).prepare([cap])
    msg = str(got.value)
    assert "(captures: steps.csv)" in msg and "step pattern" in msg
    assert "fit_linear_to_sine" not in msg and "from_data" not in msg


def test_inverse_round_trip_acceptable_zeros_is_exact():
    """Well-damped zeros (|z| ≤ 0.9, Re z ≥ 0) are inverted exactly."""
    lin = LinearSS.from_tf(np.array([0.0, 0.3, -0.12]), np.array([1.0, -1.2, 0.5]), DT).normalized()
    assert lin.inverse_plan().kinds == ("acceptable",)
    m = model_with(lin)
    t = np.arange(4000) * DT
    stroke = 10.0
    y_d = 2 + stroke * 0.5 * (1 - np.cos(2 * np.pi * 10 * t))
    u = m.invert(THETA, y_d, DT)
    e = np.abs(m.simulate_one(THETA, u, DT) - y_d)
    assert e.max() < 1e-4 * stroke  # start: the plant starts at rest, the target with an acceleration step
    assert e[100:-2].max() < 1e-10 * stroke  # one-sample delay inverted exactly; last sample lacks its preview


def test_inverse_of_the_zero_order_hold_sampling_zero_is_zero_phase():
    """A fast zero-order hold puts a zero near z = −1 (here −0.84): its exact inverse alternates sign
    every sample. ZPETC leaves it uninverted: zero phase error, gain error O(ω²) at low frequency."""
    m = model_with(second_order_zoh().normalized())
    plan = m.linear.inverse_plan()
    assert plan.kinds == ("zero-phase",) and -1 < plan.zeros[0].real < -0.5
    t = np.arange(4000) * DT
    stroke = 10.0
    y_d = 2 + stroke * 0.5 * (1 - np.cos(2 * np.pi * 10 * t))
    u = m.invert(THETA, y_d, DT)
    e = np.abs(m.simulate_one(THETA, u, DT) - y_d)
    assert e.max() < 1e-4 * stroke
    assert e[100:-2].max() < 1e-5 * stroke


def test_inverse_round_trip_non_minimum_phase_eq16():
    """Eq. 16 has right-half-plane zeros (|z| = 1.96 after discretization): its inverse uses the reflected
    (minimum-phase) zeros plus the all-pass's low-frequency delay as a time advance (003 §4.2, our variant).
    Exact up to the all-pass's phase beyond a pure delay: O((ω/ω_z)³)."""
    m = model_with(paper_003_eq16().normalized())
    plan = m.linear.inverse_plan()
    assert plan.delay == 1 and 2.0 < plan.tau_allpass < 3.0 and np.all(np.abs(np.roots(plan.b_a)) < 1)
    assert plan.kinds.count("reflected") == 2 and plan.kinds.count("acceptable") == 3  # 286 Hz pair kept
    t = np.arange(4000) * DT
    stroke = 10.0
    y_d = 2 + stroke * 0.5 * (1 - np.cos(2 * np.pi * 5 * t))
    u = m.invert(THETA, y_d, DT)
    e = np.abs(m.simulate_one(THETA, u, DT) - y_d)
    assert e.max() < 1e-4 * stroke
    assert e[200:-200].max() < 5e-6 * stroke


def test_structure_summary_says_how_the_linear_part_was_found():
    """Reports say which route identified the linear part (issue 3: 'with sine-only data ... say so')."""
    assert "none" in Hammerstein().structure_summary()
    m = model_with(second_order_zoh(800.0, 0.3).normalized())
    assert "f_n 800 Hz ζ 0.3" in m.structure_summary()
    us = [30 * (1 - np.cos(2 * np.pi * f * np.arange(3000) * DT)) for f in (20.0, 100.0, 300.0)]
    ys = [second_order_zoh(800.0, 0.3).normalized().filter(pi_output(u)) for u in us]
    text = Hammerstein.from_data(us, ys, DT).structure_summary()
    assert "gain and phase measured per frequency" in text and "limit" not in text
    era = Hammerstein(10, thresholds_V=THRESHOLDS).with_linear(
        replace(second_order_zoh(800.0, 0.3).normalized(), method="era"))
    assert "Hankel SVD" in era.structure_summary()
