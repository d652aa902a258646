"""SVG: a picture of 2D contours, one path per polyline."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh, polylines
from .header import escape_comment


def write_svg(mesh: Mesh, fh: BinaryIO, ascii: bool = True) -> None:
    """Draw 2D contour segments; x to the right, y down (as images are shown).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)`` in one plane of constant z, ``cells (C, 2)``.
    fh : binary file
        Receives UTF-8 XML; the comment naming the level and the source is
        escaped (:func:`~isoconvert.writers.header.escape_comment`) so that it
        stays a valid XML comment whatever the source path holds.
    ascii : bool
        Ignored (SVG is text).
    """
    if mesh.is_triangles:
        raise FormatError("SVG draws 2D contours; write surfaces as PLY, OBJ or STL")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if len(v) and np.ptp(v[:, 2]) > 0:
        raise FormatError(
            "SVG draws 2D contours, but these lie in several planes (a slice stack); "
            "write them as OBJ or PLY"
        )
    lo = v[:, :2].min(axis=0) if len(v) else np.zeros(2)
    hi = v[:, :2].max(axis=0) if len(v) else np.ones(2)
    size = np.maximum(hi - lo, 1e-9)
    pad = 0.02 * size.max()
    stroke = 0.003 * size.max()
    note = escape_comment(
        f"isoconvert: level {mesh.info.get('level', '?')} source {mesh.info.get('source', '?')}",
        xml=True,
    )
    fh.write(
        (
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<svg xmlns="http://www.w3.org/2000/svg" '
            f'viewBox="{lo[0] - pad:.6g} {lo[1] - pad:.6g} {size[0] + 2 * pad:.6g} '
            f'{size[1] + 2 * pad:.6g}">\n'
            f"<!-- {note} -->\n"
            f'<g fill="none" stroke="black" stroke-width="{stroke:.4g}" '
            'stroke-linejoin="round" stroke-linecap="round">\n'
        ).encode()
    )
    for line, closed in polylines(mesh.cells):
        pts = v[line, :2]
        coords = " L".join(f"{x:.6g} {y:.6g}" for x, y in pts)
        fh.write(f'<path d="M{coords}{" Z" if closed else ""}"/>\n'.encode("ascii"))
    fh.write(b"</g>\n</svg>\n")
