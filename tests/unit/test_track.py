"""Closed-loop tracking (hystfit.track): textbook PID on a linear plant, margins, steps, SMC, limits."""

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy import signal

from hystfit.errors import ConfigError
from hystfit.invert import invert_target, sine_target, steps_target, target_from_array
from hystfit.models.base import Model
from hystfit.models.pi import PI
from hystfit.params import DataScale, Param
from hystfit.registry import models
from hystfit.results import Cell, ParamsFile
from hystfit.synth import DEFAULT_THRESHOLDS_V, DEFAULT_WEIGHTS_UM_PER_V
from hystfit.track import (NominalPlant, _static, auto_pid, design_smc, given_pid, loop_margins, nominal_plant,
                           parse_controllers, step_metrics, track)


@dataclass(frozen=True)
class FirstOrderLag(Model):
    """Test-only linear plant (not registered): y[k] = a·y[k−1] + (1 − a)·K·u[k], a = exp(−Ts/τ).

    θ = (K in um/V, τ in s). At rest at the first sample (y[0] = K·u[0]).
    """

    name = "test-lag"
    title = "first-order lag (test)"
    reference = "tests"
    equation = "tau dy/dt + y = K u"
    rate_dependent = True

    def params(self, scale):
        return (Param("K", "out/V", 0.0, 10.0, 0.3, "gain"), Param("tau", "s", 1e-6, 1.0, 1e-3, "time constant"))

    @staticmethod
    def _a(theta, dt):
        return math.exp(-dt / float(theta[1]))

    def simulate(self, theta, u, dt):
        theta = self.check_theta(theta, 2)
        u = np.asarray(u, float)
        out = np.empty((theta.shape[0], u.size))
        for i, (K, tau) in enumerate(theta):
            a = math.exp(-dt / tau)
            out[i] = signal.lfilter([(1 - a) * K], [1.0, -a], u, zi=[a * K * u[0]])[0]
        return out

    def initial_state(self, theta, u0, dt):
        return np.array([float(theta[0]) * u0])

    def step(self, theta, state, u_prev, u_new, dt):
        a = self._a(theta, dt)
        y = a * float(state[0]) + (1 - a) * float(theta[0]) * np.asarray(u_new, float)
        return y, y[:, None]

    def invert(self, theta, y_target, dt, u_range=None):
        a = self._a(theta, dt)
        y = np.asarray(y_target, float)
        prev = np.r_[y[0], y[:-1]]
        return (y - a * prev) / ((1 - a) * float(theta[0]))


def lag_table(K=0.3, tau=1e-3, dt=1e-4):
    sc = DataScale(0.0, 60.0, 0.0, 60 * K, dt, 1e4)
    cell = Cell("global", float("nan"), float("nan"), FirstOrderLag(), np.array([K, tau]), sc)
    return ParamsFile("lag.json", "test-lag", "um", "global", (cell,), {})


def pi_table(scale_w=1.0, path="pi.json"):
    w = np.asarray(DEFAULT_WEIGHTS_UM_PER_V) * scale_w
    sc = DataScale(0.0, 60.0, 0.25, 0.25 + 0.31 * 60, 1e-4, 4000.0)
    cell = Cell("60V_10Hz", 60.0, 10.0, PI(10, thresholds_V=DEFAULT_THRESHOLDS_V), np.r_[w, 0.25], sc)
    return ParamsFile(path, "pi", "um", "per-condition", (cell,), {})


def closed_loop_tf(K, a, kp, ki, kd, tf, dt):
    """Exact discrete closed loop r → y of hystfit's loop: y = P·v, v = z⁻¹·(C_e·(r − y) − C_d·y)."""
    P = np.poly1d
    Gn, Gd = P([(1 - a) * K]), P([1.0, -a])  # z⁻¹·P(z) = (1 − a)K/(z − a)
    Cen, Ced = P([kp, -kp]) + P([ki * dt, 0.0]), P([1.0, -1.0])
    Cdn, Cdd = P([kd, -kd]), P([tf + dt, -tf])
    num = Gn * Cen * Cdd
    den = Gd * Ced * Cdd + Gn * (Cen * Cdd + Cdn * Ced)
    return num.coeffs, den.coeffs


