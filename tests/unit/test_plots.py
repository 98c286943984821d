"""Figures: readable PNGs of the expected size, written atomically, long inputs decimated."""

import io
import os

import matplotlib.axes
import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from hystfit.errors import OutputError
from hystfit.report import plots
from hystfit.report.plots import (
    MAX_POINTS,
    _decimate,
    _decimate_minmax,
    _grid_shape,
    _stride,
    boxplot_figure,
    convergence_figure,
    display_unit,
    heatmap_figure,
    loop_figure,
    overview_figure,
    parity_figure,
    timeseries_figure,
)


def _loop(rng, n=400, amp=60.0):
    t = np.linspace(0.0, 2.0, n)
    u = amp / 2 * (1 - np.cos(2 * np.pi * t))
    y_model = 0.15 * u + 0.8 * np.sin(2 * np.pi * t)
    return t, u, y_model + rng.normal(0, 0.02, n), y_model


def _read(path):
    """Image read back by matplotlib: (height, width, channels)."""
    assert path.is_file() and path.stat().st_size > 1000
    return matplotlib.image.imread(path)


def _only(tmp_path, *names):
    """The directory holds exactly these files: no temporary leftovers."""
    assert sorted(os.listdir(tmp_path)) == sorted(names)


def test_loop_figure_size_and_no_temp_files(tmp_path, rng):
    _, u, y, yp = _loop(rng)
    out = loop_figure(tmp_path / "loop.png", u, y, yp, unit="um", title="pi – 60 V 1 Hz")
    assert out == tmp_path / "loop.png"
    img = _read(out)
    assert img.shape[:2] == (round(4.8 * plots.DPI), round(6.4 * plots.DPI))  # (height, width), landscape
    small = _read(loop_figure(tmp_path / "small.png", u, y, yp, dpi=55))
    assert small.shape[0] == img.shape[0] // 2
    _only(tmp_path, "loop.png", "small.png")


def test_loop_figure_accepts_lists_of_captures_and_checks_them(tmp_path, rng):
    caps = [_loop(rng, n) for n in (300, 500)]
    out = loop_figure(tmp_path / "l.png", [c[1] for c in caps], [c[2] for c in caps], [c[3] for c in caps])
    _read(out)
    with pytest.raises(ValueError, match="numbers of captures"):
        loop_figure(tmp_path / "bad.png", [c[1] for c in caps], [c[2] for c in caps], [caps[0][3]])
    with pytest.raises(ValueError, match="differ in length"):
        loop_figure(tmp_path / "bad.png", [caps[0][1]], [caps[1][2]], [caps[0][3]])
    _only(tmp_path, "l.png")


def test_timeseries_figure_with_non_finite_model(tmp_path, rng):
    t, _, y, yp = _loop(rng)
    yp[50:60] = np.inf
    yp[70] = np.nan
    img = _read(timeseries_figure(tmp_path / "ts.png", t, y, yp, unit="nm", title="ts"))
    assert img.shape[0] > 300 and img.shape[1] > img.shape[0]
    with pytest.raises(ValueError, match="length"):
        timeseries_figure(tmp_path / "bad.png", t[:-1], y, yp)
    _only(tmp_path, "ts.png")


def test_convergence_figure_variants(tmp_path, rng):
    best = np.minimum.accumulate(np.exp(-np.linspace(0, 6, 200)) + rng.random(200) * 0.01)
    _read(convergence_figure(tmp_path / "c1.png", best, best * 2, title="pso", runs=[best * 1.1, best * 0.9]))
    # zero/negative values fall back to a linear axis; inf (diverged population) becomes a gap
    mean = best * 3
    mean[:5] = np.inf
    _read(convergence_figure(tmp_path / "c2.png", best - best[-1], mean, log=True))
    _read(convergence_figure(tmp_path / "c3.png", [], None))  # solver without iterations
    _read(convergence_figure(tmp_path / "c4.png", [0.3], None))
    _only(tmp_path, "c1.png", "c2.png", "c3.png", "c4.png")


