"""The recommended model diagnose hands over: identified on all the data from the diagnosis's own
fit (``auto``), or from scratch where that start does not apply; and identify's ``starts``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import hystfit.diagnose as diag
from hystfit.blocks.asymmetry import Asymmetry
from hystfit.cells import CellStore
from hystfit.effects import EffectFit
from hystfit.diagnose import HANDED_OVER_START, diagnose, fit_recommended, recommended_starts
from hystfit.errors import ConfigError
from hystfit.factory import make_model, make_optimizer
from hystfit.identify import adapted_model, identify, prepare_shared
from hystfit.io import load_captures
from hystfit.optimizers.lsq import LSQ
from hystfit.registry import optimizers

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"


@pytest.fixture(scope="module")
def diagnosed():
    caps = load_captures([SAMPLE / f"a40V_f{f}Hz.csv" for f in (10, 40, 80)])
    model, opt = make_model("pi", {}), make_optimizer(optimizers.get("auto"))
    d = diagnose(caps, model, opt, seed=0)
    assert d.explained_by, "the three sample captures need a named effect for these tests"
    return caps, model, opt, d


def _spy_on_lsq_starts(monkeypatch) -> list:
    """The start point of every LSQ run from now on."""
    seen = []
    real = LSQ.minimize

    def spy(self, objective, lower, upper, *, rng, x0=None, callback=None):
        seen.append(np.array(x0))
        return real(self, objective, lower, upper, rng=rng, x0=x0, callback=callback)

    monkeypatch.setattr(LSQ, "minimize", spy)
    return seen


def test_the_start_is_the_diagnosis_final_model_in_the_recommended_model_order(diagnosed):
    caps, _, _, d = diagnosed
    rec = prepare_shared(make_model(d.recommended_model, d.recommended_options), caps)
    starts = recommended_starts(caps, d, rec)
    assert list(starts) == ["global"]
    state = d.final_state
    (g,) = state.groups
    theta = starts["global"]
    assert np.array_equal(theta[:g.theta.size], g.theta)
    fits = {f.effect.name: f for f in state.chain}
    assert set(fits) == set(d.explained_by)
    at = g.theta.size
    adapted, _ = adapted_model(caps, rec)  # adapted to all the data (creep's time constants: from its span)
    for b in adapted.composition[1]:  # the blocks in the recommended model's order, not the order named
        f = fits[b.name]
        assert np.array_equal(theta[at:at + b.n_theta], np.concatenate([f.phi, f.shared]))
        at += b.n_theta
    assert at == theta.size


def test_auto_polishes_the_diagnosis_fit_and_reaches_the_fit_from_scratch(diagnosed, monkeypatch):
    caps, model, opt, d = diagnosed
    rec = prepare_shared(make_model(d.recommended_model, d.recommended_options), caps)
    theta0 = recommended_starts(caps, d, rec)["global"]
    seen = _spy_on_lsq_starts(monkeypatch)
    warm = fit_recommended(caps, d, model, opt, seed=0)
    assert warm.optimizer_name == "lsq" and warm.model_name == d.recommended_model
    assert len(seen) == 1 and np.array_equal(seen[0], theta0)  # the polish starts at the diagnosis's fit
    assert warm.start == HANDED_OVER_START
    monkeypatch.setattr(diag, "recommended_starts", lambda *a, **k: None)
    cold = fit_recommended(caps, d, model, opt, seed=0)
    assert cold.optimizer_name == "auto" and cold.start == "defaults"
    assert warm.pooled_rmse <= cold.pooled_rmse * (1 + 1e-3)


def test_other_optimizers_and_starts_that_are_not_the_diagnosis_model_identify_from_scratch(diagnosed, monkeypatch):
    caps, model, opt, d = diagnosed
    calls = []
    real = diag.recommended_starts
    monkeypatch.setattr(diag, "recommended_starts", lambda *a: calls.append(a) or real(*a))
    lsq = make_optimizer(optimizers.get("lsq"), {"max_evals": 50})
    assert fit_recommended(caps, d, model, lsq, seed=0).optimizer_name == "lsq" and calls == []
    rec = prepare_shared(make_model(d.recommended_model, d.recommended_options), caps)
    assert real(caps, d, rec) is not None
    # the start must fit as well as the diagnosis's final model did (here: as well as a perfect one)
    perfect = replace(d, figures_data={**d.figures_data, "explained_predictions": [c.y for c in caps]})
    assert real(caps, perfect, rec) is None
    assert fit_recommended(caps, perfect, model, opt, seed=0).optimizer_name == "auto"
    # nothing named: nothing to start from
    assert real(caps, replace(d, final_state=None), rec) is None


def test_effects_named_in_another_order_than_the_model_applies_them_give_no_start_where_it_matters(diagnosed):
    """asymmetry (a static bow) does not commute with creep: named after creep, the diagnosis's model
    is not pi+asymmetry+creep+… (the signal order), and its parameters are no start for that model.
    Data: the diagnosis's model in each order plus 0.01 µm of noise."""
    caps, _, _, d = diagnosed
    views = d.figures_data["views"]
    base = np.concatenate(d.figures_data["base_predictions"])
    m, h = float(0.5 * (base.min() + base.max())), float(0.5 * np.ptp(base))
    bow = EffectFit(Asymmetry(center=m, half_range=h), np.empty(0), np.array([0.2 * h, 0.0]),
                    np.zeros((len(caps), 0)), np.empty(0), 0.0, 0)
    chain = [replace(f, shared=5.0 * f.shared) if f.effect.name == "creep" else f for f in d.final_state.chain]
    named = ("asymmetry",) + tuple(f.effect.name for f in chain)
    rng = np.random.default_rng(0)
    for order, expect in (([bow] + chain, True), (chain + [bow], False)):
        state = replace(d.final_state, chain=order)
        preds = diag._predictions(state, caps, views)
        data = [replace(c, y=p + 0.01 * rng.standard_normal(c.n)) for c, p in zip(caps, preds)]
        dd = replace(d, final_state=state, explained_by=named,
                     figures_data={**d.figures_data, "captures": data, "explained_predictions": preds})
        assert dd.recommended_model.split("+")[1] == "asymmetry"  # the signal order: asymmetry first
        rec = prepare_shared(make_model(dd.recommended_model, {**dd.recommended_options, "asymmetry.center": m,
                                                               "asymmetry.half_range": h}), data)
        assert (recommended_starts(data, dd, rec) is not None) is expect, [f.effect.name for f in order]


