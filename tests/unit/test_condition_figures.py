"""A condition's figures drawn as soon as it is fitted: identify's on_fit and the report's ConditionFigures."""

import os
from pathlib import Path

import numpy as np
import pytest

from hystfit.identify import condition_groups, identify
from hystfit.io import load_captures
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit.optimizers.pso import PSO
from hystfit.report import render
from hystfit.report.identify_report import ConditionFigures, write_identify_outputs

SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"


@pytest.fixture(scope="module")
def captures():
    return load_captures([SAMPLE / f"a{a}V_f{f}Hz.csv" for a in (20, 60) for f in (10, 50)])


def test_on_fit_sees_each_condition_once_when_all_its_runs_are_done(captures):
    seen = []
    res = identify(captures, PI(), PSO(pop=12, iters=5), runs=2, seed=3, jobs=1,
                   on_fit=lambda f: seen.append((f.label, len(f.runs), f)))
    assert sorted(label for label, _, _ in seen) == sorted(f.label for f in res.fits)
    assert all(n == 2 for _, n, _ in seen)
    assert [f.label for f in res.fits] == [f"{a}V_{f}Hz" for a in (20, 60) for f in (10, 50)]  # condition order
    by_label = {label: f for label, _, f in seen}
    assert all(by_label[f.label] is f for f in res.fits)  # the result holds the fits on_fit saw
    again = identify(captures, PI(), PSO(pop=12, iters=5), runs=2, seed=3, jobs=1)
    for a, b in zip(res.fits, again.fits):
        np.testing.assert_array_equal(a.theta, b.theta)


def test_condition_groups_count_what_identify_fits(captures):
    assert len(condition_groups(captures)) == 4
    assert len(condition_groups(captures, global_fit=True)) == 1


def _report_bytes(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / "plots").glob("*.png"))}


@pytest.mark.parametrize("serve", [False, True])
def test_streamed_figures_equal_the_ones_drawn_after_the_fit(tmp_path, captures, serve):
    render._close_server()
    if serve and hasattr(os, "fork"):
        render._server = render._FigureServer()
    try:
        streamed, batch = tmp_path / "streamed", tmp_path / "batch"
        streamed.mkdir()
        batch.mkdir()
        opt = PSO(pop=12, iters=5)
        with ConditionFigures(streamed, opt.name, 2, n_conditions=4) as figures:
            res = identify(captures, PI(), opt, seed=1, jobs=1, on_fit=figures.add)
            write_identify_outputs(res, streamed, figures=figures)
        write_identify_outputs(res, batch)
    finally:
        render._close_server()
    a, b = _report_bytes(streamed), _report_bytes(batch)
    assert len(a) == 4 * 3 + 1 and a == b  # loop, time series, convergence per condition; the overview
    assert (streamed / "report.md").read_text() == (batch / "report.md").read_text()


def test_a_failure_while_fitting_stops_the_drawing(tmp_path, captures, monkeypatch):
    stopped = []
    monkeypatch.setattr(render.FigureStream, "cancel", lambda self: stopped.append(True))
    with pytest.raises(RuntimeError, match="boom"):
        with ConditionFigures(tmp_path, "pso") as figures:
            figures.add(identify(captures[:1], PI(), PSO(pop=8, iters=3), jobs=1).fits[0])
            raise RuntimeError("boom")
    assert stopped == [True]


def test_figures_must_match_the_result_and_the_report(tmp_path, captures):
    res = identify(captures[:1], PI(), Auto(), jobs=1)
    with pytest.raises(ValueError, match="optimizer"):
        ConditionFigures(tmp_path, "pso").result(res)
    (tmp_path / "other").mkdir()
    with pytest.raises(ValueError, match="figures go to"):
        write_identify_outputs(res, tmp_path / "other", figures=ConditionFigures(tmp_path, res.optimizer_name))


def test_two_conditions_with_one_label_keep_the_first_ones_figures(tmp_path, captures):
    """Keys that differ below the label's 12 digits (0.7 V, and 700 mV read as 0.7000000000000001 V)
    share a label: identify must not fail on it (the report has one figure set per label)."""
    res = identify(captures[:2], PI(), Auto(), jobs=1)
    figures = ConditionFigures(tmp_path, res.optimizer_name)
    figures.add(res.fits[0])
    jobs = list(figures._stream.jobs)
    figures.add(res.fits[0])  # the same label again
    assert figures._stream.jobs == jobs
    assert set(figures.result(res)) == {f.label for f in res.fits}
