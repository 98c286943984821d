"""A corner legend of lines and filled bands, drawn straight onto the canvas.

matplotlib's :class:`~matplotlib.legend.Legend` builds a tree of offset boxes on creation and lays
it out again on every draw, measuring each text several times. The fixed-layout figures (loop and
time series) only need a legend in a corner of the axes, with line and band handles and one-line
labels, so :func:`corner_legend` draws that directly: the geometry of matplotlib's legend (the
rcParams ``legend.*`` in force: padding, spacing, handle size, frame colour and transparency,
rounded corners), computed from the texts' cached layouts (:mod:`hystfit.report.canvas`), then
one frame, one handle and one text per entry — the same pixels (``tests/unit/test_legend.py``).
Settings it does not draw (label colours taken from the lines, a shadow) and anything else
(markers, titles, columns, ``loc="best"``) are left to matplotlib's legend.

This module imports matplotlib; :mod:`hystfit.report.plots` imports it when it draws.
"""

from __future__ import annotations

from typing import Sequence

import matplotlib as mpl
from matplotlib.artist import Artist
from matplotlib.lines import Line2D
from matplotlib.patches import FancyBboxPatch, Patch, Rectangle
from matplotlib.text import Text
from matplotlib.transforms import Bbox, IdentityTransform

__all__ = ["CornerLegend", "corner_legend", "LOCATIONS"]

#: where the legend sits: the corner's anchor for :meth:`~matplotlib.transforms.Bbox.anchored`
LOCATIONS = {"upper right": "NE", "upper left": "NW", "lower left": "SW", "lower right": "SE"}


def _entries(ax) -> list[tuple[Artist, str]]:
    """The (handle, label) pairs ``ax.legend()`` would show of its lines and patches: those with a
    label not starting with an underscore, in the order they were added."""
    return [(a, a.get_label()) for a in ax._children
            if isinstance(a, (Line2D, Patch)) and a.get_label() and not a.get_label().startswith("_")]


class CornerLegend(Artist):
    """A legend in a corner of ``ax`` (see the module's description), kept by the axes and shown
    again with new entries (:meth:`show`) by each figure of a template: its texts, handles and
    frame are made once and restyled, not rebuilt.

    Parameters
    ----------
    ax : Axes
    """

    zorder = 5  # as matplotlib's legend: above the lines
    #: a template's reset hides it instead of removing it (:func:`hystfit.report.plots._reset_axes`)
    reusable = True

    def __init__(self, ax) -> None:
        super().__init__()
        self.ax = ax
        self.loc = "upper right"
        self.fontsize_pt = 10.0
        self._texts: list[Text] = []
        self._handles: list[Artist] = []
        rc = mpl.rcParams
        linewidth = rc["legend.linewidth"] if rc.get("legend.linewidth") is not None else rc["patch.linewidth"]
        face, edge = rc["legend.facecolor"], rc["legend.edgecolor"]
        self._frame = FancyBboxPatch(
            (0.0, 0.0), 1.0, 1.0, transform=IdentityTransform(), snap=True, linewidth=linewidth,
            facecolor=ax.get_facecolor() if face == "inherit" else face,
            edgecolor=rc["axes.edgecolor"] if edge == "inherit" else edge,
            alpha=rc["legend.framealpha"],
            boxstyle="round,pad=0,rounding_size=0.2" if rc["legend.fancybox"] else "square,pad=0",
            visible=rc["legend.frameon"])
        self._frame.set_figure(ax.get_figure())

    def show(self, entries: Sequence[tuple[Artist, str]], loc: str = "upper right", fontsize=None) -> None:
        """Show ``entries`` — (line or band whose style the legend copies, label), top to bottom —
        at ``loc`` (one of :data:`LOCATIONS`) in ``fontsize`` (as matplotlib's: ``"small"``, 10, …;
        default ``legend.fontsize``)."""
        if loc not in LOCATIONS:
            raise ValueError(f"loc must be one of {sorted(LOCATIONS)}, not {loc!r}")
        figure = self.ax.get_figure()
        size = mpl.rcParams["legend.fontsize"] if fontsize is None else fontsize
        while len(self._texts) < len(entries):
            text = Text(0.0, 0.0, "", color=_label_colour(), ha="left", va="baseline", transform=IdentityTransform())
            text.set_figure(figure)
            self._texts.append(text)
        del self._texts[len(entries):]
        handles = []
        for i, ((source, label), text) in enumerate(zip(entries, self._texts)):
            text.set_text(label)
            text.set_fontsize(size)
            old = self._handles[i] if i < len(self._handles) else None
            handles.append(_handle(source, old))
            handles[-1].set_figure(figure)
        self._handles = handles
        self.loc = loc
        self.fontsize_pt = self._texts[0].get_fontsize() if self._texts else 10.0
        self.set_visible(bool(entries))

    def draw(self, renderer) -> None:
        if not self.get_visible() or not self._texts:
            return
        rc = mpl.rcParams
        to_px = renderer.points_to_pixels(1.0)
        fs = self.fontsize_pt * to_px
        # each row: the text's extent above and below its baseline as matplotlib's TextArea
        # measures a label (its layout, at least as tall as "lp" above the baseline), the
        # handle's above the baseline
        _, lp_h, lp_d = _metrics(renderer, "lp", self._texts[0].get_fontproperties())
        rows, width = [], 0.0
        for text in self._texts:
            w, h, descent = _extent(text, renderer)
            rows.append((max(lp_h - lp_d, h - descent, rc["legend.handleheight"] * fs), descent))
            width = max(width, w)
        pad = rc["legend.borderpad"] * fs
        handle_w = rc["legend.handlelength"] * fs
        width += 2 * pad + handle_w + rc["legend.handletextpad"] * fs
        height = 2 * pad + sum(a + b for a, b in rows) + rc["legend.labelspacing"] * fs * (len(rows) - 1)
        corner = self.ax.bbox.padded(-rc["legend.borderaxespad"] * fs)
        x0, y0 = Bbox.from_bounds(0.0, 0.0, width, height).anchored(LOCATIONS[self.loc], container=corner).p0
        self._frame.set_bounds(x0, y0, width, height)
        self._frame.set_mutation_scale(fs)
        self._frame.draw(renderer)
        top = y0 + height - pad
        handle_h = rc["legend.handleheight"] * fs
        for (above, below), handle, text in zip(rows, self._handles, self._texts):
            baseline = top - above
            if isinstance(handle, Line2D):
                y = baseline + handle_h / 2
                handle.set_data([x0 + pad, x0 + pad + handle_w], [y, y])
            else:
                handle.set_bounds(x0 + pad, baseline, handle_w, handle_h)
            handle.draw(renderer)
            text.set_position((x0 + pad + handle_w + rc["legend.handletextpad"] * fs, baseline))
            text.draw(renderer)
            top = baseline - below - rc["legend.labelspacing"] * fs
        self.stale = False


