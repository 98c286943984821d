"""Figures for reports, written as PNG files.

Every function takes plain arrays, a unit and a title (and ``dpi``, the resolution, default 110),
draws one figure, writes it atomically (:func:`hystfit.io.atomic_write_bytes`: a hidden temporary
file in the target directory, then :func:`os.replace`, so a reader never sees a half-written PNG)
and returns the :class:`~pathlib.Path` written. ``path`` may instead be a binary file object
(:class:`io.BytesIO`, an open file): the PNG is written to it, and it is returned. Nothing is
printed and nothing is shown on screen.

Figures are built with the object-oriented :class:`matplotlib.figure.Figure` API and rendered by
the Agg canvas directly, without :mod:`matplotlib.pyplot`: no global backend is selected and no
figure is registered in pyplot's state, so importing this module does not disturb an interactive
session (Jupyter, an IDE) and no figure can leak.

Long series are reduced once per pixel before drawing, never by keeping every k-th sample (which
aliases on periodic captures: a 10⁷-sample loop drawn as a vertical line). A time series keeps, per
pixel column of its axes, the first, lowest, highest and last sample (:func:`column_envelope`), so
the picture equals the one of every sample; a loop (output against voltage) keeps one segment per
pair of neighbouring pixels visited, each drawn once however many cycles pass through it
(:func:`pixel_path`). Both keep the extreme samples exactly and cost O(N) array passes (a loop of
10⁷ samples ≈ 0.7 s per line on the 2-core machine), and matplotlib draws a few points per pixel
instead of every sample. Non-finite model values (a diverged simulation) are drawn as gaps.

The simple figures use a fixed layout (margins in inches, :func:`_new_figure` with ``margins``): no
constrained-layout pass, which measured half of each figure's time; the loop, time-series and
convergence layouts are built once per thread and reused (:func:`_template`). The Agg canvas's
pixels are encoded by :func:`png_bytes` (RGB, no row filters, zlib level 1: on a time-series
figure 7 ms instead of Pillow's 21 ms, the file ≈ 10 % smaller). Output is deterministic: the same inputs give the same bytes, in any process
(:mod:`hystfit.report.render` draws many figures in parallel).

Units: ``"um"`` is shown as ``µm``; see :func:`display_unit`.
"""

from __future__ import annotations

import math
import struct
import textwrap
import threading
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import numpy as np

from ..capture import display_unit  # noqa: F401  (re-exported: the report modules import it from here)

from ..io import atomic_write_bytes

if TYPE_CHECKING:  # matplotlib is imported when the first figure is drawn (≈ 0.4 s saved when no plot is made)
    from matplotlib.figure import Figure

__all__ = [
    "MAX_POINTS",
    "boxplot_figure",
    "convergence_figure",
    "column_envelope",
    "display_unit",
    "has_convergence_history",
    "pixel_path",
    "png_bytes",
    "heatmap_figure",
    "loop_overlay_figure",
    "convergence_compare_figure",
    "loop_figure",
    "overview_figure",
    "parity_figure",
    "timeseries_figure",
]

#: most points drawn per line by the stride helpers kept for older callers (:func:`_decimate`)
MAX_POINTS = 20_000
#: default resolution of written PNGs (dots per inch)
DPI = 110
#: sub-pixel resolution of :func:`pixel_path` (grid cells per pixel along each axis)
OVERSAMPLE = 2
#: at most this many tick intervals per axis of the loop and time-series figures (matplotlib's
#: ``nbins="auto"`` puts up to 9 on these axes): each tick label is a text to lay out and draw, and
#: 5 cut the figures' drawing time by ≈ 15 % (time series) and ≈ 20 % (loops)
TICK_BINS = 5
#: zlib level of written PNGs (:func:`png_bytes`): 1 encodes ≈ 2.5× faster than 6, files ≈ 15 % larger
PNG_COMPRESS_LEVEL = 1

_QUANTITY = {"um": "Displacement", "nm": "Displacement", "mm": "Displacement", "m": "Displacement",
             "urad": "Angle", "mrad": "Angle", "rad": "Angle", "deg": "Angle"}
# The measurement is drawn wide and the model thin on top of it, half transparent: on a 50-cycle
# capture the model line no longer hides the measurement's spread (issue 14).
_MEAS_STYLE = {"color": "0.15", "lw": 1.4, "solid_capstyle": "round"}
_MODEL_STYLE = {"color": "tab:red", "lw": 0.8, "alpha": 0.75, "solid_capstyle": "round"}


# ----------------------------------------------------------------------------------------------
# helpers



def _output_label(unit: str, what: str | None = None) -> str:
    return f"{what or _QUANTITY.get(unit, 'Output')} ({display_unit(unit)})"


def _stride(n: int, max_points: int = MAX_POINTS) -> int:
    """Step ``k`` such that ``x[::k]`` has at most ``max_points`` of ``n`` samples (1 if short)."""
    if max_points < 1:
        raise ValueError(f"max_points must be >= 1, got {max_points}")
    return max(1, math.ceil(n / max_points))


def _decimate(x, max_points: int = MAX_POINTS) -> np.ndarray:
    """Every k-th sample of ``x`` so that at most ``max_points`` remain (``x`` itself if short).

    Arrays of the same length get the same stride, so decimated ``u`` and ``y`` stay paired.
    """
    x = np.asarray(x)
    return x[:: _stride(x.shape[0], max_points)]


