"""The recommended model diagnose hands over: identified on all the data from the diagnosis's own
fit (``auto``), or from scratch where that start does not apply; and identify's ``starts``."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import hystfit.diagnose as diag
from hystfit.cells import CellStore
from hystfit.diagnose import _same_operator, _same_structure, diagnose, fit_recommended, recommended_starts
from hystfit.errors import ConfigError
from hystfit.factory import make_model, make_optimizer
from hystfit.identify import adapted_model, identify, prepare_shared
from hystfit.io import load_captures
from hystfit.models.pi import PI
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


def _pooled_rmse(result) -> float:
    sse = n = 0.0
    for f in result.fits:
        k = sum(c.n for c in f.captures)
        sse += f.metrics[f"rmse_{result.unit}"] ** 2 * k
        n += k
    return math.sqrt(sse / n)


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
    warm = fit_recommended(caps, d, model, opt, seed=0)
    assert warm.optimizer_name == "lsq" and warm.model_name == d.recommended_model
    monkeypatch.setattr(diag, "recommended_starts", lambda *a, **k: None)
    cold = fit_recommended(caps, d, model, opt, seed=0)
    assert cold.optimizer_name == "auto"
    assert _pooled_rmse(warm) <= _pooled_rmse(cold) * (1 + 1e-3)


def test_other_optimizers_and_other_structures_identify_from_scratch(diagnosed, monkeypatch):
    caps, model, opt, d = diagnosed
    calls = []
    real = diag.recommended_starts
    monkeypatch.setattr(diag, "recommended_starts", lambda *a: calls.append(a) or real(*a))
    lsq = make_optimizer(optimizers.get("lsq"), {"max_evals": 50})
    assert fit_recommended(caps, d, model, lsq, seed=0).optimizer_name == "lsq" and calls == []
    # a base whose thresholds the fit part set 5 % lower than all the data do: no start, auto's own route
    (g,) = d.final_state.groups
    moved = replace(g, model=replace(g.model, thresholds_V=tuple(0.95 * r for r in g.model.thresholds_V)))
    d2 = replace(d, final_state=replace(d.final_state, groups=[moved]))
    rec = prepare_shared(make_model(d.recommended_model, d.recommended_options), caps)
    assert real(caps, d2, rec) is None
    assert fit_recommended(caps, d2, model, opt, seed=0).optimizer_name == "auto"
    # nothing named: nothing to start from
    assert real(caps, replace(d, final_state=None), rec) is None


def test_same_structure_allows_a_percent_in_the_numbers_only():
    a = PI(4, "uniform", (0.0, 10.0, 20.0, 30.0), True)
    assert _same_structure(a, replace(a, thresholds_V=(0.0, 10.05, 20.1, 30.15)))  # 0.5 %
    assert not _same_structure(a, replace(a, thresholds_V=(0.0, 10.5, 21.0, 31.5)))  # 5 %
    assert not _same_structure(a, replace(a, nonnegative=False))
    assert not _same_structure(a, PI(5, "uniform", (0.0, 8.0, 16.0, 24.0, 32.0), True))
    assert not _same_structure(a, make_model("bw", {}))


def test_identify_starts_each_cell_where_it_is_told(monkeypatch, tmp_path):
    caps = load_captures([SAMPLE / "a20V_f10Hz.csv", SAMPLE / "a40V_f10Hz.csv"])
    model = make_model("pi", {"n_operators": 4})
    seen = []
    real = LSQ.minimize

    def spy(self, objective, lower, upper, *, rng, x0=None, callback=None):
        seen.append(np.array(x0))
        return real(self, objective, lower, upper, rng=rng, x0=x0, callback=callback)

    monkeypatch.setattr(LSQ, "minimize", spy)
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
    with pytest.raises(ConfigError, match=f"start of {labels[0]} has 3 values"):
        identify(caps, model, lsq, seed=0, starts={labels[0]: np.zeros(3)})
    # a stored cell is reused only for the same start
    store = CellStore(tmp_path / "cells")
    identify(caps[:1], model, lsq, seed=0, starts={labels[0]: start}, store=store)
    again = identify(caps[:1], model, lsq, seed=0, starts={labels[0]: start}, store=store, resume=True)
    other = identify(caps[:1], model, lsq, seed=0, starts={labels[0]: 0.5 * start}, store=store, resume=True)
    assert (again.cell_stats.reused, other.cell_stats.reused) == (1, 0)


def test_a_block_is_the_same_operator_whatever_its_search_box_but_not_with_other_structure():
    from hystfit.blocks.creep import Creep
    from hystfit.blocks.dynamics import Dynamics
    from hystfit.capture import Capture
    from hystfit.synth import raised_cosine

    t, u = raised_cosine(40.0, 20.0, 3, 10_000)
    cap = Capture(source="x.csv", t=t, u=u, y=u.copy(), dt=1e-4, amplitude_V=40.0, frequency_Hz=20.0)
    dyn = Dynamics(fn_min_Hz=160.0, fn_max_Hz=4500.0)
    assert _same_operator(replace(dyn, fn_min_Hz=1125.0), dyn, np.array([1200.0, 0.15]), cap)
    creep = Creep(tau_s=(0.01, 0.1, 1.0))
    gains = np.array([0.01, 0.02, 0.03])
    assert _same_operator(creep, replace(creep), gains, cap)
    assert not _same_operator(Creep(tau_s=(0.02, 0.2, 2.0)), creep, gains, cap)
