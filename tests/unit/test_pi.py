import numpy as np
import pytest

from hystfit.errors import ConfigError
from hystfit.models._kernels import play_matrix
from hystfit.models.pi import PI
from hystfit.params import DataScale


def reference_play(u, r):
    """Plain-Python play operator (paper 003 eq. 1-2) to check the compiled kernel."""
    out = np.empty(len(u))
    prev = max(u[0] - r, min(u[0] + r, 0.0))
    out[0] = prev
    for k in range(1, len(u)):
        prev = max(u[k] - r, min(u[k] + r, prev))
        out[k] = prev
    return out


def test_play_matrix_matches_reference(rng):
    u = np.cumsum(rng.normal(size=500))
    r = np.array([0.0, 0.5, 2.0, 7.5])
    F = play_matrix(u, r)
    for j, rj in enumerate(r):
        np.testing.assert_allclose(F[:, j], reference_play(u, rj), rtol=0, atol=1e-12)


def test_zero_threshold_is_identity(rng):
    u = rng.normal(size=100)
    np.testing.assert_allclose(play_matrix(u, np.array([0.0]))[:, 0], u)


def _scale(u, y, dt=1e-3):
    return DataScale.from_arrays([u], [y], [dt])


def test_pi_adapt_thresholds_uniform_and_quadratic():
    u = np.linspace(0, 50, 10)
    sc = _scale(u, u)
    assert PI(5).adapt(sc).thresholds_V == (0.0, 10.0, 20.0, 30.0, 40.0)
    q = PI(5, placement="quadratic").adapt(sc).thresholds_V
    np.testing.assert_allclose(q, [0, 2, 8, 18, 32])


def test_pi_rejects_bad_structure():
    with pytest.raises(ConfigError):
        PI(0)
    with pytest.raises(ConfigError):
        PI(3, thresholds_V=(0.0, 2.0, 1.0))
    with pytest.raises(ConfigError, match="placement"):
        PI(3, placement="random")


def test_pi_simulate_population_shapes_and_linearity(rng):
    t = np.arange(2000) * 1e-4
    u = 30 * (1 - np.cos(2 * np.pi * 5 * t))
    m = PI(6).adapt(_scale(u, u))
    theta = rng.random((7, 7))
    y = m.simulate(theta, u, 1e-4)
    assert y.shape == (7, 2000)
    np.testing.assert_allclose(m.simulate(theta[:1] + theta[1:2], u, 1e-4)[0], y[0] + y[1] - 0, atol=1e-9 + 0)


def test_pi_inverse_round_trip(rng):
    t = np.arange(4000) * 1e-4
    u = 25 * (1 - np.cos(2 * np.pi * 2 * t)) * (1 - 0.3 * np.sin(2 * np.pi * 0.7 * t))
    m = PI(10).adapt(_scale(u, u))
    theta = np.r_[0.2, rng.random(9) * 0.05, 1.5]
    y = m.simulate_one(theta, u, 1e-4)
    u_back = m.invert(theta, y, 1e-4)
    np.testing.assert_allclose(u_back, u, atol=1e-9)
    # and forward(inverse(y_d)) = y_d for a target trajectory
    y_d = 2 + 5 * (1 - np.cos(2 * np.pi * 3 * t))
    np.testing.assert_allclose(m.simulate_one(theta, m.invert(theta, y_d, 1e-4), 1e-4), y_d, atol=1e-9)


def test_pi_inverse_refuses_non_invertible_weights():
    m = PI(3, thresholds_V=(0.0, 1.0, 2.0))
    with pytest.raises(ConfigError, match="inverse"):
        m.invert(np.array([0.0, 0.1, 0.1, 0.0]), np.zeros(10), 1e-3)


