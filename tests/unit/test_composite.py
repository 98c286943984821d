"""Composite models ``BASE+BLOCK+...``: expressions, equivalences, joint identification, inverse, files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hystfit import synth
from hystfit.capture import Capture
from hystfit.errors import ConfigError
from hystfit.identify import identify
from hystfit.objective import Objective, Series
from hystfit.params import DataScale
from hystfit.registry import optimizers
from hystfit.results import identify_to_dict, load_params
from hystfit.factory import make_model, make_optimizer

DT = 1e-4
TRUE_R = list(synth.DEFAULT_THRESHOLDS_V)


# ----------------------------------------------------------------------------------------------
# expressions


def test_expression_builds_a_composite_in_the_written_order():
    m = make_model("PI + creep+delay")
    assert m.name == "pi+creep+delay"
    base, blocks = m.composition
    assert base.name == "pi" and [b.name for b in blocks] == ["creep", "delay"]
    assert make_model("pi").composition is None


@pytest.mark.parametrize("expr, words", [
    ("pi+thermal", ["unknown block 'thermal'", "valid blocks", "creep"]),
    ("pi+creep+creep", ["appears twice"]),
    ("creep+pi", ["is a block"]),
    ("pi++delay", ["expected BASE[+BLOCK...]"]),
    ("foo+delay", ["unknown model 'foo'"]),
])
def test_bad_expressions_are_one_line_config_errors(expr, words):
    with pytest.raises(ConfigError) as exc:
        make_model(expr)
    msg = str(exc.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_options_go_to_the_base_or_to_a_block():
    m = make_model("pi+creep", {"n_operators": 6, "creep.tau_s": [0.02, 0.3]})
    assert m.base.n_operators == 6
    assert m.blocks[0].tau_s == (0.02, 0.3)
    with pytest.raises(ConfigError, match="no block 'delay'"):
        make_model("pi+creep", {"delay.max_delay_s": 0.001})
    with pytest.raises(ConfigError, match="unknown option"):
        make_model("pi+creep", {"creep.nope": 1})


def test_parameter_names_are_prefixed_by_block():
    m = make_model("pi+dynamics+delay").adapt(DataScale(0, 60, 0, 20, DT, 1e4, 1.0, 1.0))
    names = [p.name for p in m.params(DataScale(0, 60, 0, 20, DT, 1e4, 1.0, 1.0))]
    assert names[-3:] == ["dynamics.fn_Hz", "dynamics.zeta", "delay.delay_s"]


# ----------------------------------------------------------------------------------------------
# one implementation: pi2 is gpi+dynamics (paper 000); the classical-PI variant is pi+dynamics


def test_gpi_plus_dynamics_equals_pi2(rng):
    from hystfit.models.gpi import GPI

    t, u = synth.raised_cosine(60.0, 40.0, 3, 10_000)
    scale = DataScale.from_arrays([u], [0.3 * u], [DT])
    theta = np.r_[[p.default for p in GPI().params(scale)], 900.0, 0.2]
    comp = make_model("gpi+dynamics")
    pi2 = make_model("pi2", {"identification": "joint"})
    np.testing.assert_allclose(comp.simulate_one(theta, u, DT), pi2.simulate_one(theta, u, DT), rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------------
# joint identification recovers a known plant


def _plant_captures(eff: synth.Effects, freqs=(20.0, 50.0), cycles=10, amplitude=60.0, rising=True, seed=0):
    plant = synth.Plant.default().with_effects(eff)
    caps = []
    for i, f in enumerate(freqs):
        t, u = (synth.rising_sine if rising else synth.raised_cosine)(amplitude, f, cycles, 10_000)
        y = synth.simulate_plant(plant, t, u, seed=seed + i)
        caps.append(Capture(source=f"f{f:g}.csv", t=t, u=u, y=y, dt=DT, y_unit="um",
                            amplitude_V=float(np.ptp(u)), frequency_Hz=f))
    return caps


@pytest.mark.slow
def test_joint_identification_recovers_stage_creep_and_delay():
    """Virtual plant with asymmetry, two creep time constants, a 450 Hz stage (ζ 0.1) and a 0.5 ms
    delay, identified with the matching composite (true thresholds and time constants as
    structure): the noise floor, f_n within 2 %, the delay within one sample, the total creep
    gain within 10 %."""
    sigma = 0.01
    eff = synth.Effects(asymmetry=True, creep=True, creep_tau_s=(0.02, 0.3), creep_gain=(0.03, 0.02),
                        dynamics=True, dynamics_fn_Hz=450.0, dynamics_zeta=0.1, delay=True, delay_s=0.5e-3,
                        noise=True, noise_sigma_um=sigma)
    caps = _plant_captures(eff, freqs=(20.0, 100.0), cycles=20)
    model = make_model("pi+asymmetry+creep+dynamics+delay", {"thresholds_V": TRUE_R, "creep.tau_s": [0.02, 0.3]})
    res = identify(caps, model, make_optimizer(optimizers.get("auto")), global_fit=True, seed=0)
    fit = res.fits[0]
    vals = dict(zip([p.name for p in fit.params], fit.theta))
    assert fit.metrics["rmse_um"] <= 1.2 * sigma
    assert vals["dynamics.fn_Hz"] == pytest.approx(450.0, rel=0.02)
    assert abs(vals["delay.delay_s"] - 0.5e-3) <= DT
    total_true = 0.05 / 1.05  # the virtual actuator's gains g_i are c_i·(1 + Σg)
    assert vals["creep.c0"] + vals["creep.c1"] == pytest.approx(total_true, rel=0.10)


def test_drift_offsets_are_fitted_per_capture_and_reported():
    """Two captures of one plant whose sensor was re-zeroed in between: pi+drift takes the offset
    and rate of each capture out; plain pi cannot."""
    caps = _plant_captures(synth.Effects(noise=True, noise_sigma_um=0.005), freqs=(20.0, 20.0), rising=False, cycles=4)
    t = caps[1].t
    caps[1] = Capture(source="later.csv", t=t, u=caps[1].u, y=caps[1].y + 0.9 + 0.05 * t, dt=DT, y_unit="um",
                      amplitude_V=caps[1].amplitude_V, frequency_Hz=20.0)
    opt = make_optimizer(optimizers.get("auto"))
    opts = {"thresholds_V": TRUE_R}
    plain = identify(caps, make_model("pi", opts), opt, global_fit=True).fits[0]
    drift = identify(caps, make_model("pi+drift", opts), opt, global_fit=True).fits[0]
    assert drift.metrics["rmse_um"] < 1.2 * 0.005 and plain.metrics["rmse_um"] > 0.1
    d = drift.per_capture
    assert d[1]["drift_offset_um"] - d[0]["drift_offset_um"] == pytest.approx(0.9, abs=0.02)
    assert d[1]["drift_rate_um_per_s"] - d[0]["drift_rate_um_per_s"] == pytest.approx(0.05, abs=0.02)


# ----------------------------------------------------------------------------------------------
# inverse and stepping through a composite


def _fitted_theta(model, u, scale):
    ps = model.params(scale)
    th = np.array([p.default for p in ps])
    names = [p.name for p in ps]
    n = model.base.n_operators
    th[:n] = np.array(synth.DEFAULT_WEIGHTS_UM_PER_V)[:n]
    for k, v in {"creep.c0": 0.02, "creep.c1": 0.015, "dynamics.fn_Hz": 900.0, "dynamics.zeta": 0.3,
                 "asymmetry.a2": -0.4, "asymmetry.a3": 0.05, "delay.delay_s": 2.5e-4}.items():
        if k in names:
            th[names.index(k)] = v
    return th


def test_feedforward_through_a_composite_follows_the_target():
    expr = "pi+asymmetry+creep+dynamics+delay"
    model = make_model(expr, {"thresholds_V": TRUE_R, "creep.tau_s": [0.02, 0.3]})
    t = np.arange(20_000) * DT
    target = 0.25 + 7.0 * (1 - np.cos(2 * np.pi * 5.0 * t))
    scale = DataScale(0.0, 60.0, 0.25, 14.25, DT, 2e3, 1.0, 2.0)
    model = model.adapt(scale)
    th = _fitted_theta(model, None, scale)
    u = model.invert(th, target, DT)
    y = model.simulate_one(th, u, DT)
    err = y[200:] - target[200:]
    assert np.sqrt(np.mean(err ** 2)) < 0.002 * np.ptp(target)  # 0.2 % of the stroke


def test_stepping_a_composite_reproduces_its_simulation():
    model = make_model("pi+creep+dynamics+delay+asymmetry", {"thresholds_V": TRUE_R})
    scale = DataScale(0.0, 60.0, 0.25, 14.25, DT, 2e3, 1.0, 0.5)
    model = model.adapt(scale)
    th = _fitted_theta(model, None, scale)
    _, u = synth.raised_cosine(50.0, 40.0, 2, 10_000)
    ref = model.simulate_one(th, u, DT)
    state = model.initial_state(th, u[0], DT)
    out = [ref[0]]
    for k in range(1, u.size):
        y, st = model.step(th, state, u[k - 1], np.array([u[k]]), DT)
        out.append(float(y[0]))
        state = st[0]
    np.testing.assert_allclose(out, ref, atol=1e-9)


# ----------------------------------------------------------------------------------------------
# params.json


def test_params_file_round_trip_of_a_composite(tmp_path):
    caps = _plant_captures(synth.Effects(creep=True, delay=True, noise=True), freqs=(20.0,), rising=False, cycles=4)
    res = identify(caps, make_model("pi+creep+delay"), make_optimizer(optimizers.get("auto")))
    data = identify_to_dict(res)
    assert data["schema_version"] == 2
    assert data["model"]["name"] == "pi+creep+delay" and data["model"]["blocks"] == ["creep", "delay"]
    cond = data["conditions"][0]
    assert [b["name"] for b in cond["blocks"]] == ["creep", "delay"]
    assert "delay_s" in cond["blocks"][1]["parameters"]
    path = tmp_path / "params.json"
    path.write_text(json.dumps(data))
    pf = load_params(path)
    cell = pf.cells[0]
    np.testing.assert_allclose(cell.predict(caps[0].u, DT), res.fits[0].predictions[0], atol=1e-9)


def test_version_1_params_files_still_load(tmp_path):
    caps = _plant_captures(synth.Effects(noise=True), freqs=(20.0,), rising=False, cycles=3)
    data = identify_to_dict(identify(caps, make_model("pi"), make_optimizer(optimizers.get("auto"))))
    data["schema_version"] = 1
    for key in ("base", "blocks"):
        data["model"].pop(key)
    for c in data["conditions"]:
        c["data_scale"].pop("duration_s")
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    pf = load_params(path)
    assert pf.model_name == "pi" and len(pf.cells) == 1


def test_lti_block_is_identified_from_broadband_captures_and_matches_hammerstein():
    """pi+lti: the ERA stage identified once from the broadband captures, the PI fitted through it."""
    from hystfit.io import LoadOptions, load_captures

    caps = load_captures([str(Path(__file__).resolve().parents[2] / "sample_data" / "broadband")], LoadOptions())
    opt = make_optimizer(optimizers.get("auto"))
    comp = identify(caps, make_model("pi+lti"), opt, global_fit=True).fits[0]
    ham = identify(caps, make_model("hammerstein"), opt, global_fit=True).fits[0]
    plain = identify(caps, make_model("pi"), opt, global_fit=True).fits[0]
    assert comp.model.blocks[0].order > 0 and comp.model.blocks[0].method == "era"
    assert comp.metrics["rmse_um"] < 0.02 * plain.metrics["rmse_um"]
    assert comp.metrics["rmse_um"] <= 1.05 * ham.metrics["rmse_um"]


def test_lti_block_refuses_sine_only_data():
    caps = _plant_captures(synth.Effects(dynamics=True), freqs=(20.0,), rising=False, cycles=3)
    with pytest.raises(ConfigError, match="no broadband capture"):
        make_model("pi+lti").prepare(caps)


def test_natural_frequency_of_a_stage_is_read_from_theta_or_the_structure():
    """What simulate checks against a capture's Nyquist frequency (check_below_nyquist)."""
    from hystfit.blocks.dynamics import check_below_nyquist
    from hystfit.models.pi2 import PI2

    sc = DataScale(0.0, 60.0, 0.0, 20.0, 1e-4, 4000.0)
    m = make_model("pi+dynamics").adapt(sc)
    theta = np.array([p.default for p in m.params(sc)])
    names = [p.name for p in m.params(sc)]
    theta[names.index("dynamics.fn_Hz")] = 1234.0
    assert m.natural_frequency_Hz(theta) == 1234.0
    assert make_model("pi+delay").natural_frequency_Hz(np.zeros(len(make_model("pi+delay").params(sc)))) is None
    two_step = PI2(fn_Hz=900.0, zeta=0.2)
    assert two_step.natural_frequency_Hz(np.zeros(len(two_step.params(sc)))) == 900.0
    assert PI2().natural_frequency_Hz(np.zeros(len(PI2().params(sc)))) is None  # not identified yet
    check_below_nyquist(1234.0, 1e-4, "x")  # 5 kHz Nyquist
    with pytest.raises(ConfigError, match="^x: the stage's natural frequency f_n = 1234 Hz is not below the Nyquist "
                                          "frequency 500 Hz of data sampled at 1000 Hz; use data sampled above 2468 Hz"):
        check_below_nyquist(1234.0, 1e-3, "x")


