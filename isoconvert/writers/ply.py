"""PLY (Stanford polygon format), binary little-endian or ASCII."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..mesh import Mesh
from .chunks import ROWS, row_chunks
from .header import header_comments
from .text import write_rows


def write_ply(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write vertices as x, y, z (then ``nx, ny, nz`` and ``value``, float, when
    the mesh has normals and values) and cells as ``face`` (triangles) or
    ``edge`` (segments) elements, indices int32; faces of a label volume's
    mesh also get ``inside_label`` and ``outside_label`` (int).

    Coordinates are ``double`` when ``mesh.info["stored_precision"]`` is
    "float64", else ``float`` (float32, rounded here); :func:`isoconvert.write_mesh` decides
    (see :func:`isoconvert.writers.stored_mesh`). The header's comments say
    what made the mesh and record the grid it came from.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)``.
    fh : binary file
    ascii : bool
        ``format ascii 1.0`` instead of ``binary_little_endian 1.0``.
    """
    double = mesh.info.get("stored_precision") == "float64"
    verts = mesh.vertices
    cells = mesh.cells
    triangles = cells.shape[1] == 3
    kind = "double" if double else "float"
    header = [
        "ply",
        f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
        *[f"comment {line}" for line in header_comments(mesh, ascii=True)],
        f"element vertex {len(verts)}",
        f"property {kind} x",
        f"property {kind} y",
        f"property {kind} z",
    ]
    columns = [verts]
    if mesh.normals is not None:
        header += ["property float nx", "property float ny", "property float nz"]
        columns.append(mesh.normals)
    if mesh.values is not None:
        header.append("property float value")
        columns.append(mesh.values.reshape(-1, 1))
    labels = mesh.cell_labels
    if triangles:
        header += [f"element face {len(cells)}", "property list uchar int vertex_indices"]
        if labels is not None:
            # the labels on the two sides: normals point from the first to the second
            header += ["property int inside_label", "property int outside_label"]
    else:
        header += [f"element edge {len(cells)}", "property int vertex1", "property int vertex2"]
    fh.write(("\n".join(header) + "\nend_header\n").encode("ascii"))
    stored = np.float64 if double else np.float32
    if ascii:
        # 17 significant digits give a double back exactly, 9 a float
        digits = 17 if double else 9
        extra = sum(c.shape[1] for c in columns[1:])
        row = " ".join([f"%.{digits}g"] * 3 + ["%.9g"] * extra) + "\n"
        for i, block in enumerate(row_chunks(verts)):
            # attributes are float32 values: exact in either precision
            a = i * ROWS
            rows = [block.astype(stored)] + [c[a : a + ROWS].astype(stored) for c in columns[1:]]
            write_rows(fh, np.hstack(rows), row)
        if triangles and labels is not None:
            for i, block in enumerate(row_chunks(cells)):
                rows = np.hstack([block, labels[i * ROWS : (i + 1) * ROWS]])
                write_rows(fh, rows, "3 %d %d %d %d %d\n")
            return
        write_rows(fh, cells, "3 %d %d %d\n" if triangles else "%d %d\n")
        return
    if len(columns) == 1:
        for block in row_chunks(verts):
            fh.write(np.ascontiguousarray(block, dtype="<f8" if double else "<f4"))
    else:
        fields = [("xyz", "<f8" if double else "<f4", (3,))]
        if mesh.normals is not None:
            fields.append(("normal", "<f4", (3,)))
        if mesh.values is not None:
            fields.append(("value", "<f4"))
        vertex = np.dtype(fields)
        for i, block in enumerate(row_chunks(verts)):
            a = i * ROWS
            out = np.empty(len(block), dtype=vertex)
            out["xyz"] = block
            if mesh.normals is not None:
                out["normal"] = mesh.normals[a : a + ROWS]
            if mesh.values is not None:
                out["value"] = mesh.values[a : a + ROWS]
            fh.write(out)
    fields = [("n", "u1"), ("v", "<i4", (3,))]
    if labels is not None:
        fields.append(("labels", "<i4", (2,)))
    record = np.dtype(fields) if triangles else np.dtype("<i4")
    for i, block in enumerate(row_chunks(cells)):
        if triangles:
            out = np.empty(len(block), dtype=record)
            out["n"] = 3
            out["v"] = block
            if labels is not None:
                out["labels"] = labels[i * ROWS : (i + 1) * ROWS]
        else:
            out = block.astype(record)
        fh.write(out)  # the array's memory, without a copy as bytes
