"""Decimation by quadric-error edge collapse, through meshoptimizer (optional extra).

Why meshoptimizer (checked on the engine surface, 593,734 triangles, 90 % reduction):

- It is the only candidate with an error limit in world units and a border lock:
  ``meshopt_simplify(..., target_error, options)`` with ``meshopt_SimplifyErrorAbsolute``
  (the limit is a distance, not a fraction of the mesh extent) and
  ``meshopt_SimplifyLockBorder`` (vertices on edges used by one triangle never move).
  fast-simplification 0.2 (pyvista's) and pyfqmr 0.5 have ``preserve_border`` but only
  a target count (pyfqmr's ``threshold_lossless`` is a squared quadric value, not a
  distance); pymeshlab and Open3D have no absolute bound either.
- It collapses edges onto one of their ends and never places new vertices, so every
  vertex of the result is a vertex of the input: no vertex moves off the original
  surface at all, and positions keep their float64 values.
- Its reported error is an estimate (the square root of an area-weighted quadric, a
  mean of squared distances to the original planes), not a maximum: on the engine it
  reported 0.49 for a limit of 0.5 while an original vertex lay 1.06 from the result.
  So :func:`decimate` measures the true distance itself and tightens the limit until
  the measured bound holds (see :func:`decimate`'s Notes).
- About 0.3 s on the engine surface; the Python package is MIT, from the
  meshoptimizer repository (github.com/zeux/meshoptimizer), built from source on install.
"""

from __future__ import annotations

import numpy as np

from ..errors import IsoconvertError
from ..graph import ragged_pairs
from ..mesh import Mesh

_NEEDS = "decimation needs meshoptimizer: pip install isoconvert[simplify]"
#: Attempts with a tightened library limit before giving the input back unchanged.
_MAX_ATTEMPTS = 8


def _meshoptimizer():
    """The meshoptimizer module, imported on first use (it is an optional extra)."""
    try:
        import meshoptimizer
    except ImportError:
        raise IsoconvertError(_NEEDS) from None
    return meshoptimizer