def test_overview_figure_grid(tmp_path, rng):
    panels = []
    for i in range(24):
        _, u, y, yp = _loop(rng, 200, amp=20 + i)
        caps = 2 if i % 5 == 0 else 1
        panels.append({"title": f"{20 + i}V_{10 * (i % 6 + 1)}Hz", "u": [u] * caps, "y_meas": [y] * caps,
                       "y_model": [yp] * caps, "subtitle": "R²=0.999 RMSE=0.01 µm"})
    img = _read(overview_figure(tmp_path / "ov.png", panels, unit="um", title="overview"))
    assert img.shape[1] > img.shape[0]  # 4 rows × 6 columns: landscape
    with pytest.raises(ValueError, match="lacks"):
        overview_figure(tmp_path / "bad.png", [{"title": "x", "u": [1.0, 2.0]}])
    with pytest.raises(ValueError, match="at least one panel"):
        overview_figure(tmp_path / "bad.png", [])
    _only(tmp_path, "ov.png")


@pytest.mark.parametrize("n", range(1, 41))
def test_grid_shape_is_near_square_and_fits(n):
    rows, cols = _grid_shape(n)
    assert rows * cols >= n
    assert rows * cols - n < cols  # no empty row
    assert rows <= cols <= max(3, 2 * rows)


def test_grid_shape_examples():
    assert _grid_shape(24) == (4, 6)
    assert _grid_shape(9) == (3, 3)
    assert _grid_shape(1) == (1, 1)
    assert _grid_shape(3) == (1, 3)


def test_parity_heatmap_boxplot(tmp_path, rng):
    _, _, y, yp = _loop(rng)
    par = _read(parity_figure(tmp_path / "p.png", [y, y], [yp, yp], unit="um"))
    assert abs(par.shape[0] - par.shape[1]) < 0.1 * par.shape[1]  # roughly square
    m = rng.random((5, 8))
    m[1, 2], m[3, 4] = np.nan, np.inf
    hm = _read(heatmap_figure(tmp_path / "h.png", m, [f"m{i}" for i in range(5)], [f"c{j}" for j in range(8)],
                              title="RMSE", colorbar_label="RMSE (µm)"))
    assert hm.shape[1] > hm.shape[0]
    _read(heatmap_figure(tmp_path / "h_nan.png", np.full((2, 2), np.nan), ["a", "b"], ["c", "d"]))
    with pytest.raises(ValueError, match="labels"):
        heatmap_figure(tmp_path / "bad.png", m, ["a"], [f"c{j}" for j in range(8)])
    _read(boxplot_figure(tmp_path / "b.png", {"pso": rng.random(10), "de": [], "lsq": [0.0, 0.2, np.nan]},
                         ylabel="RMSE (µm)", log=True))
    with pytest.raises(ValueError, match="at least one group"):
        boxplot_figure(tmp_path / "bad.png", {})
    _only(tmp_path, "p.png", "h.png", "h_nan.png", "b.png")


def test_decimate_helpers():
    assert _stride(MAX_POINTS) == 1
    assert _stride(MAX_POINTS + 1) == 2
    short = np.arange(1000.0)
    np.testing.assert_array_equal(_decimate(short), short)
    x = np.arange(10**6)
    d = _decimate(x)
    assert MAX_POINTS // 2 < d.size <= MAX_POINTS
    assert d[0] == 0 and np.all(np.diff(d) == d[1])  # an even stride


def test_decimate_minmax_keeps_peaks(rng):
    n = 10**6 + 7
    t = np.arange(n, dtype=float)
    r = rng.normal(0, 0.01, n)
    r[123_457], r[n - 2] = 5.0, -4.0  # a spike a plain stride would drop, one in the short tail
    td, rd = _decimate_minmax(t, r)
    assert rd.size <= MAX_POINTS + 2
    assert rd.max() == 5.0 and rd.min() == -4.0
    assert np.all(np.diff(td) > 0)
    assert r[::_stride(n)].max() < 5.0  # the spike really is between stride points


def test_long_capture_is_drawn_decimated(tmp_path, monkeypatch):
    drawn = []
    original = matplotlib.axes.Axes.add_line  # every curve's route onto the axes

    def spy(self, line):
        drawn.append(len(line.get_xdata()))
        return original(self, line)

    monkeypatch.setattr(matplotlib.axes.Axes, "add_line", spy)
    n = 10**6
    t = np.arange(n) * 1e-5
    u = 30 * (1 - np.cos(2 * np.pi * 10 * t))
    loop_figure(tmp_path / "big.png", u, 0.1 * u, 0.1 * u + 0.01)
    timeseries_figure(tmp_path / "bigts.png", t, 0.1 * u, 0.1 * u + 0.01)
    assert drawn and max(drawn) <= MAX_POINTS + 2
    _only(tmp_path, "big.png", "bigts.png")


