"""STL, binary or ASCII: the one format without shared vertices."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .text import write_rows

#: The name on an ASCII STL's ``solid`` line (no text from the mesh goes there).
SOLID_NAME = "isoconvert"


def write_stl(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write each triangle with its own three vertices and unit normal, float32.

    Zero-area triangles get a zero normal rather than NaN (cf. scikit-image
    PR #4872, where NaN normals broke slicers). :func:`isoconvert.write_mesh`
    passes the mesh as :func:`~isoconvert.writers.stored_mesh` gives it (three
    float32-rounded vertices per triangle), so the normals are those of the
    triangles the file holds.

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
    normals = mesh.triangle_normals().astype(np.float32)
    corners = np.asarray(mesh.vertices, dtype=np.float32)[mesh.cells]  # (C, 3, 3)
    if ascii:
        fh.write(f"solid {SOLID_NAME}\n".encode("ascii"))
        rows = np.concatenate([normals, corners.reshape(-1, 9)], axis=1)
        facet = (
            "facet normal %.9g %.9g %.9g\n outer loop\n"
            + "  vertex %.9g %.9g %.9g\n" * 3
            + " endloop\nendfacet\n"
        )
        write_rows(fh, rows, facet)
        fh.write(f"endsolid {SOLID_NAME}\n".encode("ascii"))
        return
    header = b"binary STL written by isoconvert"
    fh.write(header.ljust(80, b" "))
    fh.write(np.uint32(len(normals)).tobytes())
    record = np.zeros(
        len(normals), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")]
    )
    record["n"] = normals
    record["v"] = corners
    fh.write(record.tobytes())
