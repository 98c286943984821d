"""The text-caching Agg canvas: the same picture as Agg's, independent of what was drawn before."""

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from hystfit.report import canvas


def _figure(title="pi – 40V_50Hz"):
    fig = Figure(figsize=(4.0, 3.0), dpi=110)
    ax = fig.add_subplot()
    ax.plot([0.0, 1.0], [0.0, 2.0], label="measured")
    ax.set_xlabel("Voltage (V)")
    ax.set_ylabel("Displacement (µm)")  # drawn at 90°
    ax.set_title(title)
    ax.text(0.5, 0.5, "tilted", rotation=30)  # drawn the ordinary way
    ax.legend(loc="upper left")
    return fig


def _pixels(canvas_class, fig=None):
    c = canvas_class(fig or _figure())
    c.draw()
    return np.asarray(c.buffer_rgba()).astype(int)


@pytest.fixture
def empty_cache(monkeypatch):
    monkeypatch.setattr(canvas, "_text_images", {})


def test_same_picture_as_agg_up_to_subpixel_placement(empty_cache):
    ours, agg = _pixels(canvas.Canvas), _pixels(FigureCanvasAgg)
    differ = np.abs(ours - agg).max(axis=2) > 0
    assert differ.any()  # texts sit on whole pixels
    assert differ.mean() < 0.02
    ink = lambda a: (255 - a[..., :3]).sum()  # noqa: E731 - the same amount of ink: no text lost or doubled
    assert ink(ours) == pytest.approx(ink(agg), rel=0.01)
    assert "Voltage (V)" in {k[0] for k in canvas._text_images}


def test_pixels_do_not_depend_on_the_cache(empty_cache):
    cold = _pixels(canvas.Canvas)
    assert canvas._text_images
    warm = _pixels(canvas.Canvas)
    canvas._text_images.clear()
    assert np.array_equal(_pixels(canvas.Canvas), cold)
    assert np.array_equal(warm, cold)


def test_a_full_cache_starts_again(empty_cache, monkeypatch):
    monkeypatch.setattr(canvas, "MAX_CACHED_TEXTS", 3)
    _pixels(canvas.Canvas)
    assert 0 < len(canvas._text_images) <= 3


def test_colour_is_part_of_the_key(empty_cache):
    fig = Figure(figsize=(2.0, 1.0), dpi=100)
    fig.text(0.1, 0.5, "same", color="red")
    fig.text(0.6, 0.5, "same", color="blue")
    px = _pixels(canvas.Canvas, fig)
    red = (px[..., 0] > 200) & (px[..., 2] < 100)
    blue = (px[..., 2] > 200) & (px[..., 0] < 100)
    assert red.any() and blue.any()
    assert red[:, :100].any() and not red[:, 100:].any()


@pytest.fixture
def empty_layouts(monkeypatch):
    monkeypatch.setattr(canvas, "_layouts", {})


def test_cached_text_layouts_give_the_same_pixels(empty_cache, empty_layouts, monkeypatch):
    from matplotlib.text import Text

    fig = _figure()
    fig.axes[0].text(0.2, 0.8, "two\nlines", ha="center", va="baseline", multialignment="right")
    first = _pixels(canvas.Canvas, fig)
    assert ("Voltage (V)" in {k[0] for k in canvas._layouts}) and ("two\nlines" in {k[0] for k in canvas._layouts})
    again = _pixels(canvas.Canvas, fig)  # every layout from the cache
    monkeypatch.setattr(Text, "_get_layout", canvas._matplotlib_layout)
    computed = _pixels(canvas.Canvas, fig)
    assert np.array_equal(first, computed) and np.array_equal(again, computed)


def test_layouts_on_other_renderers_are_not_kept(empty_layouts):
    _pixels(FigureCanvasAgg)
    assert not canvas._layouts


def test_layout_key_tells_apart_what_moves_a_text(empty_layouts):
    fig = Figure(figsize=(2.0, 1.0), dpi=100)
    texts = [fig.text(0.5, 0.5, "same", ha=ha, va=va, rotation=rot, fontsize=size)
             for ha, va, rot, size in [("left", "bottom", 0, 10), ("right", "bottom", 0, 10),
                                       ("left", "top", 0, 10), ("left", "bottom", 90, 10), ("left", "bottom", 0, 12)]]
    c = canvas.Canvas(fig)
    c.draw()
    boxes = [t.get_window_extent(c.get_renderer()).bounds for t in texts]
    assert len(canvas._layouts) == len(texts) and len(set(boxes)) == len(texts)


