"""Shared helpers of the stages' PNG plots (matplotlib, Agg backend forced: no display needed).

Figures are rendered to memory and written atomically (:func:`oacli.io.atomic.atomic_path`), so a run folder never
holds a half-written PNG.

Speed (issue 9): a figure is laid out once with fixed margins in inches (:func:`fixed_layout`: room for the tick
labels, titles and the legends outside the axes, whose sizes are measured, not the whole figure's tight box), no
constrained layout and no ``bbox_inches="tight"`` (each of those draws every tick label several times); series
longer than :data:`MAX_POINTS` are drawn through :func:`decimate` (min and max per bin: the peaks stay). Second pass:
figures are plain :class:`~matplotlib.figure.Figure` objects (no pyplot), one per shape kept blank between PNGs
(:data:`REUSE`: its axes and tick objects are made once per mission, not once per PNG); horizontal text is drawn as
cached whole-string bitmaps (:class:`TextCachingRenderer`, :data:`FAST_TEXT`); linear axes get at most
:data:`MAX_TICKS` ticks (:class:`FewTicks`), log axes plain-text labels (:class:`PowerFormatter`, no mathtext); the
PNG is written by :func:`png_bytes` (RGB, no row filter, zlib level 1). The old path stays reachable with
:data:`LEGACY` (``benchmarks/bench_outputs.py`` compares both).

:func:`guarded_plots` runs each figure of a stage so that a plotting failure never loses the run: the failure
becomes a warning in the summary and the status is kept.
"""

from __future__ import annotations

import io
import logging
import os
import struct
import sys
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import matplotlib

matplotlib.use("Agg", force=True)

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg, get_hinting_flag
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.patches import Ellipse, Rectangle
from matplotlib.ticker import AutoLocator, Formatter, LogLocator, MaxNLocator
from matplotlib.transforms import Bbox, offset_copy

from oacli.geometry import Scene
from oacli.io.atomic import atomic_path

_LOG = logging.getLogger(__name__)
DPI = 110
#: The old drawing path (constrained layout, tight bounding box, every sample drawn); set by
#: ``benchmarks/bench_outputs.py`` or the environment variable ``OACLI_LEGACY_PLOTS=1``.
LEGACY = os.environ.get("OACLI_LEGACY_PLOTS", "") == "1"
#: Reuse one blank figure per shape (:func:`subplots`, :func:`_blank`) instead of building a new one per PNG.
#: Relies on private matplotlib API (``Axes._request_autoscale_view``, ``FigureCanvasAgg._lastKey``): on only where
#: it exists, and the pixel-identity test of ``tests/test_stage_plots.py`` checks a reused figure draws as a fresh one.
REUSE = hasattr(matplotlib.axes.Axes, "_request_autoscale_view")
#: Blank template figures per shape (:func:`subplots`).
_TEMPLATES: dict[tuple, list[Figure]] = {}
#: Draw horizontal text through :class:`TextCachingRenderer`.
#: Relies on private Agg renderer API (``_prepare_font``, ``_renderer.draw_text_image``), checked on the matplotlib
#: versions it was written for (3.11): any other version draws text as matplotlib does.
FAST_TEXT = matplotlib.__version__.startswith("3.11.") and hasattr(RendererAgg, "_prepare_font")
#: Most major ticks per axis (linear axes; a long axis would get about ten).
MAX_TICKS = 6
#: Longest series drawn as is; longer ones are decimated to about this many points (min and max per bin).
MAX_POINTS = 4000
#: zlib level of the PNGs (1: several times faster to encode than the default 6, files somewhat larger).
PNG_COMPRESS_LEVEL = 1
#: Axis names of the world frame.
AXES = ("x", "y", "z")


class RunFiles(Protocol):
    """What :func:`guarded_plots` needs of a run folder (:class:`oacli.io.runfolder.RunFolder`)."""

    run_dir: Path

    def file(self, role: str, name: str) -> Path: ...


