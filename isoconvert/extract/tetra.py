"""Marching Tetrahedra: each cube split into six tetrahedra (Kuhn triangulation)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..volume import Volume
from .jit import compile_notice
from .placement import finish_mesh
from .prepare import check_level, check_vertex_offset, kernel_array
from .tables import (
    CUBE_TETRAHEDRA,
    DEFAULT_AMBIGUITY,
    TETRA_DIRECTIONS,
    TETRA_EDGE_BASE,
    TETRA_EDGE_DIR,
    marching_tetrahedra_table,
)

_IN_LAYER = np.flatnonzero(TETRA_DIRECTIONS[:, 2] == 0).astype(np.int64)
_CROSSING = np.flatnonzero(TETRA_DIRECTIONS[:, 2] == 1).astype(np.int64)


def marching_tetrahedra(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float = 0.0,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract the isosurface of a 3D volume with Marching Tetrahedra.

    Tetrahedra have no ambiguous configurations, so ``ambiguity`` must be left
    at its default. Vertices lie on cube edges, face diagonals and cube
    diagonals; ``edge_ids`` are ``7 * (i + X * (j + Y * k)) + direction`` with
    directions x, y, z, xy, xz, yz, xyz. Other parameters and the result are as
    for :func:`~isoconvert.extract.cubes.marching_cubes`.
    """
    if ambiguity != DEFAULT_AMBIGUITY:
        raise IsoconvertError("tetra has no ambiguous configurations; drop --ambiguity")
    arr, stats = kernel_array(volume, 3, "tetra", nan_as=nan_as, on_status=on_status)
    level = check_level(level, stats, volume.source)
    offset = check_vertex_offset(vertex_offset)
    counts, table = marching_tetrahedra_table()
    notice = f"compiling the Marching Tetrahedra kernel for {arr.dtype} data (first run only)"
    with compile_notice(on_status, notice):
        from .kernels.tetra import count_tetra, fill_tetra

        n_vert, n_tri = count_tetra(arr, level, TETRA_DIRECTIONS, CUBE_TETRAHEDRA, counts)
        verts = np.empty((n_vert, 3), dtype=np.float64)
        edge_ids = np.empty(n_vert, dtype=np.int64)
        tris = np.empty((n_tri, 3), dtype=np.int64)
        fill_tetra(
            arr,
            level,
            offset,
            TETRA_DIRECTIONS,
            _IN_LAYER,
            _CROSSING,
            CUBE_TETRAHEDRA,
            counts,
            table,
            TETRA_EDGE_BASE,
            TETRA_EDGE_DIR,
            verts,
            edge_ids,
            tris,
        )
    return finish_mesh(volume, verts, tris, edge_ids, flip, method="tetra", level=level)