def test_a_full_layout_cache_starts_again(empty_layouts, monkeypatch):
    monkeypatch.setattr(canvas, "MAX_CACHED_TEXTS", 3)
    _pixels(canvas.Canvas)
    assert 0 < len(canvas._layouts) <= 3


@pytest.mark.parametrize("angle", [0, 90])
def test_a_text_rasterised_on_a_bounded_canvas_is_the_measured_one(angle):
    """_rasterise sizes its scratch canvas from a bound instead of measuring the text: the same
    image and offsets as on the measured canvas, and a text that outgrows the bound (its ink at the
    canvas's edge) is drawn again on the measured one."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    renderer = RendererAgg(200, 200, 110)
    gc = renderer.new_gc()
    for s, size in (("0.0123", 6), ("WWWWMMMM", 14), ("µm – Ω", 10), ("1", 30), ("  ", 8)):
        prop = FontProperties(size=size)
        w, h, _ = renderer.get_text_width_height_descent(s, prop, False)
        measured = canvas._draw_alone(renderer, gc, s, prop, angle, None, w, h)
        got = canvas._rasterise(renderer, gc, s, prop, angle, None)
        if measured is None:
            assert got is None, s
            continue
        np.testing.assert_array_equal(got[0], measured[0])
        assert got[1:] == measured[1:], s
    assert canvas._draw_alone(renderer, gc, "WWWWMMMM", FontProperties(size=14), angle, None, 5.0, 3.0) \
        is canvas._CLIPPED


def test_a_text_that_outgrows_the_bound_is_drawn_again_on_the_measured_canvas(monkeypatch):
    """_rasterise's fallback: when the bounded canvas clips the ink, the text is measured and drawn
    again, giving the measured canvas's image (here the bound is made too small on purpose)."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    renderer = RendererAgg(200, 200, 110)
    gc = renderer.new_gc()
    prop = FontProperties(size=12)
    w, h, _ = renderer.get_text_width_height_descent("0.0123", prop, False)
    want = canvas._draw_alone(renderer, gc, "0.0123", prop, 0, None, w, h)
    calls = []
    draw = canvas._draw_alone

    def first_too_small(r, g, s, p, angle, mtext, w_, h_):
        calls.append((w_, h_))
        return draw(r, g, s, p, angle, mtext, *((2.0, 2.0) if len(calls) == 1 else (w_, h_)))

    monkeypatch.setattr(canvas, "_draw_alone", first_too_small)
    got = canvas._rasterise(renderer, gc, "0.0123", prop, 0, None)
    assert len(calls) == 2 and calls[1] == (w, h)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[1:] == want[1:]


@pytest.mark.parametrize("angle", [0, 90])
@pytest.mark.parametrize("antialiased", [True, False])
def test_glyphs_drawn_as_agg_draws_them(angle, antialiased):
    """_draw_glyphs (the scratch canvas's text drawing) gives Agg's own pixels, at fractional
    anchors, for upright and 90° texts, antialiased or not, in several sizes and with the
    characters hystfit's labels use (–, µ, ±, −, ², Ω)."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.font_manager import FontProperties

    for s, size in (("pi – 40V_50Hz (a40V_f50Hz.csv)", 12), ("R²=0.9999 RMSE=0.0145 µm", 8.3),
                    ("±RMSE = 0.0307 µm", 10), ("−0.050", 6.5), ("WAVE Ω", 20), ("", 10)):
        prop = FontProperties(size=size)
        pictures = []
        for draw in (lambda r, g: RendererAgg.draw_text(r, g, 120.3, 250.7, s, prop, angle, False, None),
                     lambda r, g: canvas._draw_glyphs(r, g, 120.3, 250.7, s, prop, angle, None)):
            r = RendererAgg(400, 300, 110)
            g = r.new_gc()
            g.set_antialiased(antialiased)
            g.set_foreground("tab:red")
            draw(r, g)
            pictures.append(np.asarray(r.buffer_rgba()).copy())
        np.testing.assert_array_equal(pictures[1], pictures[0], err_msg=s)
        assert pictures[0][..., 3].any() == bool(s.strip())