@pytest.mark.parametrize("kp,ki,kd", [(2.0, 3000.0, 0.0), (1.0, 2000.0, 2e-4), (0.0, 2500.0, 0.0)])
def test_pid_step_response_matches_scipy_discrete_closed_loop(kp, ki, kd):
    K, tau, dt = 0.3, 1e-3, 1e-4
    pf = lag_table(K, tau, dt)
    tgt = steps_target((10.0,), hold_s=0.03, fs=1 / dt, offset=3.0, lead_s=0.005)
    res = track(pf, tgt, ["pid"], kp=kp, ki=ki, kd=kd, vmin=-1e4, vmax=1e4)
    run = res.runs[0]
    gains = res.pid
    assert (gains.kp, gains.ki, gains.kd) == (kp, ki, kd) and gains.rule == "given"
    num, den = closed_loop_tf(K, math.exp(-dt / tau), kp, ki, kd, gains.tf_s, dt)
    _, y_dev = signal.dlsim((num, den, dt), tgt.y - tgt.y[0])
    np.testing.assert_allclose(run.output - tgt.y[0], y_dev[:, 0], atol=1e-9)
    assert run.metrics["n_samples"] == tgt.n and not run.limit_spans


def test_pi_step_response_matches_the_continuous_textbook_response():
    """First-order plant K/(τs+1) with PI control: T(s) = K(kp s + ki)/(τs² + (1 + K kp)s + K ki)."""
    K, tau, dt, kp, ki = 0.3, 2e-3, 1e-5, 1.0, 600.0
    pf = lag_table(K, tau, dt)
    tgt = steps_target((1.0,), hold_s=0.04, fs=1 / dt, offset=0.0, lead_s=0.001)
    run = track(pf, tgt, ["pid"], kp=kp, ki=ki, vmin=-1e4, vmax=1e4).runs[0]
    k0 = tgt.steps[0].index
    t = (np.arange(tgt.n - k0)) * dt
    _, y_ct = signal.step(([K * kp, K * ki], [tau, 1 + K * kp, K * ki]), T=t)
    # sampling adds ≈ 1.5 samples of delay (15 µs against time constants of milliseconds)
    np.testing.assert_allclose(run.output[k0:], y_ct, atol=0.01)
    m = step_metrics(tgt, run.output)[0]
    outside = np.flatnonzero(np.abs(y_ct - 1.0) > 0.02)
    assert m["settling_time_2pct_s"] == pytest.approx(t[outside[-1] + 1], rel=0.02)
    assert m["overshoot_pct"] == pytest.approx(100 * max(0.0, y_ct.max() - 1), abs=1.0)


def test_loop_margins_of_an_integrator_on_a_delayed_gain():
    """L(z) = K·ki·T/(z − 1): GM = 2/(K·ki·T) at Nyquist, PM = 90° − θc/2 with 2 sin(θc/2) = K·ki·T."""
    dt, K = 1e-4, 0.3
    nominal = _static(K, dt)
    ki = 0.5 / (K * dt)
    gm, pm, fc = loop_margins(nominal, 0.0, ki)
    theta_c = 2 * math.asin(0.25)
    assert gm == pytest.approx(4.0, rel=1e-3)
    assert pm == pytest.approx(90 - math.degrees(theta_c) / 2, abs=0.2)
    assert fc == pytest.approx(theta_c / (2 * math.pi * dt), rel=0.01)