def test_inverted_output_gives_weights_of_one_negative_sign_and_an_exact_inverse(rng):
    """A stage whose sensor reads downwards: the data's sign is −1, the non-negative constraint
    becomes w ≤ 0, the exact least-squares fit recovers the weights and the inverse is exact."""
    from hystfit.identify import fit_captures
    from hystfit.capture import Capture
    from hystfit.optimizers.auto import Auto

    t = np.arange(4000) * 1e-4
    u = 30 * (1 - np.cos(2 * np.pi * 10 * t))
    m = PI(6).adapt(_scale(u, u))
    w = np.array([0.2, 0.05, 0.03, 0.02, 0.01, 0.005])
    y = -m.simulate_one(np.r_[w, 0.0], u, 1e-4) + 80.0
    sc = _scale(u, y)
    assert sc.sign == -1.0 and _scale(u, -y).sign == 1.0
    assert all(p.upper == 0.0 and p.lower < 0 for p in m.params(sc)[:-1])
    cap = Capture(source="inv.csv", t=t, u=u, y=y, dt=1e-4, y_unit="um", amplitude_V=60.0, frequency_Hz=10.0)
    fit = fit_captures([cap], PI(6), Auto(), seed=0)
    np.testing.assert_allclose(fit.theta[:6], -w, rtol=1e-4)
    assert fit.metrics["rmse_um"] < 1e-5
    target = 80.0 - 5.0 * (1 - np.cos(2 * np.pi * 5 * t))
    back = m.simulate_one(fit.theta, m.invert(fit.theta, target, 1e-4), 1e-4)
    np.testing.assert_allclose(back, target, atol=1e-9)


def test_head_simulator_keeps_the_design_matrix_of_short_inputs_only(monkeypatch):
    """A diagnosis keeps a PI's head simulator per capture: the design matrix is kept up to
    HEAD_SIMULATOR_MAX entries (simulated at each call beyond), the same bits either way."""
    import hystfit.models.pi as pi_module

    m = PI(n_operators=8, thresholds_V=tuple(float(j) for j in range(8)))
    u = 4.0 * np.sin(np.linspace(0, 6 * np.pi, 500)) + 4.0
    theta = np.linspace(0.1, 1.0, 9)
    kept = m.head_simulator(u, 1e-3)
    monkeypatch.setattr(pi_module, "HEAD_SIMULATOR_MAX", 100)
    each = m.head_simulator(u, 1e-3)
    for n in (500, 321, 1):
        np.testing.assert_array_equal(kept(theta, n), m.simulate_one(theta, u[:n], 1e-3))
        np.testing.assert_array_equal(each(theta, n), kept(theta, n))


def test_a_relaxed_history_starts_every_play_at_the_first_input_and_is_the_ramp_model_translated(rng):
    """``history="relaxed"``: every play operator at u₀ before the first sample (an actuator whose loops
    closed at u₀), the ramp model translated to u₀ — simulation, stepping, the analytic inverse and the
    state agree with each other and with a plain-Python play started there; the option survives
    adapt and refined; an unknown history is refused."""
    t = np.arange(3000) / 1e4
    u = 45.0 + np.clip(t / 0.2, 0, 1) * 30.0 * np.sin(2 * np.pi * 10 * t)
    scale = DataScale.from_arrays([u], [u], [1e-4])
    m = PI(n_operators=8, history="relaxed").adapt(scale)
    assert m.history == "relaxed" and PI(history="relaxed").refined().history == "relaxed" and m.starts_at_rest
    assert not PI().adapt(scale).starts_at_rest
    th = np.r_[0.3 * np.exp(-m.r / 15.0), 1.5]
    y = m.simulate_one(th, u, 1e-4)

    def relaxed_play(r):
        prev, out = u[0], np.empty(u.size)
        for k, v in enumerate(u):
            prev = max(v - r, min(v + r, prev))
            out[k] = prev
        return out

    want = np.column_stack([relaxed_play(r) for r in m.r]) @ th[:-1] + th[-1]
    np.testing.assert_allclose(y, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(m.initial_state(th, u[0], 1e-4), np.full(8, u[0]))
    np.testing.assert_allclose(m.invert(th, y, 1e-4), u, rtol=0, atol=1e-9)
    state, stepped = m.initial_state(th, u[0], 1e-4), []
    for k in range(1, 400):
        out, plays = m.step(th, state, u[k - 1], u[k], 1e-4)
        state = plays[0]
        stepped.append(out[0])
    np.testing.assert_allclose(stepped, y[1:400], rtol=0, atol=1e-12)
    ramp = PI(n_operators=8).adapt(scale)
    assert abs(ramp.simulate_one(th, u, 1e-4)[0] - y[0]) > 1.0  # the two histories differ at mid-stroke
    with pytest.raises(ConfigError, match="history must be one of ramp, relaxed"):
        PI(history="centred")