def _decimate_minmax(t, y, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Decimate ``(t, y)`` to at most ``max_points`` points, keeping each bucket's min and max of ``y``.

    Used for residuals, where a stride would drop the peaks a reader is looking for. Falls back
    to a plain stride when ``y`` holds non-finite values.
    """
    t, y = np.asarray(t), np.asarray(y)
    n = y.shape[0]
    if n <= max_points:
        return t, y
    if not np.all(np.isfinite(y)):
        k = _stride(n, max_points)
        return t[::k], y[::k]
    k = _stride(n, max(1, max_points // 2))  # two points per bucket
    nb = n // k
    body = y[: nb * k].reshape(nb, k)
    base = np.arange(nb) * k
    idx = np.concatenate([base + body.argmin(axis=1), base + body.argmax(axis=1)])
    if nb * k < n:  # tail shorter than a bucket
        tail = y[nb * k:]
        idx = np.concatenate([idx, nb * k + np.array([tail.argmin(), tail.argmax()])])
    idx = np.unique(idx)
    return t[idx], y[idx]


def _finite_or_nan(y: np.ndarray) -> np.ndarray:
    """Float copy with ±inf replaced by NaN (drawn as gaps, harmless to autoscaling)."""
    y = np.asarray(y, dtype=float)
    return np.where(np.isfinite(y), y, np.nan) if not np.all(np.isfinite(y)) else y


def _is_multi(x) -> bool:
    """True for a list/tuple of array-likes (several captures), False for one series."""
    return isinstance(x, (list, tuple)) and len(x) > 0 and all(np.ndim(el) >= 1 for el in x)


def _captures(name_arrays: Mapping[str, object]) -> list[tuple[np.ndarray, ...]]:
    """Normalise one series or lists of series into a list of equal-length tuples per capture.

    ``None`` values stay ``None`` in every tuple (e.g. no model output).
    """
    present = {k: v for k, v in name_arrays.items() if v is not None}
    multi = {k: _is_multi(v) for k, v in present.items()}
    if any(multi.values()) and not all(multi.values()):
        raise ValueError("pass either one array or a list of arrays for each of "
                         f"{', '.join(present)}, not a mixture")
    lists = {k: (list(v) if multi[k] else [v]) for k, v in present.items()}
    counts = {k: len(v) for k, v in lists.items()}
    if len(set(counts.values())) > 1:
        raise ValueError(f"different numbers of captures: {counts}")
    n_cap = next(iter(counts.values()))
    out = []
    for i in range(n_cap):
        row = {k: np.asarray(lists[k][i], dtype=float).ravel() for k in lists}
        lengths = {k: a.size for k, a in row.items()}
        if len(set(lengths.values())) > 1:
            raise ValueError(f"capture {i}: arrays differ in length {lengths}")
        out.append(tuple(row.get(k) for k in name_arrays))
    return out


def _first_per_run(keys: np.ndarray) -> np.ndarray:
    """Positions where a run of equal consecutive ``keys`` starts."""
    if keys.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])


def _first_occurrences(keys: np.ndarray) -> np.ndarray:
    """Mask of the first occurrence of each value of ``keys``, in one hashing pass.

    pandas hashes (O(N)); ``np.unique(return_index=True)`` sorts and was ≈ 5× slower on 10⁷ keys,
    but importing pandas costs ≈ 0.3–0.4 s and sorting 10⁶ keys ≈ 0.1 s: below
    :data:`HASH_KEYS_FROM` keys numpy sorts (same mask), so a short capture's loop figure never
    imports pandas.
    """
    keys = np.asarray(keys)
    if keys.size < HASH_KEYS_FROM:
        first = np.zeros(keys.size, dtype=bool)
        first[np.unique(keys, return_index=True)[1]] = True
        return first
    import pandas as pd

    return ~pd.Series(keys, copy=False).duplicated(keep="first").to_numpy()


#: from this many keys :func:`_first_occurrences` hashes with pandas instead of sorting with numpy
HASH_KEYS_FROM = 1_000_000


def column_envelope(x, y, columns: int) -> np.ndarray | None:
    """Indices of the samples that draw ``y`` against a monotonic ``x`` exactly at ``columns`` pixels.

    Per pixel column of ``x`` the first, lowest, highest and last sample are kept (the M4
    reduction): the line drawn through them covers the same pixels as the line through every
    sample, and the series' minimum and maximum are kept exactly. The first non-finite sample of
    each run of them is kept too, so that gaps stay gaps. Cost O(N), no sort.

    Parameters
    ----------
    x : ndarray, shape (N,)
        Non-decreasing abscissa (time, sample index); if it is not, the sample index is used.
    y : ndarray, shape (N,)
    columns : int
        Pixel columns of the axes.

    Returns
    -------
    ndarray of int or None
        Sorted indices, or None when the series is short enough to draw whole (N ≤ 4 · columns).
    """
    y = np.asarray(y, dtype=float)
    n = y.size
    columns = max(1, int(columns))
    if n <= 4 * columns:
        return None
    x = np.asarray(x, dtype=float)
    lo, hi = float(x[0]), float(x[-1])
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo) or np.any(x[1:] < x[:-1]):
        x, lo, hi = np.arange(n, dtype=float), 0.0, float(n - 1)
    col = ((x - lo) * (columns / (hi - lo))).astype(np.int64)
    np.minimum(col, columns - 1, out=col)
    starts = _first_per_run(col)
    ends = np.r_[starts[1:], n] - 1
    finite = np.isfinite(y)
    all_finite = bool(finite.all())
    yf = y if all_finite else np.where(finite, y, np.nan)
    seg = np.cumsum(np.r_[False, col[1:] != col[:-1]])  # column run of each sample
    keep = [starts, ends]
    for reduce in (np.fmin, np.fmax):
        ext = reduce.reduceat(yf, starts)
        hits = np.flatnonzero(yf == ext[seg])  # NaN never equals: all-NaN columns have none
        keep.append(hits[_first_per_run(seg[hits])])
    if not all_finite:
        keep.append(np.flatnonzero(~finite & np.r_[True, finite[:-1]]))
    return np.unique(np.concatenate(keep))


def _span(a: np.ndarray) -> tuple[float, float] | None:
    a = a[np.isfinite(a)]
    return (float(a.min()), float(a.max())) if a.size else None


def pixel_path(x, y, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """The polyline ``(x, y)`` reduced to one segment per pair of neighbouring grid cells visited.

    The data range is divided into ``nx × ny`` cells (:data:`OVERSAMPLE` per pixel of the axes);
    consecutive samples in the same cell are merged, and each segment between two cells is kept
    once, however often the path crosses it (a periodic capture redraws the same loop at every
    cycle). The picture equals the one of every sample to within a cell, without the aliasing of
    a stride, and the samples with the lowest and highest ``x`` and ``y`` are kept exactly.
    Segments are returned in time order, chained where they join, with NaN between chains;
    non-finite samples become gaps.

    Returns
    -------
    (xs, ys) : ndarrays
        Coordinates to pass to ``Axes.plot`` (the input itself when nothing would be saved).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = y.size
    if n <= 2 * (nx + ny):
        return x, _finite_or_nan(y)
    finite = np.isfinite(x) & np.isfinite(y)
    if not finite.any():
        return x[:1], np.full(1, np.nan)
    (x0, x1), (y0, y1) = _span(x[finite]), _span(y[finite])
    ix = np.where(finite, x - x0, 0.0) * (nx / (x1 - x0 if x1 > x0 else 1.0))
    iy = np.where(finite, y - y0, 0.0) * (ny / (y1 - y0 if y1 > y0 else 1.0))
    code = ix.astype(np.int64) * (ny + 1) + iy.astype(np.int64)
    code[~finite] = -1
    cells = (nx + 1) * (ny + 1)
    fin_idx = np.flatnonzero(finite)
    extremes = fin_idx[[np.argmin(x[finite]), np.argmax(x[finite]), np.argmin(y[finite]), np.argmax(y[finite])]]
    is_extreme = np.zeros(n, dtype=bool)
    is_extreme[extremes] = True
    mark = is_extreme.copy()
    mark[0] = True
    mark[1:] |= code[1:] != code[:-1]  # first sample of each run in one cell
    keep = np.flatnonzero(mark)
    c = code[keep]
    a, b = c[:-1], c[1:]
    key = a * cells + b
    valid = (a >= 0) & (b >= 0)
    # segments touching an extreme sample are never merged with others, so that sample is drawn
    special = np.flatnonzero(is_extreme[keep[:-1]] | is_extreme[keep[1:]])
    key[special] = -1 - special
    pos = np.flatnonzero(valid)
    if pos.size == 0:
        pts = keep[c >= 0]
        return x[pts], y[pts]
    pos = pos[_first_occurrences(key[pos])]
    s, e = keep[pos], keep[pos + 1]
    new = np.r_[True, s[1:] != e[:-1]]  # a segment that does not continue the previous one
    cnt = 1 + new.astype(np.int64) + (new & (np.arange(s.size) > 0))  # [NaN] [start] end
    out = np.empty(int(cnt.sum()), dtype=np.int64)
    at_end = np.cumsum(cnt) - 1
    out[at_end] = e
    out[at_end[new] - 1] = s[new]
    gap = new.copy()
    gap[0] = False
    out[at_end[gap] - 2] = -1
    nan = out < 0
    idx = np.where(nan, 0, out)
    xs, ys = x[idx], y[idx]
    xs[nan] = np.nan
    ys[nan] = np.nan
    return xs, ys


def png_bytes(rgba: np.ndarray, dpi: float) -> bytes:
    """A PNG file of an 8-bit RGBA image, encoded for speed: RGB when every pixel is opaque, no
    row filter, zlib level :data:`PNG_COMPRESS_LEVEL`, the resolution in a ``pHYs`` chunk.

    On a figure (flat colours, antialiased lines) the filters PNG encoders try on every row shrink
    the file little and cost more than the compression; this writes ≈ 3× faster than Pillow's
    encoder at the same zlib level, and the file is no larger.

    Parameters
    ----------
    rgba : ndarray of uint8, shape (H, W, 4)
    dpi : float
        Resolution stored in the file (dots per inch).
    """
    rgba = np.ascontiguousarray(rgba, dtype=np.uint8)
    h, w, _ = rgba.shape
    opaque = bool(rgba[..., 3].min() == 255)
    channels = 3 if opaque else 4
    rows = np.empty((h, 1 + w * channels), dtype=np.uint8)
    rows[:, 0] = 0  # filter type "None" on every row
    # one copy, pixel by pixel: each pixel's first ``channels`` bytes as one 3- or 4-byte item
    # (a copy byte by byte, with an inner loop of 3, takes ≈ 4× as long)
    pixels = rgba.reshape(h, w * 4).view(np.dtype({"names": ["px"], "formats": [f"V{channels}"], "itemsize": 4}))
    rows[:, 1:].view(f"V{channels}")[...] = pixels["px"]
    per_metre = round(dpi / 0.0254)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", w, h, 8, 2 if opaque else 6, 0, 0, 0)  # 8 bit RGB(A), not interlaced
    return b"".join([b"\x89PNG\r\n\x1a\n", chunk(b"IHDR", header),
                     chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)),
                     chunk(b"IDAT", zlib.compress(rows, PNG_COMPRESS_LEVEL)), chunk(b"IEND", b"")])


