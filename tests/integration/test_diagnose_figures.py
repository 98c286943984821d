"""The where-figures of ``hystfit diagnose`` are drawn while the effects are tested
(``diagnose(on_where=...)``, :func:`hystfit.report.diagnose_report.start_where_figures`): the files
are byte for byte those drawn from the finished diagnosis, and drawn again from it when its
where-analysis is not the one they were started from (a refined noise floor)."""

import time
from dataclasses import replace

import pytest

from hystfit.report import render

from hystfit.diagnose import DiagnoseSettings, diagnose, withheld_effect_captures
from hystfit.models.pi import PI
from hystfit.optimizers.auto import Auto
from hystfit.report.diagnose_report import EARLY_DIR, WHERE_FIGURES, start_figures, start_where_figures, write_figures


@pytest.fixture(scope="module")
def diagnosed():
    caps = withheld_effect_captures("delay", 1.0, 5, amplitudes_V=(30.0, 60.0), frequencies_Hz=(10.0, 80.0),
                                    steps_s=0)
    early = []
    d = diagnose(caps, PI(), Auto(), seed=5, settings=DiagnoseSettings(max_effects=1), on_where=early.append)
    return d, early


@pytest.fixture(scope="module")
def reference(diagnosed, tmp_path_factory):
    """The figures drawn from the finished diagnosis (no early start): (paths, bytes)."""
    d, _ = diagnosed
    folder = tmp_path_factory.mktemp("reference") / "figures"
    return write_figures(d, folder), _bytes(folder)


@pytest.fixture(params=["server", "here"])
def drawing(request):
    """Figures drawn by a figure server (as the CLI does), or in this process."""
    render._close_server()
    if request.param == "server":
        render._server = render._FigureServer()
    yield request.param
    render._close_server()


def _bytes(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def test_on_where_gives_the_final_where_analysis(diagnosed):
    d, early = diagnosed
    assert len(early) == 1  # once, after the base model's where-analysis
    assert early[0].same_as(d.where_figure_data)
    assert early[0].sigma == d.noise["sigma"] and early[0].n_captures == len(d.captures)
    assert not early[0].same_as(replace(d.where_figure_data, where=dict(d.where)))  # another analysis


def test_early_where_figures_are_the_final_ones(diagnosed, reference, tmp_path, drawing):
    d, early = diagnosed
    started = start_where_figures(early[0], tmp_path / "figures")
    paths = start_figures(d, tmp_path / "figures", early=started).paths()
    assert paths == reference[0]  # the same names, in the same order, relative to the report
    assert list(paths)[:len(WHERE_FIGURES)] == list(WHERE_FIGURES)
    got = _bytes(tmp_path / "figures")
    assert got == reference[1]  # byte for byte, and no scratch folder left
    assert EARLY_DIR not in got


@pytest.mark.parametrize("drawing", ["server"], indirect=True)
def test_early_where_figures_of_another_floor_are_drawn_again(diagnosed, reference, tmp_path, drawing):
    d, early = diagnosed
    other = replace(early[0], where=dict(early[0].where), sigma=2.0 * early[0].sigma)  # as a refined floor would
    started = start_where_figures(other, tmp_path / "figures")
    paths = start_figures(d, tmp_path / "figures", early=started).paths()
    assert paths == reference[0]
    assert _bytes(tmp_path / "figures") == reference[1]


def test_cancelled_early_figures_write_nothing_more(diagnosed, tmp_path):
    """The command failed or was interrupted while the where-figures were drawn: the server stops
    at once and nothing is written after ``cancel`` returns."""
    d, early = diagnosed
    render._close_server()
    render._server = render._FigureServer()
    try:
        started = start_where_figures(early[0], tmp_path / "figures")
        started.cancel()
        assert render._server is None
        scratch = tmp_path / "figures" / EARLY_DIR
        now = _bytes(scratch)
        time.sleep(1.0)
        assert _bytes(scratch) == now
    finally:
        render._close_server()
