"""Per-pixel reduction of long series and parallel figure rendering: what is drawn is what was measured."""

import numpy as np
import pytest

from hystfit.report import plots
from hystfit.report.plots import column_envelope, pixel_path
from hystfit.report.render import FigureJob, render_figures


def _periodic(n, cycles, rng, noise=0.0):
    """A periodic capture whose period is a whole number of samples: a stride would alias it."""
    t = np.arange(n) / n
    u = 30.0 * (1 - np.cos(2 * np.pi * cycles * t))
    y = 0.1 * u + 0.8 * np.sin(2 * np.pi * cycles * t) + (rng.normal(0, noise, n) if noise else 0.0)
    return t, u, y


def test_column_envelope_keeps_min_and_max_of_every_pixel_column(rng):
    n, columns = 200_003, 640
    t = np.sort(rng.random(n))
    y = rng.normal(size=n)
    idx = column_envelope(t, y, columns)
    assert idx is not None and np.all(np.diff(idx) > 0)
    assert idx.size <= 4 * columns
    col = np.minimum(((t - t[0]) * (columns / (t[-1] - t[0]))).astype(int), columns - 1)
    for reduce in (np.minimum, np.maximum):
        full = reduce.reduceat(y, np.flatnonzero(np.r_[True, np.diff(col) != 0]))
        kept = reduce.reduceat(y[idx], np.flatnonzero(np.r_[True, np.diff(col[idx]) != 0]))
        np.testing.assert_array_equal(kept, full)
    assert column_envelope(t[:1000], y[:1000], columns) is None  # short: drawn whole


def test_column_envelope_keeps_gaps_and_handles_unsorted_time(rng):
    n = 100_000
    y = rng.normal(size=n)
    y[5000:5100] = np.nan
    y[70_000] = np.inf
    idx = column_envelope(np.arange(n, dtype=float), y, 500)
    assert np.any(np.isnan(y[idx])) and np.any(np.isinf(y[idx]))
    assert np.nanmax(np.where(np.isfinite(y[idx]), y[idx], np.nan)) == np.nanmax(np.where(np.isfinite(y), y, np.nan))
    idx2 = column_envelope(rng.random(n), y, 500)  # not monotonic: the sample index is used
    assert idx2 is not None and np.all(np.diff(idx2) > 0)


@pytest.mark.parametrize("n,cycles", [(10**6, 20_000), (10**6, 4000), (10**6, 200), (10**5, 50)])
def test_loop_path_spans_the_data_on_periodic_captures(n, cycles, rng):
    # every k-th sample of such a capture sits at one phase: the old plot was a point or a line
    _, u, y = _periodic(n, cycles, rng, noise=0.01)
    k = plots._stride(n)
    if k % (n // cycles) == 0:
        assert np.ptp(u[::k]) < 1e-9  # the aliasing this replaces
    xs, ys = pixel_path(u, y, 1100, 800)
    assert xs.size < n  # noise makes neighbouring samples change cells: the reduction is smaller then
    assert np.nanmin(xs) == u.min() and np.nanmax(xs) == u.max()
    assert np.nanmin(ys) == y.min() and np.nanmax(ys) == y.max()


def test_loop_path_covers_every_cell_the_path_visits(rng):
    _, u, y = _periodic(300_000, 37, rng, noise=0.02)
    nx, ny = 400, 300
    xs, ys = pixel_path(u, y, nx, ny)

    def cells(a, b):
        ok = np.isfinite(a) & np.isfinite(b)
        ix = ((a[ok] - u.min()) * (nx / np.ptp(u))).astype(int)
        iy = ((b[ok] - y.min()) * (ny / np.ptp(y))).astype(int)
        return set(zip(ix.tolist(), iy.tolist()))

    assert cells(xs, ys) == cells(u, y)


def test_loop_path_gaps_for_non_finite_and_short_input_untouched(rng):
    _, u, y = _periodic(50_000, 10, rng)
    y[1000:1010] = np.nan
    xs, ys = pixel_path(u, y, 200, 150)
    assert np.isnan(ys).any()
    short_x, short_y = pixel_path(u[:100], y[:100], 200, 150)
    np.testing.assert_array_equal(short_x, u[:100])
    const_x, const_y = pixel_path(np.zeros(10_000), np.ones(10_000), 50, 50)
    assert const_x.size >= 1 and np.all(const_y[np.isfinite(const_y)] == 1.0)


def test_long_periodic_capture_plot_spans_the_data(tmp_path, monkeypatch, rng):
    import matplotlib.axes

    drawn = []
    original = matplotlib.axes.Axes.add_line  # every curve's route onto the axes

    def spy(self, line):
        if line.get_label() in ("measured", "model"):  # not the time series' zero line
            drawn.append((np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)))
        return original(self, line)

    monkeypatch.setattr(matplotlib.axes.Axes, "add_line", spy)
    t, u, y = _periodic(10**6, 5000, rng)  # 200 samples per cycle, a multiple of the old stride
    plots.loop_figure(tmp_path / "loop.png", u, y, y + 0.01)
    plots.timeseries_figure(tmp_path / "ts.png", t, y, y + 0.01)
    loop_meas = drawn[0]
    assert np.nanmin(loop_meas[0]) == u.min() and np.nanmax(loop_meas[0]) == u.max()
    assert np.nanmin(loop_meas[1]) == y.min() and np.nanmax(loop_meas[1]) == y.max()
    ts_meas = drawn[2]
    assert np.nanmin(ts_meas[1]) == y.min() and np.nanmax(ts_meas[1]) == y.max()
    assert max(d[0].size for d in drawn) < 10**5