def spans_decades(values: np.ndarray, decades: float = 2.0) -> bool:
    """True when the positive finite values span more than ``decades`` powers of ten."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    return v.size > 1 and float(np.log10(v.max() / v.min())) > decades


#: Text bitmaps already rendered (:class:`TextCachingRenderer`), by string, font, dpi and antialiasing.
_TEXT_BITMAPS: dict[tuple, tuple[np.ndarray, float, float]] = {}
_TEXT_BITMAPS_MAX = 4000


class TextCachingRenderer(RendererAgg):
    """The Agg renderer drawing each horizontal plain-text string as one bitmap (rendered by FreeType in one call,
    placed at a whole pixel, as matplotlib did before 3.11) and reusing that bitmap wherever the same string in the
    same font is drawn again (tick labels, titles and legends repeat across the figures of a mission). Matplotlib 3.11
    renders every glyph through several Python calls per draw, the largest cost of a plot figure. Rotated text and
    mathtext are drawn as matplotlib does."""

    def draw_text(self, gc: Any, x: float, y: float, s: str, prop: Any, angle: float, ismath: Any = False,
                  mtext: Any = None) -> None:
        if ismath or angle != 0 or (mtext is not None and (mtext.get_fontfeatures() or mtext.get_language())):
            return super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
        key = (s, hash(prop), prop.get_size_in_points(), self.dpi, bool(gc.get_antialiased()))
        hit = _TEXT_BITMAPS.get(key)
        if hit is None:
            font = self._prepare_font(prop)
            font.set_text(s, 0, flags=get_hinting_flag())
            font.draw_glyphs_to_bitmap(antialiased=bool(gc.get_antialiased()))
            x_off, y_off = font.get_bitmap_offset()
            image = np.array(font.get_image(), dtype=np.uint8)
            hit = (image, x_off / 64.0, y_off / 64.0 + font.get_descent() / 64.0)
            if len(_TEXT_BITMAPS) >= _TEXT_BITMAPS_MAX:
                _TEXT_BITMAPS.clear()
            _TEXT_BITMAPS[key] = hit
        image, x_off, y_off = hit
        self._renderer.draw_text_image(image, round(x + x_off), round(y + y_off) + 1, 0, gc)
        return None


class CachingCanvas(FigureCanvasAgg):
    """An Agg canvas drawing with :class:`TextCachingRenderer`."""

    def get_renderer(self) -> TextCachingRenderer:
        w, h = self.get_width_height(physical=True)
        key = w, h, self.figure.dpi
        if self._lastKey != key:
            self.renderer = TextCachingRenderer(w, h, self.figure.dpi)
            self._lastKey = key  # type: ignore[assignment]
        return self.renderer


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float],
             **kwargs: Any) -> tuple[Figure, Any]:
    """A figure with a grid of axes, laid out by :func:`fixed_layout` in :func:`save_png` (no layout engine); with
    :data:`LEGACY`, ``plt.subplots`` with constrained layout as before.

    Axes titles sit at a fixed height (``axes.titley`` 1.0: just above the axes, which carry no top tick labels)
    instead of being moved above whatever overlaps them at every draw (that search measures every tick label).

    The figure is a plain :class:`~matplotlib.figure.Figure` on its own Agg canvas (no pyplot figure manager) and,
    with :data:`REUSE`, a blank template of this shape saved by an earlier :func:`save_png` (:func:`_blank`): its
    axes, tick objects and the text metrics cached on its renderer are made once per shape, not once per PNG.
    """
    if LEGACY:
        import matplotlib.pyplot as plt

        return plt.subplots(nrows, ncols, figsize=figsize, constrained_layout=True, **kwargs)
    key = (nrows, ncols, tuple(float(v) for v in figsize), tuple(sorted(kwargs.items())))
    free = _TEMPLATES.get(key, []) if REUSE else []
    if free:
        fig = free.pop()
        return fig, fig._oacli_axes  # type: ignore[attr-defined]
    with matplotlib.rc_context({"axes.titley": 1.0}):
        fig = Figure(figsize=figsize)
        (CachingCanvas if FAST_TEXT else FigureCanvasAgg)(fig)
        axes = fig.subplots(nrows, ncols, **kwargs)
    fig._oacli_template = key  # type: ignore[attr-defined]
    fig._oacli_axes = axes  # type: ignore[attr-defined]
    fig._oacli_title_size = matplotlib.rcParams["axes.titlesize"]  # type: ignore[attr-defined]
    return fig, axes


def _blank(fig: Figure) -> None:
    """Make a drawn template figure blank again, as :func:`subplots` made it: every artist added to its axes
    (lines, patches, collections, texts, legends), the figure legends and title removed; titles, labels, scales,
    limits, aspect, grids and the colour cycle back to their defaults. The axes and their tick objects stay
    (``tests/test_stage_plots.py`` checks that a figure drawn on a reused template is pixel-identical to a fresh one).
    """
    for leg in list(fig.legends):
        leg.remove()
    if fig.get_suptitle():
        fig.suptitle("")  # an empty title draws nothing; the next suptitle() sets all its properties again
    size = fig._oacli_title_size  # type: ignore[attr-defined]
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is not None:
            legend.remove()
        for artist in [*ax.lines, *ax.patches, *ax.collections, *ax.texts, *ax.images, *ax.artists]:
            artist.remove()
        for loc in ("left", "center", "right"):
            if ax.get_title(loc):
                ax.set_title("", loc=loc, y=1.0, fontsize=size)  # type: ignore[arg-type]
        ax.set_xlabel("")
        ax.set_ylabel("")
        ax.grid(False, which="both")
        for axis, set_scale in ((ax.xaxis, ax.set_xscale), (ax.yaxis, ax.set_yscale)):
            if axis.get_scale() != "linear":  # setting a scale autoscales (costly); linear axes keep theirs
                set_scale("linear")
        ax.set_aspect("auto", adjustable="box")
        ax.set_prop_cycle(None)
        ax.dataLim = Bbox.null()
        ax.ignore_existing_data_limits = True
        ax.set_autoscale_on(True)
        ax._request_autoscale_view()  # type: ignore[attr-defined]


def decimate(x: np.ndarray, y: np.ndarray, max_points: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """At most about ``max_points`` samples of the curve ``(x, y)`` that look the same drawn: per bin of consecutive
    samples its first sample and the samples where ``x`` and ``y`` are smallest and largest (in sample order), and
    the last sample; NaNs are kept (gaps). Works for time series and for paths (x-y) alike.

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        The curve (``y`` may also be (N, k): the bins keep each column's extremes).
    max_points : int, optional
        Target length (default :data:`MAX_POINTS`); a curve this short or shorter, or :data:`LEGACY`, is returned
        unchanged.

    Returns
    -------
    tuple of ndarray
        The kept ``x`` and ``y`` (views or copies; the global minimum, maximum, first and last samples are kept).
    """
    limit = MAX_POINTS if max_points is None else int(max_points)
    x, y = np.asarray(x), np.asarray(y)
    n = len(x)
    if LEGACY or n <= limit:
        return x, y
    y2 = np.column_stack([x.astype(float), y.reshape(n, -1)])
    per_bin = max(3, int(np.ceil((1 + 2 * y2.shape[1]) * n / limit)))
    bins = n // per_bin
    edge = bins * per_bin
    keep = [np.arange(0, edge, per_bin)]
    with np.errstate(invalid="ignore"):
        for col in y2.T:
            block = col[:edge].reshape(bins, per_bin)
            base = np.arange(bins) * per_bin
            filled_lo = np.where(np.isnan(block), np.inf, block)
            filled_hi = np.where(np.isnan(block), -np.inf, block)
            keep += [base + np.argmin(filled_lo, axis=1), base + np.argmax(filled_hi, axis=1)]
        nan_at = np.flatnonzero(np.isnan(y2[:edge]).any(axis=1))
    keep += [nan_at, np.arange(edge, n), np.array([n - 1])]
    idx = np.unique(np.concatenate(keep))
    return x[idx], y[idx]


def _legend_width_in(ax: Axes, renderer: Any) -> float:
    """Width [in] of ``ax``'s legend when it sits right of the axes (:func:`legend_outside`), else 0."""
    leg = ax.get_legend()
    if leg is None or not getattr(leg, "_oacli_outside", False):
        return 0.0
    return _px(leg.get_window_extent(renderer).width) / float(ax.figure.dpi)


def _title_height_in(ax: Axes) -> float:
    """Height [in] the axes' titles take above it (their font's line height and the title pad), 0 without one."""
    if not any(ax.get_title(loc) for loc in ("left", "center", "right")):
        return 0.0
    return (1.3 * float(ax.title.get_fontsize()) + float(matplotlib.rcParams["axes.titlepad"])) / 72.0


def _xaxis_height_in(ax: Axes, renderer: Any) -> float:
    """Height [in] of the x axis's tick labels and label below the axes (measured), 0 when nothing is shown."""
    box = ax.xaxis.get_tightbbox(renderer)
    if box is None or box.height <= 0:
        return 0.0
    return _px(box.height) / float(ax.figure.dpi) + 0.05


def _px(value: float) -> float:
    """A measured size [px] rounded to 1/1000 px: the measurement depends (in its last bits) on where the legend
    sat before, so a reused template (:data:`REUSE`) would otherwise be laid out a hair differently."""
    return round(float(value), 3)


def fixed_layout(fig: Figure) -> None:
    """Place the axes of a grid figure with margins in inches sized for their decorations, without a layout engine.

    Room: left of each column for its tick labels and y label; right of it for the widest legend outside its axes
    (measured); above each row for the axes titles (and the figure's title); below each row for x tick labels
    and x labels where they are shown; the figure legend at the bottom (measured).

    Parameters
    ----------
    fig : Figure
        A figure whose axes all come from one ``subplots`` grid (other figures are left as they are).
    """
    specs = [(a, spec) for a in fig.axes if (spec := a.get_subplotspec()) is not None]
    if not specs or fig.get_layout_engine() is not None:
        return
    gs = specs[0][1].get_gridspec()
    if any(spec.get_gridspec() is not gs for _, spec in specs):
        return
    nrows, ncols = gs.get_geometry()
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    renderer = canvas.get_renderer()
    width_in, height_in = (float(v) for v in fig.get_size_inches())
    legend_in = [0.0] * ncols
    title_in = [0.0] * nrows  # above each row: its axes titles
    xaxis_in = [0.0] * nrows  # below each row: its x tick labels and x label (measured)
    for a, spec in specs:
        col, row = spec.colspan.stop - 1, spec.rowspan.start
        legend_in[col] = max(legend_in[col], _legend_width_in(a, renderer))
        title_in[row] = max(title_in[row], _title_height_in(a))
        last = spec.rowspan.stop - 1
        xaxis_in[last] = max(xaxis_in[last], _xaxis_height_in(a, renderer))
    ylabel_in = 0.95
    left = ylabel_in
    right = max(legend_in[-1] + 0.2, 0.3)
    top = 0.15 + title_in[0] + (0.4 if fig.get_suptitle() else 0.0)
    bottom = 0.15 + xaxis_in[-1]
    for leg in fig.legends:
        bottom += _px(leg.get_window_extent(renderer).height) / float(fig.dpi) + 0.1
    # gaps between rows: the lower row's title and the upper row's x tick labels
    row_gap = 0.2 + max(title_in[1:], default=0.0) + max(xaxis_in[:-1], default=0.0)
    col_gap = ylabel_in + max(legend_in[:-1], default=0.0) + 0.1
    avail_h = max(height_in - top - bottom - (nrows - 1) * row_gap, 0.5 * height_in)
    avail_w = max(width_in - left - right - (ncols - 1) * col_gap, 0.4 * width_in)
    fig.subplots_adjust(
        left=left / width_in, right=1.0 - right / width_in, bottom=bottom / height_in, top=1.0 - top / height_in,
        hspace=row_gap * nrows / avail_h if nrows > 1 else 0.0,
        wspace=col_gap * ncols / avail_w if ncols > 1 else 0.0,
    )
    for leg in fig.legends:  # the figure legend sits in the bottom margin
        leg.set_bbox_to_anchor((0.5, 0.1 / height_in), transform=fig.transFigure)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bytes(rgba: np.ndarray, level: int | None = None) -> bytes:
    """A PNG of an opaque RGBA image (a drawn figure): 8-bit RGB, no row filter, zlib ``level`` (default
    :data:`PNG_COMPRESS_LEVEL`). About twice as fast as Pillow's encoder at level 1, whose adaptive row filters
    cost more than they save on plots (large flat areas); files are somewhat larger.

    Parameters
    ----------
    rgba : ndarray, shape (H, W, 4), uint8
        The pixels (alpha dropped: the figure's background is opaque).
    level : int, optional
        zlib level 0-9.

    Returns
    -------
    bytes
        The PNG file.
    """
    height, width = rgba.shape[:2]
    rows = np.empty((height, 1 + 3 * width), dtype=np.uint8)
    rows[:, 0] = 0  # filter type 0 (None) per row
    rows[:, 1:].reshape(height, width, 3)[...] = rgba[..., :3]
    data = zlib.compress(rows.data, PNG_COMPRESS_LEVEL if level is None else level)
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)  # 8-bit RGB, deflate, no filter, no interlace
    return b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", header) + _png_chunk(b"IDAT", data) + _png_chunk(b"IEND", b"")