def test_failed_save_leaves_previous_file_and_no_temp(tmp_path, rng, monkeypatch):
    _, u, y, yp = _loop(rng)
    target = tmp_path / "loop.png"
    target.write_bytes(b"previous")

    def boom(self, *args, **kwargs):
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(Figure, "draw", boom)
    with pytest.raises(RuntimeError, match="renderer failed"):
        loop_figure(target, u, y, yp)
    assert target.read_bytes() == b"previous"
    _only(tmp_path, "loop.png")


def test_unwritable_location_is_an_output_error(tmp_path, rng):
    _, u, y, yp = _loop(rng)
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("x")
    with pytest.raises(OutputError, match="not_a_dir"):
        loop_figure(blocker / "loop.png", u, y, yp)
    _only(tmp_path, "not_a_dir")


def test_parent_directories_are_created(tmp_path, rng):
    _, u, y, yp = _loop(rng)
    _read(loop_figure(tmp_path / "plots" / "sub" / "l.png", u, y, yp))


def test_png_bytes_round_trip_rgb_and_rgba(rng):
    from PIL import Image

    rgba = rng.integers(0, 256, size=(7, 5, 4), dtype=np.uint8)
    opaque = rgba.copy()
    opaque[..., 3] = 255
    for img, mode in ((opaque, "RGB"), (rgba, "RGBA")):
        back = Image.open(io.BytesIO(plots.png_bytes(img, 110)))
        assert back.mode == mode and back.size == (5, 7)
        assert np.array_equal(np.asarray(back.convert("RGBA")), img)
        assert back.info["dpi"] == pytest.approx((110, 110), abs=0.01)


def test_written_png_has_the_pixels_of_the_canvas(tmp_path, rng):
    _, u, y, yp = _loop(rng)
    fig = Figure(figsize=(3.0, 2.0), dpi=80)
    fig.add_subplot().plot(u, y)
    written = matplotlib.image.imread(plots._save(fig, tmp_path / "ours.png", 80))
    drawn = np.asarray(fig.canvas.buffer_rgba())
    assert written.shape == (160, 240, 3)  # opaque: written as RGB
    assert np.array_equal(np.round(written * 255).astype(np.uint8), drawn[..., :3])


def test_unit_display():
    assert display_unit("um") == "µm"
    assert display_unit("nm") == "nm"
    assert display_unit("furlong") == "furlong"


def test_heatmap_annotation_colours_follow_each_cell(tmp_path, monkeypatch):
    """White text on dark cells, black on bright ones, grey on blank (NaN, or ≤ 0 on a log scale):
    the colours computed for all cells at once equal the colour map of each cell."""
    import matplotlib.axes

    import hystfit.report.plots as plots_module

    seen = []
    orig = matplotlib.axes.Axes.text

    def text(self, x, y, s, *args, **kwargs):
        seen.append((int(x), int(y), kwargs.get("color")))
        return orig(self, x, y, s, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "text", text)
    m = np.array([[1e-3, 1e-2, 1e-1], [1.0, np.nan, -1.0]])
    plots_module.heatmap_figure(tmp_path / "h.png", m, ["a", "b"], ["c", "d", "e"], log=True, cmap="viridis")
    colours = {(y, x): c for x, y, c in seen}
    assert colours[(0, 0)] == "white"  # the smallest value: viridis' dark end
    assert colours[(1, 0)] == "black"  # the largest: viridis' bright end
    assert colours[(1, 1)] == "0.3" and colours[(1, 2)] == "0.3"  # NaN, and ≤ 0 on a log scale


def test_loop_and_timeseries_axes_have_at_most_tick_bins_intervals(tmp_path, rng):
    # every tick label is a text laid out and drawn: the reused layouts keep TICK_BINS, also after
    # a reset (a scale reset restores matplotlib's default locator of up to 9 intervals)
    u = np.linspace(0.0, 137.0, 4000)
    y = 0.3 * u + rng.normal(0, 0.01, u.size)
    t = np.arange(u.size) * 1e-4
    for _ in range(2):  # a fresh layout, then the reused one
        plots.loop_figure(tmp_path / "l.png", u, y, y + 0.01, title="x")
        plots.timeseries_figure(tmp_path / "t.png", t, y, y + 0.01, title="x")
        for key, fig in plots._templates.figures.items():
            if key[0] not in ("loop", "timeseries"):
                continue
            for ax in fig.axes:
                for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
                    inside = [v for v in axis.get_majorticklocs() if lo <= v <= hi]
                    assert len(inside) <= plots.TICK_BINS + 1, (axis, inside)


