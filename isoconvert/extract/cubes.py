"""Marching Cubes (Wenger, *Isosurfaces*, section 2.3)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..mesh import Mesh
from ..volume import Volume
from .jit import compile_notice
from .placement import finish_mesh
from .prepare import check_level, check_vertex_offset, kernel_array
from .tables import DEFAULT_AMBIGUITY, EDGE_AXIS, EDGE_BASE, marching_cubes_table


def marching_cubes(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float = 0.0,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract the isosurface of a 3D volume with Marching Cubes.

    Parameters
    ----------
    volume : Volume
        A 3D volume with at least 2 samples along each axis.
    level : float
        The isovalue; grid vertices with value >= level are positive.
    flip : bool
        Reverse the orientation (normals then point from negative to positive).
    ambiguity : str
        Rule for ambiguous faces: "separate-positive" (default, as VTK)
        or "separate-negative"; see :mod:`isoconvert.extract.tables`.
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    vertex_offset : float
        Keep every vertex at least this fraction of its edge's length away from
        the edge's ends (0 <= f < 0.5). With f > 0, a level equal to grid values
        gives no zero-length edges (see :func:`check_vertex_offset`).
    on_status : callable or None
        Receives one-line notices (e.g. that numba is compiling).

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` in world units, ``cells (C, 3) int64``,
        ``edge_ids (V,) int64``. Normals point from the positive to the negative
        side, i.e. out of bright objects.
    """
    arr, stats = kernel_array(volume, 3, "cubes", nan_as=nan_as, on_status=on_status)
    level = check_level(level, stats, volume.source)
    offset = check_vertex_offset(vertex_offset)
    counts, table = marching_cubes_table(ambiguity)
    notice = f"compiling the Marching Cubes kernel for {arr.dtype} data (first run only)"
    with compile_notice(on_status, notice):
        from .kernels.cubes import count_cubes, fill_cubes

        per_slab_vertices, per_slab_triangles = count_cubes(arr, level, counts)
        # where each slab's output begins, so slabs fill in parallel
        vert_start = np.concatenate([[0], np.cumsum(per_slab_vertices)])
        tri_start = np.concatenate([[0], np.cumsum(per_slab_triangles)])
        verts = np.empty((vert_start[-1], 3), dtype=np.float64)
        edge_ids = np.empty(vert_start[-1], dtype=np.int64)
        tris = np.empty((tri_start[-1], 3), dtype=np.int64)
        fill_cubes(
            arr,
            level,
            offset,
            counts,
            table,
            EDGE_BASE,
            EDGE_AXIS,
            vert_start,
            tri_start,
            verts,
            edge_ids,
            tris,
        )
    return finish_mesh(volume, verts, tris, edge_ids, flip, method="cubes", level=level)