def _jobs(out, rng):
    jobs = []
    panels = []
    for i in range(5):
        t, u, y = _periodic(20_000, 3 + i, rng, noise=0.01)
        jobs.append(FigureJob("loop_figure", out / f"loop_{i}.png", (u, y, y + 0.01), {"title": f"c{i}"}))
        jobs.append(FigureJob("timeseries_figure", out / f"ts_{i}.png", (t, y, y + 0.01), {"unit": "nm"}))
        panels.append({"title": f"c{i}", "u": u, "y_meas": y, "y_model": y + 0.01, "subtitle": "R²=1"})
    jobs.append(FigureJob("convergence_figure", out / "conv.png", (np.geomspace(1, 1e-4, 300),), {}))
    jobs.append(FigureJob("overview_figure", out / "overview.png", (panels,), {"title": "all"}))
    return jobs


def test_parallel_rendering_writes_the_same_bytes_as_serial(tmp_path, rng):
    seed = rng.integers(1 << 30)
    serial = render_figures(_jobs(tmp_path / "one", np.random.default_rng(seed)), n_jobs=1)
    parallel = render_figures(_jobs(tmp_path / "two", np.random.default_rng(seed)), n_jobs=2)
    assert [p.name for p in serial] == [p.name for p in parallel]
    for a, b in zip(serial, parallel):
        assert a.read_bytes() == b.read_bytes(), a.name
    again = render_figures(_jobs(tmp_path / "one", np.random.default_rng(seed)), n_jobs=2)
    assert [p.read_bytes() for p in again] == [p.read_bytes() for p in parallel]


def test_rendering_error_reaches_the_caller(tmp_path, rng):
    from hystfit.errors import OutputError

    blocker = tmp_path / "file"
    blocker.write_text("x")
    jobs = _jobs(tmp_path / "ok", rng)
    jobs.insert(3, FigureJob("loop_figure", blocker / "x.png", (np.arange(10.0), np.arange(10.0)), {}))
    with pytest.raises(OutputError):
        render_figures(jobs, n_jobs=2)