def test_a_log_heatmap_colour_bar_is_labelled_with_plain_numbers(tmp_path, monkeypatch):
    """Like the convergence figure's log axis: 0.01, not 10⁻² (mathtext costs a parse per label)."""
    import matplotlib.figure

    seen = {}
    original = matplotlib.figure.Figure.colorbar

    def colorbar(self, *args, **kwargs):
        seen["cb"] = original(self, *args, **kwargs)
        return seen["cb"]

    monkeypatch.setattr(matplotlib.figure.Figure, "colorbar", colorbar)
    m = np.array([[1e-3, 1e-2, 1e-1], [1.0, 0.5, 0.02]])
    plots.heatmap_figure(tmp_path / "h.png", m, ["a", "b"], ["c", "d", "e"], log=True)
    labels = [t.get_text() for t in seen["cb"].ax.yaxis.get_ticklabels() if t.get_text()]
    assert labels and not any("$" in t for t in labels)
    assert "0.01" in labels and "0.1" in labels


def test_template_axes_draw_their_ticks_as_matplotlib_does(tmp_path, rng, monkeypatch):
    """A template axis works out its ticks once per draw and draws the ticks' lines together
    (plots._TicksOncePerDraw): the same bytes as matplotlib's own Axis.draw, for the loop, time
    series and overview figures (linear axes: batched) and the convergence figure (log axis:
    matplotlib's draw), and the ticks are worked out afresh on the next draw."""
    u = np.linspace(0.0, 60.0, 3000)
    y = 0.3 * u + rng.normal(0, 0.05, u.size)
    t = np.arange(u.size) * 1e-4
    hist = np.geomspace(1.0, 1e-4, 50)

    def draw_all(d):
        d.mkdir()
        plots.loop_figure(d / "l.png", u, y, y + 0.01, title="a")
        plots.timeseries_figure(d / "t.png", t, y, y + 0.01, title="a")
        plots.loop_figure(d / "l2.png", 2 * u, -y, y, title="b")  # other ranges: other ticks
        plots.timeseries_figure(d / "t2.png", 1e3 + t, 1e6 + y, 1e6 + y + 0.01)  # offset texts on both axes
        plots.convergence_figure(d / "c.png", hist, hist * 2, title="a")
        plots.overview_figure(d / "o.png", [{"title": f"p{i}", "u": u * (i + 1), "y_meas": y, "y_model": y + 0.01}
                                            for i in range(3)], title="o")
        return {p.name: p.read_bytes() for p in d.iterdir()}

    drawn = []
    batched = plots._TicksOncePerDraw._draw_batched

    def counting(self, renderer):
        drawn.append(self.axis.get_scale())
        return batched(self, renderer)

    import threading

    monkeypatch.setattr(plots._TicksOncePerDraw, "_draw_batched", counting)
    monkeypatch.setattr(plots, "_templates", threading.local())  # templates made in this test
    ours = draw_all(tmp_path / "ours")
    assert "linear" in drawn and "log" not in drawn  # batched on linear axes only
    monkeypatch.setattr(plots._TicksOncePerDraw, "_draw", lambda self, renderer, *a, **k: self.draw(renderer, *a, **k))
    monkeypatch.setattr(plots._TicksOncePerDraw, "_update_ticks", lambda self: self.update())
    monkeypatch.setattr(plots._TicksOncePerDraw, "_measure", lambda self, ticks, renderer: self.measure(ticks, renderer))
    monkeypatch.setattr(plots, "_templates", threading.local())  # new templates: matplotlib's methods
    assert draw_all(tmp_path / "matplotlib's") == ours


