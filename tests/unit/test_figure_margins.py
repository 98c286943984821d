"""Fixed-layout figures widen their left margin where a y axis's tick labels and label would not fit
(plots._fit_left_margin): no y label is cut at the figure's edge, whatever the data's scale."""

from __future__ import annotations

import io

import numpy as np
import pytest

from hystfit.report import plots


def _drawn(key: str):
    fig = plots._templates.figures[next(k for k in plots._templates.figures if k[0] == key)]
    return fig, fig.canvas.get_renderer()


def _label_left_px(fig, renderer) -> float:
    return min(ax.yaxis.get_tightbbox(renderer).x0 for ax in fig.axes)


def _series(scale: float, resid: float):
    t = np.linspace(0.0, 0.2, 4000)
    ym = scale * (1.0 + np.sin(2 * np.pi * 30 * t))
    yp = ym + resid * np.sin(2 * np.pi * 170 * t + 0.3)
    return t, ym, yp


@pytest.mark.parametrize("scale, resid", [(6.0, 0.05), (6.0, 0.0025), (3e5, 2.5e4), (1e-3, 1e-5), (6.0, 250.0)])
def test_timeseries_labels_are_never_cut(scale, resid):
    plots._templates.figures = {}
    plots.timeseries_figure(io.BytesIO(), *_series(scale, resid), title="t")
    fig, renderer = _drawn("timeseries")
    assert _label_left_px(fig, renderer) >= plots._EDGE_PX - 1
    default = 0.8 / fig.get_figwidth()
    assert fig.subplotpars.left >= default - 1e-12


@pytest.mark.parametrize("scale", [6.0, 2.5e5, -3e-4])
def test_loop_labels_are_never_cut(scale):
    plots._templates.figures = {}
    u = np.linspace(0.0, 20.0, 500)
    plots.loop_figure(io.BytesIO(), u, scale * u, scale * u * 1.01, title="t")
    fig, renderer = _drawn("loop")
    assert _label_left_px(fig, renderer) >= plots._EDGE_PX - 1


def test_convergence_and_parity_labels_are_never_cut():
    plots._templates.figures = {}
    h = np.geomspace(0.00421, 0.00173, 60)  # less than a decade: minor ticks labelled too
    plots.convergence_figure(io.BytesIO(), h, title="t")
    fig, renderer = _drawn("convergence")
    assert _label_left_px(fig, renderer) >= plots._EDGE_PX - 1
    y = np.linspace(-250000.0, 250000.0, 300)
    buf = io.BytesIO()
    plots.parity_figure(buf, y, y * 1.001, title="t")
    assert buf.getvalue()[:4] == b"\x89PNG"


def test_the_margin_grows_only_where_needed_and_returns_on_the_next_figure():
    plots._templates.figures = {}
    plots.timeseries_figure(io.BytesIO(), *_series(6.0, 0.5))
    fig, _ = _drawn("timeseries")
    default = 0.8 / fig.get_figwidth()
    assert fig.subplotpars.left == pytest.approx(default)  # short labels: the fixed layout as it was
    plots.timeseries_figure(io.BytesIO(), *_series(3e5, 2.5e4))
    assert fig.subplotpars.left > default + 0.01
    plots.timeseries_figure(io.BytesIO(), *_series(6.0, 0.5))
    assert fig.subplotpars.left == default


def test_loop_overlay_labels_are_never_cut():
    plots._templates.figures = {}
    u = np.linspace(0.0, 20.0, 500)
    plots.loop_overlay_figure(io.BytesIO(), u, -2.5e5 * u, {"m1": -2.5e5 * u * 1.01, "m2": -2.5e5 * u * 0.99})
    fig, renderer = _drawn("loop_overlay")
    assert _label_left_px(fig, renderer) >= plots._EDGE_PX - 1