def _save(fig: Figure, path, dpi: int, draw: Callable | None = None) -> Path:
    """Render ``fig`` at ``dpi`` on the Agg canvas and write it to ``path`` as PNG, atomically.

    The figure is drawn on a :class:`~hystfit.report.canvas.Canvas` (texts stamped from a cache of
    their images), whose pixels are encoded by :func:`png_bytes` (without Pillow's filter search) and written by :func:`hystfit.io.atomic_write_bytes`
    (temporary file in the same directory, then :func:`os.replace`; parent directories are
    created), so a reader sees the previous file or the complete new one, and a failed render
    leaves nothing. ``path`` may also be a binary file object (e.g. :class:`io.BytesIO`): the PNG is
    written to it and nothing touches the disk. The figure is not cleared: a template
    (:func:`_template`) is reset on its next use, any other figure is dropped by its caller.
    ``draw(renderer)``: draws the figure on the cleared canvas instead of ``Figure.draw``.

    Raises
    ------
    OutputError
        If the location cannot be written.
    """
    from .canvas import Canvas

    if fig.dpi != dpi:
        fig.set_dpi(dpi)
    canvas = fig.canvas if isinstance(fig.canvas, Canvas) else Canvas(fig)
    if draw is None:
        canvas.draw()
    else:
        renderer = canvas.get_renderer()
        renderer.clear()
        draw(renderer)
    png = png_bytes(np.asarray(canvas.buffer_rgba()), dpi)
    if hasattr(path, "write"):  # a binary file object, as matplotlib's savefig takes
        path.write(png)
        return path
    path = Path(path)
    atomic_write_bytes(path, png, sync=False)  # a figure is redrawn from the numbers: no wait for the disk
    return path


def _new_figure(width: float, height: float, margins: tuple[float, float, float, float] | None = None,
                *, dpi: int = DPI, hspace: float | None = None, wspace: float | None = None) -> Figure:
    """A figure of ``width × height`` inches.

    With ``margins = (left, right, bottom, top)`` in inches the axes grid gets that fixed place
    (``hspace``/``wspace`` as in :meth:`~matplotlib.figure.Figure.subplots_adjust`) and no layout
    engine runs; without, constrained layout places it (kept for figures whose labels vary a lot).
    """
    from matplotlib.figure import Figure

    if margins is None:
        return Figure(figsize=(width, height), dpi=dpi, layout="constrained")
    fig = Figure(figsize=(width, height), dpi=dpi)
    left, right, bottom, top = margins
    fig.subplots_adjust(left=left / width, right=1 - right / width, bottom=bottom / height, top=1 - top / height,
                        hspace=hspace, wspace=wspace)
    return fig


_templates = threading.local()


def _template(key: tuple, build: Callable[[], Figure]) -> Figure:
    """A figure laid out once per thread and reused for every later figure of the same ``key``.

    Creating a figure's axes, ticks and tick labels costs ≈ 20 % of drawing a small figure; a
    report draws dozens of identical layouts. Reuse removes the previous figure's artists and data
    limits (:func:`_reset`); the bytes written equal those of a fresh figure (tested).
    """
    cache = getattr(_templates, "figures", None)
    if cache is None:
        cache = _templates.figures = {}
    fig = cache.get(key)
    if fig is None:
        fig = cache[key] = build()
        for ax in fig.axes:
            _TicksOncePerDraw.install(ax.xaxis)
            _TicksOncePerDraw.install(ax.yaxis)
        _unpainted_backgrounds(fig)
    else:
        _reset(fig)
    return fig


def _unpainted_backgrounds(fig: Figure) -> None:
    """Leave out the axes' backgrounds that paint the figure's own background again: an opaque
    axes patch of the figure's colour, over an axes no other axes overlaps, changes no pixel
    (the figure's background is drawn first). It still clips the axes' curves."""
    from matplotlib.colors import to_rgba

    face = to_rgba(fig.get_facecolor())
    if not fig.patch.get_visible() or face[3] != 1.0:
        return
    boxes = [ax.get_position() for ax in fig.axes]
    for i, ax in enumerate(fig.axes):
        alone = not any(j != i and box.overlaps(boxes[i]) for j, box in enumerate(boxes))
        if alone and to_rgba(ax.patch.get_facecolor()) == face and ax.patch.get_visible() and ax.patch.get_alpha() in (None, 1.0):
            ax.patch.set_visible(False)