_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


class PowerFormatter(Formatter):
    """Tick labels of a log axis as plain text: ``10⁻³`` at the powers of ten; other ticks (minor) labelled
    (``0.002``) only when the axis spans at most a decade. The default formatter typesets every label with mathtext
    (``$10^{-3}$``), which costs more than the rest of the axis."""

    def __call__(self, x: float, pos: int | None = None) -> str:
        if not np.isfinite(x) or x <= 0:
            return ""
        exponent = float(np.log10(x))
        if abs(exponent - round(exponent)) < 1e-9:
            return "10" + str(round(exponent)).translate(_SUPERSCRIPT)
        lo, hi = (float(v) for v in self.axis.get_view_interval()) if self.axis is not None else (x, x)
        if lo > 0 and hi > 0 and abs(np.log10(hi / lo)) > 1.0:
            return ""
        return f"{x:.3g}"


class FewTicks(MaxNLocator):
    """The default linear tick locator (steps 1, 2, 2.5, 5, 10; as many ticks as fit the axis' length) with at most
    :data:`MAX_TICKS` ticks: fewer tick objects to make, lay out and draw."""

    def __init__(self) -> None:
        super().__init__(nbins="auto", steps=[1, 2, 2.5, 5, 10])

    def _raw_ticks(self, vmin: float, vmax: float) -> np.ndarray:
        space = self.axis.get_tick_space() if self.axis is not None else MAX_TICKS
        self._nbins = int(np.clip(space, 1, MAX_TICKS - 1))
        return super()._raw_ticks(vmin, vmax)  # type: ignore[misc]


