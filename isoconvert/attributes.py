"""Per-vertex attributes sampled from a volume: normals and values.

Both come from trilinear interpolation at the vertices (the compiled
``sample_points`` kernel), a cheap second pass after extraction that reads the
volume slab by slab again, so it works on every volume the extraction does,
larger than memory included. At an isosurface vertex (which lies on a grid
edge) trilinear interpolation is linear interpolation along that edge: the
normals are the central-difference gradients at the edge's two samples mixed
by the vertex's place on the edge, as VTK's contour filters and scikit-image
compute them. At vertices that smoothing or decimation moved, it is the
gradient field of the trilinear interpolant.

Marching Cubes computes the same normals (the same bits, through the same
per-point code, src/sample.hpp) in its filling pass when asked
(``extract(..., normals=True)``, which ``convert`` and
:func:`isoconvert.marching_cubes` use); this second pass remains for the rest:
meshes after post-processing, tetrahedra, the trilinear rule block-wise, runs
on a cluster, and any mesh a caller brings.
"""

from __future__ import annotations

import numpy as np

from .errors import VolumeError
from .extract.cubes import SLACK, gradient_maps, triangle_normals_where_flat
from .extract.prepare import kernel_type
from .grid import grid_slab_zyx
from .memory import row_chunks
from .mesh import Mesh
from .threads import kernel_threads
from .volume import Volume

#: Grid layers read at a time when the volume is read from its file.
SLAB_LAYERS = 64

#: Layers read below and above each slab: one for a central difference, one
#: for a point the kernel places in the neighbouring cell by rounding.
HALO = 2


def check_3d(volume: Volume, what: str) -> None:
    """Refuse a volume that per-vertex ``what`` ("normals", "values") cannot come from."""
    if volume.ndim != 3 or any(n < 2 for n in volume.shape):
        raise VolumeError(
            f"{volume.source}: {what} need a 3D volume with at least 2 samples along every "
            f"axis, got shape {volume.shape}"
        )


def _sample(
    volume: Volume,
    vertices: np.ndarray,
    gradient: bool,
    nan_as: float | None,
    sign: float = 1.0,
) -> np.ndarray:
    """Trilinear values ``(V,)`` or unit world gradients times ``sign`` ``(V, 3)``
    (zero where the gradient vanishes), float32, of ``volume`` at world points
    ``vertices (V, 3)``; NaN outside the grid."""
    from . import _native

    out = np.empty((len(vertices), 3) if gradient else len(vertices), dtype=np.float32)
    depth = volume.shape[2]
    origin = np.ascontiguousarray(volume.origin, dtype=np.float64)
    maps = (origin, *gradient_maps(volume.affine))
    to_index = maps[2]  # inv(affine): a point's index z is (world - origin) @ to_index[2]
    threads = kernel_threads()

    def run(zyx: np.ndarray, k0: int, points: np.ndarray, into: np.ndarray) -> None:
        _native.sample_points(
            zyx,
            k0,
            depth,
            np.ascontiguousarray(points, dtype=np.float64),
            *maps,
            sign,
            gradient,
            gradient,
            nan_as is not None,
            float(nan_as or 0.0),
            SLACK,
            threads,
            into,
        )

    if volume.grid is None:
        # converted once (a byte swap or a non-contiguous array is a copy), not per block
        zyx = kernel_type(volume.data.T, volume.source)
        start = 0
        for block in row_chunks(vertices):
            run(zyx, 0, block, out[start : start + len(block)])
            start += len(block)
        return out

    # A file-backed volume: take vertices in order of the grid layer below
    # them and read only the slabs (with the layers their stencils reach) that
    # hold some.
    layer = np.empty(len(vertices), dtype=np.int64)
    start = 0
    for block in row_chunks(vertices):
        z = (block - origin) @ to_index[2]
        z = np.nan_to_num(z, nan=0.0, posinf=depth - 1, neginf=0.0)
        layer[start : start + len(block)] = np.clip(np.floor(z), 0, depth - 1)
        start += len(block)
    # vertices of extracted meshes come in layer order: then slabs are ranges
    in_order = bool(np.all(layer[1:] >= layer[:-1]))
    order = None if in_order else np.argsort(layer, kind="stable")
    cuts = np.arange(0, depth + SLAB_LAYERS, SLAB_LAYERS)
    bounds = np.searchsorted(layer if in_order else layer[order], cuts)
    for s, k in enumerate(range(0, depth, SLAB_LAYERS)):
        a, b = bounds[s], bounds[s + 1]
        these = slice(a, b) if in_order else order[a:b]
        if a == b:
            continue
        # a cell's corners reach one layer up; a gradient one more each way.
        # And one more layer each way again: the kernel finds each point's cell
        # from its world position with its own arithmetic, which may round a
        # point on a layer (index z = 64 exactly) to the other side of it
        # (63.99999999999999) than `layer` above did, when a direction matrix
        # mixes z with x and y. Without that layer the stencil of the cell
        # below reached past the slab: NaN, replaced by the triangles' normal
        # (issue 20); the kernel now raises instead.
        lo, hi = max(0, k - HALO), min(depth, k + SLAB_LAYERS + 1 + HALO)
        zyx = kernel_type(grid_slab_zyx(volume.samples, lo, hi), volume.source)
        if in_order:
            run(zyx, lo, vertices[these], out[these])
            continue
        result = np.empty((b - a, 3) if gradient else b - a, dtype=np.float32)
        run(zyx, lo, vertices[these], result)
        out[these] = result
    return out


def vertex_normals(
    mesh: Mesh, volume: Volume, *, flip: bool = False, nan_as: float | None = None
) -> np.ndarray:
    """Unit normals at the vertices of a surface extracted from ``volume``.

    The negated gradient of the volume in world coordinates, so that normals
    point from the positive side (values >= level) to the negative side, like
    the triangles (the other way with ``flip``). Where the gradient vanishes
    (a flat neighbourhood), the area-weighted mean of the normals of the
    vertex's triangles stands in.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)`` in world units, ``cells (C, 3)``.
    volume : Volume
        The 3D volume the mesh was extracted from (its placement included).
    flip : bool
        The mesh was extracted with ``flip``.
    nan_as : float or None
        The value NaN/Inf samples stood for in the extraction.

    Returns
    -------
    normals : (V, 3) float32
    """
    check_3d(volume, "normals")
    if not mesh.is_triangles:
        raise VolumeError("normals need a triangle mesh; contours (squares) have none")
    normals = _sample(volume, mesh.vertices, True, nan_as, sign=1.0 if flip else -1.0)
    triangle_normals_where_flat(normals, mesh)
    return normals


def vertex_values(mesh: Mesh, volume: Volume, *, nan_as: float | None = None) -> np.ndarray:
    """Values of ``volume`` at the vertices of ``mesh``, by trilinear interpolation
    in world coordinates.

    The volume may be another scan than the one the mesh came from (colour a
    bone surface by a PET scan, or by a distance map), on its own grid: each
    vertex is placed in it through its spacing, origin and direction. When both
    state an anatomical frame, give them the same one (:meth:`Volume.in_frame`).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)`` in world units.
    volume : Volume
        A 3D volume.
    nan_as : float or None
        Value its NaN/Inf samples stand for; None leaves them NaN.

    Returns
    -------
    values : (V,) float32
        NaN at vertices outside the volume's grid.
    """
    check_3d(volume, "values")
    return _sample(volume, mesh.vertices, False, nan_as)


__all__ = ["vertex_normals", "vertex_values"]
