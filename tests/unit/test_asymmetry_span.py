"""The asymmetry block's middle and half-range: the span of the signal it bends (the hysteresis
output), not the measured output's range, which a lightly damped stage widens by its ringing
after steps and on a PRBS (the blind campaign's seed 9090 at strength 2: h 36.6 µm instead of
10.5 µm and a₂ at its bound)."""

from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np
import pytest

import hystfit.diagnose as diag
from hystfit.blocks.asymmetry import MAX_COEF, Asymmetry
from hystfit.capture import Capture
from hystfit.effects import CaptureView
from hystfit.factory import make_model, make_optimizer
from hystfit.identify import adapted_model, fit_captures, identify
from hystfit.params import DataScale, bound_side, output_span
from hystfit.registry import optimizers
from hystfit.synth import DEFAULT_THRESHOLDS_V, Effects, Plant, prbs, raised_cosine, simulate_plant, steps

DT = 1e-4
A2 = -0.24  # the virtual actuator's bow at strength 2: z + a·z(z − s)/s
#: the seed-9090 campaign's stage at strength 2 (the default 1.2 kHz halved), lightly damped
STAGE = dict(dynamics=True, dynamics_fn_Hz=600.0, dynamics_zeta=0.15)


def _captures(effects: Effects, sigma: float = 0.0, seed: int = 0) -> list[Capture]:
    """A 60 V raised cosine at 20 Hz (3 cycles) and a 0…60 V PRBS (2.5 kHz clock, 0.3 s)."""
    rng = np.random.default_rng(seed)
    drives = (raised_cosine(60.0, 20.0, 3, 1 / DT) + (20.0,), prbs(60.0, 1 / DT, 0.3, 2500.0, seed=1) + (np.nan,))
    plant = Plant(effects=effects)
    return [Capture(f"c{i}", t, u, simulate_plant(plant, t, u) + sigma * rng.standard_normal(t.size), DT,
                    amplitude_V=60.0, frequency_Hz=f) for i, (t, u, f) in enumerate(drives)]


def _hysteresis_range() -> tuple[float, float]:
    t, u = raised_cosine(60.0, 20.0, 3, 1 / DT)
    z = simulate_plant(Plant(effects=Effects()), t, u)
    return float(z.min()), float(z.max())


def _scale(caps) -> DataScale:
    return DataScale.from_arrays([c.u for c in caps], [c.y for c in caps], [c.dt for c in caps],
                                 [c.frequency_Hz for c in caps])


def test_the_span_leaves_out_a_ringing_stage():
    lo, hi = _hysteresis_range()
    scale = _scale(_captures(Effects(**STAGE)))
    assert scale.y_max - scale.y_min > 2.0 * (hi - lo)  # the PRBS rings far beyond the hysteresis
    span = scale.y_span
    assert span == pytest.approx((lo, hi), abs=0.02 * (hi - lo))
    block = Asymmetry().adapt(scale)
    assert block.half_range == pytest.approx(0.5 * (hi - lo), rel=0.03)


def test_steps_alone_give_the_settled_levels():
    """No smoothly driven capture: the medians of the output where the input dwells at its extremes."""
    t, u = steps([0.0, 30.0, 60.0, 20.0, 45.0, 0.0], [0.2, 0.3, 0.3, 0.3, 0.3, 0.3], 1 / DT)
    y = simulate_plant(Plant(effects=Effects(**STAGE)), t, u)
    z = simulate_plant(Plant(effects=Effects()), t, u)
    lo, hi = output_span([u], [y], [DT], [np.nan])
    assert y.max() - z.max() > 3.0  # the overshoot
    assert hi == pytest.approx(z.max(), abs=0.005 * np.ptp(z))
    assert z.min() - 0.005 * np.ptp(z) <= lo <= z[-1] + 0.005 * np.ptp(z)


def test_files_written_before_keep_their_numbers():
    """A data scale without the span (params.json written before it) falls back to the output's
    range; a stored m, h is never replaced."""
    old = DataScale(0.0, 60.0, -24.7, 48.6, DT, 6e5, 1.0, 7.5, 1.5e4)
    assert old.y_span == (-24.7, 48.6)
    assert Asymmetry().adapt(old).half_range == pytest.approx(36.65)
    stored = Asymmetry(center=11.93, half_range=36.63)
    new = _scale(_captures(Effects(**STAGE)))
    assert stored.adapt(new) == stored
    model = make_model("pi+asymmetry+dynamics", {"asymmetry.center": 11.93, "asymmetry.half_range": 36.63})
    adapted, params = adapted_model(_captures(Effects(**STAGE)), model)
    assert adapted.blocks[0] == stored
    assert {p.name: p.upper for p in params}["asymmetry.a2"] == pytest.approx(MAX_COEF * 36.63)
    assert DataScale(**json.loads(json.dumps(asdict(new)))) == new  # params.json's data_scale round trip


