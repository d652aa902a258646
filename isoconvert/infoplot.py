"""A picture of a volume for choosing a level: the histogram and the middle slices.

``isoconvert info VOLUME --plot info.png`` draws, in one picture (PNG, SVG or
PDF, as the file's suffix says: :data:`PLOT_FORMATS`):

- the histogram of the finite samples (log counts), with the suggested levels
  (:func:`~isoconvert.stats.suggested_levels`, the very values ``info --json``
  prints) marked in their own colours and the chosen level dashed;
- the three middle slices of a 3D volume (xy at the middle z, xz at the middle
  y, yz at the middle x), or the whole of a 2D image, in world units with equal
  scales on both axes (so anisotropic spacing shows as it is), with the
  isocontour at the chosen level drawn over them. The contour is isoconvert's
  own Marching Squares (:func:`~isoconvert.extract.squares.marching_squares`)
  on the slice, so it is the curve where the extracted surface cuts the slice.

matplotlib (the ``plot`` extra) draws it, with its Agg canvas directly (no
pyplot, no display, no global backend switch), and is imported only here.

Memory: a volume in memory is sliced directly; a lazy grid (a file read on
demand) is read one slab at a time, keeping only the three slices, as the
histogram's scan does (:func:`~isoconvert.volume.slabs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .atomic import atomic_output, check_output
from .errors import IsoconvertError, LevelError, OutputError, extra_hint
from .stats import Histogram, histogram, no_levels_reason, suggested_levels
from .volume import Volume, slabs

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Colour of each suggested level's marker (distinct from the grey histogram,
#: the grey slices and the contour, so that a picture can be checked by colour).
LEVEL_COLORS = {
    "otsu": "#e41a1c",
    "p50": "#377eb8",
    "p90": "#4daf4a",
    "p99": "#ff7f00",
}
#: Colour of the isocontour on the slices and of the chosen level on the histogram.
CONTOUR_COLOR = "#ff00ff"
_OTHER_COLORS = ("#a65628", "#984ea3", "#00ced1", "#999900")
_HIST_COLOR = "#8c96a0"

#: Figure width in inches at :data:`DPI` (1000 pixels); the height follows the slices.
FIGSIZE = (10.0, 6.8)
DPI = 100
#: Height of the histogram row, inches.
HIST_HEIGHT = 2.4
#: What ``--plot`` writes, by the file's suffix: matplotlib's format names.
PLOT_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}


@dataclass(frozen=True)
class SliceView:
    """One middle slice, ready to draw.

    Attributes
    ----------
    name : str
        "xy", "xz" or "yz" (the horizontal, then the vertical axis).
    axes : (int, int)
        Grid axes shown horizontally and vertically.
    fixed : (int, int) or None
        The axis across the slice and the index of the slice on it (None for a
        2D image).
    samples : (H, V) array
        The slice's samples, first index along the horizontal axis.
    start, step : (2,) float64
        Display coordinate of sample 0 and the signed distance between samples,
        along each shown axis: world coordinates when the grid's axes are the
        world's (direction diagonal, +-1), else distances from the grid origin
        along the grid axes.
    y_down : bool
        Whether the vertical axis grows downwards (the xy slice and images, as
        pictures and radiological views are shown).
    """

    name: str
    axes: tuple[int, int]
    fixed: tuple[int, int] | None
    samples: np.ndarray
    start: np.ndarray
    step: np.ndarray
    y_down: bool

    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) of the samples' pixels, each a step wide,
        in display coordinates, increasing."""
        n = np.array(self.samples.shape, dtype=np.float64)
        a = self.start - 0.5 * self.step
        b = self.start + (n - 0.5) * self.step
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


@dataclass(frozen=True)
class Panel:
    """Where one panel's data area landed in the PNG.

    Attributes
    ----------
    bbox : (left, top, right, bottom) float
        Pixel coordinates in the image (x to the right, y down from the top row).
    xlim, ylim : (float, float)
        Data coordinates at the left and right edge, and at the bottom and top
        edge of ``bbox`` (``ylim[0] > ylim[1]`` when the axis grows downwards).
    """

    bbox: tuple[float, float, float, float]
    xlim: tuple[float, float]
    ylim: tuple[float, float]

    def to_pixel(self, x: float, y: float) -> tuple[float, float]:
        """Pixel (column, row) of data point (x, y)."""
        left, top, right, bottom = self.bbox
        u = (x - self.xlim[0]) / (self.xlim[1] - self.xlim[0])
        v = (y - self.ylim[0]) / (self.ylim[1] - self.ylim[0])
        return left + u * (right - left), bottom - v * (bottom - top)


