"""The corner legend of the fixed-layout figures: matplotlib's legend geometry, drawn directly."""

import numpy as np
import pytest
from matplotlib.figure import Figure

from hystfit.report import canvas, legend


def _axes(band=True):
    fig = Figure(figsize=(6.4, 4.8), dpi=110)
    ax = fig.add_subplot()
    if band:
        ax.axhspan(-0.2, 0.2, color="tab:blue", alpha=0.15, lw=0, label="±RMSE = 0.0307 µm")
    ax.axhline(0.0, color="0.5", lw=0.6)  # unlabelled: not in the legend
    ax.plot([0.0, 1.0], [0.0, 2.0], color="0.15", lw=1.4, label="measured")
    ax.plot([0.0, 1.0], [0.5, 1.5], color="tab:red", lw=0.8, alpha=0.75, label="_hidden")
    ax.plot([0.0, 1.0], [0.1, 1.9], color="tab:red", lw=0.8, alpha=0.75, label="model")
    return fig, ax


@pytest.mark.parametrize("loc", ["upper right", "upper left", "lower left", "lower right"])
@pytest.mark.parametrize("fontsize", [None, "small", 12])
def test_frame_where_and_as_large_as_matplotlibs(loc, fontsize):
    """The frame has the size and place of matplotlib's legend frame for the same entries (within
    half a pixel): the same padding, spacing, handle length and distance from the axes' corner."""
    fig, ax = _axes()
    reference = ax.legend(loc=loc, fontsize=fontsize)
    c = canvas.Canvas(fig)
    c.draw()
    want = reference.get_frame().get_window_extent(c.get_renderer()).bounds
    reference.remove()
    ours = legend.corner_legend(ax, loc, fontsize)
    c.draw()
    got = ours._frame.get_window_extent(c.get_renderer()).bounds
    np.testing.assert_allclose(got, want, atol=0.5)
    assert [t.get_text() for t in ours._texts] == ["±RMSE = 0.0307 µm", "measured", "model"]


def test_handles_copy_the_style_of_the_curves():
    fig, ax = _axes()
    ours = legend.corner_legend(ax)
    band, measured, model = ours._handles
    assert band.get_facecolor() == pytest.approx((0.12156862745098039, 0.4666666666666667, 0.7058823529411765, 0.15))
    assert measured.get_linewidth() == 1.4 and model.get_alpha() == 0.75
    assert model.get_color() == "tab:red" and measured.get_color() == "0.15"


def test_pixels_of_a_reused_legend_equal_a_new_ones():
    """A legend shown again elsewhere, in another size and with other entries (a template's next
    figure) draws what a new legend of those entries draws."""
    fig, ax = _axes(band=True)
    ax.lines[-1].set_label("_not yet")
    first = legend.corner_legend(ax, "upper left")
    c = canvas.Canvas(fig)
    c.draw()
    ax.lines[-1].set_label("model")
    assert legend.corner_legend(ax, "upper right", "small") is first
    c.draw()
    fresh_fig, fresh_ax = _axes(band=True)
    legend.corner_legend(fresh_ax, "upper right", "small")
    fresh = canvas.Canvas(fresh_fig)
    fresh.draw()
    np.testing.assert_array_equal(np.asarray(c.buffer_rgba()), np.asarray(fresh.buffer_rgba()))


def test_no_labelled_curve_no_legend():
    fig = Figure(figsize=(3.0, 2.0), dpi=100)
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1])
    assert legend.corner_legend(ax) is None
    ax.plot([0, 1], [1, 0], label="shown")
    shown = legend.corner_legend(ax)
    assert shown.get_visible()
    ax.lines[-1].set_label("_gone")
    assert legend.corner_legend(ax) is None and not shown.get_visible()


def test_unknown_corner_is_refused():
    fig, ax = _axes()
    with pytest.raises(ValueError, match="loc must be one of"):
        legend.corner_legend(ax, "best")


@pytest.mark.parametrize("setting", [{"legend.labelcolor": "linecolor"}, {"legend.shadow": True}])
def test_settings_it_does_not_draw_are_left_to_matplotlib(setting):
    import matplotlib as mpl

    with mpl.rc_context(setting):
        fig, ax = _axes()
        assert legend.corner_legend(ax) is None
        assert ax.get_legend() is not None  # matplotlib's legend, with the setting applied
    fig, ax = _axes()
    assert legend.corner_legend(ax) is not None and ax.get_legend() is None