def test_auto_pid_rule_on_a_static_plant():
    dt, K = 1e-4, 0.31
    g = auto_pid(_static(K, dt))
    assert g.ki == pytest.approx(2 * math.pi * 500 / K) and g.kp == pytest.approx(0.25 / K) and g.kd == 0
    assert g.gain_margin >= 2 and g.phase_margin_deg >= 45 and g.bandwidth_Hz == pytest.approx(500)
    g2 = auto_pid(_static(K, dt), bandwidth_Hz=100.0)
    assert g2.ki == pytest.approx(2 * math.pi * 100 / K) and "given bandwidth" in g2.rule
    with pytest.raises(ConfigError):
        auto_pid(_static(K, dt), bandwidth_Hz=6000.0)


def test_auto_pid_backs_off_on_a_resonant_nominal_plant():
    dt = 1e-4
    wn, zeta = 2 * math.pi * 1200, 0.05
    b, a = signal.bilinear([wn * wn], [1, 2 * zeta * wn, wn * wn], fs=1 / dt)
    num, den = 0.3 * b, np.r_[a, 0.0]
    A, B, C, _ = signal.tf2ss(num, den)
    nominal = NominalPlant(num, den, A, B[:, 0], C[0], dt, 0.3, "second-order", 0.0, "resonant")
    g = auto_pid(nominal)
    assert g.bandwidth_Hz < 500 and g.gain_margin >= 2 * 0.999 and g.phase_margin_deg >= 45 - 0.1


def test_a_bandwidth_that_makes_the_nominal_loop_unstable_is_refused_with_the_highest_safe_one():
    """Found by a blind test: --bandwidth 1000 Hz on a 5 kHz loop gave GM 0.61, a run whose error
    diverged, and exit 0. Now: one line with the margins and what to give."""
    dt, K = 2e-4, 0.31
    with pytest.raises(ConfigError, match=r"--bandwidth 1000 Hz makes the nominal loop unstable \(GM = 0\.\d+.*"
                                          r"at most 250 Hz keeps GM ≥ 2 and PM ≥ 45°"):
        auto_pid(_static(K, dt), bandwidth_Hz=1000.0)
    g = auto_pid(_static(K, dt), bandwidth_Hz=400.0)  # lower margins than the rule's, but stable: the user's choice
    assert 1 < g.gain_margin < 2 and "given bandwidth" in g.rule


def test_margins_without_a_crossing_are_said_in_words():
    from hystfit.track import margins_text

    assert margins_text(2.5, 61.0) == "GM = 2.5, PM = 61°"
    assert "inf" not in margins_text(float("inf"), float("inf"))
    assert "PM: none" in margins_text(0.5, float("inf")) and "GM = ∞" in margins_text(float("inf"), 30.0)


def test_nominal_plant_of_a_rate_dependent_model_recovers_its_dynamics():
    pf = lag_table(0.3, 1e-3, 1e-4)
    inv = invert_target(pf, sine_target(5.0, 10.0, cycles=1))
    nom = nominal_plant(pf, inv.choices, 1e-4)
    assert nom.kind == "second-order" and nom.fit_nrmse_pct < 1e-6
    a = math.exp(-0.1)
    w = np.array([1.0, 300.0, 3000.0])
    expected = (1 - a) * 0.3 / (np.exp(1j * w * 1e-4) - a)  # z⁻¹·P(z)
    gain = pf.cells[0].scale.gain
    np.testing.assert_allclose(nom.frequency_response(w), expected * gain / 0.3, rtol=1e-6)
    assert nominal_plant(pi_table(), invert_target(pi_table(), sine_target(5, 10, 1)).choices, 1e-4).kind == "static"


