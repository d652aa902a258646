"""Closing a surface where its object is cut by the grid's boundary (``--close``).

A Marching Cubes surface is open where the object touches a face of the grid:
an organ cut by the scan's field of view. Padding the volume with values below
the level would close it, with a copy of the volume and with the cap one cell
outside the grid. Instead, the cap is built on the grid's faces themselves:
on each face, the region where samples are positive (>= level) is bounded by
the very segments along which the surface meets that face (Marching Squares on
the face image, with the cubes' rule for ambiguous faces: under ``trilinear``
the asymptotic decider of each ambiguous cell, the test the cubes made). Each face cell's
positive part is a convex polygon (a triangle, quadrilateral, pentagon or the
hexagon of an ambiguous face whose positive corners connect), whose corners are
positive samples of the face and vertices of the surface on the cell's edges.
Triangulating those polygons gives a cap that meets the surface at its own
vertices (found by grid edge id, no welding), lies exactly in the faces, and
shares its vertices at positive samples between faces that meet at a grid edge:
the closed surface bounds exactly the part of the object inside the grid.

The tables are derived here; the per-cell work (cases, the decider, finding
the surface's vertices on the faces' edges, numbering the cap's samples) is
compiled (src/cap.cpp): ``cap_count`` counts, then ``cap_fill`` writes the
closed mesh into arrays allocated here at their final size, the surface copied
in once and the cap appended.
"""

from __future__ import annotations

import functools

import numpy as np

from ..errors import IsoconvertError
from ..extract.placement import reversed_orientation
from ..extract.tables import DEFAULT_AMBIGUITY
from ..mesh import Mesh
from ..methods import TRILINEAR
from ..threads import kernel_threads
from ..volume import Volume, slabs

# A face cell's corners 0-3 run cyclically in its (p, q) plane, (0, 0), (1, 0),
# (1, 1), (0, 1); edge c runs from corner c to corner c + 1 (mod 4), so edges 0
# and 2 lie along p, 1 and 3 along q (src/cap.cpp builds the cells from them).


def _cell_triangles(case: int, rule: str) -> list[tuple[int, int, int]]:
    """Triangles of the positive part of a face cell, as slots: 0-3 are the
    corners, 4-7 the vertices on edges 0-3; counter-clockwise in (p, q).

    Parameters
    ----------
    case : int
        Bit c set when corner c is positive.
    rule : str
        The cubes' ambiguity rule: "separate-positive" cuts the two positive
        corners of an ambiguous cell apart, "separate-negative" joins them.
    """
    positive = [bool(case >> c & 1) for c in range(4)]
    bipolar = [positive[c] != positive[(c + 1) % 4] for c in range(4)]
    if sum(bipolar) == 4 and rule == "separate-positive":
        # a triangle at each positive corner c: edge c - 1, corner c, edge c
        polygons = [[4 + (c - 1) % 4, c, 4 + c] for c in range(4) if positive[c]]
    else:
        # walk the cell's border, keeping the positive corners and the crossings
        polygon = []
        for c in range(4):
            if positive[c]:
                polygon.append(c)
            if bipolar[c]:
                polygon.append(4 + c)
        polygons = [polygon] if any(positive) else []
    # every polygon is convex (the square minus corner triangles): a fan will do
    return [(p[0], p[i], p[i + 1]) for p in polygons for i in range(1, len(p) - 1)]


def _face_images(volume: Volume):
    """Yield ``(axis, side, image)`` for the six faces of a 3D grid: ``image``
    is ``(n_p, n_q)``, p and q the other two axes in increasing order."""
    shape = volume.shape
    if volume.grid is None:
        data = volume.data
        for axis in range(3):
            for side in (0, shape[axis] - 1):
                index = [slice(None)] * 3
                index[axis] = side
                yield axis, side, data[tuple(index)]  # a view
        return
    # a volume read from its file: one pass over it for the x and y faces
    faces = {
        (0, 0): np.empty((shape[1], shape[2]), volume.dtype),
        (0, 1): np.empty((shape[1], shape[2]), volume.dtype),
        (1, 0): np.empty((shape[0], shape[2]), volume.dtype),
        (1, 1): np.empty((shape[0], shape[2]), volume.dtype),
    }
    z_faces = {}
    k = 0
    for slab in slabs(volume.samples):
        n = slab.shape[2]
        faces[0, 0][:, k : k + n] = slab[0]
        faces[0, 1][:, k : k + n] = slab[-1]
        faces[1, 0][:, k : k + n] = slab[:, 0]
        faces[1, 1][:, k : k + n] = slab[:, -1]
        if k == 0:
            z_faces[0] = np.array(slab[:, :, 0])
        if k + n == shape[2]:
            z_faces[1] = np.array(slab[:, :, -1])
        k += n
    for axis in (0, 1):
        yield axis, 0, faces[axis, 0]
        yield axis, shape[axis] - 1, faces[axis, 1]
    yield 2, 0, z_faces[0]
    yield 2, shape[2] - 1, z_faces[1]


