"""Marching Cubes (Wenger, *Isosurfaces*, section 2.3), in the manner of Flying Edges.

The kernel is C++ (src/cubes.cpp): a first pass reads every sample once (see
:func:`~isoconvert.extract.prepare.prepare`), a counting pass and a filling
pass then visit only the stretch of each row of cubes where the surface can
be, in parallel, writing straight into the output arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

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
    normals: bool = False,
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
    normals : bool
        Also give ``mesh.normals`` (when there are triangles): the normals of
        :func:`isoconvert.vertex_normals`, computed in the filling pass from
        the gradients at the two ends of each bipolar edge instead of by a
        second pass over the volume (see :func:`fill_pass_normals`); not
        when ``nan_as`` has no exact twin in the sample type
        (:func:`nan_as_exact`), which leaves ``mesh.normals`` None.

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
    if not normals or not nan_as_exact(prep.array.dtype, nan_as):
        verts, edge_ids, tris = block.extract(prep.array, prep.scan)
        return Mesh(
            verts,
            tris,
            edge_ids,
            mesh_info(volume, "cubes", prep.level, flip, prep.offset, ambiguity),
        )
    sign = 1.0 if flip else -1.0
    verts, edge_ids, tris, gradients = block.extract_with_normals(prep.array, prep.scan, sign)
    mesh = Mesh(
        verts, tris, edge_ids, mesh_info(volume, "cubes", prep.level, flip, prep.offset, ambiguity)
    )
    if len(tris):  # as vertex_normals is asked: only for a mesh with triangles
        mesh.normals = fill_pass_normals(mesh, gradients, prep.array, block, sign, prep.threads)
    return mesh


class FilledNormals(NamedTuple):
    """The normals the filling pass wrote (:meth:`CubesBlock.extract_with_normals`).

    Attributes
    ----------
    normals : (V, 3) float32
        Unit world normals of the vertices on grid edges: 0 where the gradient
        vanishes, NaN where it is not finite; interior vertices unset.
    flat : int
        How many edge vertices' normals are 0 or NaN.
    """

    normals: np.ndarray
    flat: int


def nan_as_exact(dtype: np.dtype, nan_as: float | None) -> bool:
    """Whether NaN/Inf samples replaced by ``nan_as`` in ``dtype`` (as
    :func:`~isoconvert.extract.prepare.prepare` does) read as ``nan_as`` itself.

    The filling pass reads the replaced samples; ``vertex_normals`` reads the
    volume and puts the float64 ``nan_as`` in their place. They agree unless
    ``nan_as`` has no exact twin in the sample type (0.1 in float32), and only
    then do normals near NaN samples differ (by some 1e-6 degrees): those
    runs keep the second pass, so that ``--normals`` stays what it was.
    """
    if nan_as is None or not np.issubdtype(dtype, np.floating):
        return True
    return float(dtype.type(nan_as)) == nan_as


#: How far outside a grid (in samples) a point may be and still be sampled on
#: its face (rounding of world coordinates); beyond it, the value is NaN. The
#: filling pass's normals and :func:`isoconvert.vertex_normals` share it.
SLACK = 1e-6


def gradient_maps(affine: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(to_index, to_world)`` as ``_native.sample_points`` and the filling
    pass take them, for a grid whose index-to-world matrix is ``affine``.

    Row vectors: ``index = (world - origin) @ to_index`` with ``to_index =
    inv(affine).T``, and gradients, being covectors, go to world space as
    ``d/d(world) = d/d(index) @ inv(affine)``. One function for both callers,
    so that both hand their kernel the same bits.
    """
    inverse = np.linalg.inv(np.asarray(affine, dtype=np.float64))
    return np.ascontiguousarray(inverse.T), np.ascontiguousarray(inverse)


def fill_pass_normals(
    mesh: Mesh,
    gradients: FilledNormals,
    samples: np.ndarray | None,
    block: CubesBlock,
    sign: float,
    threads: int,
) -> np.ndarray:
    """Finish the normals the filling pass gave, as :func:`isoconvert.vertex_normals` does.

    The filling pass (src/cubes.cpp, ``EdgeNormals``) writes the normal of
    every vertex on a grid edge: the central-difference gradients at the
    edge's two samples mixed by the vertex's place on the edge, which is what
    ``vertex_normals``' trilinear sampling of the gradient field gives there.
    Left to do here: the vertices inside cubes (``ambiguity="trilinear"``),
    which lie on no grid edge and are sampled as ``vertex_normals`` samples
    them, and the vertices whose gradient vanishes or is not finite, which
    take the area-weighted normal of their triangles.

    Parameters
    ----------
    mesh : Mesh
        The extracted mesh (vertices, cells and edge ids).
    gradients : FilledNormals
        The filling pass's normals; finished in place.
    samples : (Z, Y, X) array or None
        The samples the mesh was extracted from (NaN/Inf already replaced);
        None when there are no vertices inside cubes (not the trilinear rule).
    block : CubesBlock
        The whole grid's block.
    sign : float
        -1.0 (from values >= level to values < level), or 1.0 with ``flip``.
    threads : int

    Returns
    -------
    normals : (V, 3) float32
        ``gradients.normals``.
    """
    from .. import _native

    normals, flat = gradients
    # only the trilinear rule places vertices inside cubes; the scans below run
    # only when there is something to find (they cost a fifth of the normals)
    inner = (
        np.flatnonzero(mesh.edge_ids >= inner_base(block.grid_shape))
        if block.ambiguity == TRILINEAR
        else ()
    )
    if len(inner):
        # not on a grid edge: the trilinear gradient field at the point, sampled
        # by the kernel vertex_normals uses, with the same maps
        sampled = np.empty((len(inner), 3), dtype=np.float32)
        _native.sample_points(
            samples,
            0,
            samples.shape[0],
            np.ascontiguousarray(mesh.vertices[inner], dtype=np.float64),
            np.ascontiguousarray(block.origin, dtype=np.float64),
            *gradient_maps(block.affine),
            sign,
            True,
            True,
            False,
            0.0,
            SLACK,
            threads,
            sampled,
        )
        normals[inner] = sampled
        flat += int(np.count_nonzero(~sampled.any(axis=1) | np.isnan(sampled[:, 0])))
    if flat:
        triangle_normals_where_flat(normals, mesh)
    return normals