def test_reused_figure_templates_write_the_same_bytes_as_fresh_figures(tmp_path, rng):
    t, u, y = _periodic(30_000, 7, rng, noise=0.01)
    h = np.geomspace(1.0, 1e-4, 200)

    def panels(k, shift=0.0):
        return [{"u": u * (1 + i), "y_meas": y, "y_model": y + shift + 0.01 * i, "title": f"c{i}",
                 "subtitle": f"RMSE={i}"} for i in range(k)]

    def draw_all(tag):
        return [plots.loop_figure(tmp_path / f"l_{tag}.png", u, y, y + 0.01, title="a"),
                plots.timeseries_figure(tmp_path / f"t_{tag}.png", t, y, y + 0.01, title="a"),
                plots.convergence_figure(tmp_path / f"c_{tag}.png", h, h * 2, title="a"),
                plots.overview_figure(tmp_path / f"o_{tag}.png", panels(5), title="a"),  # 2 × 3, one left empty
                plots.loop_overlay_figure(tmp_path / f"lo_{tag}.png", u, y, {"m1": y + 0.01, "m2": y - 0.02}, title="a"),
                plots.convergence_compare_figure(tmp_path / f"cc_{tag}.png", {"o1": [h, h * 3], "o2": [h * 2]},
                                                 title="a")]

    plots._templates.figures = {}  # fresh figures
    fresh = [p.read_bytes() for p in draw_all("fresh")]
    # other data, units and scales in between (a linear convergence axis, non-finite model values)
    yp = y + 0.5
    yp[100:200] = np.nan
    plots.loop_figure(tmp_path / "x1.png", u * 2, y, yp, unit="nm", title="a")
    plots.timeseries_figure(tmp_path / "x2.png", None, y[:500], yp[:500], title="a")
    plots.timeseries_figure(tmp_path / "x2w.png", t, y * 1e5, y * 1e5 + 3e3 * np.sin(t), title="a")  # a wider margin
    plots.loop_figure(tmp_path / "x1w.png", u, y * 1e5, y * 1e5 - 2e5, title="a")
    plots.convergence_figure(tmp_path / "x3.png", h - h[-1], None, title="a")
    plots.overview_figure(tmp_path / "x4.png", panels(5, shift=0.5), unit="nm", title="b")
    plots.overview_figure(tmp_path / "x5.png", panels(6), title="a")  # the same grid, another layout
    plots.loop_overlay_figure(tmp_path / "x6.png", u * 2, y, {"m1": yp, "m2": y, "m3": y * 2}, unit="nm", title="a")
    plots.convergence_compare_figure(tmp_path / "x8.png", {"o1": [h - h[-1]]}, log=False, title="a")
    reused = [p.read_bytes() for p in draw_all("reused")]
    assert [i for i, (a, b) in enumerate(zip(reused, fresh)) if a != b] == []


def test_first_occurrences_sorting_and_hashing_agree(monkeypatch):
    """The numpy route (short inputs) and the pandas route (long ones) mark the same first occurrences."""
    keys = np.random.default_rng(3).integers(0, 40, size=2000)
    sorted_route = plots._first_occurrences(keys)
    monkeypatch.setattr(plots, "HASH_KEYS_FROM", 0)
    hashed_route = plots._first_occurrences(keys)
    np.testing.assert_array_equal(sorted_route, hashed_route)
    assert sorted_route.sum() == np.unique(keys).size and sorted_route[0]


def test_a_prepared_overview_writes_the_same_bytes_as_a_fresh_one(tmp_path, rng):
    t, u, y = _periodic(3_000, 3, rng, noise=0.01)
    panels = [{"u": u, "y_meas": y, "y_model": y + 0.01 * i, "title": f"c{i}", "subtitle": "x"} for i in range(7)]
    plots._templates.figures = {}
    fresh = plots.overview_figure(tmp_path / "fresh.png", panels, title="t").read_bytes()
    plots._templates.figures = {}
    plots.prepare_overview(7, titled=True)
    (fig,) = plots._templates.figures.values()
    (ax,) = fig.axes  # one axes, drawn in each cell in turn
    assert len(ax.xaxis.majorTicks) > 1 and len(ax.yaxis.majorTicks) > 1  # its ticks exist before the first drawing
    assert plots.overview_figure(tmp_path / "prepared.png", panels, title="t").read_bytes() == fresh
    assert len(plots._templates.figures) == 1  # the prepared layout was the one used


