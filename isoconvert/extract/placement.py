"""From index space to world space, keeping the orientation convention."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..volume import Volume, grid_from_volume


def reversed_orientation(volume: Volume, flip: bool) -> bool:
    """Whether triangles must be written in reverse for normals to keep pointing
    from the positive to the negative side (the other way with ``flip``).

    A left-handed index-to-world map (negative determinant, as some NRRD
    ``space directions`` are) mirrors the surface.
    """
    return bool(np.linalg.det(volume.affine) < 0) != flip


def mesh_info(
    volume: Volume,
    method: str,
    level: float,
    flip: bool,
    vertex_offset: float | None = None,
    ambiguity: str | None = None,
) -> dict:
    """The ``info`` of an extracted mesh: how it was made (``ambiguity``: the
    rule for ambiguous faces, for methods that have them), and from which grid."""
    info = {
        "method": method,
        "level": level,
        "source": volume.source,
        "flip": flip,
        # the grid, so checks can tell the grid's boundary from holes
        "grid": grid_from_volume(volume),
    }
    if ambiguity is not None:
        info["ambiguity"] = ambiguity
    if vertex_offset is not None:
        info["vertex_offset"] = vertex_offset
    # where the coordinates are, for file headers (readers that know say so)
    if volume.frame is not None:
        info["frame"] = volume.frame
    if volume.unit is not None:
        info["unit"] = volume.unit
    return info


def kernel_placement(
    affine: np.ndarray,
    origin: np.ndarray,
    grid_xy: tuple[int, int],
    offset: float,
    reverse: bool,
    index_origin: tuple[int, int, int] = (0, 0, 0),
) -> tuple:
    """The placement arguments every fill kernel of ``isoconvert._native`` takes.

    Parameters
    ----------
    affine : (3, 3) float
        Index offsets to world offsets.
    origin : (3,) float
        World position of grid index (0, 0, 0).
    grid_xy : (X, Y) of the whole grid, which numbers the edge ids.
    offset : float
        Vertex offset.
    reverse : bool
        Write cells in reverse orientation.
    index_origin : (i0, j0, k0)
        Grid index of the block's first sample.

    Returns
    -------
    tuple
        ``(affine, origin, index_origin, id_dims, offset, reverse)`` as the kernels want them.
    """
    return (
        np.ascontiguousarray(affine, dtype=np.float64),
        np.ascontiguousarray(origin, dtype=np.float64),
        np.asarray(index_origin, dtype=np.int64),
        np.asarray(grid_xy, dtype=np.int64),
        float(offset),
        bool(reverse),
    )


#: ``allocate(n_vertices, n_cells, arity)`` gives a fill kernel's output arrays
#: (:func:`kernel_outputs`, or views into a growing mesh, see blocks.py).
Allocate = Callable[[int, int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Block:
    """Where one block of a grid goes: what every method's block extractor
    (``CubesBlock``, ``TetraBlock``, ``SquaresBlock``) shares.

    A block is a brick of samples (z, y and x ranges) with a one-sample overlap
    on the high side of each cut; its vertices come out in world units and with
    the edge ids of the whole grid, so blocks merge by id with no welding.
    Called on the whole grid (``index_origin`` 0) it gives the whole mesh.

    Attributes
    ----------
    affine : (3, 3) float64
        Index offsets to world offsets (:attr:`Volume.affine`).
    origin : (3,) float64
        World position of the grid's sample (0, 0, 0).
    grid_shape : (3,) int
        (X, Y, Z) of the whole grid, for edge ids.
    offset : float
        Vertex offset (see :func:`~isoconvert.extract.prepare.resolve_vertex_offset`).
    reverse : bool
        Write cells in reverse orientation.
    threads : int
    """

    affine: np.ndarray
    origin: np.ndarray
    grid_shape: tuple[int, int, int]
    offset: float = 0.0
    reverse: bool = False
    threads: int = 1

    @classmethod
    def whole(cls, volume: Volume, offset: float, flip: bool, threads: int, **options):
        """The block that is the whole of a 3D ``volume`` (``options``: the
        method's own fields, e.g. ``ambiguity``)."""
        return cls(
            affine=volume.affine,
            origin=volume.origin,
            grid_shape=volume.shape,
            offset=offset,
            reverse=reversed_orientation(volume, flip),
            threads=threads,
            **options,
        )

    def placement(self, index_origin: tuple[int, int, int]) -> tuple:
        """The fill kernels' placement arguments for a block at ``index_origin``."""
        return kernel_placement(
            self.affine, self.origin, self.grid_shape[:2], self.offset, self.reverse, index_origin
        )


def kernel_outputs(
    n_vertices: int, n_cells: int, arity: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty ``vertices (V, 3) float64``, ``edge_ids (V,) int64`` and ``cells
    (C, arity) int64`` for a fill kernel (numpy backs large ones with huge pages,
    which makes their first write cheaper)."""
    return (
        np.empty((n_vertices, 3), dtype=np.float64),
        np.empty(n_vertices, dtype=np.int64),
        np.empty((n_cells, arity), dtype=np.int64),
    )
