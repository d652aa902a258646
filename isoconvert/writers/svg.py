"""SVG: a picture of 2D contours, one path per polyline.

The picture has a size in world units: where the mesh records its grid
(``info["grid"]``, as every extracted contour does), the view box is the
image's extent (each sample a pixel one spacing wide, so the contour sits in
its image's frame), and ``width``/``height`` state that extent in the
volume's unit when SVG has it (mm, cm, in; metres as mm). Without a unit SVG
can state, the width and height are user units (CSS pixels) at a round scale
(1, 2 or 5 times a power of ten pixels per world unit) that makes the larger
side 320 to 800 pixels. A white rectangle behind the paths keeps the picture
readable on dark viewers (``background=None`` leaves it transparent).
"""

from __future__ import annotations

import math
from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh, polylines
from ..units import meters_per_unit
from .header import escape_comment

#: The units SVG can state a length in, by meters per unit of the volume (see
#: :mod:`isoconvert.units` for the names volumes use): the SVG unit and the
#: factor from the volume's unit to it. Micrometres and smaller are left out: a
#: picture a few hundredths of a millimetre wide is useless on screen.
SVG_UNITS = {1e-3: ("mm", 1.0), 1e-2: ("cm", 1.0), 0.0254: ("in", 1.0), 1.0: ("mm", 1000.0)}
#: Largest side of a picture without a stated unit, in user units (CSS pixels).
_TARGET_PIXELS = 800.0


def write_svg(
    mesh: Mesh, fh: BinaryIO, ascii: bool = True, *, background: str | None = "white"
) -> None:
    """Draw 2D contour segments; x to the right, y down (as images are shown).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)`` in one plane of constant z, ``cells (C, 2)``;
        ``info["grid"]`` and ``info["unit"]`` give the picture's frame and size.
    fh : binary file
        Receives UTF-8 XML; the comment naming the level and the source is
        escaped (:func:`~isoconvert.writers.header.escape_comment`) so that it
        stays a valid XML comment whatever the source path holds.
    ascii : bool
        Ignored (SVG is text).
    background : str or None
        Fill of a rectangle behind the contours (an SVG colour), or None for none.
    """
    if mesh.is_triangles:
        raise FormatError("SVG draws 2D contours; write surfaces as PLY, OBJ or STL")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if len(v) and np.ptp(v[:, 2]) > 0:
        raise FormatError(
            "SVG draws 2D contours, but these lie in several planes (a slice stack); "
            "write them as OBJ or PLY"
        )
    lo, hi = picture_frame(mesh)
    size = hi - lo
    width, height = svg_size(size, mesh.info.get("unit"))
    stroke = 0.003 * size.max()
    note = escape_comment(
        f"isoconvert: level {mesh.info.get('level', '?')} source {mesh.info.get('source', '?')}",
        xml=True,
    )
    box = f"{lo[0]:.9g} {lo[1]:.9g} {size[0]:.9g} {size[1]:.9g}"
    head = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="{box}">\n'
        f"<!-- {note} -->\n"
    )
    if background is not None:
        fill = escape_comment(str(background), xml=True).replace('"', "")
        head += (
            f'<rect x="{lo[0]:.9g}" y="{lo[1]:.9g}" width="{size[0]:.9g}" '
            f'height="{size[1]:.9g}" fill="{fill}"/>\n'
        )
    head += (
        f'<g fill="none" stroke="black" stroke-width="{stroke:.4g}" '
        'stroke-linejoin="round" stroke-linecap="round">\n'
    )
    fh.write(head.encode())
    for line, closed in polylines(mesh.cells):
        pts = v[line, :2]
        coords = " L".join(f"{x:.6g} {y:.6g}" for x, y in pts)
        fh.write(f'<path d="M{coords}{" Z" if closed else ""}"/>\n'.encode("ascii"))
    fh.write(b"</g>\n</svg>\n")


def picture_frame(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper (x, y) corners of the picture, in world units.

    The 2D grid's pixel extent (half a spacing beyond the first and last
    samples) when ``mesh.info["grid"]`` has one, grown to hold every vertex;
    else the vertices' bounding box with a 2% margin.

    Returns
    -------
    (2,) float64, (2,) float64
        ``lo < hi`` on both axes.
    """
    v = np.asarray(mesh.vertices, dtype=np.float64)[:, :2]
    grid = mesh.info.get("grid") or {}
    shape = grid.get("shape")
    if shape is not None and len(shape) == 2:
        affine = np.asarray(grid["affine"], dtype=np.float64)
        origin = np.asarray(grid["origin"], dtype=np.float64)
        n = np.asarray(shape, dtype=np.float64)
        corners = np.array(
            [[a, b] for a in (-0.5, n[0] - 0.5) for b in (-0.5, n[1] - 0.5)], dtype=np.float64
        )
        world = corners @ affine.T + origin
        lo, hi = world.min(axis=0), world.max(axis=0)
        if len(v):
            lo, hi = np.minimum(lo, v.min(axis=0)), np.maximum(hi, v.max(axis=0))
        return lo, hi
    lo = v.min(axis=0) if len(v) else np.zeros(2)
    hi = v.max(axis=0) if len(v) else np.ones(2)
    size = np.maximum(hi - lo, 1e-9)
    pad = 0.02 * size.max()
    return lo - pad, lo + size + pad


def svg_size(size: np.ndarray, unit: str | None) -> tuple[str, str]:
    """The ``width`` and ``height`` attributes of a picture ``size`` world units large.

    Parameters
    ----------
    size : (2,) float
        Width and height in the volume's unit.
    unit : str or None
        The volume's unit.

    Returns
    -------
    (str, str)
        E.g. ``("12.5mm", "8mm")`` for a unit SVG has (see :data:`SVG_UNITS`),
        else unitless user units at a round scale (see the module).
    """
    known = SVG_UNITS.get(meters_per_unit(unit))
    if known is not None:
        name, factor = known
        return f"{size[0] * factor:.9g}{name}", f"{size[1] * factor:.9g}{name}"
    scale = nice_scale(_TARGET_PIXELS / float(max(size.max(), 1e-300)))
    return f"{size[0] * scale:.9g}", f"{size[1] * scale:.9g}"


def nice_scale(limit: float) -> float:
    """The largest of 1, 2, 5 times a power of ten that is at most ``limit`` (> 0)."""
    exponent = math.floor(math.log10(limit))
    for mantissa in (5.0, 2.0, 1.0):
        value = mantissa * 10.0**exponent
        if value <= limit * (1 + 1e-12):
            return value
    return 10.0**exponent