def _overview_as_a_grid_of_axes(path, panels, *, unit="um", title=""):
    """The overview drawn the plain way: one axes per panel in one grid, drawn by ``Figure.draw``
    (what :func:`plots.overview_figure`, which moves one axes from cell to cell, must reproduce)."""
    rows, cols = plots._grid_shape(len(panels))
    margins = (0.6, 0.12, 0.72, 0.42 + (0.3 if title else 0.0))
    width = margins[0] + margins[1] + cols * plots._PANEL_W + (cols - 1) * plots._PANEL_WGAP
    height = margins[2] + margins[3] + rows * plots._PANEL_H + (rows - 1) * plots._PANEL_HGAP
    fig = plots._new_figure(width, height, margins, wspace=plots._PANEL_WGAP / plots._PANEL_W,
                            hspace=plots._PANEL_HGAP / plots._PANEL_H)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[len(panels):]:
        ax.set_axis_off()
    for i, (ax, p) in enumerate(zip(axes, panels)):
        ax.tick_params(labelsize=6.5, pad=1.5)
        ax.grid(True, alpha=0.3)
        caps = plots._captures({"u": p["u"], "y_meas": p["y_meas"], "y_model": p.get("y_model")})
        plots._draw_loops(ax, caps, ("measured", "model"), lw_scale=0.8)
        sub = p.get("subtitle", "")
        ax.set_title(f"{p.get('title', '')}\n{sub}" if sub else p.get("title", ""), fontsize=7.5, pad=3, y=1.0)
        ax.locator_params(nbins=plots._OVERVIEW_TICK_BINS)
        if i + cols >= len(panels):
            ax.set_xlabel("Voltage (V)", fontsize=7)
        if i % cols == 0:
            ax.set_ylabel(plots._output_label(unit), fontsize=7)
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncols=len(handles), fontsize=8,
                   frameon=False)
    if title:
        fig.suptitle(title, fontsize=10, y=1 - 0.12 / height, va="top")
    return plots._save(fig, path, plots.DPI)


@pytest.mark.parametrize("n", [1, 5, 7, 13])
def test_the_overview_equals_a_grid_of_one_axes_per_panel(tmp_path, rng, n):
    """One axes moved from cell to cell draws the same bytes as a grid with an axes per panel:
    panels of other ranges (tick labels of other widths, an offset), several captures per panel,
    without a model or a subtitle, with nothing finite or nothing at all to draw, empty cells,
    with and without a title, in µm and nm."""
    t, u, y = _periodic(3_000, 3, rng, noise=0.01)
    panels = []
    for i in range(n):
        uu, yy = u * (1 + 0.7 * i), y * (1 + 0.3 * i) + (100.0 if i == 3 else 0.0)
        p = {"u": uu, "y_meas": yy, "y_model": yy + 0.01 * i, "title": f"c{i}", "subtitle": f"RMSE={0.01 * i:.3g}"}
        if i == 1:
            p = {**p, "u": [uu, uu[:1500]], "y_meas": [yy, yy[:1500] + 0.1], "y_model": [yy, yy[:1500]]}
        if i == 2:
            p = {k: v for k, v in p.items() if k not in ("y_model", "subtitle")}
        if i == 4:  # nothing finite to draw: the axes' own default ranges, not the previous panel's
            p = {**p, "y_meas": np.full_like(yy, np.nan), "y_model": np.full_like(yy, np.nan)}
        if i == 6:
            p = {**p, "u": np.array([]), "y_meas": np.array([]), "y_model": np.array([])}
        panels.append(p)
    for kw in ({"title": "all"}, {"unit": "nm", "title": ""}):
        plain = _overview_as_a_grid_of_axes(tmp_path / "plain.png", panels, **kw).read_bytes()
        assert plots.overview_figure(tmp_path / "moved.png", panels, **kw).read_bytes() == plain


def test_a_reused_template_draws_a_figure_without_data_as_a_fresh_one(tmp_path):
    """Without any finite point a figure shows the axes' default ranges, not those of the figure the
    template drew before (the view limits are reset with the data limits)."""
    empty = np.array([])
    plots._templates.figures = {}
    fresh = plots.loop_figure(tmp_path / "fresh.png", empty, empty, title="x").read_bytes()
    plots._templates.figures = {}
    u = np.linspace(0.0, 100.0, 50)
    plots.loop_figure(tmp_path / "data.png", u, u, title="x")
    assert plots.loop_figure(tmp_path / "again.png", empty, empty, title="x").read_bytes() == fresh
