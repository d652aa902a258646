"""OFF (Object File Format; Geomview, the book's examples): indexed triangles, text."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .header import header_comments
from .text import write_rows


def write_off(mesh: Mesh, fh: BinaryIO, ascii: bool = True) -> None:
    """Write an OFF file: ``OFF``, ``#`` comments, ``V F 0``, the vertices, the faces.

    The comments (after the ``OFF`` line, before the counts, where Geomview,
    meshio and trimesh skip them) say what made the mesh and record the grid
    it came from (``# isoconvert grid {...}``); they are ASCII (escaped).
    Vertices are written with 17 significant digits (float64 exactly), faces
    as ``3 i j k`` with 0-based indices. Written block by block.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` (OFF faces cannot be segments).
    fh : binary file
    ascii : bool
        Ignored (this OFF writer writes text).
    """
    if not mesh.is_triangles:
        raise FormatError("OFF holds faces (triangles) only; write contours as OBJ, PLY or VTP")
    comments = header_comments(mesh, ascii=True)
    head = ["OFF", *[f"# {line}" for line in comments], f"{len(mesh.vertices)} {len(mesh.cells)} 0"]
    fh.write(("\n".join(head) + "\n").encode("ascii"))
    write_rows(fh, mesh.vertices, "%.17g %.17g %.17g\n", dtype=np.float64)
    write_rows(fh, mesh.cells, "3 %d %d %d\n")