def few_ticks(fig: Figure) -> None:
    """Every linear axis of ``fig`` with the default locator gets :class:`FewTicks`."""
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            if axis.get_scale() == "linear" and type(axis.get_major_locator()) is AutoLocator:
                axis.set_major_locator(FewTicks())


def fixed_xlabels(fig: Figure) -> None:
    """Put each x label where matplotlib would (``labelpad`` below the x tick labels, or below the axes when they are
    hidden) at a fixed offset from the axes instead of measuring the tick labels at every draw (that measurement
    formats and places every tick a second time). The tick labels are one line of text: their height is the font's
    line height."""
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    renderer = canvas.get_renderer()
    dpi = float(fig.dpi)
    for ax in fig.axes:
        axis = ax.xaxis
        if axis.get_label_position() != "bottom":
            continue
        offset_pt = float(axis.labelpad)
        params = axis.get_tick_params()
        if params.get("labelbottom", True):
            tick = axis.majorTicks[0]
            size = FontProperties(size=tick.label1.get_fontsize(), family=tick.label1.get_fontfamily())
            _, line_px, _ = renderer.get_text_width_height_descent("lp", size, ismath=False)
            pad_pt = float(tick._pad)  # type: ignore[attr-defined]  # tick length (out) and tick label pad
            offset_pt += pad_pt + float(line_px) * 72.0 / dpi
        axis.set_label_coords(0.5, 0.0, transform=offset_copy(ax.transAxes, fig=fig, y=-offset_pt, units="points"))