def test_diagnose_configures_the_bow_on_the_same_span_as_identify():
    caps = _captures(Effects(**STAGE))
    views = [CaptureView(c.t, c.dt, c.y, np.ones(c.n, bool), c.frequency_Hz, False, i, c.u)
             for i, c in enumerate(caps)]
    assert Asymmetry().configure(views, [c.y for c in caps]) == Asymmetry().adapt(_scale(caps))


def test_a_bow_behind_a_ringing_stage_is_recovered_not_bound():
    """The default plant's hysteresis, bowed (a = −0.24, as at strength 2), through a 600 Hz stage
    (ζ 0.15) rung by a PRBS, 5 nm of noise. Diagnose's joint refit (a 20-operator base, the stage,
    then the bow before it): h the hysteresis output's half-range within 3 %, the bow's curvature
    a₂/h² the plant's a/s within 10 % (measured 5 %) and a₂ well inside its box ±0.3·h. With h from
    the output's range (33.8 µm) the refit reached 60 % of the curvature (a₂ = −7.8 µm, a₃ = 4.8 µm
    making up part of it)."""
    s = 21.0
    caps = _captures(Effects(asymmetry=True, asymmetry_a2=A2, asymmetry_span_um=s, **STAGE), sigma=0.005)
    views = [CaptureView(c.t, c.dt, c.y, np.arange(c.n) < int(0.8 * c.n), c.frequency_Hz,
                         bool(np.isfinite(c.frequency_Hz)), i, c.u) for i, c in enumerate(caps)]
    fit = fit_captures([diag._truncate(c, v.fit_end) for c, v in zip(caps, views)],
                       make_model("pi", {"n_operators": 20}), make_optimizer(optimizers.get("auto")), seed=0)
    group = diag._Group("global", (60.0, 20.0), fit.model, fit.params, np.asarray(fit.theta, float).copy(),
                        np.array([p.lower for p in fit.params]), np.array([p.upper for p in fit.params]), (0, 1))
    state = diag._State([group], [], (0, 0))
    pred0 = diag._predictions(state, caps, views)
    dynamics, bow = diag._configured(["dynamics", "asymmetry"], pred0, views)
    lo, hi = _hysteresis_range()
    assert bow.half_range == pytest.approx(0.5 * (hi - lo), rel=0.03)
    state, _ = diag._augment(state, dynamics, caps, views, diag._linearize(state, caps, views), 2)
    state, f = diag._augment(state, bow, caps, views, diag._linearize(state, caps, views), 2)
    a2 = float(f.shared[0])
    assert a2 / bow.half_range ** 2 == pytest.approx(A2 / s, rel=0.10), (a2, bow.half_range)
    assert abs(a2) < 0.5 * MAX_COEF * bow.half_range


def test_identify_recovers_a_bow_behind_a_ringing_stage():
    """The same plant identified as pi+asymmetry+dynamics (the plant's thresholds): the noise floor,
    the bow's curvature within 3 %, the stage within 0.5 %. Before, h from the output's range
    (34.6 µm) put a₂ at its bound (0.0091 µm, the curvature 24 % short); and ``auto``'s staged start
    fitted the bow before the stage, to its ringing, which left the polish at both coefficient
    bounds (0.24 µm) once the box was the right size."""
    s, sigma = 21.0, 0.005
    caps = _captures(Effects(asymmetry=True, asymmetry_a2=A2, asymmetry_span_um=s, **STAGE), sigma=sigma)
    model = make_model("pi+asymmetry+dynamics", {"thresholds_V": list(DEFAULT_THRESHOLDS_V)})
    fit = identify(caps, model, make_optimizer(optimizers.get("auto")), global_fit=True, seed=0).fits[0]
    vals = dict(zip([p.name for p in fit.params], fit.theta))
    h = fit.model.blocks[0].half_range
    assert fit.metrics["rmse_um"] <= 1.1 * sigma
    assert vals["asymmetry.a2"] / h ** 2 == pytest.approx(A2 / s, rel=0.03)
    assert not any(p.name.startswith("asymmetry.") for p in fit.params
                   if bound_side(vals[p.name], p.lower, p.upper) is not None)
    assert vals["dynamics.fn_Hz"] == pytest.approx(600.0, rel=0.005)