def test_step_metrics_of_a_first_order_response():
    fs, tau = 10_000.0, 2e-3
    tgt = steps_target((2.0,), hold_s=0.05, fs=fs, offset=1.0, lead_s=0.01)
    k0 = tgt.steps[0].index
    t = np.arange(tgt.n - k0) / fs
    y = np.r_[np.full(k0, 1.0), 1.0 + 2.0 * (1 - np.exp(-t / tau))]
    (m,) = step_metrics(tgt, y)
    T = 1 / fs
    assert m["t90_s"] == pytest.approx(tau * math.log(10), abs=T)
    assert m["rise_time_s"] == pytest.approx(tau * math.log(9), abs=T)
    assert m["settling_time_5pct_s"] == pytest.approx(tau * math.log(20), abs=T)
    assert m["settling_time_2pct_s"] == pytest.approx(tau * math.log(50), abs=T)
    assert m["overshoot_pct"] == 0.0 and abs(m["steady_state_error_um"]) < 1e-6
    y2 = y.copy()
    y2[-1] = 0.0  # leaves the band at the very end: not settled
    assert math.isnan(step_metrics(tgt, y2)[0]["settling_time_2pct_s"])
    # paper 002 Table 6's emax/RMSE of a step: after the transient (from the ±5 % settling time)
    ks = int(round(m["settling_time_5pct_s"] * fs))
    e = 2.0 * np.exp(-t[ks:] / tau)
    assert m["e_max_settled_um"] == pytest.approx(e.max(), rel=1e-9) and m["e_max_settled_um"] <= 0.05 * 2.0
    assert m["rmse_settled_um"] == pytest.approx(np.sqrt(np.mean(e ** 2)), rel=1e-9)
    assert math.isnan(step_metrics(tgt, 1.0 + 0.5 * (y - 1.0))[0]["rmse_settled_um"])  # never settles


def test_feedforward_loop_reproduces_the_invert_preview():
    pf = pi_table()
    tgt = sine_target(10.0, 20.0, cycles=2, offset=2.0)
    res = track(pf, tgt, ["ff"])
    run = res.runs[0]
    np.testing.assert_allclose(run.output, res.inversion.predicted, atol=1e-9)
    np.testing.assert_allclose(run.voltage_V, res.inversion.voltage_V, atol=1e-12)
    assert run.metrics["max_error_um"] < 1e-9 and res.pid is None and res.smc is None


