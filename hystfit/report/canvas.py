"""The Agg canvas of hystfit's figures: each text is rasterised once per process, then stamped.

A report draws the same strings in figure after figure (axis labels, legend entries, tick labels
such as ``0``, ``10``, ``20``), and Agg lays out and rasterises every glyph of every text on every
draw: ≈ a third of a small figure's time. :class:`Canvas` draws with :class:`TextCachingRenderer`,
which rasterises a text once (at a whole-pixel position, in its colour, on a transparent scratch
canvas), keeps the image, and stamps it wherever the same text is drawn again, however many
figures later. Every text goes through the image (on a miss it is made first), so a figure's
pixels do not depend on what the process drew before: the same inputs give the same bytes in any
process. Mathtext and texts at angles other than 0° and 90° are drawn the ordinary way.

Before a text is drawn (and again when an axis measures its tick labels, a legend its entries),
matplotlib lays it out: it measures each line and places the lines in a box relative to the
text's anchor (``Text._get_layout``, ≈ 15 % of a small figure's time). That layout depends only on
the text's string, font, rotation, alignments, line spacing and the dpi, not on where the text
sits, so on this canvas it is kept per process as well (:func:`_layout`): the same numbers as
matplotlib's own computation, looked up instead of recomputed. Texts drawn on any other renderer,
wrapped texts and TeX texts are laid out by matplotlib as before.

This module imports matplotlib; :mod:`hystfit.report.plots` imports it when it draws.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.text import Text

__all__ = ["Canvas", "TextCachingRenderer", "MAX_CACHED_TEXTS"]

#: most text images, and most text layouts, kept per process (each cache starts again when full)
MAX_CACHED_TEXTS = 4096

_text_images: dict[tuple, tuple[np.ndarray, int, int] | None] = {}
_layouts: dict[tuple, tuple] = {}
_matplotlib_layout = Text._get_layout


def _layout(text: Text, renderer):
    """``Text._get_layout`` (the text's box and lines relative to its anchor), kept per process
    for texts drawn on a :class:`TextCachingRenderer` (see the module's description)."""
    if type(renderer) is not TextCachingRenderer or text.get_wrap() or text.get_usetex():
        return _matplotlib_layout(text, renderer)
    try:
        key = (text.get_text(), text.get_fontproperties().copy(), text.get_rotation(), text.get_rotation_mode(),
               text._horizontalalignment, text._verticalalignment, text._get_multialignment(), text._linespacing,
               text.get_parse_math(), text.get_figure(root=True).dpi, renderer.dpi)
    except (AttributeError, TypeError):  # a matplotlib whose Text keeps these elsewhere: no cache
        return _matplotlib_layout(text, renderer)
    try:
        return _layouts[key]
    except KeyError:
        if len(_layouts) >= MAX_CACHED_TEXTS:
            _layouts.clear()
        value = _layouts[key] = _matplotlib_layout(text, renderer)
        return value


Text._get_layout = _layout


def _rasterise(renderer: RendererAgg, gc, s: str, prop, angle: float, mtext) -> tuple[np.ndarray, int, int] | None:
    """``s`` drawn alone: its RGBA image (rows bottom-up) and the offsets of the image's left
    column and bottom row from the text's anchor (x right, y down), or None when it has no ink.

    The scratch canvas is first sized from a bound on the text's extent (1.5 em a character, 1.5 em
    high) instead of measuring it — a measurement lays the text out once more, a third of a new
    text's cost (a heat map's 240 new cell numbers) — and the text drawn at the same whole-pixel
    anchor, so the cropped image and its offsets are the same; where the ink reaches the canvas's
    edge (a glyph wider than the bound) the text is measured and drawn again, as before."""
    em = float(prop.get_size_in_points()) * renderer.dpi / 72.0
    bound = (1.5 * em * (len(s) + 1), 1.5 * em)
    image = _draw_alone(renderer, gc, s, prop, angle, mtext, *bound)
    if image is _CLIPPED:
        w, h, _ = renderer.get_text_width_height_descent(s, prop, False)
        image = _draw_alone(renderer, gc, s, prop, angle, mtext, w, h)
    return image


#: what :func:`_draw_alone` returns when the ink touches its canvas's edge
_CLIPPED = object()


def _draw_alone(renderer: RendererAgg, gc, s: str, prop, angle: float, mtext, w: float, h: float):
    """``s`` drawn on a scratch canvas that holds a text of width ``w`` and height ``h`` (pixels) at
    ``angle`` (0° or 90°) around its anchor: (image, left, bottom) as :func:`_rasterise`, None
    without ink, or :data:`_CLIPPED` when the ink reaches the canvas's edge.

    The canvas runs along the text only (``w`` + 2 ``h`` by 3 ``h``, the anchor ``h`` in from the
    start and the baseline side): a square one of ``w`` + 2 ``h`` held both angles, ≈ 25 times the
    pixels for a title, cleared and searched for ink. The image and offsets are the same on any
    canvas that holds the ink (tested)."""
    along, across = math.ceil(w + 2 * h) + 8, math.ceil(3 * h) + 8
    margin = math.ceil(h) + 4
    if angle == 0:  # runs right from the anchor; ascent up (2 h of room), descent down
        width, height, x0, y0 = along, across, margin, across - margin
    else:  # 90°: runs up from the anchor; ascent to the left (2 h of room), descent to the right
        width, height, x0, y0 = across, along, across - margin, along - margin
    scratch = RendererAgg(width, height, renderer.dpi)
    local = scratch.new_gc()
    local.copy_properties(gc)
    local.set_clip_rectangle(None)  # the clip of the figure applies when the image is stamped
    local.set_clip_path(None)
    _draw_glyphs(scratch, local, x0, y0, s, prop, angle, mtext)
    local.restore()
    rgba = np.asarray(scratch.buffer_rgba())
    ink = rgba[..., 3] > 0
    rows = np.flatnonzero(ink.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(ink.any(axis=0))
    top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    if top == 0 or left == 0 or bottom == height or right == width:
        return _CLIPPED
    return rgba[top:bottom, left:right][::-1].copy(), int(left - x0), int(bottom - y0)


def _glyph_api() -> bool:
    """Whether this matplotlib draws a text glyph by glyph through the private FreeType calls
    :func:`_draw_glyphs` repeats (matplotlib ≥ 3.11; older ones rasterise a whole string in C++)."""
    from matplotlib import ft2font

    needed = ("_layout", "_set_transform", "_render_glyph")
    return (hasattr(RendererAgg, "_draw_text_glyphs_and_boxes") and hasattr(RendererAgg, "_prepare_font")
            and all(hasattr(ft2font.FT2Font, name) for name in needed) and hasattr(ft2font, "RenderMode"))


_GLYPH_API = _glyph_api()
#: FreeType's 16.16 transform of a text at 0° and 90°, with the angle's cosine and sine
_ROTATIONS = {0: ([[0x10000, 0], [0, 0x10000]], 1.0, 0.0), 90: ([[0, -0x10000], [0x10000, 0]], 0.0, 1.0)}


def _draw_glyphs(scratch: RendererAgg, gc, x: float, y: float, s: str, prop, angle: float, mtext) -> None:
    """``RendererAgg.draw_text`` of a plain text at 0° or 90°: the same pixels (tested).

    matplotlib 3.11 draws a text glyph by glyph in Python, rebuilding the same rotation matrix with
    numpy and setting the font's size for every glyph (``python benchmarks/bench_figures.py
    --texts``: ≈ 2.3 ms for a 30-character title). Here the matrix is built once per angle and the
    size set once per font, the same FreeType calls with the same arguments otherwise. Other matplotlib versions, and anything but
    an upright or 90° text, are drawn by matplotlib itself."""
    if not _GLYPH_API or angle not in _ROTATIONS:
        RendererAgg.draw_text(scratch, gc, x, y, s, prop, angle, False, mtext)
        return
    from matplotlib.backends.backend_agg import get_hinting_flag
    from matplotlib.ft2font import RenderMode

    flags = get_hinting_flag()
    font = scratch._prepare_font(prop)
    items = font._layout(s, flags=flags, features=mtext.get_fontfeatures() if mtext is not None else None,
                         language=mtext.get_language() if mtext is not None else None)
    size = prop.get_size_in_points()
    matrix, cos, sin = _ROTATIONS[angle]
    antialiased = gc.get_antialiased()
    mode = RenderMode.NORMAL if antialiased else RenderMode.MONO
    height = scratch.height
    draw = scratch._renderer.draw_text_image
    sized = None
    for item in items:
        glyph_font, dx, dy = item.ft_object, item.x, item.y  # dy is upwards
        if glyph_font is not sized:
            glyph_font.set_size(size, scratch.dpi)
            sized = glyph_font
        glyph_font._set_transform(matrix, [round(0x40 * (x + dx * cos - dy * sin)),
                                           round(0x40 * (height - y + dx * sin + dy * cos))])  # FreeType's y is up
        bitmap = glyph_font._render_glyph(item.glyph_index, flags, mode)
        buffer = bitmap.buffer
        if not antialiased:
            buffer *= 0xff
        draw(buffer, bitmap.left, int(height) - bitmap.top + buffer.shape[0], 0, gc)


class TextCachingRenderer(RendererAgg):
    """:class:`~matplotlib.backends.backend_agg.RendererAgg` that draws texts from a per-process
    cache of their images (see the module's description)."""

    def draw_text(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
        if ismath or angle not in (0, 90):
            return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
        key = (s, prop.copy(), angle, self.dpi, gc.get_antialiased(), tuple(gc.get_rgb()), gc.get_alpha(),
               gc.get_forced_alpha(), None if mtext is None else (mtext.get_fontfeatures(), mtext.get_language()))
        try:
            image = _text_images[key]
        except KeyError:
            if len(_text_images) >= MAX_CACHED_TEXTS:
                _text_images.clear()
            image = _text_images[key] = _rasterise(self, gc, s, prop, angle, mtext)
        if image is not None:
            rgba, left, bottom = image
            # x, y: the anchor, y from the top; draw_image takes the lower-left corner, y from the bottom
            self.draw_image(gc, round(x) + left, self.height - (round(y) + bottom), rgba)


class Canvas(FigureCanvasAgg):
    """An Agg canvas that draws with :class:`TextCachingRenderer`."""

    def get_renderer(self):
        w, h = self.get_width_height(physical=True)
        key = (w, h, self.figure.dpi)
        if getattr(self, "_renderer_key", None) != key:
            self.renderer = TextCachingRenderer(w, h, self.figure.dpi)
            self._renderer_key = key
        return self.renderer
