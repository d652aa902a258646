"""Wavefront OBJ (text): ``v`` vertices, ``f`` triangles, ``l`` segments."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..mesh import Mesh
from .chunks import row_chunks
from .header import header_comments
from .text import write_rows


def write_obj(mesh: Mesh, fh: BinaryIO, ascii: bool = True) -> None:
    """Write an indexed OBJ file (always text, UTF-8; indices are 1-based).

    Normals, when the mesh has them, follow the vertices as ``vn`` lines (9
    significant digits: float32), one per vertex, and triangles name them as
    ``f a//a b//b c//c``.

    Leading ``#`` comments say what made the mesh and record the grid it came
    from; vertices are written with 17 significant digits (float64 exactly).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` (``f``) or ``(C, 2)`` (``l``).
    fh : binary file
    ascii : bool
        Ignored (OBJ is text).
    """
    comments = header_comments(mesh, ascii=False)
    fh.write("".join(f"# {line}\n" for line in comments).encode("utf-8"))
    # 17 significant digits: vertices round-trip as float64
    write_rows(fh, mesh.vertices, "v %.17g %.17g %.17g\n", dtype=np.float64)
    cells = mesh.cells
    if mesh.normals is not None and cells.shape[1] == 3:
        write_rows(fh, mesh.normals, "vn %.9g %.9g %.9g\n", dtype=np.float32)
        for block in row_chunks(cells):
            write_rows(fh, block[:, [0, 0, 1, 1, 2, 2]], "f %d//%d %d//%d %d//%d\n", add=1)
        return
    write_rows(fh, cells, "f %d %d %d\n" if cells.shape[1] == 3 else "l %d %d\n", add=1)
