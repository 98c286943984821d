"""``hystfit diagnose``: the withheld-effect proof, the noise floor, the split, and the CLI contract.

The proof (issue 7): captures of the virtual actuator with exactly one effect switched on (or
none), diagnosed with the PI base model, which lacks every effect. The verdict must name the
withheld effect, its held-out reduction must be at least 0.5, nothing else may be named, and the
``where`` section must point at the right place. Strengths and seeds per effect are below; the
full confusion matrix is ``benchmarks/diagnose_confusion.py`` (see docs/diagnose.md).
"""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from hystfit.capture import Capture
from hystfit.cli import app
from hystfit.diagnose import (DiagnoseSettings, choose_effect, diagnose, estimate_noise, fit_masks, is_periodic,
                              withheld_effect_captures)
from hystfit.errors import ConfigError, InputError
from hystfit.models.bw import BoucWen
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit.synth import raised_cosine, write_capture

SETTINGS = DiagnoseSettings(max_effects=2)

#: (effect, strength, seed): two strengths and two seeds per effect (drift's default moves a 3-s
#: capture by only 0.03 µm ≈ 4σ, so it is tested at 5× and 10×).
CASES = [
    ("dynamics", 0.5, 0), ("dynamics", 2.0, 1),
    ("delay", 0.5, 0), ("delay", 2.0, 1),
    ("creep", 0.5, 0), ("creep", 2.0, 1),
    ("asymmetry", 0.5, 0), ("asymmetry", 2.0, 1),
    ("drift", 5.0, 0), ("drift", 10.0, 1),
]


def _check_where(effect: str, where: dict) -> None:
    s = where["summary"]
    pointers = " ".join(where["pointers"])
    if effect in ("dynamics", "delay"):
        # high frequencies: the gap grows with the drive frequency and lives above the 5th harmonic
        assert s["frequency_exponent"] > 0.15
        assert s["high_frequency_share"] > 0.5
        assert "high frequencies" in pointers
    elif effect in ("creep", "drift"):
        # low frequencies and long captures: slow trends below the drive frequency that build up in time
        assert s["low_frequency_share"] > 0.25
        assert s["heldout_to_fit_ratio"] > 1.05  # the gap grows into the later, held-out time
        assert "low frequencies" in pointers
    elif effect == "asymmetry":
        # large amplitudes: per condition the gap grows with the square of the amplitude or faster
        assert s["amplitude_exponent_alone"] >= 2.0
        assert "large amplitudes" in pointers


@pytest.mark.parametrize("effect,strength,seed", CASES)
def test_withheld_effect_is_named(effect, strength, seed):
    caps = withheld_effect_captures(effect, strength, seed)
    d = diagnose(caps, PI(), Auto(), seed=seed, settings=SETTINGS)
    assert d.verdict == effect, [(r.effect, round(r.reduction, 3), r.passes) for r in d.effects]
    assert d.explained_by == (effect,)  # nothing spurious in the second step
    top = d.effects[0] if d.effects[0].effect == effect else next(r for r in d.effects if r.effect == effect)
    assert top.reduction >= 0.5
    assert top.improvement > top.placebo_improvement
    assert top.heldout_rmse_after < top.heldout_rmse_before
    _check_where(effect, d.where)


@pytest.mark.parametrize("seed", [0, 1])
def test_clean_plant_gives_none(seed):
    caps = withheld_effect_captures("none", 1.0, seed)
    d = diagnose(caps, PI(), Auto(), seed=seed, settings=SETTINGS)
    assert d.verdict == "none" and d.explained_by == ()
    assert all(r.reduction < 0.3 for r in d.effects)
    # the noise floor is estimated from the data: σ = 8 nm
    assert d.noise["sigma"] == pytest.approx(0.008, rel=0.05)