class _TicksOncePerDraw:
    """An axis of a template that works out its ticks once per draw and draws their lines together.

    matplotlib's ``Axis.draw`` updates the ticks (locator, formatter, each tick's position and
    text) and measures the tick labels, then places the axis label by updating and measuring them
    all again, and the spine's extent it unions with updates them a third time. Nothing changes the ticks while what they are made from is unchanged (the
    view, the axes' place, the locators and formatters: :meth:`_state`), so later updates return
    the first one's ticks — those :func:`_fit_left_margin` made before the draw, as a rule — and
    within a draw the labels' boxes measured for them (the same objects, so the same pixels;
    tested). After a draw the next update computes afresh.

    On a linear axis whose drawn ticks are all major ticks, their grid lines, tick marks and labels
    are drawn as matplotlib's ``Tick.draw`` would, except that the grid lines are one line
    broken between ticks and the marks one line of markers (the same style, copied from the
    first tick): a few draw calls instead of three per tick, which do not overlap, so the pixels
    are the same (tested). Anything else (a log axis, minor ticks, ticks styled one by one) is
    drawn by matplotlib. Installed on the axes of :func:`_template` figures, where the matplotlib
    in use has these methods.
    """

    #: what :meth:`_draw_batched` calls on the axis, besides the methods replaced
    NEEDED = ("_update_label_position", "_update_offset_text_position", "label", "offsetText", "major", "majorTicks",
              "get_scale")

    def __init__(self, axis) -> None:
        self.axis = axis
        self.update, self.measure, self.draw = axis._update_ticks, axis._get_ticklabel_bboxes, axis.draw
        self.drawing = False
        self.ticks = self.boxes = self.key = None
        self.batches: dict[str, tuple] = {}  # part -> (its line, the style it was given)
        self.batchable = all(hasattr(axis, name) for name in self.NEEDED)
        axis._update_ticks, axis._get_ticklabel_bboxes, axis.draw = self._update_ticks, self._measure, self._draw
        axis._hystfit_ticks = self  # for the template's reset (:meth:`forget`)

    @classmethod
    def install(cls, axis) -> None:
        if all(hasattr(axis, name) for name in ("_update_ticks", "_get_ticklabel_bboxes", "draw")):
            cls(axis)

    def _draw(self, renderer, *args, **kwargs):
        self.drawing = True
        self.boxes = None  # the labels' boxes: measured once per draw
        try:
            if not (self.batchable and self.axis.get_visible() and self.axis.get_scale() == "linear"
                    and self._draw_batched(renderer)):
                return self.draw(renderer, *args, **kwargs)
        finally:
            self.drawing = False
            self.ticks = self.boxes = None

    def _draw_batched(self, renderer) -> bool:
        """``Axis.draw`` with the ticks' lines drawn together; False (nothing drawn) when the ticks
        are not all major ticks of one style."""
        axis = self.axis
        ticks = axis._update_ticks()
        major = {id(t) for t in axis.majorTicks}
        if any(id(t) not in major for t in ticks):
            return False
        ticks = [t for t in ticks if t.get_visible()]
        parts = {}
        for part in ("gridline", "tick1line", "tick2line"):
            lines = [getattr(t, part) for t in ticks]
            if not all(line.get_visible() == lines[0].get_visible() for line in lines):
                return False
            if lines and lines[0].get_visible():
                parts[part] = lines
        tlb1, tlb2 = axis._get_ticklabel_bboxes(axis._update_ticks(), renderer)
        for part, lines in parts.items():
            self._batch(part, lines).draw(renderer)
        for t in ticks:
            t.label1.draw(renderer)
            t.label2.draw(renderer)
        # the label and the offset text placed only when they draw something (an empty text draws
        # nothing wherever it is: most overview panels, the upper time-series axes)
        if axis.label.get_visible() and axis.label.get_text():
            axis._update_label_position(renderer)
            axis.label.draw(renderer)
        offset = axis.major.formatter.get_offset()
        axis.offsetText.set_text(offset)
        if offset and axis.offsetText.get_visible():
            axis._update_offset_text_position(tlb1, tlb2)
            axis.offsetText.draw(renderer)
        axis.stale = False
        return True

    def _batch(self, part: str, lines: list):
        """One line with the style of ``lines[0]`` through every line's points, NaN between lines
        (markers only where a line has its points: a tick mark's one point). The style is copied
        again only when ``lines[0]`` is another line or has another style (ticks are kept by the
        axis from figure to figure)."""
        from matplotlib.lines import Line2D

        if len(lines) == 1:
            return lines[0]
        first = lines[0]
        style = (id(first), first.get_color(), first.get_linewidth(), first.get_alpha(), first.get_linestyle(),
                 first.get_marker(), first.get_markersize(), first.get_markeredgewidth(), first.get_markeredgecolor(),
                 first.get_transform(), first.get_clip_path(), first.get_clip_box())
        batch, seen = self.batches.get(part, (None, None))
        if batch is None:
            batch = Line2D([], [])
        if style != seen:
            batch.update_from(first)
            batch.set_figure(first.get_figure())
            self.batches[part] = (batch, style)
        # as set (no units on these axes), broadcast as the line does when it draws (a grid line
        # holds its one position and the span 0, 1)
        xs, ys = zip(*(np.broadcast_arrays(np.asarray(line.get_xdata(), dtype=float),
                                           np.asarray(line.get_ydata(), dtype=float)) for line in lines))
        if all(x.size == 1 for x in xs):  # one point each (tick marks): no break needed
            batch.set_data(np.concatenate(xs), np.concatenate(ys))
        else:
            gap = np.array([np.nan])
            batch.set_data(np.concatenate([v for x in xs for v in (x, gap)][:-1]),
                           np.concatenate([v for y in ys for v in (y, gap)][:-1]))
        return batch

    def forget(self) -> None:
        """Drop the ticks kept (a template's next figure): the next update computes afresh."""
        self.ticks = self.boxes = self.key = None

    def _update_ticks(self):
        key = self._state()
        if self.ticks is None or key != self.key:
            self.ticks, self.key, self.boxes = self.update(), key, None
        return self.ticks

    def _state(self) -> tuple:
        """What the ticks are made from: the view, where the axes sits (a locator may size its
        ticks to it), the locators and formatters and the scale. The ticks worked out before a
        draw (:func:`_fit_left_margin` measures their labels) serve the draw while it is unchanged."""
        axis = self.axis
        return (tuple(axis.get_view_interval()), axis.axes.bbox.bounds, axis.get_scale(),
                id(axis.major.locator), id(axis.major.formatter), id(axis.minor.locator), id(axis.minor.formatter))

    def _measure(self, ticks, renderer):
        if not self.drawing or ticks is not self.ticks:
            return self.measure(ticks, renderer)
        if self.boxes is None:
            self.boxes = self.measure(ticks, renderer)
        return self.boxes


def _reset(fig: Figure) -> None:
    """Remove what the previous use of a template drew: artists, legends, titles, scales, limits."""
    for ax in fig.axes:
        _reset_axes(ax)
    for leg in list(fig.legends):
        leg.remove()


def _reset_axes(ax) -> None:
    """Return ``ax`` to its state before anything was drawn on it (see :func:`_reset`)."""
    from matplotlib.transforms import Bbox

    for artist in [*ax.lines, *ax.patches, *ax.collections, *ax.texts, *ax.images]:
        artist.remove()
    for axis in (ax.xaxis, ax.yaxis):
        kept = getattr(axis, "_hystfit_ticks", None)
        if kept is not None:
            kept.forget()
    for artist in ax.artists:  # a corner legend is kept, hidden, and shown again with new entries
        if getattr(artist, "reusable", False):
            artist.set_visible(False)
        else:
            artist.remove()
    if ax.legend_ is not None:
        ax.legend_.remove()
    ax.set_title("", y=1.0)
    ax.set_xlabel("")
    ax.set_ylabel("")
    # a log axis back to linear, with linear's default locator and formatter (a linear axis
    # keeps its own: every figure of a template sets the same locator parameters each time)
    if ax.get_xscale() != "linear":
        ax.set_xscale("linear")
    if ax.get_yscale() != "linear":
        ax.set_yscale("linear")
    # the view limits of a new axes: what autoscaling falls back to when a figure has no finite
    # point (else it would keep the previous figure's, or the previous overview panel's, ranges)
    ax.set_xlim(0.0, 1.0)
    ax.set_ylim(0.0, 1.0)
    ax.dataLim.set_points(Bbox.null().get_points())
    ax.ignore_existing_data_limits = True
    ax.set_autoscale_on(True)
    ax.set_prop_cycle(None)


def _corner_legend(ax, loc: str, fontsize=None) -> None:
    """The legend of ``ax``'s labelled curves in a corner (:func:`hystfit.report.legend.corner_legend`:
    drawn without matplotlib's offset boxes; the fixed-layout figures' legends)."""
    from .legend import corner_legend

    corner_legend(ax, loc, fontsize)


def _with_axes(fig: Figure) -> Figure:
    fig.add_subplot()
    return fig


def _gridded(fig: Figure) -> Figure:
    """``fig`` with its grid lines and tick density set once (a template keeps them; every figure of
    it would set the same)."""
    for ax in fig.axes:
        ax.grid(True, alpha=0.3)
        ax.locator_params(nbins=TICK_BINS)
    return fig


def _axes_pixels(ax) -> tuple[int, int]:
    """Width and height of ``ax`` in pixels (at the figure's dpi)."""
    fig = ax.get_figure()
    pos = ax.get_position()
    w, h = fig.get_size_inches() * fig.dpi
    return max(1, round(pos.width * w)), max(1, round(pos.height * h))


def _plot_xy(ax, x, y, style: dict, label=None, lw_scale: float = 1.0):
    """Draw the path ``(x, y)`` reduced to the pixels of ``ax`` (:func:`pixel_path`)."""
    w, h = _axes_pixels(ax)
    xs, ys = pixel_path(x, y, OVERSAMPLE * w, OVERSAMPLE * h)
    _add_line(ax, xs, ys, **{**style, "lw": style["lw"] * lw_scale}, label=label)


def _plot_series(ax, t, y, style: dict, label=None):
    """Draw ``y`` against monotonic ``t``, reduced per pixel column of ``ax`` (:func:`column_envelope`)."""
    idx = column_envelope(t, y, _axes_pixels(ax)[0])
    if idx is not None:
        t, y = t[idx], y[idx]
    return _add_line(ax, t, _finite_or_nan(y), **style, label=label)


def _add_line(ax, x, y, **style) -> list:
    """``ax.plot(x, y, **style)`` for float arrays and a style that names its colour: the same
    line, added without ``plot``'s argument parsing and property cycle (which such a style does
    not advance); the axes autoscale to it as after ``plot``."""
    from matplotlib.lines import Line2D

    if "color" not in style or not hasattr(ax, "_request_autoscale_view"):
        return ax.plot(x, y, **style)
    line = Line2D(x, y, **style)
    ax.add_line(line)
    ax._request_autoscale_view("x")
    ax._request_autoscale_view("y")
    return [line]


def _draw_loops(ax, caps, labels: Sequence[str], lw_scale: float = 1.0) -> None:
    for i, (u, ym, yp) in enumerate(caps):
        _plot_xy(ax, u, ym, _MEAS_STYLE, labels[0] if i == 0 else None, lw_scale)
    for i, (u, ym, yp) in enumerate(caps):  # every model line above every measurement
        if yp is not None:
            _plot_xy(ax, u, yp, _MODEL_STYLE, labels[1] if i == 0 else None, lw_scale)