def test_feedback_corrects_a_plant_that_differs_from_the_model():
    pf, plant = pi_table(), pi_table(1.15, "plant.json")  # the real stage is 15 % stiffer in gain
    tgt = sine_target(10.0, 10.0, cycles=2, offset=2.0)
    res = track(pf, tgt, ["ff", "pid", "ff+pid", "smc"], plant_pf=plant)
    rmse = {r.controller: r.metrics["rmse_pct_of_stroke"] for r in res.runs}
    assert rmse["ff"] > 5  # open loop: the gain error shows fully
    assert rmse["ff+pid"] < rmse["pid"] < rmse["ff"] and rmse["smc"] < rmse["pid"]
    assert rmse["ff+pid"] < 0.2 and rmse["smc"] < 0.2
    assert res.plant_path == "plant.json" and [r["controller"] for r in res.table()] == ["ff", "pid", "ff+pid", "smc"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sliding_mode_stays_bounded_with_noise(seed):
    pf, plant = pi_table(), pi_table(0.9, "plant.json")
    tgt = sine_target(10.0, 10.0, cycles=3, offset=2.0)
    sigma = 0.05
    res = track(pf, tgt, ["smc"], plant_pf=plant, noise_std=sigma, seed=seed)
    run = res.runs[0]
    lo, hi = res.limits["vmin_V"], res.limits["vmax_V"]
    assert np.all(np.isfinite(run.output)) and lo <= run.voltage_V.min() and run.voltage_V.max() <= hi
    assert run.metrics["max_error_um"] < 10 * sigma and run.metrics["rmse_um"] < 2 * sigma
    # the noise passes to the voltage only through the integral and the tanh boundary layer: no chattering
    assert np.std(np.diff(run.voltage_V - res.inversion.desired_voltage_V)) < 0.5
    assert np.std(run.measured - run.output) == pytest.approx(sigma, rel=0.1)


def test_sliding_mode_design_places_the_integral_pole():
    dt = 1e-4
    smc = design_smc(_static(0.3, dt), 500.0, 72.0)
    zs = math.exp(-2 * math.pi * 500 * dt)
    assert smc.Mx @ smc.B == pytest.approx(1.0)  # M·B_d = 1 (003 eq. 36)
    # on S = 0 the state (the last correction) is x = −Mp·p/Mx, so p[k+1] = p + Ts·C·x = (1 − Ts·C·Mp/Mx)·p:
    # the integral mode has the placed pole z_s
    assert 1 - dt * float(smc.C[0]) * smc.Mp / smc.Mx[0] == pytest.approx(zs)
    assert smc.alpha * smc.eps * dt + smc.q * dt < 1.0


def test_anti_windup_recovers_after_saturation():
    pf = pi_table()
    tgt = steps_target((14.0, 4.0), hold_s=0.03, fs=10_000.0, offset=2.0, lead_s=0.005)
    inv = invert_target(pf, tgt)
    vmax = float(inv.desired_voltage_V.max()) - 6.0  # the 16 um level is out of reach
    for aw in ("backcalc", "clamp"):
        res = track(pf, tgt, ["pid"], vmax=vmax, anti_windup=aw)
        run = res.runs[0]
        assert run.limit_spans and run.voltage_V.max() <= vmax + 1e-12
        k1 = tgt.steps[1].index
        late = np.abs(run.error[k1 + 30:tgt.steps[1].stop])  # 3 ms after stepping back into reach
        assert late.max() < 0.05 * tgt.stroke, aw


def test_option_validation():
    pf = pi_table()
    tgt = sine_target(10.0, 10.0, cycles=1)
    for kw in ({"noise_std": -1.0}, {"anti_windup": "none"}, {"max_slew": -5.0}, {"kp": -1.0},
               {"kp": 0.0, "ki": 0.0, "kd": 0.0}):
        with pytest.raises(ConfigError):
            track(pf, tgt, ["pid"], **kw)
    for bad in ("", "pid,pid", "lqr", "ff,"):
        with pytest.raises(ConfigError):
            parse_controllers(bad)
    assert parse_controllers("PID, ff+pid") == ["pid", "ff+pid"]
    g = given_pid(_static(0.3, 1e-4), 1.0, 100.0, 1e-2)  # Ti = Kp/Ki = 10 ms, Td = Kd/Kp = 10 ms
    assert g.tf_s == pytest.approx(1e-3) and g.tt_s == pytest.approx(0.01)  # Tf = Td/10, Tt = √(Ti·Td)
    assert given_pid(_static(0.3, 1e-4), 0.0, 100.0, 0.0).tt_s == pytest.approx(1e-4)  # pure I: Tt = Ts


@pytest.mark.parametrize("name", models.names())
def test_every_registered_model_runs_as_a_plant(name):
    """Stepping through the pre-roll reproduces the invert preview (ff), and the feedback loops stay finite."""
    dt = 1e-4
    u = 30.0 * (1 - np.cos(2 * np.pi * 10 * np.arange(2001) * dt))
    sc = DataScale.from_arrays([u], [0.3 * u + 0.25], [dt])
    cls = models.get(name)
    model = cls.example(sc)
    theta = np.array([p.default for p in model.params(sc)])
    pf = ParamsFile("m.json", name, "um", "global", (Cell("global", float("nan"), float("nan"), model, theta, sc),),
                    {})
    y = model.simulate_one(theta, u, dt)
    res = track(pf, target_from_array(y[:1200], dt), ["ff", "ff+pid", "smc"], vmin=-1e3, vmax=1e3)
    ff = res.runs[0]
    np.testing.assert_allclose(ff.output, res.inversion.predicted, rtol=0, atol=1e-9 * np.ptp(y))
    for run in res.runs:
        assert np.all(np.isfinite(run.output)) and run.metrics["rmse_pct_of_stroke"] < 0.5


def test_feedback_on_a_stage_whose_displacement_falls_with_the_voltage():
    """An inverted sensor: the table's weights are negative (DataScale.sign = −1), K < 0, and the
    automatic and the given PID gains take K's sign, so the loop is stable and corrects a gain error."""
    def inverted(scale_w, path):
        w = -np.asarray(DEFAULT_WEIGHTS_UM_PER_V) * scale_w
        sc = DataScale(0.0, 60.0, 100.0 - 0.31 * 60, 100.0, 1e-4, 4000.0, sign=-1.0)
        cell = Cell("60V_10Hz", 60.0, 10.0, PI(10, thresholds_V=DEFAULT_THRESHOLDS_V), np.r_[w, 100.0], sc)
        return ParamsFile(path, "pi", "um", "per-condition", (cell,), {})

    pf, plant = inverted(1.0, "pi.json"), inverted(1.15, "plant.json")
    up = sine_target(10.0, 10.0, cycles=2, offset=2.0)  # the mirror image of the rising stage's test
    tgt = target_from_array(100.0 - up.y, up.dt, frequency_Hz=10.0)
    res = track(pf, tgt, ["ff", "pid", "ff+pid"], plant_pf=plant)
    rmse = {r.controller: r.metrics["rmse_pct_of_stroke"] for r in res.runs}
    assert res.pid.kp < 0 and res.pid.ki < 0 and res.pid.gain_margin >= 2
    assert rmse["ff"] > 5 and rmse["ff+pid"] < 0.2 and rmse["pid"] < rmse["ff"]
    given = given_pid(nominal_plant(pf, res.inversion.choices, 1e-4), 0.0, 2000.0, 0.0)
    assert given.ki < 0 and "sign of K" in given.rule


# ----------------------------------------------------------------------------------------------
# sliding mode of paper 003: design options, observer, without inverse compensation, bandwidths


def test_smc_design_options_and_the_observer_of_003():
    from hystfit.track import SMC_OPTIONS, check_smc_options

    pf = pi_table()
    nom = nominal_plant(pf, invert_target(pf, sine_target(5, 10, 1)).choices, 1e-4)
    base = design_smc(nom, 300.0, 66.0)
    assert not np.any(base.G)  # default: G = 0 (module docstring)
    n = nom.A.shape[0]
    obs = [0.3] * n
    sl = [0.8] + [0.1] * (n - 1)
    d = design_smc(nom, 300.0, 66.0, eps=50.0, alpha=2.0, k=1000.0, sliding_poles=sl, observer_poles=obs)
    assert (d.eps, d.alpha, d.q) == (50.0, 2.0, 1000.0)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(nom.A - np.outer(d.G, nom.C)).real), obs, atol=1e-9)
    # the sliding motion (S = 0 enforced: δ = −(M B)⁻¹ M A x) has the chosen poles
    Ad = np.block([[nom.A, np.zeros((n, 1))], [1e-4 * nom.C[None, :], np.ones((1, 1))]])
    Bd = np.r_[nom.B, 0.0]
    M = np.r_[d.Mx, d.Mp]
    closed = Ad - np.outer(Bd, M @ Ad) / (M @ Bd)
    ev = np.sort(np.abs(np.linalg.eigvals(closed)))
    np.testing.assert_allclose(ev[ev > 1e-6], sorted(p for p in sl if p > 1e-6), atol=1e-6)
    for bad, word in (({"sliding_poles": [0.5] * (n + 1)}, "sliding_poles"), ({"observer_poles": [1.2] * n}, "unit circle"),
                      ({"eps": -1.0}, "eps"), ({"k": 1e9}, "k")):
        with pytest.raises(ConfigError, match=word):
            design_smc(nom, 300.0, 66.0, **bad)
    with pytest.raises(ConfigError, match="unknown"):
        check_smc_options({"gain": 1})
    assert set(SMC_OPTIONS) == {"eps", "alpha", "k", "sliding_poles", "observer_poles"}