def _label_colour():
    return mpl.rcParams["text.color"]  # legend.labelcolor unset (:func:`drawable`)


def _extent(text: Text, renderer) -> tuple[float, float, float]:
    """Width, height and last line's descent of ``text``'s layout (pixels), as matplotlib lays it
    out (kept per process on hystfit's canvas: :func:`hystfit.report.canvas._layout`)."""
    bbox, info, third = text._get_layout(renderer)
    if isinstance(third, (int, float)):  # matplotlib < 3.11: (bbox, lines, descent)
        descent = float(third)
    else:  # (bbox, [(line, (width, ascent, descent), xy), …], box)
        descent = float(info[-1][1][2])
    return float(bbox.width), float(bbox.height), descent


def _metrics(renderer, s: str, prop) -> tuple[float, float, float]:
    """Width, height and descent of the plain text ``s`` (pixels), kept per renderer by matplotlib."""
    if not s:
        return 0.0, 0.0, 0.0
    try:
        from matplotlib.text import _get_text_metrics_with_cache
    except ImportError:  # a matplotlib without its metrics cache: measured every time
        return renderer.get_text_width_height_descent(s, prop, False)
    return _get_text_metrics_with_cache(renderer, s, prop, False, renderer.dpi)


def _handle(source: Artist, old: Artist | None = None) -> Artist:
    """A legend handle drawn in pixels with ``source``'s style: a line for a line, a box for a band
    (``old`` restyled when it is of that kind)."""
    if isinstance(source, Line2D):
        line = old if type(old) is Line2D else Line2D([0.0, 1.0], [0.0, 0.0], transform=IdentityTransform())
        line.update_from(source)
        line.set_marker("None")
        line.set_transform(IdentityTransform())
        line.set_clip_on(False)  # inside the legend's frame, as matplotlib's handles
        return line
    box = old if type(old) is Rectangle else Rectangle((0.0, 0.0), 1.0, 1.0, transform=IdentityTransform())
    box.update_from(source)
    box.set_transform(IdentityTransform())
    box.set_clip_on(False)
    return box


def drawable() -> bool:
    """Whether the legend settings in force are ones :class:`CornerLegend` draws as matplotlib's
    legend would: label colours of their own (not taken from the lines) and no shadow."""
    return mpl.rcParams["legend.labelcolor"] in (None, "None", "none") and not mpl.rcParams["legend.shadow"]


def corner_legend(ax, loc: str = "upper right", fontsize=None) -> CornerLegend | None:
    """Show a :class:`CornerLegend` of ``ax``'s labelled lines and bands (as ``ax.legend(loc=loc)``
    would show them) and return it; None when nothing is labelled, or when the legend settings in
    force are not :func:`drawable` (then ``ax.legend`` draws it). The axes keeps its legend (a
    template's next figure restyles it)."""
    legend = next((a for a in ax.artists if isinstance(a, CornerLegend)), None)
    entries = _entries(ax)
    if not entries or not drawable():
        if legend is not None:
            legend.set_visible(False)
        if entries:  # settings this legend does not draw: matplotlib's own
            ax.legend(loc=loc, fontsize=fontsize)
        return None
    if legend is None:
        legend = CornerLegend(ax)
        ax.add_artist(legend)
    legend.show(entries, loc, fontsize)
    return legend