def lay_out(fig: Figure) -> None:
    """What :func:`save_png` does to a figure before drawing it: the PNG resolution, :func:`few_ticks`,
    :func:`fixed_xlabels`, :func:`fixed_layout` (in this order: the tick choice moves the decorations that the layout
    measures).

    Parameters
    ----------
    fig : Figure
    """
    fig.set_dpi(DPI)
    few_ticks(fig)
    fixed_xlabels(fig)
    fixed_layout(fig)


def save_png(fig: Figure, path: Path) -> Path:
    """Lay ``fig`` out (:func:`few_ticks`, :func:`fixed_layout`), render it to PNG in memory, write the bytes to
    ``path`` atomically and close the figure, or, for a template of :func:`subplots`, blank it for the next PNG of its
    shape (with :data:`LEGACY`: constrained layout and a tight bounding box, as before)."""
    buf = io.BytesIO()
    template = getattr(fig, "_oacli_template", None)
    reuse = False
    try:
        if LEGACY:
            fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
        else:
            lay_out(fig)
            canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
            canvas.draw()
            buf.write(png_bytes(np.asarray(canvas.buffer_rgba())))
            if REUSE and template is not None:
                _blank(fig)
                reuse = True
    finally:
        if reuse and template is not None:
            _TEMPLATES.setdefault(template, []).append(fig)
        elif template is None:
            _pyplot_close(fig)
    with atomic_path(Path(path)) as tmp:
        tmp.write_bytes(buf.getvalue())
    return Path(path)


