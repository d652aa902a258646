"""Clean-up by connected components: keep the largest, drop small ones, fill cavities.

Components are vertex-connected through triangles (two triangles sharing a vertex
index are in one component), as :func:`isoconvert.graph.connected_components`
labels them. Every function returns a Mesh whose vertices are the used input
vertices in their input order (compactly re-indexed), whose triangles are the
kept input triangles in their input order, with ``edge_ids`` carried along and
``info["cleanup"]`` recording what was done. Pure numpy.
"""

from __future__ import annotations

import numpy as np

from ..errors import IsoconvertError
from ..graph import connected_components
from ..mesh import Mesh
from ..threads import kernel_threads

#: Ray directions of the inside test: generic (no grid axis, no diagonal), so a ray
#: through a triangle's edge or vertex has probability zero; three, for a majority.
_RAYS = np.array(
    [
        [0.8660254, 0.3826834, 0.3217505],
        [-0.2588190, 0.9238795, 0.2817325],
        [0.3420201, -0.1736482, 0.9235429],
    ]
)


def _labels(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Component of each triangle.

    Returns
    -------
    tri_comp : (C,) int64
        Component number of each triangle, 0..K-1, numbered by smallest vertex index.
    sizes : (K,) int64
        Triangles per component.
    roots : (K,) int64
        Smallest vertex index of each component.
    """
    if not mesh.is_triangles:
        raise IsoconvertError("component clean-up needs a triangle mesh ((C, 3) cells)")
    cells = np.asarray(mesh.cells, dtype=np.int64)
    u = np.concatenate([cells[:, 0], cells[:, 1]])
    v = np.concatenate([cells[:, 1], cells[:, 2]])
    labels = connected_components(mesh.n_vertices, u, v)
    roots, tri_comp = np.unique(labels[cells[:, 0]], return_inverse=True)
    tri_comp = tri_comp.reshape(-1)
    return tri_comp, np.bincount(tri_comp, minlength=len(roots)), roots


def _subset(mesh: Mesh, keep_tri: np.ndarray, record: dict) -> Mesh:
    """The kept triangles over their vertices, compactly re-indexed in input order."""
    cells = np.asarray(mesh.cells, dtype=np.int64)[keep_tri]
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[cells.reshape(-1)] = True
    new_index = np.cumsum(used) - 1
    edge_ids = None if mesh.edge_ids is None else np.asarray(mesh.edge_ids)[used]
    info = dict(mesh.info)
    info["cleanup"] = list(info.get("cleanup", [])) + [record]
    return Mesh(np.asarray(mesh.vertices)[used], new_index[cells], edge_ids, info)


def keep_largest(mesh: Mesh, k: int = 1) -> Mesh:
    """Keep the ``k`` components with the most triangles.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)``.
    k : int
        How many to keep (>= 1). Ties in triangle count go to the component
        whose smallest vertex index comes first (stable in the input's order).

    Returns
    -------
    Mesh
        ``info["cleanup"]`` gains ``{"step": "keep_largest", "k", "components_before",
        "components_after"}``.
    """
    if int(k) < 1:
        raise IsoconvertError(f"keep_largest: k={k} must be at least 1")
    tri_comp, sizes, _ = _labels(mesh)
    # components are numbered by smallest vertex index, so a stable sort breaks ties
    order = np.argsort(-sizes, kind="stable")[: int(k)]
    keep = np.zeros(len(sizes), dtype=bool)
    keep[order] = True
    record = {
        "step": "keep_largest",
        "k": int(k),
        "components_before": int(len(sizes)),
        "components_after": int(keep.sum()),
    }
    return _subset(mesh, keep[tri_comp], record)


def drop_small(
    mesh: Mesh, min_triangles: int | None = None, min_volume: float | None = None
) -> Mesh:
    """Drop components with fewer triangles, or less enclosed volume, than a minimum.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)``.
    min_triangles : int or None
        Components with fewer triangles are dropped.
    min_volume : float or None
        Closed components (no edge used by a single triangle) enclosing less
        than this absolute volume, in world units cubed, are dropped. Open
        components (cut by the grid boundary) enclose no defined volume and are
        never dropped by this rule.

    Returns
    -------
    Mesh
        ``info["cleanup"]`` gains ``{"step": "drop_small", "min_triangles",
        "min_volume", "components_before", "components_after", "largest_triangles",
        "largest_volume"}``: the last two are the most triangles of a component,
        and the largest volume a closed component encloses (None without
        ``min_volume`` or without closed components), before the step, so a
        caller can say how far a minimum was from keeping something.
    """
    if min_triangles is None and min_volume is None:
        raise IsoconvertError("drop_small needs min_triangles or min_volume")
    tri_comp, sizes, _ = _labels(mesh)
    keep = np.ones(len(sizes), dtype=bool)
    largest_volume = None
    if min_triangles is not None:
        keep &= sizes >= int(min_triangles)
    if min_volume is not None:
        closed = _closed(mesh, tri_comp, len(sizes))
        volume = np.abs(_volumes(mesh, tri_comp, len(sizes)))
        keep &= ~closed | (volume >= float(min_volume))
        if closed.any():
            largest_volume = float(volume[closed].max())
    record = {
        "step": "drop_small",
        "min_triangles": None if min_triangles is None else int(min_triangles),
        "min_volume": None if min_volume is None else float(min_volume),
        "components_before": int(len(sizes)),
        "components_after": int(keep.sum()),
        "largest_triangles": int(sizes.max()) if len(sizes) else 0,
        "largest_volume": largest_volume,
    }
    return _subset(mesh, keep[tri_comp], record)


def fill_cavities(mesh: Mesh) -> Mesh:
    """Remove closed components that lie inside an outer closed component.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)``, oriented as extracted (normals
        point from the positive to the negative side).

    Returns
    -------
    Mesh
        ``info["cleanup"]`` gains ``{"step": "fill_cavities", "removed",
        "components_before", "components_after"}``.

    Notes
    -----
    The rule, like nii2mesh's bubble filling: an *outer* surface is a closed
    component (no edge in one triangle) with positive signed volume, i.e. its
    normals point out of what it encloses. A closed component A is removed when
    a point of A (the centroid of its first triangle) lies inside an outer
    surface B other than A; everything B encloses is then filled: cavities
    (negative volume, normals pointing into the hole) and islands inside them.
    Inside is decided by the parity of a ray's crossings with B's triangles,
    by majority of three generic ray directions. Two separate balls are both
    outer and neither is inside the other, so both stay. For a mesh extracted
    with ``flip`` (dark objects), flip it first so its outer surfaces are
    positive.
    """
    tri_comp, sizes, _ = _labels(mesh)
    n_comp = len(sizes)
    closed = _closed(mesh, tri_comp, n_comp)
    volume = _volumes(mesh, tri_comp, n_comp)
    outer = closed & (volume > 0)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    corners = vertices[cells]  # (C, 3 corners, 3)

    # component bounding boxes: A can only be inside B when B's box holds A's
    lo = np.full((n_comp, 3), np.inf)
    hi = np.full((n_comp, 3), -np.inf)
    np.minimum.at(lo, tri_comp, corners.min(axis=1))
    np.maximum.at(hi, tri_comp, corners.max(axis=1))
    first_tri = np.full(n_comp, len(cells))
    np.minimum.at(first_tri, tri_comp, np.arange(len(cells)))
    probe = np.zeros((n_comp, 3))
    has = first_tri < len(cells)
    probe[has] = corners[first_tri[has]].mean(axis=1)

    # candidate pairs (A closed, B outer, A's box within B's), in chunks of A so the
    # pair matrix stays small when a noisy mesh has many components
    cand_a, cand_b = np.flatnonzero(closed), np.flatnonzero(outer)
    pairs_a, pairs_b = [], []
    for c0 in range(0, len(cand_a), 1024):
        a = cand_a[c0 : c0 + 1024]
        within = (lo[cand_b][None] <= lo[a][:, None]).all(axis=2) & (
            hi[a][:, None] <= hi[cand_b][None]
        ).all(axis=2)
        i, j = np.nonzero(within & (a[:, None] != cand_b[None, :]))
        pairs_a.append(a[i])
        pairs_b.append(cand_b[j])
    a_idx = np.concatenate(pairs_a) if pairs_a else np.zeros(0, np.int64)
    b_idx = np.concatenate(pairs_b) if pairs_b else np.zeros(0, np.int64)
    inside = _inside(probe[a_idx], b_idx, tri_comp, vertices, cells)
    remove = np.zeros(n_comp, dtype=bool)
    remove[a_idx[inside]] = True
    record = {
        "step": "fill_cavities",
        "removed": int(remove.sum()),
        "components_before": int(n_comp),
        "components_after": int(n_comp - remove.sum()),
    }
    return _subset(mesh, ~remove[tri_comp], record)


def _closed(mesh: Mesh, tri_comp: np.ndarray, n_comp: int) -> np.ndarray:
    """(K,) bool: the component has no edge used by exactly one triangle."""
    cells = np.asarray(mesh.cells, dtype=np.int64)
    edges = np.sort(np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]]), axis=1)
    key = edges[:, 0] * max(mesh.n_vertices, 1) + edges[:, 1]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    single = counts[inverse.reshape(-1)] == 1
    open_comp = np.zeros(n_comp, dtype=bool)
    open_comp[np.tile(tri_comp, 3)[single]] = True
    return ~open_comp


def _volumes(mesh: Mesh, tri_comp: np.ndarray, n_comp: int) -> np.ndarray:
    """(K,) signed volume of each component (positive with outward normals).

    Tetrahedra from each component's mean corner, which keeps the sum well
    conditioned far from the origin; meaningful for closed components only.
    """
    corners = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.cells, dtype=np.int64)]
    count = np.maximum(np.bincount(tri_comp, minlength=n_comp), 1)
    centre = (
        np.stack(
            [np.bincount(tri_comp, corners[:, :, i].mean(axis=1), n_comp) for i in range(3)], axis=1
        )
        / count[:, None]
    )
    p = corners - centre[tri_comp][:, None, :]
    det = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2]))
    return np.bincount(tri_comp, det, n_comp) / 6.0


def _inside(
    points: np.ndarray,
    comps: np.ndarray,
    tri_comp: np.ndarray,
    vertices: np.ndarray,
    cells: np.ndarray,
) -> np.ndarray:
    """(N,) bool: ``points[i]`` is inside closed component ``comps[i]``: at
    least two of the three rays ``_RAYS`` from it cross the component an odd
    number of times (the compiled ``ray_parity_votes``, which meets only the
    triangles whose shadow across each ray covers the point).

    Parameters
    ----------
    points : (N, 3) float64
    comps : (N,) int64
    tri_comp : (C,) int64
        Component of each triangle.
    vertices : (V, 3) float64
    cells : (C, 3) int64
    """
    from .. import _native

    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    order = np.argsort(tri_comp, kind="stable")  # triangles grouped by component
    sizes = np.bincount(tri_comp)
    starts = np.cumsum(sizes) - sizes
    votes = np.empty(len(points), dtype=np.int64)
    _native.ray_parity_votes(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(cells, dtype=np.int64),
        order.astype(np.int64),
        starts.astype(np.int64),
        sizes.astype(np.int64),
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(comps, dtype=np.int64),
        _RAYS,
        kernel_threads(),
        votes,
    )
    return votes >= 2