def test_smc_without_inverse_compensation_tracks_on_feedback_alone():
    pf = pi_table()
    tgt = sine_target(10.0, 5.0, cycles=2, offset=2.0)
    res = track(pf, tgt, ["smc", "smc-noinv"], smc_options={"observer_poles": [0.5]})
    smc, noinv = res.runs
    assert noinv.details["uses_feedforward"] is False and smc.details["uses_feedforward"] is True
    assert smc.metrics["rmse_um"] < 1e-9  # perfect model: the feedforward does it all
    assert 1e-3 < noinv.metrics["rmse_um"] < 0.02 * 10.0  # the sliding mode alone: small, not zero


def test_measured_bandwidths_of_feedback_and_feedforward():
    from hystfit.track import measure_bandwidths

    bw = measure_bandwidths(pi_table(), ["pid", "ff", "smc-noinv"], amplitude=2.0, offset=5.0, fs=10_000.0,
                            freqs_Hz=[5.0, 50.0, 200.0, 500.0, 1000.0, 2000.0])
    pid, ff, noinv = (bw["controllers"][c] for c in ("pid", "ff", "smc-noinv"))
    # the automatic PID aims at a crossover ≈ fs/20 = 500 Hz: −3 dB a little below it
    assert 150.0 < pid["tracking_bandwidth_Hz"] < 600.0
    assert pid["sensitivity_gain"][0] < 0.05 and pid["disturbance_bandwidth_Hz"] > 200.0
    assert math.isnan(ff["tracking_bandwidth_Hz"])  # perfect model: |T| = 1 at every frequency
    assert ff["disturbance_bandwidth_Hz"] == 0.0 and np.allclose(ff["sensitivity_gain"], 1.0)  # no feedback
    assert 100.0 < noinv["tracking_bandwidth_Hz"] < 1000.0