def test_recovered_parameters_are_physical():
    """The fitted effect says what the stage is: f_n and ζ of the withheld dynamics, creep gains."""
    d = diagnose(withheld_effect_captures("dynamics", 1.0, 0), PI(), Auto(), settings=DiagnoseSettings(max_effects=1))
    p = d.effects[0].params
    assert d.effects[0].effect == "dynamics"
    assert p["fn_Hz"] == pytest.approx(1200.0, rel=0.02) and p["zeta"] == pytest.approx(0.15, rel=0.05)


def test_any_base_model_bw():
    """The effects augment any registered model: Bouc–Wen as the base, a strong delay withheld."""
    caps = withheld_effect_captures("delay", 2.0, 0, amplitudes_V=(60.0,), frequencies_Hz=(10.0, 80.0), steps_s=0)
    d = diagnose(caps, BoucWen(), Auto(), seed=0, settings=DiagnoseSettings(max_effects=1))
    assert d.base_model == "bw"
    red = {r.effect: r for r in d.effects}
    assert set(red) == {"dynamics", "creep", "asymmetry", "drift", "delay"}
    assert red["delay"].reduction > 0.3 and red["delay"].heldout_rmse_after < red["delay"].heldout_rmse_before
    json.dumps(d.to_dict(), allow_nan=False)


def test_per_condition_mode_and_effect_subset():
    """One PI per condition (look-up table): creep still shows as the slow rise within the captures.
    (A step-and-hold capture is left out: a PI fitted to the first 60 % of one step pattern alone
    cannot predict the later, different steps — a structural gap no effect removes.)"""
    caps = withheld_effect_captures("creep", 2.0, 0, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 40.0), steps_s=0)
    d = diagnose(caps, PI(), Auto(), per_condition=True, effects=["creep", "delay"],
                 settings=DiagnoseSettings(max_effects=1))
    assert d.mode == "per-condition" and [r.effect for r in d.effects] in (["creep", "delay"], ["delay", "creep"])
    assert d.verdict == "creep"
    assert "by_condition_alone" not in d.where  # per condition, the fits are already "alone"
    with pytest.raises(ConfigError, match="unknown effect"):
        diagnose(caps, PI(), Auto(), effects=["thermal"])


# ----------------------------------------------------------------------------------------------
# building blocks


def test_noise_floor_from_the_data(rng):
    """White noise under a smooth model error: the third-difference MAD estimate finds σ, not the error."""
    t, u = raised_cosine(40.0, 20.0, 5, 10_000.0)
    smooth = 0.3 * np.sin(2 * np.pi * 20.0 * t) ** 3  # a model error much larger than the noise
    res, caps = [], []
    for sigma in (0.01,):
        e = smooth + sigma * rng.standard_normal(t.size)
        res.append(e)
        caps.append(Capture("x", t, u, u * 0.3 + e, 1e-4, amplitude_V=40.0, frequency_Hz=20.0))
    n = estimate_noise(caps, res, [True])
    assert n["sigma"] == pytest.approx(0.01, rel=0.06)
    assert n["repeatability"] == pytest.approx(0.01, rel=0.1)  # the smooth error repeats every cycle


def test_split_is_whole_cycles_and_periodicity():
    t, u = raised_cosine(40.0, 20.0, 5, 10_000.0)
    c = Capture("x", t, u, u, 1e-4, amplitude_V=40.0, frequency_Hz=20.0)
    assert is_periodic(u, 1e-4, 20.0) and not is_periodic(u, 1e-4, 13.0)
    (m,) = fit_masks([c], [True], 0.6)
    assert m.sum() == 3 * 500 + 1  # three of five cycles
    (m,) = fit_masks([c], [False], 0.6)
    assert m.sum() == round(0.6 * t.size)