# ----------------------------------------------------------------------------------------------
# figures


def _margins(left: float, right: float, bottom: float, top: float, title: str) -> tuple[float, float, float, float]:
    return left, right, bottom, top + (0.3 if title else 0.0)


#: pixels kept free between the figure's left edge and a y-axis label
_EDGE_PX = 5
_text_widths: dict[tuple, float] = {}


def _text_width(renderer, text) -> float:
    """Pixel width of the matplotlib ``Text`` ``text`` as drawn on ``renderer`` (its own layout,
    rotation included), kept per process by string and font (tick labels repeat)."""
    key = (text.get_text(), hash(text.get_fontproperties()), text.get_rotation(), renderer.dpi)
    width = _text_widths.get(key)
    if width is None:
        if len(_text_widths) >= 4096:
            _text_widths.clear()
        width = _text_widths[key] = float(text.get_window_extent(renderer).width)
    return width


def _tick_label_widths(axis, renderer) -> list[float]:
    """Pixel widths of the tick labels ``axis`` will draw in its view (major and minor): the ticks
    ``Axis._update_ticks`` makes for the draw (on a template's axis the draw reuses them:
    :class:`_TicksOncePerDraw`), each visible label measured once per process by string and font."""
    return [_text_width(renderer, t.label1) for t in axis._update_ticks()
            if t.label1.get_visible() and t.label1.get_text()]


def _fit_left_margin(fig: Figure, left_in: float) -> None:
    """Widen the left margin of a fixed-layout figure beyond ``left_in`` (inches) where a y axis's
    tick labels and label would not fit in it (long labels such as ``−0.025`` or ``250000``), and
    back to ``left_in`` on a template's next figure when they fit: the axes' y labels are never cut
    at the figure's edge. Measured before the draw, from the ticks and labels the draw will make
    (no layout pass); the curves' reduction to pixels has been made for the wider axes, which only
    keeps more detail than the narrower one shows."""
    from .canvas import Canvas

    canvas = fig.canvas if isinstance(fig.canvas, Canvas) else Canvas(fig)
    renderer = canvas.get_renderer()
    to_px = fig.dpi / 72.0
    need = 0.0
    for ax in fig.axes:
        axis = ax.yaxis
        if not ax.get_visible() or axis.get_label_position() != "left":
            continue
        widths = _tick_label_widths(axis, renderer) if axis.majorTicks[0].label1.get_visible() else []
        tick = axis.majorTicks[0]
        ticks_px = (max(widths) + (tick.get_tick_padding() + tick.get_pad()) * to_px) if widths else 0.0
        label_px = _text_width(renderer, axis.label) + axis.labelpad * to_px if axis.label.get_text() else 0.0
        need = max(need, ticks_px + label_px + _EDGE_PX)
    _set_left(fig, left_in if need <= left_in * fig.dpi else need / fig.dpi)


def _set_left(fig: Figure, left_in: float) -> None:
    """The figure's left margin at ``left_in`` inches (the fraction computed as :func:`_new_figure` does)."""
    left = left_in / fig.get_figwidth()
    if fig.subplotpars.left != left:
        fig.subplots_adjust(left=left)


def _layout_template(key: tuple, build: Callable[[], Figure], left_in: float) -> Figure:
    """:func:`_template` with its left margin back at ``left_in`` inches, where the previous figure
    may have widened it (:func:`_fit_left_margin`): the curves are reduced to the pixels of the
    same axes whatever was drawn before (the same bytes as a fresh figure)."""
    fig = _template(key, build)
    _set_left(fig, left_in)
    return fig


def loop_figure(path, u_V, y_meas, y_model=None, *, unit: str = "um", title: str = "",
                labels: Sequence[str] = ("measured", "model"), dpi: int = DPI) -> Path:
    """Hysteresis loop: output against input voltage, measured and modelled.

    The measurement is drawn wide and dark, the model thin and half transparent above it, so both
    stay visible where they coincide; long captures are reduced per pixel (:func:`pixel_path`).

    Parameters
    ----------
    path : str or Path
        PNG file to write (parent directories are created).
    u_V, y_meas, y_model : array_like or list of array_like
        Input voltage in V, measured and model output in ``unit``; one capture, or lists with one
        array per capture (several captures of one condition). ``y_model`` may be None.
    unit : str, default "um"
        Output unit.
    title : str
        Figure title.
    labels : (str, str)
        Legend labels of the measured and model curves.
    """
    caps = _captures({"u": u_V, "y_meas": y_meas, "y_model": y_model})
    margins = _margins(0.75, 0.15, 0.55, 0.12, title)
    fig = _layout_template(("loop", dpi, margins), lambda: _gridded(_with_axes(_new_figure(6.4, 4.8, margins, dpi=dpi))),
                           margins[0])
    ax = fig.axes[0]
    _draw_loops(ax, caps, labels)
    ax.set_xlabel("Voltage (V)")
    ax.set_ylabel(_output_label(unit))
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    _corner_legend(ax, "upper left")
    _fit_left_margin(fig, margins[0])
    return _save(fig, path, dpi)


def legend_headroom(ax, series, top: float) -> None:
    """Set ``ax``'s y-limits to the finite values of ``series`` (arrays) with ``top`` × their range of
    room above them for an upper legend (a blind test found the legend over a curve's last peak) and
    5 % below; nothing when they have no range."""
    vals = np.concatenate([np.asarray(a, float).ravel() for a in series])
    vals = vals[np.isfinite(vals)]
    if vals.size and np.ptp(vals) > 0:
        lo, hi = float(vals.min()), float(vals.max())
        ax.set_ylim(lo - 0.05 * (hi - lo), hi + top * (hi - lo))


def timeseries_figure(path, t_s, y_meas, y_model, *, unit: str = "um", title: str = "",
                      dpi: int = DPI) -> Path:
    """Measured and model output over time, with the residual below.

    The lower axes show the residual ``e = y_model − y_meas`` and a shaded ``±RMSE`` band (RMSE of
    all finite residuals, computed from every sample). Every line is reduced per pixel column
    (:func:`column_envelope`): peaks and the full range of the data stay visible.

    Parameters
    ----------
    path : str or Path
    t_s : array_like or None
        Time in s; ``None`` plots against the sample index.
    y_meas, y_model : array_like
        Measured and model output in ``unit`` (same length as ``t_s``).
    unit : str, default "um"
    title : str
    """
    ym = np.asarray(y_meas, dtype=float).ravel()
    yp = np.asarray(y_model, dtype=float).ravel()
    t = np.arange(ym.size, dtype=float) if t_s is None else np.asarray(t_s, dtype=float).ravel()
    if not (t.size == ym.size == yp.size):
        raise ValueError(f"t_s, y_meas and y_model differ in length ({t.size}, {ym.size}, {yp.size})")
    resid = yp - ym if np.all(np.isfinite(yp)) else np.where(np.isfinite(yp), yp - ym, np.nan)
    finite = np.isfinite(resid)
    rmse = float(np.sqrt(np.mean(resid[finite] ** 2))) if finite.any() else float("nan")

    margins = _margins(0.8, 0.15, 0.55, 0.12, title)

    def build() -> Figure:
        f = _new_figure(8.0, 5.6, margins, dpi=dpi, hspace=0.08)
        f.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [2.2, 1.0]})
        return _gridded(f)

    fig = _layout_template(("timeseries", dpi, margins), build, margins[0])
    ax, axr = fig.axes
    _plot_series(ax, t, ym, _MEAS_STYLE, "measured")
    _plot_series(ax, t, yp, _MODEL_STYLE, "model")
    legend_headroom(ax, (ym, yp), 0.3)
    ax.set_ylabel(_output_label(unit))
    _corner_legend(ax, "upper right")
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw

    u = display_unit(unit)
    if np.isfinite(rmse):
        which = "" if finite.all() else " (finite samples)"
        axr.axhspan(-rmse, rmse, color="tab:blue", alpha=0.15, lw=0, label=f"±RMSE{which} = {rmse:.3g} {u}")
    axr.axhline(0.0, color="0.5", lw=0.6)
    _plot_series(axr, t, resid, {"color": "tab:blue", "lw": 0.7}, "model − measured")
    legend_headroom(axr, (resid, np.array([-rmse, rmse])), 0.65)
    axr.set_ylabel(f"Residual ({u})")
    axr.set_xlabel("Time (s)" if t_s is not None else "Sample")
    _corner_legend(axr, "upper right", fontsize="small")
    _fit_left_margin(fig, margins[0])
    return _save(fig, path, dpi)