def decimate(mesh: Mesh, reduction: float | None = None, max_error: float | None = None) -> Mesh:
    """Remove triangles by quadric-error edge collapse, keeping open boundaries in place.

    Parameters
    ----------
    mesh : Mesh
        Triangles: ``vertices (V, 3)`` float64, ``cells (C, 3)`` int.
    reduction : float or None
        Fraction of triangles to remove, in [0, 1): 0.9 leaves about 10 %. None
        removes as many as ``max_error`` allows.
    max_error : float or None
        Largest distance, in world units, between the original surface and the
        result, measured at the original vertices (see Notes). None sets no limit.
        At least one of ``reduction`` and ``max_error`` is needed; with both, the
        collapse stops at whichever is reached first.

    Returns
    -------
    Mesh
        ``vertices (V', 3)``: the input vertices that are still used, in their
        input order; ``cells (C', 3)`` int64, oriented as the input; ``edge_ids``
        None (a vertex that absorbed collapsed neighbours no longer stands for one
        grid edge); ``info`` the input's plus ``info["decimation"]`` (library,
        limits, triangle counts, measured deviation, attempts).

    Raises
    ------
    IsoconvertError
        meshoptimizer is not installed, the mesh is not made of triangles, or a
        parameter is out of range.

    Notes
    -----
    Guarantees:

    - Every output vertex is an input vertex at its exact input position (the
      library never moves vertices, it only merges them), so no vertex leaves the
      original surface.
    - Vertices on an open boundary (an edge of one triangle, e.g. where the surface
      meets the grid's faces) are locked, so boundary edges stay exactly where they
      were.
    - With ``max_error=D``: every input vertex lies within D of the output surface,
      measured exactly (point-to-triangle distances over all candidate triangles in
      float64). The library's own error is only an estimate, so when the measure
      exceeds D the library's limit is scaled down and the collapse redone; after
      8 attempts the input is returned unchanged. Points inside the input's
      triangles are not measured; they are within D plus half the input's longest
      edge of the output.

    Pairs of triangles with the same three vertices (a collapsed thin tunnel folds
    into such a "fin", which makes an edge non-manifold) are removed: they enclose
    nothing, and removing them keeps a manifold input manifold.
    """
    if not mesh.is_triangles:
        raise IsoconvertError("decimate needs a triangle mesh ((C, 3) cells), not segments")
    if reduction is None and max_error is None:
        raise IsoconvertError("decimate needs reduction (e.g. 0.9) or max_error (a distance)")
    if reduction is not None and not 0.0 <= float(reduction) < 1.0:
        raise IsoconvertError(f"decimate: reduction {reduction} must be in [0, 1), e.g. 0.9")
    if max_error is not None and not (np.isfinite(max_error) and max_error > 0):
        raise IsoconvertError(f"decimate: max_error {max_error} must be a positive distance")
    mo = _meshoptimizer()

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    n_cells = len(cells)
    # the library computes in float32; output positions are taken from the float64 input
    positions = np.ascontiguousarray(vertices, dtype=np.float32)
    indices = np.ascontiguousarray(cells, dtype=np.uint32).reshape(-1)
    target = 0 if reduction is None else 3 * int(round((1.0 - float(reduction)) * n_cells))
    options = mo.SIMPLIFY_LOCK_BORDER | mo.SIMPLIFY_ERROR_ABSOLUTE
    limit = float(max_error) if max_error is not None else np.finfo(np.float32).max

    attempts = 0
    deviation = None
    out = cells
    library_error = 0.0
    fins = 0
    while attempts < _MAX_ATTEMPTS:
        attempts += 1
        destination = np.zeros(len(indices), dtype=np.uint32)  # worst case: all kept
        error = np.zeros(1, dtype=np.float32)
        count = mo.simplify(
            destination,
            indices,
            positions,
            target_index_count=target,
            target_error=limit,
            options=options,
            result_error=error,
        )
        out, fins = _drop_fins(destination[:count].reshape(-1, 3).astype(np.int64))
        library_error = float(error[0])
        if max_error is None:
            break
        deviation = _max_vertex_distance(vertices, out, float(max_error))
        if deviation <= max_error:
            break
        # the estimate undershot: scale the limit by how far it undershot, at least halving
        limit *= min(0.5, 0.9 * float(max_error) / deviation)
    else:
        out, fins, deviation = cells, 0, 0.0  # nothing met the bound: the input does

    used = np.zeros(len(vertices), dtype=bool)
    used[out.reshape(-1)] = True
    new_index = np.cumsum(used) - 1  # compact, keeping the input's vertex order
    info = dict(mesh.info)
    info["decimation"] = {
        "library": "meshoptimizer",
        "reduction": None if reduction is None else float(reduction),
        "max_error": None if max_error is None else float(max_error),
        "triangles_before": int(n_cells),
        "triangles_after": int(len(out)),
        "max_vertex_deviation": deviation,
        "library_error_estimate": library_error,
        "attempts": attempts,
        "fins_removed": int(fins),
    }
    return Mesh(vertices[used], new_index[out], None, info)