def triangle_normals_where_flat(normals: np.ndarray, mesh: Mesh) -> None:
    """Where a gradient normal is 0 (a flat neighbourhood) or NaN, put the
    area-weighted normal of the vertex's triangles instead, in place: the one
    fallback of both the filling pass and :func:`isoconvert.vertex_normals`.

    Parameters
    ----------
    normals : (V, 3) float32
    mesh : Mesh
        Its triangles.
    """
    flat = ~normals.any(axis=1)
    flat |= np.isnan(normals[:, 0])
    if flat.any():
        normals[flat] = mesh.vertex_normals()[flat]


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
        verts, edge_ids, tris, _ = self._fill(samples, scan, index_origin, allocate)
        return verts, edge_ids, tris

    def extract_with_normals(
        self,
        samples: np.ndarray,
        scan: object,
        sign: float,
        allocate: Allocate = kernel_outputs,
        halo: np.ndarray | None = None,
        halo_k0: int = 0,
        k0: int = 0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, FilledNormals]:
        """:meth:`extract` on the whole grid or a z-slab of it, and the normals
        of its edge vertices.

        The normals come from the filling pass (see :func:`fill_pass_normals`).
        Their stencils reach one sample past an edge's ends, beyond a slab's
        one-sample overlap, and a vertex that rounding puts in the next cell
        one sample more: a slab comes with up to 2 more layers each way.

        Parameters
        ----------
        samples, scan
            As for :meth:`extract`: the whole grid, or a z-slab given as a view
            into ``halo``.
        sign : float
            -1.0 (normals from values >= level to values < level) or 1.0 (``flip``).
        allocate : callable
            As for :meth:`extract`.
        halo : (L, Y, X) array or None
            For a slab: its samples with up to 2 more layers each way (within
            the grid), NaN/Inf replaced as in ``samples``; None for the grid.
        halo_k0 : int
            Grid layer of ``halo[0]``.
        k0 : int
            Grid layer of ``samples[0]``.

        Returns
        -------
        vertices, edge_ids, triangles
            As :meth:`extract`.
        normals : FilledNormals
            Unit world normals of the vertices on grid edges, and how many of
            them failed.
        """
        if halo is None:
            return self._fill(samples, scan, (0, 0, 0), allocate, sign, samples, 0)
        return self._fill(samples, scan, (0, 0, k0), allocate, sign, halo, halo_k0)

    def _fill(
        self,
        samples: np.ndarray,
        scan: object,
        index_origin: tuple[int, int, int],
        allocate: Allocate,
        sign: float | None = None,
        halo: np.ndarray | None = None,
        halo_k0: int = 0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, FilledNormals | None]:
        """Count, allocate and fill; normals too when ``sign`` is given (their
        stencils read ``halo``, see :meth:`extract_with_normals`)."""
        from .. import _native

        trilinear = self.ambiguity == TRILINEAR
        # the fixed rule's table decides every cube the trilinear tests leave alone
        counts, table = marching_cubes_table(DEFAULT_AMBIGUITY if trilinear else self.ambiguity)
        special = native_trilinear_table() if trilinear else None
        n = _native.count_cubes(samples, scan, counts, table, special, self.threads)
        verts, edge_ids, tris = allocate(n.vertices, n.triangles, 3)
        if sign is None:
            normals, maps = _NO_NORMALS, (_NO_MATRIX, _NO_MATRIX)
        else:
            normals = np.empty((n.vertices, 3), dtype=np.float32)
            maps = gradient_maps(self.affine)
        flat = _native.fill_cubes(
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
            *maps,
            sign or 0.0,
            SLACK,
            normals,
            samples if halo is None else halo,
            halo_k0,
            self.grid_shape[2],
        )
        if sign is None:
            return verts, edge_ids, tris, None
        return verts, edge_ids, tris, FilledNormals(normals, flat)


# fill_cubes' arguments for "no normals"
_NO_NORMALS = np.empty((0, 3), dtype=np.float32)
_NO_MATRIX = np.empty(0, dtype=np.float64)
