"""An object's octree and its levels cut into the octree's nodes.

Coordinates are index units (sample (i, j, k) at (i, j, k)). The finest nodes are
``chunk`` a side, or the object's box when it is not cut; a level-k node is
``2**k`` finest nodes wide. A level's triangles are cut at the planes of its
nodes' 2x2x2 partition (level 0's at its own nodes' planes), each piece going to
the node holding its centroid, and each node's vertices are quantized in its box
(``top`` = ``2**bits - 1`` steps a side).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from ...mesh import meeting_each

#: ``--fragment-size auto`` (the default): an object of more than ``AUTO_CUT``
#: triangles (some 600 KB of Draco at level 0) is cut into nodes of
#: ``AUTO_FRAGMENT`` voxels a side, so that a viewer loads only the parts it shows
#: and level 0 is made a row of nodes at a time (a label surface has about 3.5
#: triangles per voxel of its area: up to about 100,000 in a 128-voxel node); a
#: smaller one is one fragment a level, which a viewer loads whole anyway (cutting
#: adds triangles where the planes cross it, most at the coarser levels, and makes
#: the layer larger: the 1.5 M-triangle ball of bench/RESULTS.md, 3 levels, 2.5 MB
#: against 1.9 MB).
AUTO_CUT = 1 << 19
AUTO_FRAGMENT = 128.0
#: ... and the side is halved, down to ``AUTO_FINEST``, while one node holds more
#: than ``AUTO_NODE_VERTICES`` of the object's vertices (some 260,000 triangles):
#: a scan's isosurface can put most of itself in one node (the embryo at 60.5:
#: 361,782 of its 488,850 vertices in one 128-voxel node, 81,408 at most in a
#: 64-voxel one), and one node's fragment is encoded at once. Vertices, not
#: triangles: an object handed over in parts (a label's net) gives them without
#: being cut (its quads' corners); the side is not halved past
#: ``AUTO_MOST_NODES`` nodes in the box.
AUTO_NODE_VERTICES = 1 << 17
AUTO_FINEST = 32.0
AUTO_MOST_NODES = 1 << 21


def fragment_size(
    chunk: float | str | None,
    triangles: int,
    densest: Callable[[float], int] | None = None,
) -> float | None:
    """The finest nodes' side of an object of ``triangles`` triangles, None for one
    fragment a level: ``chunk`` itself, or for ``"auto"`` the rule of
    :data:`AUTO_CUT` and :data:`AUTO_NODE_VERTICES`, ``densest(side)`` giving the
    most vertices a node of that side holds (:func:`densest_node`; None: none
    too many); None or infinity: one fragment a level."""
    if isinstance(chunk, str):  # "auto", checked by the layer
        if triangles <= AUTO_CUT:
            return None
        side = AUTO_FRAGMENT
        while side > AUTO_FINEST and densest is not None and densest(side) > AUTO_NODE_VERTICES:
            side /= 2
        return side
    if chunk is None or np.isinf(chunk):
        return None
    return float(chunk)


def densest_node(
    positions: Callable[[], Iterable[np.ndarray]],
    lo: np.ndarray,
    hi: np.ndarray,
    side: float,
    phase: float = 0.0,
) -> int:
    """The most vertices one node ``side`` voxels wide holds, of an object whose
    vertices ``positions()`` gives (index coordinates, each vertex once, (n, 3)
    float64 pieces) in the box ``lo``..``hi``, its nodes as :func:`object_frame`
    places them (all of them when it is not cut); 0 when the box holds more than
    :data:`AUTO_MOST_NODES` of them (the count's table: the side is not halved
    further)."""
    grid_origin, shape, cut = object_frame(lo, hi, side, phase)
    if not cut:
        return sum(len(p) for p in positions())
    nodes = (np.floor((hi - grid_origin) / shape).astype(np.int64) + 1).clip(1)
    if int(np.prod(nodes)) > AUTO_MOST_NODES:
        return 0
    counts = np.zeros(int(np.prod(nodes)), np.int64)
    for p in positions():
        at = np.floor((p - grid_origin) / shape).astype(np.int64).clip(0, nodes - 1)
        counts += np.bincount(np.ravel_multi_index(at.T, nodes), minlength=len(counts))
    return int(counts.max())


@dataclass(frozen=True)
class Octree:
    """One level's nodes: ``origin + index * node`` (index units), the planes of
    their partition every ``split``, the quantization's ``top`` (``2**bits - 1``),
    and the object's box ``lo``..``hi`` (every level's vertices)."""

    origin: np.ndarray
    node: np.ndarray
    split: np.ndarray
    top: float
    lo: np.ndarray
    hi: np.ndarray


def object_frame(
    lo: np.ndarray, hi: np.ndarray, chunk: float | None, phase: float = 0.0
) -> tuple[np.ndarray, np.ndarray, bool]:
    """An object's octree: its grid origin, its finest nodes' shape, and whether
    it is cut (``chunk`` given and the object larger than one node).

    A cut object's grid origin is ``phase`` past a whole index below ``lo``, so that
    with a whole ``chunk`` every plane of the cut lies at that phase of the voxel
    grid: at 0, through the samples, which no triangle of an isosurface crosses
    (each lies in one cell between samples), so level 0 keeps its triangles; at
    0.5, midway, where an unsmoothed surface net's vertices lie.
    """
    # float32 in the manifest: the box is widened so that float32 rounding of its
    # origin and shape cannot leave a vertex outside it
    origin32 = np.nextafter(lo.astype(np.float32), np.float32(-np.inf))
    box32 = np.nextafter(
        np.maximum(hi - origin32.astype(np.float64), 1e-6).astype(np.float32), np.float32(np.inf)
    ).astype(np.float64)
    cut = not (chunk is None or (box32 <= chunk).all())
    if not cut:
        return origin32.astype(np.float64), box32, cut
    aligned = (np.floor(lo - phase) + phase).astype(np.float32)  # exact below 2**23
    low = aligned.astype(np.float64) > lo
    aligned[low] = np.nextafter(aligned[low], np.float32(-np.inf))
    return aligned.astype(np.float64), np.full(3, float(np.float32(chunk))), cut


def level_frame(
    grid_origin: np.ndarray, shape: np.ndarray, k: int, top: float, lo: np.ndarray, hi: np.ndarray
) -> Octree:
    """Level ``k``'s nodes, ``2**k`` finest nodes wide, cut at their halves
    (level 0's at their own planes)."""
    node = shape * 2.0**k
    return Octree(grid_origin, node, node / 2.0 if k else node, top, lo, hi)


def one_node(
    vertices: np.ndarray,
    cells: np.ndarray,
    grid_origin: np.ndarray,
    node: np.ndarray,
    top: float,
    merge: bool = False,
) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    """A level held by its octree's first node (of shape ``node``): its quantized
    vertices and triangles; with ``merge`` (a coarser level), corners that
    quantize to one position made one vertex as a cut level's are
    (:func:`merged_positions`), else every triangle kept (level 0, which keeps
    the mesh's triangle count)."""
    if np.bincount(cells.reshape(-1), minlength=len(vertices)).all():
        # every vertex used (as extracted and decimated meshes are): what
        # np.unique would give, without sorting 3C indices
        used, local = np.arange(len(vertices)), cells
    else:
        used, local = np.unique(cells, return_inverse=True)
    q = np.clip(np.rint((vertices[used] - grid_origin) / node * top), 0, top)
    local = local.reshape(-1, 3)
    if merge:
        q, local = merged_positions(q, local)
    return {(0, 0, 0): (q.astype(np.uint32), local.astype(np.uint32))}


def merged_positions(q: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fragment's corners that quantize to one position made one vertex: the
    triangles between them (no area) go, and so does each pair of triangles left
    over the same three vertices (a fin, where a pinch of the surface folded
    onto itself: the two cancel, and the rest stays closed). On a seam both
    fragments see the same positions, so they merge alike and the seam stays
    closed.

    Parameters
    ----------
    q : (V, 3) float64
        Quantized positions (integers up to 65535).
    corners : (C, 3) int64

    Returns
    -------
    q : (V', 3) int64
        The distinct positions, in np.unique's order.
    corners : (C', 3) int64
    """
    # one key per position, in the order np.unique(q, axis=0) gives, faster
    keys = q.astype(np.int64)
    keys, same = np.unique(keys[:, 0] << 32 | keys[:, 1] << 16 | keys[:, 2], return_inverse=True)
    merged = len(keys) < len(q)
    q = np.stack([keys >> 32, (keys >> 16) & 0xFFFF, keys & 0xFFFF], axis=1)
    corners = same.reshape(-1)[corners.reshape(-1, 3)]
    corners = corners[(corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2])
                      & (corners[:, 0] != corners[:, 2])]  # fmt: skip
    if merged and len(corners):  # a fin needs a merge (most fragments have none)
        ids, axis = np.sort(corners, axis=1), 0
        if len(q) < 1 << 21:  # one int64 key a triangle: far faster than unique(axis=0)
            ids, axis = ids[:, 0] << 42 | ids[:, 1] << 21 | ids[:, 2], None
        _, which, count = np.unique(ids, axis=axis, return_inverse=True, return_counts=True)
        corners = corners[count[which.reshape(-1)] % 2 == 1]  # pairs cancel, in order
    return q, corners


def cut_level(
    vertices: np.ndarray,
    cells: np.ndarray,
    frame: Octree,
    rows: Iterable[tuple[int, int]] | None = None,
) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    """One level's fragments: for each node its quantized vertices and triangles.

    The level is cut one row of nodes (along x, at one y and z) at a time: the
    triangles reaching the row (or within a snapping distance of it) are cut at
    every plane of the partition (:func:`_cut_at_planes`) and the pieces whose
    centroid lies in the row are kept. A triangle is cut the same way in each row
    that takes it (the same planes in the same order, each new vertex from the same
    two ends, the row's vertices and pieces in their order in the level), so the
    rows meet exactly and a node's fragment is the same whichever triangles besides
    it a row is given; the peak holds one row's pieces, not the whole level's (an
    object of 1.5 million triangles in 128-voxel fragments within ``--max-memory
    256M``, see bench/RESULTS.md: 324 MB cut a z-layer of nodes at a time, 208 MB
    a row at a time).

    Parameters
    ----------
    vertices : (V, 3) float64
        Index coordinates.
    cells : (C, 3) int64
    frame : Octree
    rows : iterable of (int, int) or None
        The rows of nodes to make, each its (y, z) position, z-ordered
        (``vertices`` and ``cells`` then need hold only the triangles that reach
        them, in the level's order, their vertices in theirs:
        :func:`.tasks.encode_rows`); None: every row of the object
        (:func:`node_rows`).
    """
    level: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
    for row in cut_rows(vertices, cells, frame, rows):
        level.update(row)
    return level


def cut_rows(
    vertices: np.ndarray,
    cells: np.ndarray,
    frame: Octree,
    rows: Iterable[tuple[int, int]] | None = None,
) -> Iterator[dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]]:
    """:func:`cut_level`'s fragments a row of nodes at a time, as each is cut (a
    row no piece lies in gives nothing): encoded as they come, a level's peak holds
    one run of a row's nodes' pieces (:func:`_row_runs`) and the rows encoded
    before it."""
    rows = node_rows(frame) if rows is None else list(rows)
    y_range = triangle_extents(vertices, cells, 1)
    z_range = triangle_extents(vertices, cells, 2)
    # the triangles reaching each row, those reaching its z-layer found once
    reaching = meeting_each(z_range, y_range, *row_spans(frame, rows))
    for (y, z), taken in zip(rows, reaching, strict=True):
        row: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        for run, part in _row_runs(vertices, cells, taken, frame):
            row.update(_cut_nodes(vertices, cells, frame, part, run, (y, z)))
        if row:  # else the row's triangles are all in the rows beside it
            yield row


#: Triangles up to which a row's neighbouring nodes (along x) are cut together
#: (:func:`_row_runs`): cutting holds about 100 bytes a triangle it is given, and
#: a row can hold most of an object (a 256^3 scan's isosurface, the embryo at
#: 60.5, in 128-voxel nodes: 837,354 of its 961,024 triangles reach one row).
RUN_TRIANGLES = 1 << 16


def _row_runs(
    vertices: np.ndarray, cells: np.ndarray, taken: np.ndarray, frame: Octree
) -> list[tuple[tuple[int | None, int | None], np.ndarray]]:
    """A row's triangles ``taken`` split into runs of neighbouring nodes along x,
    each reached by about :data:`RUN_TRIANGLES` of them at most (a node reached by
    more is a run alone): each run's first and last node (None: unbounded on that
    side) and the triangles reaching it or within a snapping distance of it,
    increasing. How a row is split changes no fragment (:func:`_cut_nodes`)."""
    if len(taken) <= RUN_TRIANGLES:
        return [((None, None), taken)] if len(taken) else []
    low, high = triangle_extents(vertices, cells[taken], 0)
    reach = frame.node[0] / frame.top
    span = np.floor((np.stack([frame.lo[0], frame.hi[0]]) - frame.origin[0]) / frame.node[0])
    first, last = max(int(span[0]), 0), max(int(span[1]), 0)
    nodes = last - first + 1
    # how many triangles reach each node (one reaching two counts in both)
    ends = np.floor((np.stack([low - reach, high + reach]) - frame.origin[0]) / frame.node[0])
    ends = np.clip(ends, first, last).astype(np.int64) - first
    count = np.cumsum(np.bincount(ends[0], minlength=nodes))
    count[1:] -= np.cumsum(np.bincount(ends[1], minlength=nodes))[:-1]
    del ends
    bounds, held = [0], 0
    for n in range(nodes):
        if n > bounds[-1] and held + count[n] > RUN_TRIANGLES:
            bounds.append(n)
            held = 0
        held += count[n]
    runs = []
    for a, b in zip(bounds, [*bounds[1:], nodes], strict=True):
        # the first run unbounded below, the last above (every piece is in one)
        near = np.ones(len(taken), dtype=bool)
        if a > 0:
            near &= high >= frame.origin[0] + (first + a) * frame.node[0] - reach
        if b < nodes:
            near &= low <= frame.origin[0] + (first + b) * frame.node[0] + reach
        run = (first + a if a > 0 else None, first + b - 1 if b < nodes else None)
        runs.append((run, taken[near]))
    return runs


def _cut_nodes(
    vertices: np.ndarray,
    cells: np.ndarray,
    frame: Octree,
    taken: np.ndarray,
    run: tuple[int | None, int | None],
    row: tuple[int, int],
) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    """The fragments of a row's nodes ``run`` (its first and last along x, None:
    unbounded) at ``row`` = (y, z), from the triangles ``taken`` that reach them:
    cut at every plane, each piece in the node of its centroid. A triangle is cut
    the same way whichever others it is given with (each plane's cut keeps the
    triangles' order and makes each edge's vertex from its ends in index order),
    so a node's fragment does not depend on the run or row it is made in."""
    # the vertices in their order in the level (so that each cut takes an edge's
    # ends in the same order in every row)
    used, local = _compact(cells[taken], len(vertices))
    part, pieces = _cut_at_planes(vertices[used], local, frame)
    del used, local
    # each piece's node: its centroid's, ((a + b) + c) / 3 as a mean over the
    # corners adds, an axis at a time
    where = np.empty((len(pieces), 3), dtype=np.int64)
    for axis in range(3):
        x = part[:, axis]
        centroid = (x[pieces[:, 0]] + x[pieces[:, 1]] + x[pieces[:, 2]]) / 3.0
        centroid -= frame.origin[axis]
        centroid /= frame.node[axis]
        where[:, axis] = np.maximum(np.floor(centroid), 0)
    del centroid
    mine = (where[:, 1] == row[0]) & (where[:, 2] == row[1])
    if run[0] is not None:
        mine &= where[:, 0] >= run[0]
    if run[1] is not None:
        mine &= where[:, 0] <= run[1]
    if not mine.any():
        return {}
    x, pieces = where[mine, 0], pieces[mine]
    del where, mine
    # the nodes along x, each's pieces in their order (the row's y and z are one)
    order = np.argsort(x, kind="stable")
    x, pieces = x[order], pieces[order]
    del order
    nodes = {}
    starts = np.flatnonzero(np.r_[True, x[1:] != x[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(pieces)], strict=True):
        kept, corners = _compact(pieces[a:b], len(part))
        position = (int(x[a]), *row)
        origin = frame.origin + np.array(position) * frame.node
        q = np.clip(np.rint((part[kept] - origin) / frame.node * frame.top), 0, frame.top)
        # corners within a step of each other share a quantized position: one
        # vertex (the same on both sides of a seam), the triangles between them
        # gone (Draco's edgebreaker, 5-7x smaller than its sequential encoding,
        # would drop them anyway)
        q, corners = merged_positions(q, corners)
        nodes[position] = (q.astype(np.uint32), corners.astype(np.uint32))
    return nodes


def _compact(cells: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertices (of ``n``) that triangles ``cells`` use, increasing, and the
    triangles over them: ``np.unique(cells, return_inverse=True)``, by a table of
    ``n`` entries rather than a sort of every corner where that holds less."""
    if n > 8 * len(cells):  # the table would hold more than the sort
        used, local = np.unique(cells, return_inverse=True)
        return used, local.reshape(-1, 3)
    mask = np.zeros(n, dtype=bool)
    mask[cells.reshape(-1)] = True
    used = np.flatnonzero(mask)
    table = np.cumsum(mask) - 1
    del mask
    return used, table[cells]


def node_rows(frame: Octree) -> list[tuple[int, int]]:
    """The rows of nodes (along x) an object's box reaches, each its (y, z)
    position, z-layer by z-layer."""
    span = np.floor((np.stack([frame.lo, frame.hi]) - frame.origin) / frame.node).astype(int)
    first = np.maximum(span[0], 0)
    return [
        (y, z) for z in range(first[2], span[1, 2] + 1) for y in range(first[1], span[1, 1] + 1)
    ]


def row_spans(frame: Octree, rows: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`row_span` of each of ``rows``: their lows and highs, (R, 3) each."""
    lows, highs = zip(*(row_span(frame, row) for row in rows), strict=True)
    return np.array(lows), np.array(highs)


def row_span(frame: Octree, row: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The box whose triangles a row of nodes at ``row`` = (y, z) takes: the row,
    and a snapping distance (a quantization step) beyond it each way; (3,) each,
    unbounded in x."""
    y, z = row
    start = frame.origin + np.array([0.0, y, z]) * frame.node
    reach = frame.node / frame.top
    low, high = start - reach, start + frame.node + reach
    low[0], high[0] = -np.inf, np.inf
    return low, high


def _cut_at_planes(
    vertices: np.ndarray, cells: np.ndarray, frame: Octree
) -> tuple[np.ndarray, np.ndarray]:
    """Cut triangles at every plane of the partition inside the object's box, x
    planes first, each axis's in increasing order (:func:`_cut`).

    Parameters
    ----------
    vertices : (V, 3) float64
        Changed in place (the snapping, see below).
    cells : (C, 3) int64
    frame : Octree

    Returns
    -------
    vertices : (V', 3) float64
    cells : (C', 3) int64
    """
    # the sides of each plane are taken from the snapped positions, but each cut's
    # new vertex from where its edge crosses the plane as extracted: snapped ends
    # would put it up to half a step off the surface, which rounding could double
    exact = vertices.copy()
    for axis in range(3):
        step = frame.split[axis]
        first = int(np.floor((frame.lo[axis] - frame.origin[axis]) / step)) + 1
        last = int(np.ceil((frame.hi[axis] - frame.origin[axis]) / step)) - 1
        low, high = triangle_extents(vertices, cells, axis)
        for m in range(max(first, 1), last + 1):
            plane = frame.origin[axis] + m * step
            # vertices within half a quantization step of the plane go onto it
            # first (igneous snaps too), where quantizing puts them anyway: cut
            # there, they would leave slivers whose corners quantize to one position
            near = np.abs(vertices[:, axis] - plane) <= 0.5 * frame.node[axis] / frame.top
            vertices[near, axis] = plane
            # snapping moves a vertex towards this plane only from within half a
            # step, never across another: the extents before it still hold every
            # triangle that crosses the plane
            maybe = np.flatnonzero((low < plane) & (high > plane))
            if not len(maybe):
                continue
            count = len(cells)
            vertices, exact, cells, kept = _cut(vertices, exact, cells, axis, plane, maybe)
            if len(kept) != count:  # cut: the pieces' extents after the others'
                pieces = cells[len(kept) :]
                new_low, new_high = triangle_extents(vertices, pieces, axis)
                low = np.concatenate([low[kept], new_low])
                high = np.concatenate([high[kept], new_high])
    return vertices, cells


def triangle_extents(
    vertices: np.ndarray, cells: np.ndarray, axis: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's lowest and highest coordinate along ``axis``: (C,) each."""
    x = vertices[:, axis]
    a, b, c = x[cells[:, 0]], x[cells[:, 1]], x[cells[:, 2]]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def _cut(
    vertices: np.ndarray,
    exact: np.ndarray,
    cells: np.ndarray,
    axis: int,
    plane: float,
    maybe: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split the triangles that cross the plane ``x[axis] = plane`` (strictly) so
    that none does, keeping orientation.

    Each crossing edge gets one new vertex exactly on the plane, computed from its
    ends' ``exact`` positions in increasing index order, so the two triangles beside
    it share it and the surface stays closed. A triangle with a corner on the plane
    becomes two, any other crossing one three.

    Parameters
    ----------
    vertices : (V, 3) float64
        The positions whose sides of the plane count (snapped).
    exact : (V, 3) float64
        The positions the new vertices are interpolated between (not snapped).
    cells : (C, 3) int64
    maybe : (M,) int64
        The triangles that may cross it (every other one is left as it is).

    Returns
    -------
    vertices, exact : (V + N, 3) float64
    cells : (C', 3) int64
        The triangles that do not cross, in their order, then the pieces.
    kept : (K,) int64
        Where the triangles that do not cross were in ``cells``.
    """
    side = np.sign(vertices[cells[maybe], axis] - plane).astype(np.int8)  # (M, 3)
    through = (side.min(axis=1) < 0) & (side.max(axis=1) > 0)
    if not through.any():
        return vertices, exact, cells, np.arange(len(cells))
    crossing = np.zeros(len(cells), bool)
    crossing[maybe[through]] = True
    tri, s = cells[crossing], side[through]
    # rotate each so that corner 0 is the one alone: on the plane, or on its own side
    zero = s == 0
    lone = np.where(zero.any(axis=1), np.argmax(zero, axis=1), 0)
    alone = ~zero.any(axis=1)
    for j in range(3):  # no corner on the plane: the one whose side the others share not
        others = [(j + 1) % 3, (j + 2) % 3]
        pick = alone & (s[:, others[0]] == s[:, others[1]]) & (s[:, j] != s[:, others[0]])
        lone[pick] = j
    rows = np.arange(len(tri))[:, None]
    tri = tri[rows, (lone[:, None] + np.arange(3)) % 3]
    s = s[rows, (lone[:, None] + np.arange(3)) % 3]
    # the new vertices, one per crossing edge
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    signs = np.concatenate([s[:, [0, 1]], s[:, [1, 2]], s[:, [2, 0]]])
    cut = signs[:, 0] * signs[:, 1] < 0
    pairs = np.sort(edges[cut], axis=1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    u, w = exact[unique[:, 0]], exact[unique[:, 1]]
    t = (plane - u[:, axis]) / (w[:, axis] - u[:, axis])
    new = u + t[:, None] * (w - u)
    new[:, axis] = plane
    index = np.full(len(edges), -1, np.int64)
    index[np.flatnonzero(cut)] = len(vertices) + inverse.reshape(-1)
    n = len(tri)
    m01, m12, m20 = index[:n], index[n : 2 * n], index[2 * n :]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    on = s[:, 0] == 0
    # a corner on the plane: (a, b, m12) and (a, m12, c)
    two = np.concatenate([np.stack([a, b, m12], 1)[on], np.stack([a, m12, c], 1)[on]])
    # a alone on its side: (a, m01, m20), (m01, b, c), (m01, c, m20)
    off = ~on
    three = np.concatenate(
        [
            np.stack([a, m01, m20], 1)[off],
            np.stack([m01, b, c], 1)[off],
            np.stack([m01, c, m20], 1)[off],
        ]
    )
    kept = np.flatnonzero(~crossing)
    pieces = np.vstack([cells[kept], two, three])
    return np.vstack([vertices, new]), np.vstack([exact, new]), pieces, kept