def test_design_controllers_designs_only_what_the_controllers_need():
    from hystfit.track import ControllerDesign, design_controllers

    nominal = nominal_plant(pi_table(), invert_target(pi_table(), sine_target(10.0, 10.0, 2, 1e4)).choices, 1e-4)
    d = design_controllers(nominal, ["ff"], 60.0)
    assert isinstance(d, ControllerDesign) and d.pid is None and d.smc is None
    d = design_controllers(nominal, ["ff+pid", "smc"], 60.0, kp=0.5)
    assert d.pid.kp == 0.5 and d.pid.ki == 0.0 and d.smc is not None


def _stage_table(fn_Hz: float = 800.0, zeta: float = 0.05) -> ParamsFile:
    """pi+dynamics at its default weights, with a lightly damped stage."""
    from hystfit.factory import make_model

    sc = DataScale(0.0, 60.0, 0.25, 0.25 + 0.31 * 60, 1e-4, 4000.0)
    m = make_model("pi+dynamics", {}).adapt(sc)
    names = [p.name for p in m.params(sc)]
    theta = np.array([p.default for p in m.params(sc)], float)
    theta[names.index("dynamics.fn_Hz")], theta[names.index("dynamics.zeta")] = fn_Hz, zeta
    return ParamsFile("stage.json", "pi+dynamics", "um", "per-condition", (Cell("60V_10Hz", 60.0, 10.0, m, theta, sc),), {})


