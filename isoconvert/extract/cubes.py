"""Marching Cubes (Wenger, *Isosurfaces*, section 2.3), in the manner of Flying Edges.

The kernel is C++ (src/cubes.cpp): a first pass reads every sample once (see
:func:`~isoconvert.extract.prepare.prepare`), a counting pass and a filling
pass then visit only the stretch of each row of cubes where the surface can
be, in parallel, writing straight into the output arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..mesh import Mesh
from ..methods import TRILINEAR
from ..volume import Volume
from .placement import Allocate, Block, kernel_outputs, mesh_info
from .prepare import prepare
from .tables import DEFAULT_AMBIGUITY, marching_cubes_table
from .trilinear import inner_base, native_trilinear_table


def marching_cubes(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float | None = None,
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
        or "separate-negative" (see :mod:`isoconvert.extract.tables`), or
        "trilinear": in each cube the surface is homeomorphic to the level set
        of the trilinear interpolant (see :mod:`isoconvert.extract.trilinear`;
        it may add vertices inside cubes).
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    vertex_offset : float or None
        Keep every vertex at least this fraction of its edge's length away from
        the edge's ends (0 <= f < 0.5); None chooses (see
        :func:`~isoconvert.extract.prepare.resolve_vertex_offset`).
    on_status : callable or None
        Receives one-line notices.

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` in world units, ``cells (C, 3) int64``,
        ``edge_ids (V,) int64`` (``3 * (i + X * (j + Y * k)) + axis``; a
        vertex inside a cube: :func:`~isoconvert.extract.trilinear.inner_base`). Normals
        point from the positive to the negative side, i.e. out of bright
        objects. Vertices come row of samples by row (``j + Y * k``), within a
        row x-edges, then y-edges, then z-edges, each by increasing x; triangles
        cube row by cube row, by increasing x: the order follows from the grid
        alone, whatever the number of threads.
    """
    prep = prepare(
        volume, 3, "cubes", level, nan_as=nan_as, vertex_offset=vertex_offset, on_status=on_status
    )
    block = CubesBlock.whole(volume, prep.offset, flip, prep.threads, ambiguity=ambiguity)
    verts, edge_ids, tris = block.extract(prep.array, prep.scan)
    return Mesh(
        verts, tris, edge_ids, mesh_info(volume, "cubes", prep.level, flip, prep.offset, ambiguity)
    )


@dataclass(frozen=True)
class CubesBlock(Block):
    """Marching Cubes on one block of a grid, with global positions and edge ids
    (:class:`~isoconvert.extract.placement.Block` says where the block goes).

    Attributes
    ----------
    ambiguity : str
        The rule for ambiguous faces.
    """

    ambiguity: str = DEFAULT_AMBIGUITY

    def extract(
        self,
        samples: np.ndarray,
        scan: object,
        index_origin: tuple[int, int, int] = (0, 0, 0),
        allocate: Allocate = kernel_outputs,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices, edge ids and triangles of one block.

        Parameters
        ----------
        samples : (Z, Y, X) array
            The block's samples, as :func:`~isoconvert.extract.prepare.prepare` makes them.
        scan : isoconvert._native.RowScan
            ``_native.scan_rows`` of ``samples`` at the level.
        index_origin : (3,) int
            Grid index (i, j, k) of ``samples[0, 0, 0]``.

        Returns
        -------
        vertices : (V, 3) float64
        edge_ids : (V,) int64
            ``3 * (i + X * (j + Y * k)) + axis`` in the whole grid.
        triangles : (C, 3) int64
            Indices into this block's vertices.
        """
        from .. import _native

        trilinear = self.ambiguity == TRILINEAR
        # the fixed rule's table decides every cube the trilinear tests leave alone
        counts, table = marching_cubes_table(DEFAULT_AMBIGUITY if trilinear else self.ambiguity)
        special = native_trilinear_table() if trilinear else None
        n = _native.count_cubes(samples, scan, counts, table, special, self.threads)
        verts, edge_ids, tris = allocate(n.vertices, n.triangles, 3)
        _native.fill_cubes(
            samples,
            scan,
            n,
            counts,
            table,
            special,
            inner_base(self.grid_shape),
            *self.placement(index_origin),
            self.threads,
            verts,
            edge_ids,
            tris,
        )
        return verts, edge_ids, tris
