"""Marching Tetrahedra: each cube split into six tetrahedra (Kuhn triangulation).

The kernel is C++ (src/tetra.cpp), in the manner of Flying Edges like Marching
Cubes: every edge of the decomposition joins two corners of one cube, so the
stretch of each row of cubes where the surface can be, found by the first pass
over the samples, bounds the work of the counting and filling passes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..volume import Volume
from .placement import Allocate, Block, kernel_outputs, mesh_info
from .prepare import prepare
from .tables import (
    CUBE_TETRAHEDRA,
    DEFAULT_AMBIGUITY,
    TETRA_DIRECTIONS,
    TETRA_EDGE_BASE,
    TETRA_EDGE_DIR,
    marching_tetrahedra_table,
)


def marching_tetrahedra(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract the isosurface of a 3D volume with Marching Tetrahedra.

    Tetrahedra have no ambiguous configurations, so ``ambiguity`` must be left
    at its default. Other parameters are as for
    :func:`~isoconvert.extract.cubes.marching_cubes`.

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` in world units, ``cells (C, 3) int64``
        (normals from the positive to the negative side), ``edge_ids (V,)
        int64``: vertices lie on cube edges, face diagonals and cube diagonals,
        with ids ``7 * (i + X * (j + Y * k)) + direction`` for directions x, y,
        z, xy, xz, yz, xyz (:data:`~isoconvert.extract.tables.TETRA_DIRECTIONS`)
        from grid vertex (i, j, k). Vertices come row of samples by row
        (``j + Y * k``), within a row by direction, then by increasing x;
        triangles cube row by cube row, by increasing x, then tetrahedron by
        tetrahedron: the order follows from the grid alone, whatever the
        number of threads.
    """
    if ambiguity != DEFAULT_AMBIGUITY:
        raise IsoconvertError("tetra has no ambiguous configurations; drop --ambiguity")
    prep = prepare(
        volume, 3, "tetra", level, nan_as=nan_as, vertex_offset=vertex_offset, on_status=on_status
    )
    block = TetraBlock.whole(volume, prep.offset, flip, prep.threads)
    verts, edge_ids, tris = block.extract(prep.array, prep.scan)
    return Mesh(verts, tris, edge_ids, mesh_info(volume, "tetra", prep.level, flip, prep.offset))


@dataclass(frozen=True)
class TetraBlock(Block):
    """Marching Tetrahedra on one block of a grid, with global positions and
    edge ids ``7 * (i + X * (j + Y * k)) + direction`` in the whole grid
    (:class:`~isoconvert.extract.placement.Block` says where the block goes)."""

    def extract(
        self,
        samples: np.ndarray,
        scan: object,
        index_origin: tuple[int, int, int] = (0, 0, 0),
        allocate: Allocate = kernel_outputs,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices ``(V, 3) float64``, edge ids ``(V,) int64`` and triangles
        ``(C, 3) int64`` (indices into this block's vertices) of one block; see
        :meth:`CubesBlock.extract <isoconvert.extract.cubes.CubesBlock.extract>`."""
        from .. import _native

        counts, triangles = marching_tetrahedra_table()
        tables = (
            TETRA_DIRECTIONS,
            CUBE_TETRAHEDRA,
            counts,
            triangles,
            TETRA_EDGE_BASE,
            TETRA_EDGE_DIR,
        )
        n = _native.count_tetra(samples, scan, *tables, self.threads)
        verts, edge_ids, tris = allocate(n.vertices, n.triangles, 3)
        where = self.placement(index_origin)
        _native.fill_tetra(samples, scan, n, *tables, *where, self.threads, verts, edge_ids, tris)
        return verts, edge_ids, tris
