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
  So :func:`decimate` certifies the distance itself, both ways (the Hausdorff
  distance), and locks vertices where it fails until the bound holds (see
  :func:`decimate`'s Notes). The distances come from a compiled kernel
  (src/distance.cpp): numpy took 9 s per pass on the chest CT's 746k triangles.
- It does not guarantee the topology: collapses near thin walls and tunnels can
  leave non-manifold edges and vertices, holes, or a small component collapsed
  away (7 of 8 real scans decimated by 90 % showed some). So :func:`decimate`
  checks the result's topology against the input's and locks the vertices around
  every new problem (``meshopt_simplifyWithAttributes``' vertex lock), then
  collapses again, until the result has no problem the input did not have.
- It leaves zero-area triangles where it collapses a vertex onto a line of others
  (three vertices of a row of a stair-stepped surface): a binary mask's isosurface
  got hundreds a collapse, and locking them made as many elsewhere, so that 40
  collapses ended with the input unchanged. Each such triangle is a corner lying on
  its longest edge: flipping that edge with the neighbour across it
  (:func:`_flipped_flats`) leaves the same surface without it, so the flats are
  flipped before the topology is checked, and only those that cannot be are locked.
- About 0.3 s per collapse on the engine surface; the Python package is MIT, from
  the meshoptimizer repository (github.com/zeux/meshoptimizer), built from source on
  install. Its wrapper of ``meshopt_simplifyWithAttributes`` declares no argument
  types (64-bit sizes are then passed as 32-bit ints, and it crashes), so the C
  function is called here through a prototype of its own.
"""

from __future__ import annotations

import numpy as np

from ..errors import IsoconvertError, extra_hint
from ..geometry import flat_triangles, triangle_cross
from ..graph import connected_components, row_groups, row_hashes, topology
from ..mesh import Mesh
from ..threads import kernel_threads, stop_if_interrupted

#: Collapses (each with more vertices locked, or a tighter limit) before giving the
#: input back unchanged (the chest CT at 300.5 HU needs 13 for a 90 % decimation, and
#: 31 for --max-error 1 alone: each collapse with more vertices locked can make new
#: topology problems elsewhere, which take attempts of their own).
_MAX_ATTEMPTS = 40
#: A component of fewer vertices that decimation pinches in two is locked whole.
_LOCK_WHOLE_BELOW = 5000
#: From this attempt on, two rings around each new problem are locked, not one:
#: problems that come back one edge away (pinched necks) stop sooner.
_WIDER_FROM = 3
#: Where input vertices are left farther than ``max_error``, the ring around each is
#: locked and the library's limit scaled by this; in the last ``_TIGHTEN_LAST``
#: attempts the limit is scaled by how far the estimate undershot instead. Lowering
#: the limit alone removed 9-56 % where 90 % was asked on real scans at 0.5-1 mm
#: (frog, chest CT); locking where it undershoots removes 52-85 % (the README's
#: Decimation paragraph has the cases).
_TIGHTEN_BY = 0.9
_TIGHTEN_LAST = 8
#: The library's first limit, as a fraction of ``max_error``: its estimate is a mean,
#: so a limit of the bound itself collapses far past it (the chest CT at 1 mm: to 19k
#: triangles, then 31 collapses locking their way back to 181k). At 0.4 the chest CT
#: takes 8 collapses to 137k triangles and the engine at 0.5 11 to 49k (against 19
#: to 80k); 0.2 removes less (71 % on the chest CT, against 82 %).
_FIRST_LIMIT = 0.4


def _meshoptimizer():
    """The meshoptimizer module, imported on first use (it is an optional extra)."""
    try:
        import meshoptimizer
    except ImportError:
        raise IsoconvertError(f"decimation needs meshoptimizer: {extra_hint('simplify')}") from None
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
        result, both ways: every point of each within it of the other (the
        Hausdorff distance; see Notes). None sets no limit.
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
    - The result has no non-manifold edge or vertex, inconsistently oriented
      edge, hole (boundary edge), fin, zero-area triangle, vanished or split
      component that the input did not have: the vertices around each such
      problem are locked and the collapse is done again, down to the error the
      first one reached (the count is in
      ``info["decimation"]["locked_vertices"]``). Topology comes first: on scans
      with thin walls or many small noise components fewer triangles than
      ``reduction`` asks may go (``--min-size`` removes the noise first).
    - With ``max_error=D``: every point of the input's surface lies within D of
      the output's, and every point of the output's within D of the input's
      (a Hausdorff distance of at most D), certified, not sampled: the distance
      of every input vertex to the output is measured exactly (float64
      point-to-triangle distances), and each triangle of either surface is then
      certified by :func:`within_bound` (the distance is 1-Lipschitz, and
      convex to each triangle; uncertain triangles are split and measured
      again). The result's triangles certified onto the input stay certified
      in later collapses. The library's own
      error is only an estimate, so where an input vertex lies too far, it and
      its neighbours are locked, the library's limit is lowered a little, and
      the collapse redone (in the last attempts the limit is lowered by how far
      it undershot); where a triangle fails its certificate, the vertices of the
      input it replaced are locked. The bounds reached are in ``info``
      (``input_to_result``, ``result_to_input``). The first limit is
      ``_FIRST_LIMIT`` times D.
    - When 40 collapses do not meet these, the input is returned unchanged
      (``info["decimation"]["triangles_after"]`` then equals ``triangles_before``).

    A pair of triangles on the same three vertices (a thin tunnel collapsed into
    a "fin") is one of the problems: removing it would close a handle (change the
    genus) or open a hole.
    """
    out, report = collapse(mesh, reduction, max_error)
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[out.reshape(-1)] = True
    new_index = np.cumsum(used) - 1  # compact, keeping the input's vertex order
    info = dict(mesh.info)
    info["decimation"] = report
    return Mesh(np.asarray(mesh.vertices, dtype=np.float64)[used], new_index[out], None, info)


def collapse(
    mesh: Mesh,
    reduction: float | None = None,
    max_error: float | None = None,
    locked: np.ndarray | None = None,
) -> tuple[np.ndarray, dict]:
    """:func:`decimate`'s collapse, its triangles over the input's vertices.

    Parameters
    ----------
    mesh, reduction, max_error
        As :func:`decimate`.
    locked : (V,) bool or None
        Vertices that stay where they are, besides those :func:`decimate` locks
        (a piece of a larger mesh: the vertices it shares with the rest and their
        neighbours, so that no collapse on either side joins two shared vertices).

    Returns
    -------
    cells : (C', 3) int64
        The result's triangles, indices into ``mesh.vertices``.
    report : dict
        :func:`decimate`'s ``info["decimation"]``.
    """
    if not mesh.is_triangles:
        raise IsoconvertError("decimate needs a triangle mesh ((C, 3) cells), not segments")
    if reduction is None and max_error is None:
        raise IsoconvertError("decimate needs reduction (e.g. 0.9) or max_error (a distance)")
    if reduction is not None and not 0.0 <= float(reduction) < 1.0:
        raise IsoconvertError(f"decimate: reduction {reduction} must be in [0, 1), e.g. 0.9")
    if max_error is not None and not (np.isfinite(max_error) and max_error > 0):
        raise IsoconvertError(
            f"decimate: max_error {max_error} must be a finite positive distance (None: no bound)"
        )
    mo = _meshoptimizer()
    simplify = _simplify_with_lock(mo)

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    n_cells = len(cells)
    # the library computes in float32; output positions are taken from the float64 input
    positions = np.ascontiguousarray(vertices, dtype=np.float32)
    indices = np.ascontiguousarray(cells, dtype=np.uint32).reshape(-1)
    target = 0 if reduction is None else 3 * int(round((1.0 - float(reduction)) * n_cells))
    options = mo.SIMPLIFY_LOCK_BORDER | mo.SIMPLIFY_ERROR_ABSOLUTE
    # distances are measured up to the bound, and none exceeds the mesh's extent (a
    # larger radius, say 1e308, would only overflow the search grid)
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    radius = min(float(max_error), 2.0 * extent + 1.0) if max_error is not None else 0.0
    # the library's limit (float32; 1e308 would be inf there, which it takes badly)
    limit = _FIRST_LIMIT * radius if max_error is not None else float(np.finfo(np.float32).max)
    guard = _TopologyGuard(vertices, cells)
    input_rows = _InputRows(cells)
    certified = Certified()  # the result's triangles certified onto the input so far
    # what is wrong with the input stays as it is: collapses never touch it
    fixed = None if locked is None else np.asarray(locked, dtype=bool)
    locked = guard.input_problems | (False if fixed is None else fixed)

    attempts = 0
    deviation = spread = surface = None
    bound = None if max_error is None else float(max_error)
    out = cells
    library_error = 0.0
    # no triangles: nothing to collapse or to bound (the input is the answer)
    while attempts < _MAX_ATTEMPTS and n_cells:
        stop_if_interrupted()  # on a worker thread of an interrupted run
        attempts += 1
        # the last attempt's distance grid is not held beside this one's (with the
        # input's, three grids of a large mesh were the peak of its collapse)
        output_grid = distance = nearest = None
        out, library_error = simplify(indices, positions, locked, target, limit, options)
        out, flat = _flipped_flats(vertices, out, guard.input_problems, fixed)
        new_problems = guard.new_problems(out, flat)
        if new_problems.any():
            ring = guard.around(new_problems)
            locked |= guard.around(ring) if attempts >= _WIDER_FROM else ring
            if max_error is not None:
                # and where the bound fails already: one collapse fewer for each
                distance, _ = _vertex_distances(vertices, out, TriangleGrid(vertices, out, radius))
                locked |= guard.around(distance > max_error)
            if attempts == 1:
                # with only a triangle count to reach, locked vertices would push
                # collapses elsewhere (and new problems with them); the error the
                # first collapse reached keeps the others where they were
                limit = min(limit, library_error)
            continue
        if max_error is None:
            break
        output_grid = TriangleGrid(vertices, out, radius)
        distance, nearest = _vertex_distances(vertices, out, output_grid)
        deviation = float(distance.max())
        far = distance > max_error
        if far.any():
            # the estimate undershot somewhere: keep the collapses there from happening
            locked |= guard.around(far)
            if attempts <= _MAX_ATTEMPTS - _TIGHTEN_LAST:
                limit *= _TIGHTEN_BY
            else:
                # scale the limit by how far it undershot, at least halving
                limit *= min(0.5, 0.9 * float(max_error) / deviation) if deviation < np.inf else 0.5
            continue
        # every point of the input within the bound of the result, not only its vertices
        kept, still = input_rows.shared(out)
        spread, failed = within_bound(
            vertices, cells, output_grid, out, bound, distance, shared=still
        )
        if failed.any():
            locked |= guard.around(_vertices_of(cells[failed], len(vertices)))
            continue
        # and every point of the result within the bound of the input (triangles
        # certified in an earlier collapse stay so: the input does not change)
        # (the input's distance grid is built for this check alone: one grid of
        # the mesh's size at a time, at some 0.1 s a build on 500k triangles)
        output_grid = None
        input_grid = TriangleGrid(vertices, cells, radius)
        surface, failed = within_bound(
            vertices, out, input_grid, cells, bound, known=certified, shared=kept
        )
        del input_grid
        if not failed.any():
            break
        # lock the input the failing triangles replaced (the input vertices nearest
        # to them) and their corners; the limit stays: these are few and local
        replaced = np.isin(nearest, np.flatnonzero(failed))
        replaced |= _vertices_of(out[failed], len(vertices))
        locked |= guard.around(replaced)
    else:
        # nothing met the bounds: the input does
        out, deviation, spread, surface = cells, 0.0, 0.0, 0.0

    report = {
        "library": "meshoptimizer",
        "reduction": None if reduction is None else float(reduction),
        "max_error": None if max_error is None else float(max_error),
        "triangles_before": int(n_cells),
        "triangles_after": int(len(out)),
        "max_vertex_deviation": deviation,
        # certified bounds (see within_bound): the input's surface from the
        # result's, and the result's from the input's
        "input_to_result": spread,
        "result_to_input": surface,
        "library_error_estimate": library_error,
        "attempts": attempts,
        "locked_vertices": int(locked.sum()),
    }
    return out, report


def _simplify_with_lock(mo):
    """``simplify(indices, positions, locked, target, limit, options)`` ->
    ``(cells (C', 3) int64, library error)``: ``meshopt_simplifyWithAttributes``
    with no attributes and a vertex lock, through a ctypes prototype of its own
    (see the module notes)."""
    import ctypes

    from meshoptimizer import _loader

    p = ctypes.POINTER
    size, uint, real = ctypes.c_size_t, ctypes.c_uint, ctypes.c_float
    prototype = ctypes.CFUNCTYPE(
        size, p(uint), p(uint), size, p(real), size, size,  # destination .. stride
        p(real), size, p(real), size, p(ctypes.c_ubyte),  # attributes (none), lock
        size, real, uint, p(real),  # target, error, options, result error
    )  # fmt: skip
    function = prototype(("meshopt_simplifyWithAttributes", _loader.lib))

    def simplify(indices, positions, locked, target, limit, options):
        destination = np.zeros(len(indices), dtype=np.uint32)  # worst case: all kept
        lock = np.ascontiguousarray(locked, dtype=np.uint8)
        error = real(0.0)
        count = function(
            destination.ctypes.data_as(p(uint)),
            indices.ctypes.data_as(p(uint)),
            len(indices),
            positions.ctypes.data_as(p(real)),
            len(positions),
            12,
            None,
            0,
            None,
            0,
            lock.ctypes.data_as(p(ctypes.c_ubyte)),
            target,
            limit,
            options,
            ctypes.byref(error),
        )
        return destination[:count].reshape(-1, 3).astype(np.int64), float(error.value)

    return simplify


class _TopologyGuard:
    """What a decimated mesh may not have that its input did not: non-manifold
    edges or vertices, inconsistently oriented edges, boundary edges (holes),
    triangles repeating another's vertices (fins) or of zero area, a component
    collapsed away or pinched into pieces. Collapses that avoid all of these keep the genus too.

    Parameters
    ----------
    cells : (C, 3) int64
        The input's triangles.
    n : int
        Its number of vertices.
    """

    def __init__(self, vertices: np.ndarray, cells: np.ndarray) -> None:
        self.vertices = vertices
        n = self.n = len(vertices)
        table = topology(cells, n)
        self.input_problems = self._problem_vertices(table, cells)
        self.boundary_keys = np.unique(self._keys(table["boundary"]))
        edges = np.asarray(table["all_edges"], dtype=np.int64)
        self.edges = edges
        self.component = connected_components(n, edges[:, 0], edges[:, 1])
        self.used = np.zeros(n, dtype=bool)
        self.used[cells.reshape(-1)] = True

    def _keys(self, edges: np.ndarray) -> np.ndarray:
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        return np.minimum(edges[:, 0], edges[:, 1]) * self.n + np.maximum(edges[:, 0], edges[:, 1])

    def _problem_vertices(
        self, table: dict, cells: np.ndarray, flat: np.ndarray | None = None
    ) -> np.ndarray:
        bad = np.zeros(self.n, dtype=bool)
        bad[cells[_fins(cells)].reshape(-1)] = True
        # zero-area triangles, as the report's no-degenerate check finds them
        if flat is None:
            flat = flat_triangles(self.vertices, cells, triangle_cross(self.vertices, cells))
        bad[cells[flat].reshape(-1)] = True
        for name in ("non_manifold_edges", "inconsistent"):
            bad[np.asarray(table[name], dtype=np.int64).reshape(-1)] = True
        bad[np.asarray(table["non_manifold_vertices"], dtype=np.int64)] = True
        return bad

    def new_problems(self, out: np.ndarray, flat: np.ndarray | None = None) -> np.ndarray:
        """(V,) bool: the vertices at a problem of ``out`` that the input does not have
        (``flat``: which of its triangles are flat, when known)."""
        table = topology(out, self.n)
        bad = self._problem_vertices(table, out, flat) & ~self.input_problems
        boundary = np.asarray(table["boundary"], dtype=np.int64).reshape(-1, 2)
        holes = ~np.isin(self._keys(boundary), self.boundary_keys)
        bad[boundary[holes].reshape(-1)] = True
        # a component whose every triangle collapsed away
        kept = np.zeros(self.n, dtype=bool)
        kept[out.reshape(-1)] = True
        alive = np.zeros(self.n, dtype=bool)
        alive[self.component[kept]] = True
        bad |= self.used & ~alive[self.component]
        # a component pinched into pieces: all but the largest piece of each
        edges = np.asarray(table["all_edges"], dtype=np.int64)
        piece = connected_components(self.n, edges[:, 0], edges[:, 1])
        vertices = np.flatnonzero(kept)
        pairs = np.unique(np.column_stack([self.component[vertices], piece[vertices]]), axis=0)
        split = np.flatnonzero(np.bincount(pairs[:, 0], minlength=self.n) > 1)
        if len(split):
            size = np.bincount(piece[vertices], minlength=self.n)
            in_split = pairs[np.isin(pairs[:, 0], split)]
            order = np.lexsort((-size[in_split[:, 1]], in_split[:, 0]))
            ranked = in_split[order]
            first = np.r_[True, ranked[1:, 0] != ranked[:-1, 0]]
            smaller = ranked[~first, 1]
            bad[vertices[np.isin(piece[vertices], smaller)]] = True
            # the neck that collapsed can lie far from the smaller piece (a thin
            # strand): a small component split in two is locked whole
            size = np.bincount(self.component[self.used], minlength=self.n)
            whole = split[size[split] < _LOCK_WHOLE_BELOW]
            bad |= self.used & np.isin(self.component, whole)
        return bad

    def around(self, bad: np.ndarray) -> np.ndarray:
        """(V,) bool: ``bad`` and its neighbours in the input (locking the ring
        keeps the next collapse from making the same problem one edge away)."""
        ring = bad.copy()
        near = bad[self.edges[:, 0]] | bad[self.edges[:, 1]]
        ring[self.edges[near].reshape(-1)] = True
        return ring


#: Rounds of :func:`_flipped_flats`: a flip can leave a flat triangle where the
#: neighbour's corner was on the same line (a longer row of the stair), which the
#: next round flips; on a binary mask's isosurface three rounds flipped them all.
_FLIP_ROUNDS = 8


def _flipped_flats(
    vertices: np.ndarray, cells: np.ndarray, own: np.ndarray, fixed: np.ndarray | None
) -> np.ndarray:
    """``cells`` without the zero-area triangles a collapse made, where an edge flip
    removes them: a flat triangle ``(a, b, c)`` whose corner ``c`` lies on its
    longest edge ``ab``, and the neighbour ``(b, a, d)`` across that edge, become
    ``(a, d, c)`` and ``(d, b, c)``, which cover the neighbour exactly (``c`` is
    on its side) with the same orientation. The vertices stay where they are, so
    the surface, and the distances to it, do not change.

    A flip is left out (the triangle is then locked as any other new problem)
    where it would make an edge ``cd`` the mesh already has (a non-manifold edge),
    where ``ab`` has no single neighbour, where two corners coincide (no flip
    removes that), where both ``c`` and ``d`` are ``fixed`` (a piece of a larger
    mesh: its vertices shared with the rest and their neighbours, whose edges the
    other pieces may have too), and for the input's own flat triangles (``own``
    holds all three of their corners).

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int64
        A collapse's triangles.
    own : (V,) bool
        The input's problem vertices.
    fixed : (V,) bool or None

    Returns
    -------
    cells : (C, 3) int64
        The same triangles, the flipped pairs in place.
    flat : (C,) bool
        Which of them are still flat (:func:`~isoconvert.geometry.flat_triangles`),
        for the topology check.
    """
    cells = cells.copy()
    n = len(vertices)
    if not len(cells):
        return cells, np.zeros(0, dtype=bool)
    flat = flat_triangles(vertices, cells, triangle_cross(vertices, cells))
    for _ in range(_FLIP_ROUNDS):
        ts = np.flatnonzero(flat)
        ts = ts[~own[cells[ts]].all(axis=1)]
        if not len(ts):
            break
        corners = cells[ts]
        p = vertices[corners]
        # squared length of the edge opposite each corner
        opposite = np.stack(
            [((p[:, (j + 2) % 3] - p[:, (j + 1) % 3]) ** 2).sum(1) for j in range(3)], 1
        )
        j = opposite.argmax(axis=1)
        r = np.arange(len(ts))
        c, a, b = corners[r, j], corners[r, (j + 1) % 3], corners[r, (j + 2) % 3]
        # the triangles about the flats' corners hold every edge looked for: each
        # neighbour across ab, and any edge cd (not a sort of the whole mesh's edges)
        near = np.flatnonzero(np.isin(cells, np.concatenate([a, b, c])).any(axis=1))
        # their directed edges, one corner to the next, and the triangle of each
        keys = cells[near].reshape(-1) * n + np.roll(cells[near], -1, axis=1).reshape(-1)
        order = np.argsort(keys, kind="stable")
        sorted_keys = keys[order]
        first = np.searchsorted(sorted_keys, b * n + a, "left")
        single = np.searchsorted(sorted_keys, b * n + a, "right") - first == 1
        u = near[order[np.minimum(first, len(keys) - 1)] // 3]
        other = cells[u]
        third = (other != a[:, None]) & (other != b[:, None])
        d = other[r, third.argmax(axis=1)]
        ok = single & (third.sum(axis=1) == 1) & (d != c) & (opposite.min(axis=1) > 0)
        ok &= ~_member(sorted_keys, c * n + d) & ~_member(sorted_keys, d * n + c)
        if fixed is not None:
            ok &= ~(fixed[c] & fixed[d])
        # a triangle in two flips goes to the first; the other waits a round
        pick = np.flatnonzero(ok)
        owner = np.full(len(cells), len(ts))
        np.minimum.at(owner, ts[pick], pick)
        np.minimum.at(owner, u[pick], pick)
        pick = pick[(owner[ts[pick]] == pick) & (owner[u[pick]] == pick)]
        if not len(pick):
            break
        cells[ts[pick]] = np.column_stack([a[pick], d[pick], c[pick]])
        cells[u[pick]] = np.column_stack([d[pick], b[pick], c[pick]])
        # each triangle is flat or not by itself: only the flipped ones change
        changed = np.concatenate([ts[pick], u[pick]])
        flat[changed] = flat_triangles(
            vertices, cells[changed], triangle_cross(vertices, cells[changed])
        )
    return cells, flat


def _fins(cells: np.ndarray) -> np.ndarray:
    """(C,) bool: triangles whose vertex set another triangle repeats (a thin
    tunnel collapsed into a "fin" of two triangles on the same three vertices)."""
    if len(cells) < 2:
        return np.zeros(len(cells), dtype=bool)
    order, new = row_groups(np.sort(cells, axis=1).astype(np.int64, copy=False))
    group = np.cumsum(new) - 1
    fins = np.empty(len(cells), dtype=bool)
    fins[order] = np.bincount(group)[group] > 1
    return fins


def _vertex_distances(
    points: np.ndarray, cells: np.ndarray, grid: TriangleGrid
) -> tuple[np.ndarray, np.ndarray]:
    """Distance from each of ``points`` to the triangles, exact up to ``radius``.

    Parameters
    ----------
    points : (P, 3) float64
        Vertices of the input (those the triangles use are at distance 0).
    cells : (C, 3) int64
        Triangles over ``points``.
    grid : TriangleGrid
        Over ``points`` and ``cells``: only distances up to its radius are
        resolved; a point farther from every triangle makes the result ``inf``.

    Returns
    -------
    distance : (P,) float64
        The distance of each point to the nearest triangle (0 for the vertices
        the triangles use), ``inf`` for a point with no triangle within ``radius``.
    nearest : (P,) int64
        The nearest triangle of each point not used by the triangles (-1 for
        the others and where ``distance`` is inf).
    """
    used = np.zeros(len(points), dtype=bool)
    used[cells.reshape(-1)] = True
    distance = np.zeros(len(points))
    nearest = np.full(len(points), -1, dtype=np.int64)
    asked = np.flatnonzero(~used)  # the kept vertices are on the result
    if len(asked):
        distance[asked], nearest[asked] = grid.distances(points[asked])
    return distance, nearest


#: Halvings of a triangle's edges before an uncertified piece counts as failing.
_MAX_DEPTH = 6


def within_bound(
    vertices: np.ndarray,
    triangles: np.ndarray,
    grid: TriangleGrid,
    onto: np.ndarray,
    bound: float,
    corner_distance: np.ndarray | None = None,
    known: Certified | None = None,
    shared: np.ndarray | None = None,
) -> tuple[float, np.ndarray]:
    """Whether every point of ``triangles`` lies within ``bound`` of the surface
    of ``onto`` (both over ``vertices``), certified triangle by triangle.

    Two certificates, for a triangle or a piece of one: the distance to a
    surface is 1-Lipschitz, so a piece whose corners lie within ``d`` of it lies
    within ``d + r``, ``r`` the farthest its points are from their nearest
    corner (the circumradius of an acute triangle); and the distance to one
    triangle of ``onto`` is convex, so a piece lies within the largest distance
    of its corners to the nearest triangle of one of them. A triangle that is
    also one of ``onto``'s is at distance 0; the others start with their
    corners' distances and are split into four by their edges' midpoints,
    measured there, until every piece is certified (or a point is found
    farther than ``bound``, or ``_MAX_DEPTH`` halvings do not suffice: then
    the triangle fails). The compiled ``TriangleGrid.certify``
    does the splitting. Applied both ways (the input onto the result, the
    result onto the input), this bounds the Hausdorff distance.

    Parameters
    ----------
    vertices : (V, 3) float64
    triangles : (T, 3) int64
        The triangles to certify.
    grid : TriangleGrid
        Over ``vertices`` and ``onto``, for a radius of at least ``bound``.
    onto : (C, 3) int64
        The surface they must lie near.
    bound : float
    corner_distance : (V,) float64 or None
        Each vertex's distance to ``onto`` where known (None: every vertex of
        ``triangles`` is one of ``onto``'s, at distance 0).
    known : Certified or None
        Triangles certified before against the same ``onto`` (skipped), which
        gains those certified now.
    shared : (T,) bool or None
        Which of ``triangles`` are also triangles of ``onto`` (as vertex sets),
        when known already (see :class:`_InputRows`); None: found here.

    Returns
    -------
    reach : float
        An upper bound of the distance from ``triangles`` to ``onto`` when every
        triangle is certified, else the largest distance measured on a failing one.
    failed : (T,) bool
        The triangles not certified within ``bound``.
    """
    failed = np.zeros(len(triangles), dtype=bool)
    skip = _rows_among(triangles, onto) if shared is None else shared.copy()
    if known is not None and len(known.rows):
        skip |= _rows_among(triangles, known.rows)
    fresh = np.flatnonzero(~skip)
    before = known.reach if known is not None else 0.0
    if not len(fresh):
        return before, failed
    if corner_distance is None:
        corner_distance = np.zeros(len(vertices))
    reach, status = grid.certify(vertices, triangles[fresh], corner_distance, bound, _MAX_DEPTH)
    failed[fresh] = status > 0
    good = status == 0
    if known is not None and good.any():
        known.rows = np.concatenate([known.rows, triangles[fresh[good]]])
        known.reach = max(known.reach, float(reach[good].max()))
    if failed.any():
        return float(reach[~good].max()), failed
    return max(before, float(reach.max())), failed


class Certified:
    """Triangles certified within a bound of a surface that does not change
    (decimation's input), kept across collapses: most of the result's
    triangles survive from one collapse to the next, and need no second look.

    Attributes
    ----------
    rows : (K, 3) int64
    reach : float
        The largest certified bound among them.
    """

    def __init__(self) -> None:
        self.rows = np.zeros((0, 3), dtype=np.int64)
        self.reach = 0.0


def _vertices_of(triangles: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertices ``triangles`` use."""
    used = np.zeros(n, dtype=bool)
    used[triangles.reshape(-1)] = True
    return used


class _InputRows:
    """The input's triangles as vertex sets, hashed once per decimation: which
    triangles a collapse kept comes from looking up the result's hashes among
    the input's (sorted once) instead of sorting both meshes' rows together after
    every collapse.

    Parameters
    ----------
    cells : (C, 3) int64
        The input's triangles.
    """

    def __init__(self, cells: np.ndarray) -> None:
        self.rows = np.sort(cells, axis=1).astype(np.int64, copy=False)
        self.hashes = row_hashes(self.rows)
        self.order = np.argsort(self.hashes, kind="stable")
        self.sorted_hashes = self.hashes[self.order]

    def shared(self, out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The triangles ``out`` and the input have in common (as vertex sets).

        Parameters
        ----------
        out : (C', 3) int64

        Returns
        -------
        kept : (C',) bool
            Which of ``out`` are input triangles.
        still : (C,) bool
            Which input triangles are in ``out``.
        """
        rows = np.sort(out, axis=1).astype(np.int64, copy=False)
        hashes = row_hashes(rows)
        kept = _rows_found(rows, hashes, self.rows, self.sorted_hashes, self.order)
        order = np.argsort(hashes, kind="stable")
        still = _rows_found(self.rows, self.hashes, rows, hashes[order], order)
        return kept, still


#: Rows :func:`_rows_found` compares at once.
_ROWS_BLOCK = 1 << 16


def _rows_found(
    rows: np.ndarray,
    hashes: np.ndarray,
    other: np.ndarray,
    other_sorted: np.ndarray,
    other_order: np.ndarray,
) -> np.ndarray:
    """(N,) bool: which of ``rows`` ((N, 3), each sorted; ``hashes`` theirs) are rows
    of ``other`` (its hashes ``other_sorted``, in the order ``other_order``).

    Equal rows have equal hashes: a row whose hash one row of ``other`` holds is
    found when it equals that row; a hash several hold (a repeated triangle, or
    two that share a hash) is settled exactly among those (:func:`_rows_in`).
    """
    found = np.zeros(len(rows), dtype=bool)
    n = len(other_sorted)
    if not n or not len(rows):
        return found
    at = np.searchsorted(other_sorted, hashes)
    hit = np.flatnonzero(at < n)
    hit = hit[other_sorted[at[hit]] == hashes[hit]]
    after = np.minimum(at[hit] + 1, n - 1)
    alone = (at[hit] + 1 >= n) | (other_sorted[after] != hashes[hit])
    one = hit[alone]
    for start in range(0, len(one), _ROWS_BLOCK):  # a block's rows gathered at a time
        block = one[start : start + _ROWS_BLOCK]
        found[block] = (rows[block] == other[other_order[at[block]]]).all(axis=1)
    several = hit[~alone]
    if len(several):
        held = other_order[np.isin(other_sorted, hashes[several])]
        found[several] = _rows_in(rows[several], other[held])
    return found


def _member(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """(K,) bool: which of ``keys`` are among ``sorted_keys`` (ascending)."""
    if not len(sorted_keys):
        return np.zeros(len(keys), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[at] == keys


def _rows_among(out: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """:func:`_rows_in` by hashes (:func:`_rows_found`): without sorting both
    sides' rows together, which took some 230 bytes a row."""
    a = np.sort(out, axis=1).astype(np.int64, copy=False)
    b = np.sort(cells, axis=1).astype(np.int64, copy=False)
    hashes = row_hashes(b)
    order = np.argsort(hashes, kind="stable")
    return _rows_found(a, row_hashes(a), b, hashes[order], order)


def _rows_in(out: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(C',) bool: which triangles of ``out`` are triangles of ``cells`` (as vertex sets)."""
    a = np.sort(out, axis=1).astype(np.int64, copy=False)
    b = np.sort(cells, axis=1).astype(np.int64, copy=False)
    both = np.concatenate([b, a])
    order, new = row_groups(both)
    group = np.empty(len(both), dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    in_input = np.zeros(int(group.max()) + 1 if len(group) else 0, dtype=bool)
    in_input[group[: len(b)]] = True
    return in_input[group[len(b) :]]


class TriangleGrid:
    """Distances from points to one triangle mesh, exact up to ``radius`` (the
    compiled ``TriangleGrid``: a uniform grid of buckets, each listing the
    triangles whose bounding box grown by ``radius`` touches it; built once).
    It reads ``vertices`` and ``cells`` where they are (their float64 and int64
    arrays, held), so they must not change while it is used.

    Parameters
    ----------
    vertices : (V, 3) float64
        Finite.
    cells : (C, 3) int64
        Triangles over ``vertices``.
    radius : float
    """

    def __init__(self, vertices: np.ndarray, cells: np.ndarray, radius: float) -> None:
        from .. import _native

        self._grid = _native.TriangleGrid(
            np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(cells, dtype=np.int64).reshape(-1, 3),
            float(radius),
        )

    def distances(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance and nearest triangle of each point.

        Parameters
        ----------
        points : (P, 3) float64

        Returns
        -------
        distance : (P,) float64
            Exact where at most ``radius``; larger means farther than ``radius``
            (``inf`` when no triangle's grown box holds the point).
        nearest : (P,) int64
            The nearest triangle (the first of equals), -1 where ``distance`` is inf.
        """
        points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        distance = np.empty(len(points))
        nearest = np.empty(len(points), dtype=np.int64)
        self._grid.distances(points, kernel_threads(), distance, nearest)
        return distance, nearest

    def certify(
        self,
        vertices: np.ndarray,
        cells: np.ndarray,
        corner_distance: np.ndarray,
        bound: float,
        depth: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Whether each triangle lies within ``bound`` of this mesh (see
        :func:`within_bound`).

        Parameters
        ----------
        vertices : (V, 3) float64
        cells : (C, 3) int64
        corner_distance : (V,) float64
            Each vertex's distance to this mesh (only those ``cells`` use are read).
        bound : float
        depth : int
            Halvings of the edges before a piece counts as failing.

        Returns
        -------
        reach : (C,) float64
            The certified bound, or the largest distance measured where it fails.
        status : (C,) uint8
            0 certified, 1 a point farther than ``bound`` found, 2 not certified
            within ``depth`` halvings.
        """
        cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1, 3)
        reach = np.empty(len(cells))
        status = np.empty(len(cells), dtype=np.uint8)
        self._grid.certify(
            np.ascontiguousarray(vertices, dtype=np.float64),
            cells,
            np.ascontiguousarray(corner_distance, dtype=np.float64),
            float(bound),
            int(depth),
            kernel_threads(),
            reach,
            status,
        )
        return reach, status
