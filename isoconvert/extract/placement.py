"""From index space to world space, keeping the orientation convention."""

from __future__ import annotations

import numpy as np

from ..mesh import Mesh
from ..report import grid_from_volume
from ..volume import Volume


def reversed_orientation(volume: Volume, flip: bool) -> bool:
    """Whether triangles must be written in reverse for normals to keep pointing
    from the positive to the negative side (the other way with ``flip``).

    A left-handed index-to-world map (negative determinant, as some NRRD
    ``space directions`` are) mirrors the surface.
    """
    return bool(np.linalg.det(volume.affine) < 0) != flip


def mesh_info(
    volume: Volume, method: str, level: float, flip: bool, vertex_offset: float | None = None
) -> dict:
    """The ``info`` of an extracted mesh: how it was made, and from which grid."""
    info = {
        "method": method,
        "level": level,
        "source": volume.source,
        "flip": flip,
        # the grid, so checks can tell the grid's boundary from holes
        "grid": grid_from_volume(volume),
    }
    if vertex_offset is not None:
        info["vertex_offset"] = vertex_offset
    return info


def finish_mesh(
    volume: Volume,
    verts: np.ndarray,
    cells: np.ndarray,
    edge_ids: np.ndarray,
    flip: bool,
    method: str,
    level: float,
) -> Mesh:
    """A Mesh from index-space vertices: moved to world space, oriented.

    For kernels that do not place vertices in world units themselves.
    """
    volume.index_to_world(verts)
    if reversed_orientation(volume, flip):
        cells = cells[:, ::-1].copy()
    return Mesh(verts, cells, edge_ids, mesh_info(volume, method, level, flip))