def convergence_figure(path, history_best, history_mean=None, *, title: str = "",
                       ylabel: str = "objective (MSE)", log: bool = True, runs=None,
                       dpi: int = DPI) -> Path:
    """Optimizer convergence: objective per iteration.

    Parameters
    ----------
    path : str or Path
    history_best : array_like or None
        Best-so-far objective per iteration (plotted as given, bold).
    history_mean : array_like, optional
        Population mean per iteration (dashed).
    title, ylabel : str
    log : bool, default True
        Logarithmic y axis; silently linear when a plotted value is ≤ 0.
    runs : list of array_like, optional
        Best-so-far histories of several runs (seeds), overlaid as thin lines.

    Notes
    -----
    Non-finite values (e.g. a population whose every member diverged) are left out as gaps.
    An empty history (a solver without iterations) gives a figure saying so; callers with a
    one-point history (an exact solve) should rather say so in words (see
    :func:`has_convergence_history`).
    """
    margins = _margins(0.85, 0.15, 0.55, 0.12, title)
    fig = _layout_template(("convergence", dpi, margins), lambda: _with_axes(_new_figure(6.4, 4.2, margins, dpi=dpi)),
                           margins[0])
    ax = fig.axes[0]
    plotted: list[np.ndarray] = []

    def draw(h, **kw):
        h = _finite_or_nan(np.ravel(np.asarray(h, dtype=float)))
        if h.size == 0:
            return
        it = np.arange(h.size, dtype=float)
        marker = "o" if h.size == 1 else None
        idx = column_envelope(it, h, _axes_pixels(ax)[0])
        if idx is not None:
            it, h = it[idx], h[idx]
        ax.plot(it, h, marker=marker, **kw)
        plotted.append(h)

    runs = list(runs) if runs is not None else []
    for i, h in enumerate(runs):
        draw(h, color="tab:gray", lw=0.8, alpha=0.6,
             label=(f"runs (n={len(runs)})" if i == 0 else None))
    if history_best is not None:
        draw(history_best, color="tab:blue", lw=1.8, label="best so far")
    if history_mean is not None:
        draw(history_mean, color="tab:orange", lw=1.0, ls="--", label="population mean")

    values = np.concatenate(plotted) if plotted else np.empty(0)
    values = values[np.isfinite(values)]
    if values.size == 0:
        ax.text(0.5, 0.5, "no iteration history", ha="center", va="center", transform=ax.transAxes)
    else:
        if log and np.all(values > 0):
            ax.set_yscale("log")
            _plain_log_labels(ax.yaxis, values)
        ax.legend(loc="best")
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    _fit_left_margin(fig, margins[0])
    return _save(fig, path, dpi)


def has_convergence_history(history_best) -> bool:
    """True when ``history_best`` has at least two finite values: a convergence figure shows something."""
    if history_best is None:
        return False
    h = np.ravel(np.asarray(history_best, dtype=float))
    return int(np.isfinite(h).sum()) >= 2


def _plain_log_labels(axis, values: np.ndarray) -> None:
    """Label a log axis with plain numbers (0.0025, not 2.5×10⁻³; no mathtext to lay out).

    When the finite positive ``values`` span less than a decade, the minor ticks (2…9 × 10ᵏ) are
    labelled too. Otherwise the axis has no minor ticks: labelled ticks at 1, 2 and 5 × 10ᵏ (up to
    three decades) or at each decade, with their grid lines, carry the scale. A log axis' eight
    minor ticks a decade — tick objects set up at every draw — were a quarter of a convergence
    figure's instructions (150 → 111 M warm, 400 → 299 M drawn first: ``python
    benchmarks/figure_work.py --other TREE``).
    """
    from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, NullLocator

    plain = FuncFormatter(lambda v, _: f"{v:.3g}")
    axis.set_major_formatter(plain)
    v = values[np.isfinite(values) & (values > 0)]
    if v.size > 0 and v.max() < 10.0 * v.min():
        # within a decade: four ticks spread over the values, at two significant digits (the minor
        # ticks 6, 7, 8, 9 × 10ᵏ all labelled crowded a short colour bar: a blind test's overlapping labels)
        ticks = np.unique([float(f"{x:.2g}") for x in np.geomspace(v.min(), v.max(), 4)])
        axis.set_major_locator(FixedLocator(ticks))
        axis.set_minor_locator(NullLocator())
        return
    decades = math.log10(v.max() / v.min()) if v.size else math.inf
    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0) if decades <= 3.0 else (1.0,)))
    axis.set_minor_locator(NullLocator())


def _grid_shape(n: int) -> tuple[int, int]:
    """Near-square (rows, cols) grid for ``n`` panels, landscape, few empty cells.

    At most 3 panels go in one row; otherwise among grids with ``rows ≤ cols ≤ 2·rows`` the one
    with the fewest empty cells, then the squarest, is chosen (24 → 4×6, 9 → 3×3, 7 → 2×4).
    """
    if n < 1:
        raise ValueError(f"need at least one panel, got {n}")
    if n <= 3:
        return 1, n
    best = None
    for rows in range(1, n + 1):
        cols = math.ceil(n / rows)
        if not rows <= cols <= 2 * rows:
            continue
        key = (rows * cols - n, cols - rows)
        if best is None or key < best[0]:
            best = (key, (rows, cols))
    return best[1]


#: overview panel geometry in inches: axes width and height, gaps between columns and rows
_PANEL_W, _PANEL_H, _PANEL_WGAP, _PANEL_HGAP = 2.15, 1.62, 0.42, 0.6


def overview_figure(path, panels: Sequence[dict], *, unit: str = "um", title: str = "",
                    dpi: int = DPI) -> Path:
    """Grid of small loop plots, one per condition.

    The panels are drawn by one axes moved from cell to cell (:func:`_overview_layout`): each is
    drawn where a grid of its own axes would put it, with the same artists, in the same order, so
    the pixels are those of a figure with one axes per panel, without creating and laying out that
    many axes and their ticks (≈ 40 % of a first overview of 24 panels: ``python
    benchmarks/bench_figures.py --kinds``, against the code before, in the CHANGELOG).

    Parameters
    ----------
    path : str or Path
    panels : sequence of dict
        One dict per panel with keys ``"u"``, ``"y_meas"``, ``"y_model"`` (arrays or lists of
        arrays, as :func:`loop_figure`), and optional ``"title"`` and ``"subtitle"``
        (e.g. ``"R²=0.999 RMSE=0.01 µm"``).
    unit : str, default "um"
    title : str
        Figure title.

    Raises
    ------
    ValueError
        If ``panels`` is empty or a panel lacks ``u`` / ``y_meas``.
    """
    panels = list(panels)
    for i, p in enumerate(panels):
        missing = [k for k in ("u", "y_meas") if k not in p]
        if missing:
            raise ValueError(f"panel {i} ({p.get('title', '')!r}) lacks {', '.join(missing)}")
    fig, cells = _overview_layout(len(panels), bool(title), dpi)
    (ax,) = fig.axes
    cols = _grid_shape(len(panels))[1]
    legend = None

    def draw(renderer) -> None:
        # as Figure.draw would draw a grid of axes: the background, each panel's axes in order,
        # then the figure's own artists (suptitle, legend) by z-order
        nonlocal legend
        fig.patch.draw(renderer)
        for i, (cell, p) in enumerate(zip(cells, panels)):
            _reset_axes(ax)
            ax.set_subplotspec(cell)
            caps = _captures({"u": p["u"], "y_meas": p["y_meas"], "y_model": p.get("y_model")})
            _draw_loops(ax, caps, ("measured", "model"), lw_scale=0.8)
            head = p.get("title", "")
            sub = p.get("subtitle", "")
            ax.set_title(f"{head}\n{sub}" if sub else head, fontsize=7.5, pad=3, y=1.0)
            if i + cols >= len(panels):  # the last panel of its column
                ax.set_xlabel("Voltage (V)", fontsize=7)
            if i % cols == 0:
                ax.set_ylabel(_output_label(unit), fontsize=7)
            if i == 0:
                handles, lbls = ax.get_legend_handles_labels()
                if handles:  # the legend's own artists copy the first panel's lines
                    legend = fig.legend(handles, lbls, loc="lower center", bbox_to_anchor=(0.5, 0.0),
                                        ncols=len(handles), fontsize=8, frameon=False)
            ax.apply_aspect()
            ax.draw(renderer)
        if title:
            fig.suptitle(title, fontsize=10, y=1 - 0.12 / (fig.get_size_inches()[1]), va="top")
        for artist in sorted((a for a in (fig._suptitle, legend) if a is not None), key=lambda a: a.get_zorder()):
            artist.draw(renderer)

    try:
        return _save(fig, path, dpi, draw=draw)
    finally:
        if legend is not None:
            legend.remove()
        if fig._suptitle is not None:
            fig._suptitle.set_text("")