def test_identify_starts_each_cell_where_it_is_told(monkeypatch, tmp_path):
    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f10Hz.csv"])
    model = make_model("pi", {"n_operators": 4})
    seen = _spy_on_lsq_starts(monkeypatch)
    lsq = make_optimizer(optimizers.get("lsq"), {"max_evals": 20})
    base = identify(caps, model, lsq, seed=0)
    defaults = [np.array([p.default for p in f.params]) for f in base.fits]
    assert all(np.array_equal(s, x) for s, x in zip(seen, defaults))
    seen.clear()
    labels = [f.label for f in base.fits]
    start = np.full(defaults[0].size, 0.01)
    start[-1] = 1e9  # outside the box: clipped to it
    res = identify(caps, model, lsq, seed=0, starts={labels[1]: start})
    lo, hi = base.fits[1].params[-1].lower, base.fits[1].params[-1].upper
    assert np.array_equal(seen[0], defaults[0])  # no start given: the defaults
    assert np.array_equal(seen[1][:-1], start[:-1]) and seen[1][-1] == hi and lo < hi
    assert [f.label for f in res.fits] == labels
    with pytest.raises(ConfigError, match=rf"start of {labels[0]} has shape \(3,\)"):
        identify(caps, model, lsq, seed=0, starts={labels[0]: np.zeros(3)})
    with pytest.raises(ConfigError, match="values that are not numbers .at w1"):
        identify(caps, model, lsq, seed=0, starts={labels[0]: np.where(np.arange(start.size) == 1, np.nan, start)})
    with pytest.raises(ConfigError, match="starts for global, which no cell is"):
        identify(caps, model, lsq, seed=0, starts={"global": start})
    with pytest.raises(ConfigError, match="pso takes no start point"):
        identify(caps, model, make_optimizer(optimizers.get("pso")), seed=0, starts={labels[0]: start})
    assert res.start == "given" and base.start == "defaults"
    (r1, n1), (r2, n2) = ((f.metrics[f"rmse_{base.unit}"], f.metrics["n_samples"]) for f in base.fits)
    assert base.pooled_rmse == pytest.approx(np.sqrt((r1 ** 2 * n1 + r2 ** 2 * n2) / (n1 + n2)), rel=1e-12)
    # a stored cell is reused only for the same start
    store = CellStore(tmp_path / "cells")
    identify(caps[:1], model, lsq, seed=0, starts={labels[0]: start}, store=store)
    again = identify(caps[:1], model, lsq, seed=0, starts={labels[0]: start}, store=store, resume=True)
    other = identify(caps[:1], model, lsq, seed=0, starts={labels[0]: 0.5 * start}, store=store, resume=True)
    assert (again.cell_stats.reused, other.cell_stats.reused) == (1, 0)