def test_a_step_through_a_resonant_stage_is_said_to_be_too_fast_for_it():
    """A blind test's find: a 10 µm step through pi+…+dynamics asked for a voltage impulse, clipped
    by the limits; the feedforward overshot 25 % and ff+pid 116 %, with only a count of limited
    samples said. The inversion now says why and what to do."""
    pf = _stage_table()
    inv = invert_target(pf, steps_target((10.0,), hold_s=0.02, fs=1e4, offset=2.0))
    assert inv.clip_spans
    said = [n for n in inv.notes if "faster than the model's stage (f_n = 800 Hz)" in n]
    assert said and "rise time" in said[0] and "pid alone" in said[0], inv.notes
    # a slow sine through the same stage, partly below what 0 V reaches: clipped for as long as it is
    # there (milliseconds, the limits' own report), not a stage's spike: nothing said about the stage
    inv = invert_target(pf, sine_target(10.0, 10.0, cycles=2, offset=2.0))
    assert inv.clip_spans and not any("faster than" in n for n in inv.notes)
    # clipping without a stage (a static PI asked for more than its limits) is another matter
    inv = invert_target(pi_table(), steps_target((10.0,), hold_s=0.02, fs=1e4, offset=2.0), vmax=30.0)
    assert inv.clip_spans and not any("faster than" in n for n in inv.notes)


def test_a_target_outside_the_identified_outputs_is_said_to_be_so():
    """A blind test's find: a 0…10 µm target against a table identified on −21…−1.2 µm gave only a
    clipping warning and a 51 % error. The inversion now says where the target lies and how far to
    move it (the table here: 0.25…18.85 µm)."""
    pf = pi_table()
    out = invert_target(pf, sine_target(10.0, 10.0, cycles=2, offset=15.0))  # 15…25 µm
    said = [n for n in out.notes if "outside the outputs the table was identified on" in n]
    assert said and "move it by -6.15 um (--offset for a built-in target)" in said[0], out.notes
    inside = invert_target(pf, sine_target(10.0, 10.0, cycles=2, offset=2.0))
    assert not any("outside the outputs" in n for n in inside.notes)
    # a one-cell table's lookup is that cell's condition (report.json said 1 V, a placeholder)
    assert inside.choices[0].how == "single cell" and inside.choices[0].query == (60.0, 10.0)
    wide = invert_target(pf, sine_target(30.0, 10.0, cycles=2, offset=0.0), vmax=80.0)
    assert any("stroke is larger than the identified one" in n for n in wide.notes)


def test_the_nominal_gain_carries_the_tables_unit():
    """A blind test's find: the track report read "static gain 0.3178 per V"; every other number had
    its unit."""
    pf = pi_table()
    inv = invert_target(pf, sine_target(5.0, 10.0, cycles=1))
    nom = nominal_plant(pf, inv.choices, 1e-4)
    assert " µm/V with one sample of delay" in nom.description and nom.unit == "um"
    assert "µm/V" in auto_pid(nom).rule
    assert "per V" in _static(0.3, 1e-4).description  # no unit given: words without one


def test_a_loop_that_does_not_hold_the_target_is_a_warning_naming_the_cause():
    """A blind test's find: pid on a stage with a lightly damped resonance ran to 1030 % of the
    stroke, and only "the voltage limits acted" was said. A feedback loop whose RMS error exceeds
    half the stroke, or that sits at the limits most of the time, is now a warning; ff never is."""
    from types import SimpleNamespace

    from hystfit.track import lost_loop_note

    n = 1000
    target = SimpleNamespace(y=np.sin(np.linspace(0, 6.28, n)) * 5 + 5, n=n)
    nominal = SimpleNamespace(description="second-order fit (NRMSE 3.6 %)")

    def run(name, err, limited=0):
        return SimpleNamespace(controller=name, error=err, limit_spans=(SimpleNamespace(n=limited),) if limited else ())

    wild = np.sin(np.linspace(0, 600, n)) * 80
    note = lost_loop_note(run("pid", wild, 740), target, nominal)
    assert note.startswith("warning: pid: the closed loop does not hold the target") and "unstable" in note
    assert "--bandwidth" in note and "NRMSE 3.6 %" in note
    assert lost_loop_note(run("ff", wild), target, nominal) is None
    assert lost_loop_note(run("ff+pid", np.full(n, 0.05)), target, nominal) is None
    assert "limits 60 %" in lost_loop_note(run("smc", np.full(n, 0.05), 600), target, nominal)