def _pyplot_close(which: Any) -> None:
    """``pyplot.close(which)`` when pyplot is imported (only :data:`LEGACY` figures and callers' own need it; the
    figures of :func:`subplots` are plain :class:`~matplotlib.figure.Figure` objects, and importing pyplot costs
    about 0.1 s of every CLI start)."""
    pyplot = sys.modules.get("matplotlib.pyplot")
    if pyplot is not None:
        pyplot.close(which)


def log_scale(ax: Axes) -> None:
    """A log y axis; minor ticks (and minor grid lines) at 2 and 5 times each power of ten only (with
    :data:`LEGACY`: all eight), which is fewer tick objects to make and draw; plain-text labels
    (:class:`PowerFormatter`)."""
    ax.set_yscale("log")
    if not LEGACY:
        ax.yaxis.set_minor_locator(LogLocator(base=10.0, subs=(2.0, 5.0)))
        ax.yaxis.set_major_formatter(PowerFormatter())
        ax.yaxis.set_minor_formatter(PowerFormatter())


def legend_outside(ax: Axes) -> None:
    """A legend right of the axes (it never covers the data)."""
    if ax.get_legend_handles_labels()[0]:
        leg = ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")
        leg._oacli_outside = True  # type: ignore[attr-defined]  # fixed_layout makes room for it


def ellipse_projection(center: np.ndarray, shape: np.ndarray, axes: tuple[int, int] = (0, 1),
                       grow_m: float = 0.0) -> tuple[float, float, float, float, float]:
    """The shadow of ``(p − c)ᵀ P (p − c) <= 1`` on the plane of world ``axes``: centre (2), width, height [m] and
    angle [deg]; semi-axes grown by ``grow_m`` (the robot radius: the zone the robot's centre keeps out of)."""
    i, j = axes
    cov = np.linalg.inv(np.asarray(shape, dtype=float))[np.ix_([i, j], [i, j])]  # the shadow is the ellipse of P⁻¹
    eig, vec = np.linalg.eigh(cov)
    semi = np.sqrt(np.maximum(eig, 0.0)) + grow_m
    angle = float(np.degrees(np.arctan2(vec[1, 1], vec[0, 1])))
    return float(center[i]), float(center[j]), 2.0 * float(semi[1]), 2.0 * float(semi[0]), angle


def draw_scene(ax: Axes, scene: Scene | None, robot_radius_m: float, axes: tuple[int, int] = (0, 1)) -> None:
    """Keep-in boxes (green) and keep-out ellipsoids (red; dashed: grown by the robot radius) projected on ``axes``."""
    if scene is None:
        return
    i, j = axes
    for k, box in enumerate(scene.keep_in):
        lo, hi = np.asarray(box.lower, dtype=float), np.asarray(box.upper, dtype=float)
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], fc=(0.3, 0.8, 0.45, 0.08),
                               ec="tab:green", lw=1.2, label="keep-in" if k == 0 else None))
    for k, zone in enumerate(scene.keep_out):
        x, y, w, h, a = ellipse_projection(zone.center, zone.shape, axes)
        ax.add_patch(Ellipse((x, y), w, h, angle=a, fc=(0.9, 0.25, 0.25, 0.35), ec="tab:red", lw=1.0,
                             label="keep-out (safety factor incl.)" if k == 0 else None))
        if robot_radius_m > 0:
            x, y, w, h, a = ellipse_projection(zone.center, zone.shape, axes, robot_radius_m)
            ax.add_patch(Ellipse((x, y), w, h, angle=a, fill=False, ec="tab:red", ls="--", lw=0.8,
                                 label=f"keep-out + robot radius {robot_radius_m:g} m" if k == 0 else None))