def test_template_backgrounds_left_out_only_where_they_repaint_the_figures(tmp_path, rng, monkeypatch):
    """A template's axes background of the figure's own colour is not drawn (plots._unpainted_backgrounds):
    the same bytes as with it drawn; an axes of another colour, or overlapping another, keeps it."""
    import threading

    import matplotlib.figure

    u = np.linspace(0.0, 60.0, 2000)
    y = 0.3 * u + rng.normal(0, 0.05, u.size)
    monkeypatch.setattr(plots, "_templates", threading.local())
    plots.loop_figure(tmp_path / "a.png", u, y, y + 0.01, title="a")
    (fig,) = [f for k, f in plots._templates.figures.items() if k[0] == "loop"]
    assert not fig.axes[0].patch.get_visible()
    monkeypatch.setattr(plots, "_unpainted_backgrounds", lambda fig: None)
    monkeypatch.setattr(plots, "_templates", threading.local())
    plots.loop_figure(tmp_path / "b.png", u, y, y + 0.01, title="a")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    monkeypatch.undo()

    grey = matplotlib.figure.Figure(figsize=(3, 2))
    grey.add_subplot().set_facecolor("0.9")
    plots._unpainted_backgrounds(grey)
    assert grey.axes[0].patch.get_visible()
    overlapping = matplotlib.figure.Figure(figsize=(3, 2))
    overlapping.add_axes((0.1, 0.1, 0.6, 0.6))
    overlapping.add_axes((0.5, 0.5, 0.4, 0.4))
    plots._unpainted_backgrounds(overlapping)
    assert all(ax.patch.get_visible() for ax in overlapping.axes)
    alone = matplotlib.figure.Figure(figsize=(3, 2))
    alone.add_subplot()
    plots._unpainted_backgrounds(alone)
    assert not alone.axes[0].patch.get_visible()


def test_a_box_plot_over_less_than_a_decade_is_linear_and_its_title_wraps(tmp_path, monkeypatch):
    """A blind test's find: nine y labels all "7.43e-05" (a log axis over a 1e-5 relative spread), and
    a title cut off at the figure's right edge."""
    from hystfit.report import plots

    from matplotlib.axes import Axes

    logged, titles = [], []
    monkeypatch.setattr(plots, "_plain_log_labels", lambda axis, values: logged.append(values.size))
    set_title = Axes.set_title
    monkeypatch.setattr(Axes, "set_title", lambda self, text, *a, **k: (titles.append(text), set_title(self, text, *a,
                                                                                                           **k))[1])
    title = "J of the search (before the polish) over 2 runs: pi at 60V_80Hz"
    plots.boxplot_figure(tmp_path / "narrow.png", {"auto": [7.4301e-05, 7.4302e-05]}, log=True, title=title)
    assert logged == []
    plots.boxplot_figure(tmp_path / "wide.png", {"pso": [1e-5, 3e-4, 2e-3], "de": [2e-5, 5e-5]}, log=True,
                         title=title)
    assert logged == [5]
    assert titles and all("\n" in t and t.replace("\n", " ") == title for t in titles)  # wrapped, whole
    assert (tmp_path / "narrow.png").stat().st_size > 0 and (tmp_path / "wide.png").stat().st_size > 0


def test_a_log_axis_within_a_decade_gets_four_spread_labels():
    """A blind test's find: a colour bar over 6e-5…1e-4 labelled 6, 7, 8, 9e-05 and 1e-4 on top of each
    other (every minor tick). Four ticks spread over the values, two significant digits."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hystfit.report.plots import _plain_log_labels

    fig, ax = plt.subplots()
    ax.set_yscale("log")
    ax.set_ylim(6e-5, 1e-4)
    _plain_log_labels(ax.yaxis, np.array([6e-5, 7.1e-5, 1e-4]))
    ticks = ax.yaxis.get_major_locator()()
    assert len(ticks) <= 4 and min(ticks) == pytest.approx(6e-5) and max(ticks) == pytest.approx(1e-4)
    assert list(ax.yaxis.get_minor_locator()()) == []
    plt.close(fig)


def test_the_time_series_leaves_room_for_its_legends(tmp_path, monkeypatch):
    """A blind test's find: the upper-right legend hid the last peak of a time series."""
    from hystfit.report import plots

    seen = {}
    save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path, dpi, *a, **k: (seen.setdefault(
        "lims", [ax.get_ylim() for ax in fig.axes]), save(fig, path, dpi, *a, **k))[1])
    t = np.arange(2000) * 1e-4
    y = 9.0 * (1 - np.cos(2 * np.pi * 20 * t))
    e = 0.02 * np.sin(2 * np.pi * 40 * t)
    plots.timeseries_figure(tmp_path / "ts.png", t, y, y + e, unit="um", title="t")
    (lo, hi), (rlo, rhi) = seen["lims"][:2]
    assert hi >= 18.0 + 0.25 * 18.0 and lo <= 0.0  # the data's top stays below the legend
    assert rhi >= 0.02 + 0.5 * 0.04 and rlo <= -0.02
