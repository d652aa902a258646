"""STL, binary or ASCII: the one format without shared vertices."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .chunks import ROWS, row_chunks
from .text import write_rows

#: The name on an ASCII STL's ``solid`` line (no text from the mesh goes there).
SOLID_NAME = "isoconvert"


def write_stl(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write each triangle with its own three vertices and unit normal, float32.

    Zero-area triangles get a zero normal rather than NaN (cf. scikit-image
    PR #4872, where NaN normals broke slicers). Corners are rounded to float32
    first, so the normals are those of the triangles the file holds. Written
    block by block: a mesh of any size needs little memory.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)``.
    fh : binary file
    ascii : bool
        ``solid ... endsolid`` text instead of binary records.
    """
    if not mesh.is_triangles:
        raise FormatError("STL holds triangles only; write contours as OBJ or PLY")
    if ascii:
        fh.write(f"solid {SOLID_NAME}\n".encode("ascii"))
        facet = (
            "facet normal %.9g %.9g %.9g\n outer loop\n"
            + "  vertex %.9g %.9g %.9g\n" * 3
            + " endloop\nendfacet\n"
        )
        for normals, corners in _facets(mesh):
            write_rows(fh, np.concatenate([normals, corners.reshape(-1, 9)], axis=1), facet)
        fh.write(f"endsolid {SOLID_NAME}\n".encode("ascii"))
        return
    header = b"binary STL written by isoconvert"
    fh.write(header.ljust(80, b" "))
    fh.write(np.uint32(len(mesh.cells)).tobytes())
    record = np.dtype([("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    for normals, corners in _facets(mesh):
        out = np.zeros(len(normals), dtype=record)
        out["n"] = normals
        out["v"] = corners
        fh.write(out.tobytes())


def _facets(mesh: Mesh):
    """Per block of triangles: unit normals ``(c, 3) float32`` of the triangles
    as stored, and their corners ``(c, 3, 3) float32``."""
    for block in row_chunks(mesh.cells):
        corners = np.asarray(mesh.vertices)[block].astype(np.float32)
        stored = Mesh(corners.reshape(-1, 3).astype(np.float64), _EXPANDED[: len(block)])
        yield stored.triangle_normals().astype(np.float32), corners


#: Cells of blocks of expanded triangles: triangle t is vertices 3t, 3t + 1, 3t + 2.
_EXPANDED = np.arange(3 * ROWS, dtype=np.int64).reshape(-1, 3)