def test_choose_effect_prefers_the_simpler_of_equals():
    from hystfit.diagnose import EffectResult

    def res(name, red, n, ok=True):
        return EffectResult(name, name, 1, 1.0, 1.0 - red, 1.0, 1.0, red, 0.0, 0.0, 0.0, n, 0.0, 0.0, {}, "",
                            {"a": ok})

    s = DiagnoseSettings()
    assert choose_effect([res("dynamics", 0.93, 2), res("delay", 0.90, 1)], s).effect == "delay"
    assert choose_effect([res("dynamics", 0.95, 2), res("delay", 0.80, 1)], s).effect == "dynamics"
    assert choose_effect([res("dynamics", 0.95, 2, ok=False)], s) is None
    with pytest.raises(ConfigError, match="threshold"):
        DiagnoseSettings(threshold=1.5)


def test_missing_output_is_refused():
    t, u = raised_cosine(40.0, 20.0, 5, 10_000.0)
    with pytest.raises(InputError, match="no measured output"):
        diagnose([Capture("x", t, u, None, 1e-4, amplitude_V=40.0, frequency_Hz=20.0)], PI(), Auto())


# ----------------------------------------------------------------------------------------------
# CLI


@pytest.fixture
def small_dataset(tmp_path):
    caps = withheld_effect_captures("delay", 2.0, 0, amplitudes_V=(30.0, 60.0), frequencies_Hz=(20.0, 80.0), steps_s=0)
    d = tmp_path / "data"
    for c in caps:
        write_capture(d / f"{c.source}.csv", c.t, c.u, c.y)
    return d


def test_cli_writes_the_json_contract(small_dataset, tmp_path):
    out = tmp_path / "dg"
    r = CliRunner().invoke(app, ["diagnose", str(small_dataset), "--model", "pi", "--out", str(out), "--json",
                                 "--max-effects", "1"])
    assert r.exit_code == 0, r.output
    printed = json.loads(r.stdout)
    d = json.loads((out / "diagnosis.json").read_text())
    assert printed["verdict"] == d["verdict"]
    # the contract of issue 7
    assert d["base_model"] == "pi"
    assert d["noise_floor_um"] > 0
    assert d["gap"]["rmse_um"] > 0 and d["gap"]["heldout_rmse_um"] > 0
    conds = d["where"]["by_condition"]
    assert {(c["amplitude_V"], c["frequency_Hz"]) for c in conds} == {(30.0, 20.0), (30.0, 80.0), (60.0, 20.0), (60.0, 80.0)}
    assert all(c["rmse_um"] > 0 for c in conds)
    for key in ("by_branch", "by_loop_position", "by_time", "by_band", "summary", "pointers"):
        assert key in d["where"]
    effects = d["effects"]
    assert [e["effect"] for e in effects] and {e["effect"] for e in effects} == {"dynamics", "creep", "asymmetry",
                                                                                  "drift", "delay"}
    reds = [e["reduction"] for e in effects]
    assert reds == sorted(reds, reverse=True)  # best first
    for e in effects:
        assert {"heldout_rmse_before_um", "heldout_rmse_after_um", "reduction", "evidence", "params"} <= set(e)
        assert 0.0 <= e["reduction"] <= 1.0 and e["evidence"]
    assert d["verdict"] in {"dynamics", "creep", "asymmetry", "drift", "delay", "none"}
    assert d["verdict"] == "delay" and effects[0]["params"]["delay_ms"] == pytest.approx(0.3, abs=0.01)
    md = (out / "diagnosis.md").read_text()
    assert "Verdict: `delay`" in md and "held-out" in md
    figs = sorted(p.name for p in (out / "figures").iterdir())
    assert "effects_heldout.png" in figs and "where_conditions.png" in figs and "where_bands.png" in figs


def test_cli_refuses_bad_options(small_dataset, tmp_path):
    r = CliRunner().invoke(app, ["diagnose", str(small_dataset), "--effects", "thermal", "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "unknown effect 'thermal'" in r.stderr
    assert not (tmp_path / "x").exists()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "f").write_text("x")
    r = CliRunner().invoke(app, ["diagnose", str(small_dataset), "--out", str(tmp_path / "full"), "--quiet"])
    assert r.exit_code == 2 and "not empty" in r.stderr
