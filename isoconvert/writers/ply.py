"""PLY (Stanford polygon format), binary little-endian or ASCII."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..mesh import Mesh
from .text import write_rows


def write_ply(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write vertices as float32 x, y, z and cells as ``face`` (triangles) or
    ``edge`` (segments) elements, indices int32."""
    verts = np.asarray(mesh.vertices, dtype=np.float32)
    cells = np.asarray(mesh.cells)
    triangles = cells.shape[1] == 3
    header = [
        "ply",
        f"format {'ascii' if ascii else 'binary_little_endian'} 1.0",
        *[f"comment {line}" for line in provenance(mesh)],
        f"element vertex {len(verts)}",
        "property float x",
        "property float y",
        "property float z",
    ]
    if triangles:
        header += [f"element face {len(cells)}", "property list uchar int vertex_indices"]
    else:
        header += [f"element edge {len(cells)}", "property int vertex1", "property int vertex2"]
    fh.write(("\n".join(header) + "\nend_header\n").encode("ascii"))
    if ascii:
        write_rows(fh, verts, "%.9g %.9g %.9g\n")
        write_rows(fh, cells, "3 %d %d %d\n" if triangles else "%d %d\n")
        return
    fh.write(verts.astype("<f4", copy=False).tobytes())
    if triangles:
        record = np.empty(len(cells), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        record["n"] = 3
        record["v"] = cells
        fh.write(record.tobytes())
    else:
        fh.write(cells.astype("<i4").tobytes())


def provenance(mesh: Mesh) -> list[str]:
    """Comment lines saying what made the mesh."""
    info = mesh.info
    if not info:
        return ["made by isoconvert"]
    from .. import __version__

    lines = [f"made by isoconvert {__version__}"]
    if "source" in info:
        lines.append(f"source {info['source']}")
    if "method" in info:
        lines.append(f"method {info['method']} level {info.get('level', '?'):.17g}")
    return lines