@dataclass
class InfoPlot:
    """What :func:`write_info_plot` drew, for tests and scripts.

    Attributes
    ----------
    path : Path or None
        The picture written.
    size : (int, int)
        Width and height in pixels (of the PNG; an SVG or PDF has the same
        layout, in points at 72 per inch instead of pixels at :data:`DPI`).
    level : float or None
        The level contoured on the slices; None when no level gives a surface
        (a constant volume: the slices are drawn without contour).
    marked : dict of str to float
        The suggested levels marked on the histogram (equal to ``levels``).
    colors : dict of str to str
        Marker colour of each name in ``marked``, and ``"contour"``.
    panels : dict of str to Panel
        "histogram" and each slice ("xy", "xz", "yz"; only "xy" for images).
    segments : dict of str to int
        Contour segments drawn on each slice.
    """

    path: Path | None
    size: tuple[int, int]
    level: float | None
    marked: dict[str, float]
    colors: dict[str, str]
    panels: dict[str, Panel] = field(default_factory=dict)
    segments: dict[str, int] = field(default_factory=dict)


def require_matplotlib() -> None:
    """Fail in one line, before any work, when the ``plot`` extra is missing."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise IsoconvertError(f"pictures need matplotlib: {extra_hint('plot')}") from None


def plot_format(path: str | Path) -> str:
    """matplotlib's name of the format ``path``'s suffix asks for.

    Raises
    ------
    OutputError
        A suffix that is none of :data:`PLOT_FORMATS` (one line listing them).
    """
    suffix = Path(path).suffix.lower()
    if suffix not in PLOT_FORMATS:
        raise OutputError(
            f"{path}: --plot writes {', '.join(PLOT_FORMATS)} pictures, as the name ends; "
            f"not {suffix or 'a name without suffix'}"
        )
    return PLOT_FORMATS[suffix]


def resolve_level(
    spec: str | float | None, levels: dict[str, float], hist: Histogram
) -> float | None:
    """The level to contour: a number, a suggested level's name, or the first suggestion.

    Parameters
    ----------
    spec : str, float or None
        A number, ``"auto"`` (Otsu's threshold, as ``convert --level auto``), a
        name in ``levels`` (``otsu``, ``p50``, ...), or None for the first of
        ``levels``.
    levels : dict of str to float
        The suggested levels.
    hist : Histogram
        Gives the range of the finite samples.

    Returns
    -------
    float or None
        None for no contour: ``spec`` is None and no level gives a surface
        (every finite sample has one value).

    Raises
    ------
    LevelError
        No finite sample (nothing to draw), a level asked for where no level
        gives a surface, not a number or a name, not finite, or where no
        contour can be (not above the smallest sample, or above the largest).
    """
    reason = no_levels_reason(hist)
    if not hist.finite:
        raise LevelError(f"--plot: nothing to draw: {reason}")
    if reason is not None:
        if spec is None:
            return None
        raise LevelError(f"--level {spec}: {reason}")
    if spec is None:
        return float(next(iter(levels.values())))
    text = str(spec).strip().lower()
    if text == "auto":
        text = "otsu"
    if text in levels:
        return float(levels[text])
    try:
        value = float(text)
    except ValueError:
        raise LevelError(
            f"--level must be a number or one of {', '.join(['auto', *levels])}, got {spec!r}"
        ) from None
    lo, hi = hist.low, hist.high
    # positive samples are those >= level: at or below the minimum all are
    # positive, above the maximum none are; either way nothing to contour
    if not math.isfinite(value) or not lo < value <= hi:
        raise LevelError(
            f"--level {value:g} is outside the volume's values ({lo:g} .. {hi:g}], so no "
            f"contour crosses it; choose a level inside, e.g. otsu {levels['otsu']:g}"
            if "otsu" in levels
            else f"--level {value:g} is outside the volume's values ({lo:g} .. {hi:g}]"
        )
    return value


def middle_slices(volume: Volume) -> list[SliceView]:
    """The middle slices of a 3D volume (xy, xz, yz), or the 2D image itself.

    A lazy grid is read slab by slab, each slab dropped once its part of the
    xz and yz slices is copied, so at most one slab and the three slices are
    in memory at once.

    Parameters
    ----------
    volume : Volume

    Returns
    -------
    list of SliceView
    """
    start, step, _ = _display_axes(volume)
    if volume.ndim == 2:
        data = np.asarray(volume.samples)
        return [SliceView("xy", (0, 1), None, data, start[:2], step[:2], True)]
    nx, ny, nz = volume.shape
    i, j, k = nx // 2, ny // 2, nz // 2
    if volume.grid is None:
        data = volume.data
        xy = np.array(data[:, :, k])
        xz = np.array(data[:, j, :])
        yz = np.array(data[i, :, :])
    else:
        xy = xz = yz = None
        at = 0
        for slab in slabs(volume.grid):  # (X, Y, dz) views of each slab
            dz = slab.shape[2]
            if xz is None:
                xz = np.empty((nx, nz), dtype=slab.dtype)
                yz = np.empty((ny, nz), dtype=slab.dtype)
            xz[:, at : at + dz] = slab[:, j, :]
            yz[:, at : at + dz] = slab[i, :, :]
            if at <= k < at + dz:
                xy = np.array(slab[:, :, k - at])
            at += dz
    views = []
    for name, (h, v), (f, idx), y_down in (
        ("xy", (0, 1), (2, k), True),
        ("xz", (0, 2), (1, j), False),
        ("yz", (1, 2), (0, i), False),
    ):
        samples = {"xy": xy, "xz": xz, "yz": yz}[name]
        views.append(
            SliceView(name, (h, v), (f, idx), samples, start[[h, v]], step[[h, v]], y_down)
        )
    return views


def _display_axes(volume: Volume) -> tuple[np.ndarray, np.ndarray, bool]:
    """Display coordinate of index 0 and per-index step along each grid axis,
    and whether these are world coordinates.

    When each grid axis is a world axis (direction diagonal with entries +-1,
    as in most NRRD and NIfTI files, LPS flips included), the axes show world
    coordinates. Otherwise (oblique or permuted axes) a slice is not a plane of
    two world axes, so they show distances along the grid axes from the grid
    origin; the labels say which.
    """
    d = volume.direction
    aligned = bool(np.allclose(np.abs(d), np.eye(volume.ndim)))
    if aligned:
        signs = np.sign(np.diag(d))
        return volume.origin.astype(np.float64), signs * volume.spacing, True
    return np.zeros(volume.ndim), volume.spacing.astype(np.float64), False


def slice_contour(view: SliceView, level: float, nan_as: float | None) -> np.ndarray:
    """Segments ``(S, 2, 2)`` of the isocontour of one slice, in display coordinates.

    The slice becomes a 2D :class:`Volume` placed with the display axes
    (origin ``view.start``, spacing and direction from ``view.step``), so
    :func:`~isoconvert.extract.squares.marching_squares` itself places the
    vertices, exactly where extraction puts them on the slice's grid edges.
    """
    from .extract.squares import marching_squares

    samples = view.samples
    if nan_as is not None and np.issubdtype(samples.dtype, np.floating):
        # NaN/Inf count as below the level (the picture shows them blank)
        if not np.isfinite(samples).all():
            samples = np.where(np.isfinite(samples), samples, nan_as).astype(samples.dtype)
    if samples.shape[0] < 2 or samples.shape[1] < 2:
        return np.zeros((0, 2, 2))
    plane = Volume(
        samples,
        spacing=np.abs(view.step),
        origin=view.start,
        direction=np.diag(np.sign(view.step)),
        source="slice",
    )
    try:
        mesh = marching_squares(plane, level)
    except IsoconvertError:
        return np.zeros((0, 2, 2))  # the level does not cross this slice
    return mesh.vertices[:, :2][mesh.cells]


def info_figure(
    volume: Volume,
    level: float | str | None = None,
    *,
    hist: Histogram | None = None,
    levels: dict[str, float] | None = None,
) -> tuple[Figure, InfoPlot]:
    """Draw the histogram and the middle slices of ``volume`` (see the module).

    Parameters
    ----------
    volume : Volume
    level : float, str or None
        The contour level: see :func:`resolve_level` (None: the first suggested level).
    hist : Histogram or None
        The volume's histogram when already computed (``info`` has it); else
        it is computed here (one scan).
    levels : dict of str to float or None
        The suggested levels when already computed, else
        :func:`~isoconvert.stats.suggested_levels` of ``hist``.

    Returns
    -------
    matplotlib.figure.Figure
        On an Agg canvas, not yet drawn.
    InfoPlot
        What was drawn (``panels`` is filled in by :func:`render`).
    """
    require_matplotlib()
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    if hist is None:
        hist = histogram(volume.samples)
    if levels is None:
        levels = suggested_levels(hist)
    value = resolve_level(level, levels, hist)
    views = middle_slices(volume)
    colors = {name: _level_color(name, n) for n, name in enumerate(levels)}
    colors["contour"] = CONTOUR_COLOR
    result = InfoPlot(None, (0, 0), value, dict(levels), colors)

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    # Panel widths follow each slice's width/height in world units, and the
    # slice row is as tall as that lets the row fill the figure's width (so
    # little is left blank around equal-scale panels); extreme shapes clipped.
    ratios = [min(max(_aspect(v), 0.25), 4.0) for v in views]
    room = FIGSIZE[0] - 0.9 * len(views)  # inches left after each panel's axis labels
    row = min(max(room / sum(ratios), 1.0), 4.5)
    fig = Figure(figsize=(FIGSIZE[0], HIST_HEIGHT + row + 1.3), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, len(views), height_ratios=[HIST_HEIGHT, row], width_ratios=ratios)
    # the labels name the panels in InfoPlot.panels (render reads them back)
    hist_ax = fig.add_subplot(grid[0, :], label="histogram")
    _draw_histogram(hist_ax, hist, levels, value, colors)
    unit = f" ({volume.unit})" if volume.unit else ""
    _, _, world = _display_axes(volume)
    names = "xyz"
    lo, hi = hist.low, hist.high
    for col, view in enumerate(views):
        ax = fig.add_subplot(grid[1, col], label=view.name)
        left, right, bottom, top = view.extent()
        ax.set_facecolor("white")
        ax.imshow(
            view.samples.T,
            cmap="gray",
            vmin=lo,
            vmax=hi if hi > lo else lo + 1,
            origin="lower",
            # each sample's pixel centred on its position (a step wide)
            extent=_signed_extent(view),
            interpolation="nearest",
        )
        ax.set_xlim(left, right)
        ax.set_ylim((top, bottom) if view.y_down else (bottom, top))
        # equal scales: one world unit is as long across as up (anisotropic spacing shows)
        ax.set_aspect("equal", adjustable="box")
        segs = np.zeros((0, 2, 2)) if value is None else slice_contour(view, value, nan_as=lo)
        result.segments[view.name] = len(segs)
        if len(segs):
            ax.add_collection(LineCollection(segs, colors=CONTOUR_COLOR, linewidths=1.4))
        h, v = view.axes
        prefix = "" if world else "grid "
        ax.set_xlabel(f"{prefix}{names[h]}{unit}")
        ax.set_ylabel(f"{prefix}{names[v]}{unit}")
        ax.set_title(_slice_title(volume, view, len(segs)), fontsize=9)
        ax.tick_params(labelsize=8)
    shape = " x ".join(map(str, volume.shape))
    spacing = " x ".join(f"{s:g}" for s in volume.spacing)
    contour = f"contour at {value:g}" if value is not None else no_levels_reason(hist)
    fig.suptitle(
        f"{Path(volume.source).name}: {shape} {volume.dtype.name}, spacing {spacing}"
        f"{' ' + volume.unit if volume.unit else ''}; {contour}",
        fontsize=10,
    )
    return fig, result


def _aspect(view: SliceView) -> float:
    left, right, bottom, top = view.extent()
    return (right - left) / (top - bottom)


def _signed_extent(view: SliceView) -> tuple[float, float, float, float]:
    """imshow's extent: where the first and last samples' pixel edges are
    (reversed along an axis whose step is negative, so the picture flips)."""
    n = np.array(view.samples.shape, dtype=np.float64)
    a = view.start - 0.5 * view.step
    b = view.start + (n - 0.5) * view.step
    return float(a[0]), float(b[0]), float(a[1]), float(b[1])


def _slice_title(volume: Volume, view: SliceView, segments: int) -> str:
    # short: narrow panels (a tall yz slice) share the row with wide ones
    if view.fixed is None:
        title = "image"
    else:
        axis, index = view.fixed
        start, step, world = _display_axes(volume)
        where = f"{'xyz'[axis]}={start[axis] + index * step[axis]:.4g}" if world else ""
        title = f"{view.name} at {where or 'ijk'[axis] + '=' + str(index)}"
    return title if segments else title + "\n(no contour)"


def _level_color(name: str, n: int) -> str:
    return LEVEL_COLORS.get(name, _OTHER_COLORS[n % len(_OTHER_COLORS)])


def _draw_histogram(
    ax: Axes,
    hist: Histogram,
    levels: dict[str, float],
    level: float | None,
    colors: dict[str, str],
) -> None:
    """Log counts per bin, the chosen level dashed, the suggested levels as lines."""
    edges = hist.edges
    counts = hist.counts.astype(np.float64)
    if not hist.low < hist.high:
        # one value: one bar centred on it (the bins' made-up width would show a range)
        half = max(0.5, abs(hist.low) * 1e-6)
        edges, counts = np.array([hist.low - half, hist.low + half]), counts[counts > 0]
    elif hist.integer:
        # bin b holds exactly the value edges[b]: centre its bar on that value,
        # so half-integer suggested levels fall between bars
        edges = edges - 0.5
    # log scale: empty bins drawn just under 1 (a count of 1 still shows)
    ax.stairs(np.maximum(counts, 0.5), edges, baseline=0.5, fill=True, color=_HIST_COLOR)
    ax.set_yscale("log")
    ax.set_ylim(0.5, max(float(counts.max()), 1.0) * 2.0)
    ax.set_xlim(float(edges[0]), float(edges[-1]))
    if level is not None:
        ax.axvline(
            level,
            color=CONTOUR_COLOR,
            linestyle=(0, (4, 2)),
            linewidth=1.5,
            zorder=2,
            label=f"contour {level:.6g}",
        )
    for name, value in levels.items():
        # not antialiased: the marker's pixels keep its exact colour
        ax.axvline(
            value,
            color=colors[name],
            linewidth=1.5,
            antialiased=False,
            zorder=3,
            label=f"{name} {value:.6g}",
        )
    total = int(hist.counts.sum())
    extra = f", {hist.nonfinite:,} NaN/Inf left out" if hist.nonfinite else ""
    ax.set_title(f"histogram of {total:,} samples (log counts){extra}", fontsize=9)
    ax.set_xlabel("value")
    ax.set_ylabel("samples")
    ax.tick_params(labelsize=8)
    # outside the plot, so the only marker-coloured pixels inside are the markers
    if levels or level is not None:
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, frameon=False)


def render(fig: Figure, result: InfoPlot) -> np.ndarray:
    """Draw ``fig`` and fill ``result.panels``; the picture as ``(H, W, 3) uint8``.

    The pixels are those measured, so the layout in ``result`` is exact for
    the PNG written from them.
    """
    canvas = fig.canvas
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    height, width = rgba.shape[:2]
    result.size = (width, height)
    renderer = canvas.get_renderer()
    for ax in fig.axes:
        box = ax.get_window_extent(renderer)
        result.panels[ax.get_label()] = Panel(
            (float(box.x0), float(height - box.y1), float(box.x1), float(height - box.y0)),
            tuple(float(v) for v in ax.get_xlim()),
            tuple(float(v) for v in ax.get_ylim()),
        )
    return np.ascontiguousarray(rgba[..., :3])


def write_info_plot(
    volume: Volume,
    path: str | Path,
    level: float | str | None = None,
    *,
    hist: Histogram | None = None,
    levels: dict[str, float] | None = None,
    force: bool = False,
) -> InfoPlot:
    """Write the info picture of ``volume`` (see the module).

    Parameters
    ----------
    volume : Volume
    path : str or Path
        The picture to write, in the format its suffix names (``.png``, ``.svg``
        or ``.pdf``); it appears whole or not at all.
    level, hist, levels
        See :func:`info_figure`.
    force : bool
        Overwrite an existing file.

    Returns
    -------
    InfoPlot
        What was drawn and where (pixel layout of each panel).

    Raises
    ------
    IsoconvertError
        matplotlib missing, a bad level, a suffix naming no format it writes,
        or an output that cannot be written.
    """
    from PIL import Image

    require_matplotlib()
    kind = plot_format(path)
    # fail before reading anything, and never over a file the volume is read from
    path = check_output(path, force, "info.png", inputs=volume.files)
    fig, result = info_figure(volume, level, hist=hist, levels=levels)
    pixels = render(fig, result)
    with atomic_output(path, force, "info.png") as fh:
        if kind == "png":
            Image.fromarray(pixels).save(fh, format="PNG", optimize=True)
        else:
            # vector formats from the same figure; no date, so a run is repeatable
            stamp = {"svg": {"Date": None}, "pdf": {"CreationDate": None}}[kind]
            fig.savefig(fh, format=kind, dpi=DPI, metadata=stamp)
    result.path = Path(path)
    return result


__all__ = [
    "CONTOUR_COLOR",
    "LEVEL_COLORS",
    "PLOT_FORMATS",
    "InfoPlot",
    "Panel",
    "SliceView",
    "info_figure",
    "middle_slices",
    "plot_format",
    "render",
    "resolve_level",
    "slice_contour",
    "write_info_plot",
]