def close_at_grid(
    mesh: Mesh,
    volume: Volume,
    level: float,
    *,
    ambiguity: str = DEFAULT_AMBIGUITY,
    flip: bool = False,
    nan_as: float | None = None,
) -> Mesh:
    """Cap a Marching Cubes surface on the faces of its grid.

    Parameters
    ----------
    mesh : Mesh
        The surface of ``volume`` at ``level`` by cubes, with its ``edge_ids``
        (as :func:`isoconvert.extract` returns it, also block-wise).
    volume : Volume
        The 3D volume it was extracted from.
    level : float
    ambiguity : str
        The rule the surface was extracted with.
    flip : bool
        The surface was extracted with ``flip`` (the cap is reversed as well).
    nan_as : float or None
        The value NaN/Inf samples stood for.

    Returns
    -------
    Mesh
        ``vertices (V + S, 3)``: the surface's, then one at each positive
        sample on the grid's boundary that the cap uses; ``cells (C + T, 3)``:
        the surface's, then the cap's; ``edge_ids (V + S,)``: the surface's,
        then ``-1 - n`` for the sample of linear index ``n`` (x fastest), so
        no id of the two kinds collides; ``info["closed"]`` counts the cap's
        triangles.

    Raises
    ------
    IsoconvertError
        The mesh has no edge ids or is not the cubes surface of this volume.
    """
    if mesh.edge_ids is None or not mesh.is_triangles:
        raise IsoconvertError(
            "--close needs the surface as extracted (with its grid edge ids), by --method cubes"
        )
    from .. import _native

    shape = np.asarray(volume.shape, dtype=np.int64)
    outward_flip = reversed_orientation(volume, flip)
    decided = ambiguity == TRILINEAR  # each ambiguous cell by its own decider
    tables, joined = _tables(DEFAULT_AMBIGUITY if decided else ambiguity)
    # the six face images, x0, x1, y0, y1, z0, z1, one after the other in float64
    values = np.empty(sum(_face_sizes(volume.shape)), dtype=np.float64)
    reverse = np.empty(6, dtype=np.int64)
    start = 0
    for f, (axis, side, image) in enumerate(_face_images(volume)):
        p_axis, q_axis = [a for a in range(3) if a != axis]
        n = image.shape[0] * image.shape[1]
        values[start : start + n].reshape(image.shape)[...] = image
        start += n
        # the cap's normals point out of the grid: -axis on side 0, +axis on the far side
        p_cross_q = 1 if (p_axis, q_axis) in ((1, 2), (0, 1)) else -1
        reverse[f] = (p_cross_q * (1 if side else -1) < 0) != outward_flip
    if nan_as is not None:
        np.copyto(values, nan_as, where=~np.isfinite(values))
    threads = kernel_threads()
    groups, counts, rows, n_triangles, n_samples = _native.cap_count(
        values, reverse, shape, float(level), tables, joined, decided, threads
    )
    if not n_triangles:
        return mesh
    n_vertices, n_cells = mesh.n_vertices, mesh.n_cells
    # the closed mesh's arrays, allocated once: the surface goes in first, then the cap
    vertices = np.empty((n_vertices + n_samples, 3), dtype=np.float64)
    cells = np.empty((n_cells + n_triangles, 3), dtype=np.int64)
    edge_ids = np.empty(n_vertices + n_samples, dtype=np.int64)
    # the cap's samples are placed by the kernel where the grid's axes are the
    # world's (index * spacing + origin, as Volume.index_to_world computes it),
    # else left as indices and placed here
    axis_aligned = np.array_equal(volume.direction, np.eye(3))
    scale = np.asarray(volume.spacing if axis_aligned else np.ones(3), dtype=np.float64)
    shift = np.asarray(volume.origin if axis_aligned else np.zeros(3), dtype=np.float64)
    missing = _native.cap_fill(
        values,
        reverse,
        shape,
        float(level),
        tables,
        joined,
        groups,
        counts,
        rows,
        np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(mesh.cells, dtype=np.int64),
        np.ascontiguousarray(mesh.edge_ids, dtype=np.int64),
        scale,
        shift,
        vertices,
        cells,
        edge_ids,
        threads,
    )
    if missing:
        raise IsoconvertError(
            "--close: the surface does not cross the grid's faces where the volume says it "
            "should; it must be the cubes surface of this volume at this level"
        )
    if not axis_aligned:
        volume.index_to_world(vertices[n_vertices:])
    info = dict(mesh.info)
    info["closed"] = {"cap_triangles": n_triangles, "cap_vertices": n_samples}
    return Mesh(vertices, cells, edge_ids, info)


def _face_sizes(shape: tuple[int, ...]) -> list[int]:
    """The number of samples of each face image, in ``_face_images`` order."""
    sizes = []
    for axis in range(3):
        p_axis, q_axis = [a for a in range(3) if a != axis]
        sizes += [shape[p_axis] * shape[q_axis]] * 2
    return sizes


@functools.cache
def _tables(rule: str) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's tables: the 16 cases under ``rule``, and the ambiguous cases
    5 and 10 joined (the decider's other answer)."""
    tables = np.array([_table_row(_cell_triangles(case, rule)) for case in range(16)])
    joined = np.array([_table_row(_cell_triangles(case, "separate-negative")) for case in (5, 10)])
    tables.flags.writeable = joined.flags.writeable = False
    return tables, joined


def _table_row(triangles: list[tuple[int, int, int]]) -> list[int]:
    """A case's triangles for the kernel: their number, then 4 x 3 slots (-1 unused)."""
    slots = [s for t in triangles for s in t]
    return [len(triangles)] + slots + [-1] * (12 - len(slots))


__all__ = ["close_at_grid"]