def test_feedforward_of_a_creep_model_starts_settled_at_the_initial_voltage():
    """A PI base with creep (time constants of seconds) rests at the initial voltage from the first
    pre-roll sample on: its play operators as after a monotone ramp, the creep at rest at their
    output — the stage settled there, as an identification capture starts settled at its first
    voltage. Driven from rest at its first voltage, the model itself then follows the target
    (a blind test: a plant resting at v0 tracked with a 0.047 µm bias after the 50 ms ramp and rest
    assumed before, 0.0055 µm now). A plain PI keeps its 16 + 4-sample ramp."""
    from hystfit.invert import invert_target, preroll_voltage, sine_target
    from hystfit.results import Cell, ParamsFile

    model = make_model("pi+creep", {"thresholds_V": TRUE_R, "creep.tau_s": [0.1, 1.0, 10.0]})
    scale = DataScale(0.0, 60.0, 0.25, 14.25, DT, 2e3, 1.0, 2.0)
    model = model.adapt(scale)
    ps = model.params(scale)
    th = np.array([p.default for p in ps])
    names = [p.name for p in ps]
    th[:model.base.n_operators] = np.array(synth.DEFAULT_WEIGHTS_UM_PER_V)[:model.base.n_operators]
    for k, v in {"y0": 0.25, "creep.c0": 0.01, "creep.c1": 0.01, "creep.c2": 0.01}.items():
        th[names.index(k)] = v
    cell = Cell("60V_10Hz", 60.0, 10.0, model, th, scale)
    pre = preroll_voltage(cell, 12.0, DT)
    assert pre.size == 4 and np.all(pre == 12.0)
    pi_only = Cell("60V_10Hz", 60.0, 10.0, model.base, th[:model.base.n_operators + 1], scale)
    assert preroll_voltage(pi_only, 12.0, DT)[0] == 0.0  # the ramp from 0 V stays for a plain PI
    target = sine_target(6.0, 30.0, 10, 1 / DT, offset=1.5)
    res = invert_target(ParamsFile("t.json", model.name, "um", "per-condition", (cell,), {}), target)
    assert res.voltage_V.min() > 0.0 and not res.clip_spans
    y = model.simulate_one(th, res.voltage_V, DT)  # the stage at rest at the first voltage
    err = y - target.y
    assert np.sqrt(np.mean(err ** 2)) < 1e-3 * np.ptp(target.y), np.sqrt(np.mean(err ** 2))