#: tick intervals per overview axis: legible at this size, and each tick costs a text to lay out
_OVERVIEW_TICK_BINS = 4


def _overview_layout(n_panels: int, titled: bool, dpi: int):
    """The figure of :func:`overview_figure` for ``n_panels`` and the grid's cells, one per panel
    (a template: laid out once per process). The figure holds one axes, which the overview moves
    to each cell in turn."""
    rows, cols = _grid_shape(n_panels)
    margins = (0.6, 0.12, 0.72, 0.42 + (0.3 if titled else 0.0))
    width = margins[0] + margins[1] + cols * _PANEL_W + (cols - 1) * _PANEL_WGAP
    height = margins[2] + margins[3] + rows * _PANEL_H + (rows - 1) * _PANEL_HGAP

    def build() -> Figure:
        f = _new_figure(width, height, margins, dpi=dpi, wspace=_PANEL_WGAP / _PANEL_W, hspace=_PANEL_HGAP / _PANEL_H)
        grid = f.add_gridspec(rows, cols)
        ax = f.add_subplot(grid[0])
        ax.tick_params(labelsize=6.5, pad=1.5)
        ax.grid(True, alpha=0.3)
        ax.locator_params(nbins=_OVERVIEW_TICK_BINS)  # kept: the axes stays linear
        f._overview_cells = [grid[i] for i in range(n_panels)]
        return f

    fig = _template(("overview", n_panels, dpi, margins), build)
    return fig, fig._overview_cells


def prepare_overview(n_panels: int, *, titled: bool = True, dpi: int = DPI) -> None:
    """Lay out the :func:`overview_figure` of ``n_panels`` ahead of its first drawing: its axes and
    their ticks, kept in this process's template. A figure server calls it while the caller still
    fits (:func:`hystfit.report.render.prepare`), so the process that draws the overview inherits
    the layout. The picture does not depend on it.
    """
    fig, _ = _overview_layout(n_panels, titled, dpi)
    for axis in (fig.axes[0].xaxis, fig.axes[0].yaxis):
        axis.get_major_ticks(_OVERVIEW_TICK_BINS + 2)  # the most the locator gives, with the ends


def parity_figure(path, y_meas, y_model, *, unit: str = "um", title: str = "", dpi: int = DPI) -> Path:
    """Model against measured output, sample by sample, with the 1:1 line.

    Each occupied cell of a grid finer than the pixels is drawn once (a long capture does not
    draw 10⁶ overlapping dots, and no sample's position is lost to a stride).

    Parameters
    ----------
    path : str or Path
    y_meas, y_model : array_like or list of array_like
        Measured and model output in ``unit``; lists (several captures) are pooled.
    unit : str, default "um"
    title : str
    """
    caps = _captures({"y_meas": y_meas, "y_model": y_model})
    ym = np.concatenate([c[0] for c in caps])
    yp = _finite_or_nan(np.concatenate([c[1] for c in caps]))
    margins = _margins(0.8, 0.15, 0.55, 0.12, title)
    fig = _new_figure(5.2, 5.0, margins, dpi=dpi)
    ax = fig.add_subplot()
    both = np.concatenate([ym, yp[np.isfinite(yp)]])
    lo, hi = float(both.min()), float(both.max())
    pad = 0.03 * (hi - lo) if hi > lo else 1.0
    lim = (lo - pad, hi + pad)
    ok = np.isfinite(yp) & np.isfinite(ym)
    xs, ys = ym[ok], yp[ok]
    cells = OVERSAMPLE * max(_axes_pixels(ax))
    if xs.size > cells:
        scale = cells / (lim[1] - lim[0])
        code = ((xs - lim[0]) * scale).astype(np.int64) * (cells + 1) + ((ys - lim[0]) * scale).astype(np.int64)
        first = _first_occurrences(code)
        xs, ys = xs[first], ys[first]
    ax.scatter(xs, ys, s=3, alpha=0.35, color="tab:blue", lw=0, rasterized=True, label="samples")
    ax.plot(lim, lim, color="0.2", lw=0.9, ls="--", label="1:1")
    ax.set_xlim(lim)
    ax.set_ylim(lim)
    ax.set_aspect("equal", adjustable="box")
    u = display_unit(unit)
    q = _QUANTITY.get(unit, "output").lower()
    ax.set_xlabel(f"Measured {q} ({u})")
    ax.set_ylabel(f"Model {q} ({u})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", markerscale=4)
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    _fit_left_margin(fig, margins[0])
    return _save(fig, path, dpi)


def _cell_text(v: float, fmt: str) -> str:
    if np.isnan(v):
        return "–"
    if np.isinf(v):
        return "inf" if v > 0 else "-inf"
    return fmt.format(v)