def finish_view(ax: Axes, axes: tuple[int, int], title: str) -> None:
    """Equal aspect, labels, grid, title and an outside legend of a top / side view."""
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel(f"{AXES[axes[0]]} [m]")
    ax.set_ylabel(f"{AXES[axes[1]]} [m]")
    ax.grid(True, alpha=0.3)
    ax.set_title(title, loc="left", fontsize="medium")
    legend_outside(ax)


def plot_inputs(path: Path, t_s: np.ndarray, u: np.ndarray, force_limit_N: np.ndarray, torque_limit_Nm: np.ndarray,
                title: str, limit_label: str = "limit",
                actuator: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Force and torque per axis (steps, held from each sample) against ± their limits (dashed).

    Parameters
    ----------
    path : Path
        Output PNG.
    t_s : ndarray, shape (K,)
        Sample times [s].
    u : ndarray, shape (K, 6)
        ``[f (N, world), τ (N·m, body)]``.
    force_limit_N, torque_limit_Nm : ndarray, shape (3,)
        Per-axis limits.
    title : str
        Figure title.
    limit_label : str
        Legend label of the limit lines.
    actuator : tuple of ndarray, optional
        The actuators' force [N] and torque [N·m] limits, drawn dotted when they differ from the limits above.

    Returns
    -------
    tuple of ndarray
        The plotted times and inputs.
    """
    t = np.asarray(t_s, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(t), 6)
    fig, axes = subplots(2, 3, figsize=(13, 6), sharex=True)
    for k in range(6):
        ax = axes[k // 3, k % 3]
        lim = float((force_limit_N if k < 3 else torque_limit_Nm)[k % 3])
        ax.step(*decimate(t, u[:, k]), where="post", lw=1.2, color="tab:blue", label="input")
        ax.axhline(lim, color="tab:red", ls="--", lw=1.0, label=f"± {limit_label}")
        ax.axhline(-lim, color="tab:red", ls="--", lw=1.0)
        top = 1.15 * lim
        if actuator is not None:
            act = float(actuator[0 if k < 3 else 1][k % 3])
            if abs(act - lim) > 1e-12 * lim:
                ax.axhline(act, color="tab:red", ls=":", lw=1.0, label="± actuator limit")
                ax.axhline(-act, color="tab:red", ls=":", lw=1.0)
                top = max(top, 1.15 * act)
        peak = float(np.nanmax(np.abs(u[:, k]))) if len(t) else 0.0
        top = max(top, 1.05 * peak) if np.isfinite(peak) else top
        ax.set_ylim(-top, top)
        unit = "N" if k < 3 else "N·m"
        ax.set_title(f"{'force' if k < 3 else 'torque'} {AXES[k % 3]} [{unit}] (limit ± {lim:.4g})", loc="left",
                     fontsize="medium")
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for ax in axes.flat:  # the actuator line may appear on another axis only
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center" if LEGACY else "lower center", ncols=len(labels),
               fontsize="small")
    fig.suptitle(title)
    save_png(fig, path)
    return t, u


def guarded_plots(run: RunFiles, summary: dict[str, Any], figures: Mapping[str, Callable[[Path], object]]) -> None:
    """Draw each figure ``name -> draw(path)`` into ``run.run_dir/<name>.png`` and register it as ``png_<name>``.

    A figure that fails is skipped: a warning naming it goes to the log and to ``summary["warnings"]``; the
    summary's status is kept (the run's results do not depend on its pictures).

    Parameters
    ----------
    run : RunFolder
        The open run folder.
    summary : dict
        The stage's summary (before :meth:`RunFolder.finish`).
    figures : mapping of str to callable
        Figure name -> function drawing it to the path given.
    """
    for name, draw in figures.items():
        path = Path(run.run_dir) / f"{name}.png"
        try:
            draw(path)
        except Exception as exc:  # a picture must never lose the run
            message = f"plot {name}.png not written: {type(exc).__name__}: {exc}"
            _LOG.warning(message)
            summary.setdefault("warnings", []).append(message)
            _pyplot_close("all")
            continue
        run.file(f"png_{name}", f"{name}.png")