def _drop_fins(cells: np.ndarray) -> tuple[np.ndarray, int]:
    """Remove every triangle whose vertex set another triangle repeats.

    Parameters
    ----------
    cells : (C, 3) int64

    Returns
    -------
    cells : (C', 3) int64
        The others, in their order.
    removed : int
    """
    if len(cells) < 2:
        return cells, 0
    key = np.sort(cells, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    keep = counts[inverse.reshape(-1)] == 1
    return cells[keep], int((~keep).sum())


def _max_vertex_distance(points: np.ndarray, cells: np.ndarray, radius: float) -> float:
    """Largest distance from ``points`` to the triangles, exact up to ``radius``.

    Parameters
    ----------
    points : (P, 3) float64
        Vertices of the input (those the triangles use are at distance 0).
    cells : (C, 3) int64
        Triangles over ``points``.
    radius : float
        Only distances up to this are resolved; a point farther from every
        triangle makes the result ``inf``.

    Returns
    -------
    float
        The maximum over the points of the distance to the nearest triangle,
        or ``inf`` when some point has no triangle within ``radius``.

    Notes
    -----
    A uniform grid of cubic buckets: each triangle is listed in every bucket its
    bounding box, grown by ``radius``, touches, so every triangle within
    ``radius`` of a point is listed in that point's bucket. Pairs are measured
    in chunks with a vectorized closest-point-on-triangle.
    """
    used = np.zeros(len(points), dtype=bool)
    used[cells.reshape(-1)] = True
    query = points[~used]  # the kept vertices are on the result
    if len(query) == 0:
        return 0.0
    if len(cells) == 0:
        return float("inf")
    a, b, c = points[cells[:, 0]], points[cells[:, 1]], points[cells[:, 2]]
    lo = np.minimum(np.minimum(a, b), c) - radius
    hi = np.maximum(np.maximum(a, b), c) + radius
    # buckets about as large as a grown triangle: few buckets per triangle, few
    # triangles per bucket
    size = max(float(np.median((hi - lo).max(axis=1))), 1e-12)
    origin = lo.min(axis=0)
    first = np.floor((lo - origin) / size).astype(np.int64)
    last = np.floor((hi - origin) / size).astype(np.int64)
    dims = np.maximum(last.max(axis=0), np.floor((query.max(axis=0) - origin) / size)) + 2
    dims = dims.astype(np.int64)
    span = last - first + 1
    per_tri = span.prod(axis=1)
    tri = np.repeat(np.arange(len(cells)), per_tri)
    # the k-th bucket of a triangle's box, unravelled over its (sx, sy, sz) span
    k = np.arange(len(tri)) - np.repeat(np.cumsum(per_tri) - per_tri, per_tri)
    sx, sy = span[tri, 0], span[tri, 1]
    ijk = first[tri] + np.column_stack([k % sx, (k // sx) % sy, k // (sx * sy)])
    bucket = ijk[:, 0] + dims[0] * (ijk[:, 1] + dims[1] * ijk[:, 2])
    order = np.argsort(bucket, kind="stable")
    bucket, tri = bucket[order], tri[order]

    q = np.floor((query - origin) / size).astype(np.int64)
    inside = (q >= 0).all(axis=1) & (q < dims).all(axis=1)
    if not inside.all():
        return float("inf")  # outside every grown box: no triangle within radius
    qb = q[:, 0] + dims[0] * (q[:, 1] + dims[1] * q[:, 2])
    start = np.searchsorted(bucket, qb, side="left")
    stop = np.searchsorted(bucket, qb, side="right")
    n_pairs = stop - start
    if (n_pairs == 0).any():
        return float("inf")
    best = np.full(len(query), np.inf)
    for p0, p1, pid, offset in ragged_pairs(n_pairs):  # whole points, chunks of pairs
        counts = n_pairs[p0:p1]
        t = tri[np.repeat(start[p0:p1], counts) + offset]
        d2 = _point_triangle_sq(query[pid], a[t], b[t], c[t])
        # pairs are grouped by point and every point has one: a segmented minimum
        best[p0:p1] = np.minimum.reduceat(d2, np.cumsum(counts) - counts)
    return float(np.sqrt(best.max()))


def _point_triangle_sq(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(N,) squared distances from points (N, 3) to triangles a, b, c (N, 3) each.

    Projects onto the triangle's plane and, when the projection falls outside,
    onto the nearest of its three edges (a degenerate triangle is its edges).
    """
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    ap = p - a
    # barycentric coordinates of the projection (Cramer's rule on the plane)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.einsum("ij,ij->i", np.cross(ap, ac), n) / nn
        w = np.einsum("ij,ij->i", np.cross(ab, ap), n) / nn
    interior = (nn > 0) & (v >= 0) & (w >= 0) & (v + w <= 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        plane = np.where(interior, np.einsum("ij,ij->i", ap, n) ** 2 / nn, np.inf)
    edges = np.minimum(
        np.minimum(_point_segment_sq(p, a, b), _point_segment_sq(p, b, c)),
        _point_segment_sq(p, c, a),
    )
    return np.minimum(plane, edges)


def _point_segment_sq(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) squared distances from points (N, 3) to segments a-b (N, 3)."""
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / denom, 0.0, 1.0)
    s = np.where(denom > 0, s, 0.0)
    d = p - (a + s[:, None] * ab)
    return np.einsum("ij,ij->i", d, d)