def heatmap_figure(path, matrix, row_labels: Sequence[str], col_labels: Sequence[str], *,
                   title: str = "", fmt: str = "{:.3g}", cmap: str = "viridis",
                   colorbar_label: str = "", log: bool = False, color_matrix=None, dpi: int = DPI) -> Path:
    """Annotated heat map of a 2-D table (e.g. RMSE per model × condition).

    Parameters
    ----------
    path : str or Path
    matrix : array_like, shape (R, C)
        Values; NaN and ±inf are drawn blank and annotated ``–`` / ``inf``.
    row_labels : sequence of str, length R
    col_labels : sequence of str, length C
    title : str
    fmt : str, default "{:.3g}"
        Format of the cell annotations (annotations are skipped above 600 cells).
    cmap : str, default "viridis"
    colorbar_label : str
    log : bool, default False
        Logarithmic colour scale (over the positive finite values; others are drawn blank): one
        bad cell then no longer flattens every other cell into one colour.
    color_matrix : array_like, shape (R, C), optional
        Values that set the colours, when they differ from the annotated ones (e.g. colour by
        1 − R² on a log scale, annotate R²).

    Raises
    ------
    ValueError
        If ``matrix`` is not 2-D or the label counts do not match its shape.
    """
    m = np.asarray(matrix, dtype=float)
    if m.ndim != 2:
        raise ValueError(f"matrix must be 2-D, got shape {m.shape}")
    R, C = m.shape
    if len(row_labels) != R or len(col_labels) != C:
        raise ValueError(f"matrix has shape {m.shape} but {len(row_labels)} row labels and "
                         f"{len(col_labels)} column labels")
    cm = m if color_matrix is None else np.asarray(color_matrix, dtype=float)
    if cm.shape != m.shape:
        raise ValueError(f"color_matrix has shape {cm.shape}, matrix {m.shape}")
    masked = np.ma.masked_invalid(np.where(cm > 0, cm, np.nan) if log else cm)
    # a fixed layout from the label lengths (constrained layout cost ≈ 1 s per heat map of 240 cells)
    rotate = C > 6 or max((len(str(c)) for c in col_labels), default=0) > 8
    char = 0.075  # inches per character at the tick label size
    left = 0.35 + char * max((len(str(r)) for r in row_labels), default=1)
    bottom = 0.3 + char * max((len(str(c)) for c in col_labels), default=1) * (0.75 if rotate else 0.0) + 0.2
    right, top = 1.35, 0.25 + (0.35 if title else 0.0)
    width = min(20.0, max(4.5, 0.85 * C + 2.8))
    height = min(16.0, max(3.0, 0.42 * R + 1.6))
    width = max(width, left + right + 1.5)
    height = max(height, bottom + top + 1.0)
    fig = _new_figure(width, height, (left, right, bottom, top), dpi=dpi)
    ax = fig.add_subplot()
    cax = fig.add_axes((1 - (right - 0.2) / width, bottom / height, 0.16 / width, 1 - (bottom + top) / height))
    norm = None
    if log and masked.count():
        from matplotlib.colors import LogNorm

        lo, hi = float(masked.min()), float(masked.max())
        norm = LogNorm(lo, hi if hi > lo else lo * 10)
    im = ax.imshow(masked, aspect="auto", cmap=cmap, interpolation="nearest", norm=norm)
    if masked.count() == 0:
        im.set_clim(0.0, 1.0)
    ax.set_xticks(np.arange(C), [str(c) for c in col_labels])
    ax.set_yticks(np.arange(R), [str(r) for r in row_labels])
    if rotate:
        ax.tick_params(axis="x", labelrotation=45)
        for lab in ax.get_xticklabels():
            lab.set_horizontalalignment("right")
            lab.set_rotation_mode("anchor")
    ax.tick_params(length=0)
    if R * C <= 600:
        size = 8 if R * C <= 150 else 6
        rgba = np.asarray(im.cmap(im.norm(masked)))  # every cell's colour at once (a scalar call each costs 0.4 ms)
        dark = 0.299 * rgba[..., 0] + 0.587 * rgba[..., 1] + 0.114 * rgba[..., 2] < 0.5
        blank = np.ma.getmaskarray(masked)
        for (i, j), v in np.ndenumerate(m):
            colour = "0.3" if blank[i, j] else ("white" if dark[i, j] else "black")
            ax.text(j, i, _cell_text(v, fmt), ha="center", va="center", fontsize=size, color=colour)
    cb = fig.colorbar(im, cax=cax)
    if norm is not None:  # plain numbers (0.01, not 10⁻²): no mathtext to parse and lay out
        _plain_log_labels(cb.ax.yaxis, masked.compressed())
    if colorbar_label:
        cb.set_label(colorbar_label)
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    return _save(fig, path, dpi)


def boxplot_figure(path, groups: Mapping[str, Sequence[float]], *, title: str = "", ylabel: str = "",
                   log: bool = False, dpi: int = DPI) -> Path:
    """Box plot of several groups of values (e.g. RMSE over seeds per optimizer), points overlaid.

    Parameters
    ----------
    path : str or Path
    groups : mapping of str to sequence of float
        Group name → values. Non-finite values (and values ≤ 0 with ``log``) are left out; the
        tick label shows how many values each box holds.
    title, ylabel : str
    log : bool, default False
        Logarithmic y axis.

    Raises
    ------
    ValueError
        If ``groups`` is empty.
    """
    if not groups:
        raise ValueError("boxplot_figure needs at least one group")
    names = [str(k) for k in groups]
    data = []
    for v in groups.values():
        a = np.asarray(v, dtype=float).ravel()
        keep = np.isfinite(a) & ((a > 0) if log else True)
        data.append(a[keep])
    n = len(names)
    fig = _new_figure(min(20.0, max(4.5, 0.75 * n + 2.0)), 4.4)
    ax = fig.add_subplot()
    pos = np.arange(1, n + 1)
    nonempty = [i for i, d in enumerate(data) if d.size]
    if nonempty:
        ax.boxplot([data[i] for i in nonempty], positions=pos[nonempty], widths=0.55,
                   showfliers=False, medianprops={"color": "tab:red"})
    jitter = np.random.default_rng(0)  # fixed: the same data gives the same picture
    for i in nonempty:
        d = data[i]
        ax.scatter(pos[i] + jitter.uniform(-0.12, 0.12, d.size), d, s=9, alpha=0.55,
                   color="tab:blue", lw=0, zorder=3)
    ax.set_xticks(pos, [f"{nm}\n(n={d.size})" for nm, d in zip(names, data)])
    ax.set_xlim(0.4, n + 0.6)
    if n > 6 or max(len(s) for s in names) > 10:
        ax.tick_params(axis="x", labelrotation=30)
    values = np.concatenate([data[i] for i in nonempty]) if nonempty else np.empty(0)
    # a log axis over less than a decade labels every tick alike (a blind test's nine "7.43e-05"): linear
    if log and nonempty and values.max() > 10.0 * values.min():
        ax.set_yscale("log")
        _plain_log_labels(ax.yaxis, values)
    ax.set_ylabel(ylabel)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    if title:  # wrapped to the figure's width (a long one ran off its right edge); a fixed y skips a bbox pass
        ax.set_title(textwrap.fill(title, max(30, int(9 * fig.get_figwidth()))), y=1.0, fontsize="medium")
    return _save(fig, path, dpi)


def loop_overlay_figure(path, u_V, y_meas, models: Mapping[str, np.ndarray], *, unit: str = "um",
                        title: str = "", dpi: int = DPI) -> Path:
    """One capture's measured loop with several models' loops overlaid (one colour per model).

    Parameters
    ----------
    path : str or Path
    u_V, y_meas : array_like
        Input voltage (V) and measured output (``unit``) of one capture.
    models : mapping of str to array_like
        Model name → model output for the same input.
    unit, title : str
    """
    u = np.asarray(u_V, float).ravel()
    margins = _margins(0.75, 0.15, 0.55, 0.12, title)
    fig = _layout_template(("loop_overlay", dpi, margins), lambda: _with_axes(_new_figure(6.8, 5.0, margins, dpi=dpi)),
                           margins[0])
    ax = fig.axes[0]
    _plot_xy(ax, u, np.asarray(y_meas, float).ravel(), _MEAS_STYLE, "measured")
    for i, (name, y) in enumerate(models.items()):
        _plot_xy(ax, u, np.asarray(y, float).ravel(), {"lw": 0.9, "alpha": 0.8, "color": f"C{i % 10}"}, str(name))
    ax.set_xlabel("Voltage (V)")
    ax.set_ylabel(_output_label(unit))
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    _fit_left_margin(fig, margins[0])
    return _save(fig, path, dpi)


def convergence_compare_figure(path, histories: Mapping[str, Sequence[Sequence[float]]], *, title: str = "",
                               ylabel: str = "objective (MSE)", log: bool = True, dpi: int = DPI) -> Path:
    """Best-so-far objective per iteration of several optimizers, each with one line per run.

    Parameters
    ----------
    path : str or Path
    histories : mapping of str to list of array_like
        Optimizer name → its runs' best-so-far histories; the median over runs is drawn bold.
    title, ylabel : str
    log : bool, default True
    """
    fig = _template(("convergence_compare", dpi), lambda: _with_axes(_new_figure(6.8, 4.6, dpi=dpi)))
    ax = fig.axes[0]
    any_nonpos = False
    for i, (name, runs) in enumerate(histories.items()):
        color = f"C{i % 10}"
        arrs = [np.asarray(h, float) for h in runs if len(h)]
        for a in arrs:
            ax.plot(np.arange(1, a.size + 1), a, color=color, lw=0.5, alpha=0.35)
            any_nonpos |= bool(np.any(a[np.isfinite(a)] <= 0))
        if arrs:
            n = max(a.size for a in arrs)
            padded = np.vstack([np.r_[a, np.full(n - a.size, a[-1])] for a in arrs])
            ax.plot(np.arange(1, n + 1), np.median(padded, axis=0), color=color, lw=1.8, label=str(name))
    if log and not any_nonpos:
        ax.set_yscale("log")
        drawn = [np.asarray(h, float) for runs in histories.values() for h in runs if len(h)]
        _plain_log_labels(ax.yaxis, np.concatenate(drawn) if drawn else np.empty(0))
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    if title:
        ax.set_title(title, y=1.0)  # a fixed y skips a tight-bbox pass per draw
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path, dpi)
