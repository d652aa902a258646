"""Marching Squares (Wenger, *Isosurfaces*, section 2.2): 2D isocontours.

On a 2D volume it contours the image; on a 3D volume it contours every slice
across one axis (the slice-by-slice approach of book section 1.4), giving a
stack of 3D polylines.

The kernel is C++ (src/squares.cpp), in the manner of Flying Edges like Marching
Cubes: the squares of a slice across any axis lie on the rows of samples along x
of one row of cubes, so all slices are contoured in one parallel sweep over the
rows, without a transposed copy of the volume, and only where the first pass
over the samples found sign changes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..methods import SQUARE_AMBIGUITY_RULES
from ..volume import Volume
from .placement import Allocate, Block, kernel_outputs, mesh_info, reversed_orientation
from .prepare import prepare
from .tables import DEFAULT_AMBIGUITY, marching_squares_table

_AXES = {"x": 0, "y": 1, "z": 2}


def marching_squares(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float | None = None,
    axis: str = "z",
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract isocontours: of a 2D image, or of every slice of a 3D volume.

    Parameters
    ----------
    volume : Volume
        2D, or 3D (then every slice across ``axis`` is contoured).
    level : float
        The isovalue; grid vertices with value >= level are positive.
    flip : bool
        Reverse segment directions (positive side on the right).
    ambiguity : str
        "separate-positive" (default, as scikit-image's ``find_contours``),
        "separate-negative", or "asymptotic" (the bilinear saddle decides).
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    vertex_offset : float or None
        Keep every vertex at least this fraction of its edge's length away from
        the edge's ends (0 <= f < 0.5); None chooses (see
        :func:`~isoconvert.extract.prepare.resolve_vertex_offset`). With f > 0, a
        level equal to grid values gives no zero-length edges.
    axis : str
        For 3D volumes: "x", "y" or "z", the axis the slices are across.
    on_status : callable or None
        Receives one-line notices.

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` in world units (z = 0 for 2D input),
        ``cells (C, 2) int64`` segments with the positive side on their left
        when seen from the positive end of the slice axis, ``edge_ids (V,)
        int64``: ``3 * (i + X * (j + Y * k)) + axis`` of the grid edge from
        vertex (i, j, k) along axis x (0), y (1) or z (2) on volumes,
        ``2 * (i + X * j) + axis`` on images. Each slice is contoured in the
        plane of the two axes that follow ``axis`` cyclically ((x, y) across z,
        (z, x) across y, (y, z) across x). Vertices come row of samples by row
        (``j + Y * k``), within a row by edge axis, then by increasing x;
        segments by the lowest row of their square in the same order, by
        increasing x: the order follows from the grid alone, whatever the
        number of threads.
    """
    if ambiguity not in SQUARE_AMBIGUITY_RULES:
        raise IsoconvertError(
            f"unknown ambiguity rule {ambiguity!r} for squares; "
            f"choose one of: {', '.join(SQUARE_AMBIGUITY_RULES)}"
        )
    if axis not in _AXES:
        raise IsoconvertError(f"--axis must be x, y or z, got {axis!r}")
    planar = volume.ndim == 2
    prep = prepare(
        volume,
        volume.ndim,
        "squares",
        level,
        nan_as=nan_as,
        vertex_offset=vertex_offset,
        on_status=on_status,
    )
    affine, origin = _placement3(volume)
    block = SquaresBlock(
        affine=affine,
        origin=origin,
        grid_shape=volume.shape if not planar else (*volume.shape, 1),
        axis="z" if planar else axis,
        planar=planar,
        offset=prep.offset,
        ambiguity=ambiguity,
        reverse=reversed_orientation(volume, flip),
        threads=prep.threads,
    )
    verts, edge_ids, segs = block.extract(prep.volume3, prep.scan)
    if len(segs) == 0:
        raise IsoconvertError(f"{volume.source}: no slice crosses level {prep.level:g}")
    return Mesh(
        verts,
        segs,
        edge_ids,
        mesh_info(volume, "squares", prep.level, flip, prep.offset, ambiguity),
    )


@dataclass(frozen=True)
class SquaresBlock(Block):
    """Marching Squares on every slice of one block of a grid
    (:class:`~isoconvert.extract.placement.Block` says where the block goes;
    ``affine`` is ``(3, 3)`` and ``origin`` ``(3,)`` also for images, whose
    plane is z = 0).

    Attributes
    ----------
    axis : str
        The axis the slices are across.
    planar : bool
        A 2D image, given as one slice; its ids are then ``2 * (i + X * j) + axis``.
    ambiguity : str
        One of :data:`SQUARE_AMBIGUITY_RULES`.
    """

    axis: str = "z"
    planar: bool = False
    ambiguity: str = DEFAULT_AMBIGUITY

    def extract(
        self,
        samples: np.ndarray,
        scan: object,
        index_origin: tuple[int, int, int] = (0, 0, 0),
        allocate: Allocate = kernel_outputs,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vertices ``(V, 3) float64``, edge ids ``(V,) int64`` and segments
        ``(C, 2) int64`` (indices into this block's vertices) of one block of
        ``(Z, Y, X)`` samples; see :meth:`CubesBlock.extract
        <isoconvert.extract.cubes.CubesBlock.extract>`."""
        from .. import _native

        a = _AXES[self.axis]
        counts, segments = _square_tables()
        n = _native.count_squares(samples, scan, a, counts, segments, self.threads)
        verts, edge_ids, segs = allocate(n.vertices, n.segments, 2)
        where = self.placement(index_origin)
        rule = SQUARE_AMBIGUITY_RULES.index(self.ambiguity)  # as SquareRule in src/squares.hpp
        _native.fill_squares(
            samples,
            scan,
            n,
            a,
            counts,
            segments,
            rule,
            self.planar,
            *where,
            self.threads,
            verts,
            edge_ids,
            segs,
        )
        return verts, edge_ids, segs


def _square_tables() -> tuple[np.ndarray, np.ndarray]:
    """The table of both fixed rules: counts ``(16,)``, segments ``(2, 16, 2, 2)``
    (rule 0 separate-positive, 1 separate-negative; the counts agree)."""
    counts, positive = marching_squares_table("separate-positive")
    negative = marching_squares_table("separate-negative")[1]
    return counts, np.ascontiguousarray(np.stack([positive, negative]))


def _placement3(volume: Volume) -> tuple[np.ndarray, np.ndarray]:
    """The index-to-world map as a ``(3, 3)`` matrix and ``(3,)`` origin; a 2D
    image's plane is z = 0."""
    affine = np.zeros((3, 3), dtype=np.float64)
    origin = np.zeros(3, dtype=np.float64)
    nd = volume.ndim
    affine[:nd, :nd] = volume.affine
    origin[:nd] = volume.origin
    return affine, origin
