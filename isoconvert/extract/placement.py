"""From index space to world space, keeping the orientation convention."""

from __future__ import annotations

import numpy as np

from ..mesh import Mesh
from ..report import grid_from_volume
from ..volume import Volume


def finish_mesh(
    volume: Volume,
    verts: np.ndarray,
    cells: np.ndarray,
    edge_ids: np.ndarray,
    flip: bool,
    method: str,
    level: float,
) -> Mesh:
    """Move index-space vertices to world space and settle the orientation.

    A left-handed index-to-world map (negative determinant, as some NRRD
    ``space directions`` are) mirrors the surface; the triangles are reversed
    then, so normals still point from the positive to the negative side.
    """
    mirrored = np.linalg.det(volume.affine) < 0
    volume.index_to_world(verts)
    if mirrored != flip:
        cells = cells[:, ::-1].copy()
    info = {
        "method": method,
        "level": level,
        "source": volume.source,
        "flip": flip,
        # the grid, so checks can tell the grid's boundary from holes
        "grid": grid_from_volume(volume),
    }
    return Mesh(verts, cells, edge_ids, info)
