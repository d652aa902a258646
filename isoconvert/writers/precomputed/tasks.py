"""A layer's objects as tasks of arrays and scalars, which a cluster's workers can
run: an object whole (:func:`encode_object`), a row of its level-0 fragments
(:func:`encode_rows`), its level 0 as one node (:func:`encode_node`), or a z-slab of
a large object collapsed for its coarser levels (:func:`collapse_slab`), and the
plans that put their results together (:func:`object_tasks`, :class:`Rows`).
"""

from __future__ import annotations

import contextlib
import errno
import functools
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...atomic import DISK_FULL_ERRNOS, disk_full_error
from ...errors import IsoconvertError, OutputError
from ...memory import release_freed_memory
from ...mesh import Mesh, MeshParts, meeting_counts, meeting_each, outward_float32, slab_split
from .fragments import (
    assemble,
    dracopy,
    encode_levels,
    encoded,
    encoded_level,
    levels_go_on,
)
from .octree import (
    Octree,
    cut_level,
    densest_node,
    fragment_size,
    level_frame,
    node_rows,
    object_frame,
    one_node,
    row_span,
    row_spans,
    triangle_extents,
)

#: ``collapse(mesh, bound, locked)``: the triangles of ``mesh`` (index coordinates)
#: collapsed to within ``bound`` of it both ways, over its vertices, ``locked``
#: ((V,) bool or None) kept where they are (:func:`isoconvert.post.decimate.collapse`).
Collapse = Callable[[Mesh, float, np.ndarray | None], np.ndarray]

#: ``map_objects(function, tasks)``: ``function(*args)`` for each ``(what, args,
#: kept)`` of ``tasks`` (``what`` names the task in errors), the results in order. A
#: :class:`Preceding` argument stands for the results of earlier tasks, each
#: ``kept``: those are the later task's alone (on a cluster they go from worker to
#: worker), and the map may give None in their place.
ObjectMap = Callable[[Callable[..., tuple], Iterable[tuple[str, tuple, bool]]], Iterable]

#: Triangles of an object above which its coarser levels are collapsed in z-slabs
#: of about :data:`SLAB_TRIANGLES` each (:func:`_coarse_levels`), not whole: the
#: bounded collapse holds about 290 bytes a triangle of its input.
LARGE_OBJECT = 1 << 19
SLAB_TRIANGLES = 1 << 18

#: Triangles up to which neighbouring rows of an object's level-0 nodes (one z, y
#: after y) are one task (:func:`encode_rows`) on a cluster, where each task costs
#: its round trips whatever its size (Dask's advice: tasks of 100 ms or more; a
#: row of the 1.5 M-triangle ball in 64-voxel fragments takes about 35 ms, see
#: bench/RESULTS.md); made here, each row is its own, which holds the least.
ROW_TRIANGLES = 1 << 17


@dataclass(frozen=True)
class Preceding:
    """An argument of a layer's task (see :data:`ObjectMap`): the results of
    ``count`` earlier tasks, as a list: those ending ``skip`` tasks before it."""

    count: int
    skip: int = 0


@dataclass(frozen=True)
class Rows:
    """An object made a row of level-0 nodes (along x) at a time: its octree, how
    many tasks its rows are (:func:`row_tasks`), and, with coarser levels, its
    slabs' count and what makes the levels from their collapses
    (:func:`_coarse_fragments`). Made here, the tasks' results are put together
    here; ``elsewhere`` (a cluster), the coarser levels
    are one more task, given the slabs' results, and a last task
    (:func:`assemble_object`), given the rows' and that one's, writes the object
    as an object's task does, so that only its manifest comes back."""

    shape: np.ndarray
    grid_origin: np.ndarray
    rows: int
    slabs: int = 0
    coarse: Callable[[list[tuple]], list[dict]] | None = None
    elsewhere: bool = False

    @property
    def kept(self) -> int:
        """Its tasks before the last, ``elsewhere``: the rows', the slabs' and the
        coarser levels' (whose results go to the last)."""
        return self.rows + self.slabs + (self.coarse is not None)


def object_tasks(
    meshes: Mapping[int, Mesh],
    parts: Callable[[int], MeshParts] | None,
    plans: deque,
    origin: np.ndarray,
    inverse: np.ndarray,
    lods: int,
    bits: int,
    chunk: float | str | None,
    collapse: Collapse | None,
    elsewhere: bool = False,
    phase: float = 0.0,
) -> Iterator[tuple[int, str, Callable, tuple]]:
    """Each object's tasks, ``(segment, what, encode, args)``, an object at a time,
    its plan put in ``plans`` before them: ``(segment, None)`` for one
    :func:`encode_object` task (its whole mesh), or ``(segment, Rows)`` for an
    object given in parts that is cut into fragments with one level, or for one
    large (:data:`LARGE_OBJECT` triangles) with more, given in parts or whole
    (:class:`_WholeParts`): level 0 is one :func:`encode_rows` task per few
    neighbouring rows of nodes (along x) that triangles reach (:func:`row_tasks`),
    each made of the triangles that reach them, so that no object's whole mesh is
    built (the same bytes, as :func:`cut_level` makes each row from those
    triangles alone), or, held by one
    node, one :func:`encode_node` task; then a large one's coarser levels are one
    :func:`collapse_slab` task per z-slab of it (:func:`_coarse_levels`); with
    ``elsewhere``, one task more makes them from the slabs' results, and one
    :func:`assemble_object` task puts the object together (:class:`Preceding`
    arguments; else the results are put together where they come). ``phase``
    places the cut planes in the voxel grid (:func:`.octree.object_frame`)."""
    top = float(2**bits - 1)

    def to_index(world: np.ndarray) -> np.ndarray:
        return index_of(world, origin, inverse)

    for key in meshes:  # a mapping that builds each mesh when asked for is asked once
        segment = int(key)
        mesh = pieces = None
        if parts is not None:
            pieces = parts(segment)
        else:
            mesh = meshes[key]
            check_mesh(segment, mesh)
            if lods > 1 and len(mesh.cells) > LARGE_OBJECT:  # coarser levels from slabs too
                pieces = _WholeParts(mesh)
        triangles = pieces.n_cells if pieces is not None else len(mesh.cells)
        size = fragment_size(chunk, triangles, _densest(pieces, mesh, to_index, phase))
        large = pieces is not None and lods > 1 and triangles > LARGE_OBJECT
        if pieces is not None and (size is not None or large):
            lo, hi = pieces.extent(to_index)
            grid_origin, shape, cut = object_frame(lo, hi, size, phase)
            if large or (cut and lods == 1):
                frame = level_frame(grid_origin, shape, 0, top, lo, hi)
                most = ROW_TRIANGLES if elsewhere else 0
                rows = row_tasks(pieces, to_index, frame, most) if cut else [[]]
                plan = Rows(shape, grid_origin, len(rows))
                if large:  # and its slabs, collapsed for its coarser levels
                    octree = (grid_origin, shape, top, lo, hi, cut)
                    # the sizes as planned here, wherever the levels are made
                    sizes = (LARGE_OBJECT, SLAB_TRIANGLES, triangles)
                    coarse = functools.partial(
                        _coarse_fragments, lods, collapse, octree, bits, sizes
                    )
                    slabs = -(-pieces.n_cells // SLAB_TRIANGLES)
                    plan = replace(plan, slabs=slabs, coarse=coarse)
                plan = replace(plan, elsewhere=elsewhere)
                plans.append((segment, plan))
                if not cut:  # level 0 is one fragment: the whole mesh
                    whole = pieces.whole()
                    args = (whole.vertices, whole.cells, origin, inverse, grid_origin, shape, bits)
                    del whole
                    yield segment, f"object {segment}, level 0", encode_node, args
                for task in rows if cut else ():
                    low, high = row_span(frame, task[0])[0], row_span(frame, task[-1])[1]
                    part = pieces.reaching(to_index, low, high)
                    args = (part.vertices, part.cells, origin, inverse, frame, task, bits)
                    (y, z), last = task[0], task[-1][0]
                    ys = f"s y {y}-{last}" if last > y else f" y {y}"
                    what = f"object {segment}, row{ys} z {z} of fragments"
                    yield segment, what, encode_rows, args
                for n, (slab, used, shared) in enumerate(pieces.slabs(to_index, plan.slabs)):
                    args = (slab.vertices, slab.cells, used, shared, origin, inverse, collapse)
                    yield segment, f"object {segment}, slab {n} of its levels", collapse_slab, args
                if plan.elsewhere:
                    coarser = None
                    if plan.coarse is not None:
                        what = f"object {segment}, its coarser levels"
                        yield segment, what, plan.coarse, (Preceding(plan.slabs),)
                        coarser = Preceding(1)
                    after = plan.kept - plan.rows  # the slabs' and the coarser levels'
                    args = (Preceding(plan.rows, after), coarser, plan.shape, plan.grid_origin)
                    yield segment, f"object {segment}", assemble_object, args
                continue
        if mesh is None:
            mesh = pieces.whole()
            check_mesh(segment, mesh)
        plans.append((segment, None))
        args = (mesh.vertices, mesh.cells, origin, inverse, lods, bits, size, collapse, phase)
        yield segment, f"object {segment}", encode_object, args


def _densest(
    pieces: MeshParts | None, mesh: Mesh | None, to_index: Callable, phase: float
) -> Callable[[float], int]:
    """For :func:`.octree.fragment_size`: the most vertices a node of a side holds,
    of an object given in ``pieces`` or whole (a mesh given whole and as
    :class:`_WholeParts` counts alike)."""
    if pieces is not None:
        return lambda side: densest_node(
            lambda: pieces.vertex_positions(to_index), *pieces.extent(to_index), side, phase
        )

    @functools.cache  # asked only of an object the rule would cut
    def index() -> np.ndarray:
        return to_index(np.asarray(mesh.vertices, dtype=np.float64))

    def densest(side: float) -> int:
        return densest_node(lambda: [index()], index().min(0), index().max(0), side, phase)

    return densest


def row_tasks(
    pieces: MeshParts, to_index: Callable, frame: Octree, most: int
) -> list[list[tuple[int, int]]]:
    """An object's level-0 rows of nodes (:func:`node_rows`) as tasks: the rows
    no triangle reaches left out, and each run of neighbouring rows of one z-layer
    (y after y) one task while the triangles reaching them (counted per row:
    :meth:`~isoconvert.mesh.MeshParts.reaching_counts`) add up to at most
    ``most`` (:data:`ROW_TRIANGLES` on a cluster; 0: a row a task), a row more
    when one row alone passes it."""
    rows = node_rows(frame)
    lows, highs = row_spans(frame, rows)
    tasks: list[list[tuple[int, int]]] = []
    held = 0
    for row, count in zip(rows, pieces.reaching_counts(to_index, lows, highs), strict=True):
        if not count:
            continue
        if tasks and tasks[-1][-1][1] == row[1] and held + count <= most:
            tasks[-1].append(row)
            held += count
        else:
            tasks.append([row])
            held = count
    return tasks


class _WholeParts:
    """An object given whole as :class:`~isoconvert.mesh.MeshParts` (a large
    isosurface, a post-processed label), so that its coarser levels come from
    slabs as a label's do: each triangle's slab by its lowest corner."""

    #: Vertices converted at once.
    PIECE = 1 << 18

    def __init__(self, mesh: Mesh) -> None:
        self._mesh = mesh
        self._cells = np.asarray(mesh.cells, dtype=np.int64)
        self._low = self._high = self._box = self._y = None

    @property
    def n_cells(self) -> int:
        return len(self._cells)

    def _extents(self, to_index: Callable) -> None:
        if self._low is None:
            index = to_index(np.asarray(self._mesh.vertices, dtype=np.float64))
            self._box = index.min(axis=0), index.max(axis=0)
            self._low, self._high = triangle_extents(index, self._cells, 2)
            self._y = outward_float32(*triangle_extents(index, self._cells, 1))
            del index
            release_freed_memory()  # the temporaries', before the rows are cut

    def extent(self, to_index: Callable) -> tuple[np.ndarray, np.ndarray]:
        self._extents(to_index)
        return self._box

    def reaching(self, to_index: Callable, low: np.ndarray, high: np.ndarray) -> Mesh:
        self._extents(to_index)
        (taken,) = meeting_each((self._low, self._high), self._y, low[None], high[None])
        return self._part(taken)[0]

    def reaching_counts(
        self, to_index: Callable, lows: np.ndarray, highs: np.ndarray
    ) -> np.ndarray:
        self._extents(to_index)
        return meeting_counts((self._low, self._high), self._y, lows, highs)

    def vertex_positions(self, to_index: Callable) -> Iterator[np.ndarray]:
        vertices = np.asarray(self._mesh.vertices, dtype=np.float64)
        for start in range(0, len(vertices), self.PIECE):
            yield to_index(vertices[start : start + self.PIECE])

    def slabs(
        self, to_index: Callable, count: int
    ) -> Iterator[tuple[Mesh, np.ndarray, np.ndarray]]:
        self._extents(to_index)
        order, ends, shared, base = slab_split(self._low, self._cells, count)
        # the slabs come after the rows: the ranges that found the rows' triangles go
        self._low = self._high = self._y = None
        for n in range(count):
            mesh, used = self._part(order[ends[n] : ends[n + 1]])
            yield mesh, used, shared[used - base]

    def _part(self, taken: np.ndarray) -> tuple[Mesh, np.ndarray]:
        """The triangles ``taken`` selects, over the vertices they use, in order."""
        used, local = np.unique(self._cells[taken], return_inverse=True)
        return Mesh(np.asarray(self._mesh.vertices)[used], local.reshape(-1, 3)), used

    def whole(self) -> Mesh:
        return self._mesh


def check_mesh(segment: int, mesh: Mesh) -> None:
    cells = np.asarray(mesh.cells)
    vertices = np.asarray(mesh.vertices)
    if cells.ndim != 2 or cells.shape[1] != 3 or not len(cells):
        raise IsoconvertError(f"precomputed: segment {segment} has no triangles")
    if cells.min() < 0 or cells.max() >= len(vertices):
        raise IsoconvertError(f"precomputed: a triangle of segment {segment} refers to no vertex")
    if not np.isfinite(vertices).all():
        raise IsoconvertError(f"precomputed: segment {segment} has non-finite vertices")


def encode_object(
    vertices: np.ndarray,
    cells: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    lods: int,
    bits: int,
    chunk: float | None,
    collapse: Collapse | None,
    phase: float = 0.0,
) -> tuple[bytes, bytes]:
    """One object's manifest and fragment data: its levels of detail (the coarser
    ones by ``collapse``), cut and Draco-encoded (:func:`encode_levels`). A module-level
    function of arrays and scalars, so that a cluster's worker can run it.

    Parameters
    ----------
    vertices : (V, 3) float64
        World positions.
    cells : (C, 3) int64
    origin : (3,) float64
    inverse : (3, 3) float64
        The grid's origin and the inverse of its affine: index = inverse @ (world - origin).
    lods, bits, chunk, collapse, phase
        As :func:`.layer.write_precomputed`.
    """
    full = Mesh(index_of(vertices, origin, inverse), np.asarray(cells, dtype=np.int64))
    levels = [full]
    side = float(np.ptp(full.vertices, axis=0).max())
    for k in range(1, lods):
        if not coarser_level_fits(k, side):
            break
        level = _collapsed(full, float(2 ** (k - 1)), collapse)
        if len(level.cells) >= len(levels[-1].cells):
            break
        levels.append(level)
    return encode_levels(levels, bits, dracopy(), chunk, phase)


def coarser_level_fits(k: int, side: float) -> bool:
    """Whether an object ``side`` voxels long at most (its box's longest side)
    gets a level ``k``: its bound, ``2**(k - 1)`` voxels, shorter than the object
    (a level allowed farther could be a point; its fragment's quantization step,
    the box of the object at level k, ``2**k`` times, over ``2**bits - 1``, passes
    the object from level 10 on at 10 bits). An object's levels also stop at one
    with no fewer triangles than the level before (a collapse that cannot go
    further within its bound): Neuroglancer reads each object's own count of
    levels from its manifest."""
    return 2.0 ** (k - 1) < side


def encode_rows(
    vertices: np.ndarray,
    cells: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    frame: Octree,
    rows: list[tuple[int, int]],
    bits: int,
) -> dict[tuple[int, int, int], bytes]:
    """Rows of nodes (along x) of an object's level 0, cut (:func:`cut_level`) and
    Draco-encoded: a task of arrays and scalars, which a cluster's worker can run.

    Parameters
    ----------
    vertices : (V, 3) float64
        World positions of the triangles that reach the rows (and their snapping
        distance), in the object's order, over its vertices in theirs.
    cells : (C, 3) int64
    origin, inverse
        As :func:`encode_object`.
    frame : Octree
        The object's level 0.
    rows : list of (int, int)
        Their (y, z) positions, of one z-layer, y increasing (:func:`row_tasks`).
    bits : int

    Returns
    -------
    dict
        Each node's position and its Draco fragment.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    level = cut_level(index_of(vertices, origin, inverse), cells, frame, rows)
    return encoded(level, bits, dracopy())


def encode_node(
    vertices: np.ndarray,
    cells: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    grid_origin: np.ndarray,
    shape: np.ndarray,
    bits: int,
) -> dict[tuple[int, int, int], bytes]:
    """Level 0 of an object held by one node (its box, ``grid_origin`` and
    ``shape``), Draco-encoded: a task of arrays and scalars, as :func:`encode_rows`.
    ``vertices`` are world positions, the rest as :func:`encode_object`'s."""
    index = index_of(vertices, origin, inverse)
    level = one_node(index, np.asarray(cells, np.int64), grid_origin, shape, float(2**bits - 1))
    return encoded(level, bits, dracopy())


def assemble_object(
    rows: list[dict[tuple[int, int, int], bytes]],
    coarser: list[list[dict[tuple[int, int, int], bytes]]] | None,
    shape: np.ndarray,
    grid_origin: np.ndarray,
) -> tuple[bytes, bytes]:
    """An object made in rows, put together: its manifest and fragment data, as
    :func:`encode_object` gives them (:func:`write_object` writes the data).

    Parameters
    ----------
    rows : list of dict
        Its rows' (or its one node's) level-0 fragments by node position.
    coarser : list or None
        One result of :func:`_coarse_fragments` (its coarser levels' fragments, a
        dict a level), or None for one level.
    shape : (3,) float64
    grid_origin : (3,) float64
        Its octree's finest nodes and their grid origin.
    """
    level: dict = {}
    for fragments in rows:
        level.update(fragments)
    return assemble([level, *(coarser[0] if coarser else [])], shape, grid_origin)


def collapse_slab(
    vertices: np.ndarray,
    cells: np.ndarray,
    used: np.ndarray,
    shared: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    collapse: Collapse,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One z-slab of a large object collapsed within half a unit, the first step
    of its coarser levels (:func:`_coarse_levels`): a task of arrays and a
    function, which a cluster's worker can run. The vertices it shares with other
    slabs, and their neighbours, stay where they are.

    Parameters
    ----------
    vertices : (V, 3) float64
        The slab's world positions.
    cells : (C, 3) int64
    used : (V,) int64
        Its vertices' ids in the object (:meth:`~isoconvert.mesh.MeshParts.slabs`).
    shared : (V,) bool
        Which of them other slabs use too.
    origin, inverse
        As :func:`encode_object`.
    collapse : callable

    Returns
    -------
    ids : (K,) int64
        The ids of the vertices the collapse left.
    positions : (K, 3) float64
        Their index coordinates.
    cells : (C', 3) int64
        The collapsed triangles, over the vertices' ids.
    """
    index = index_of(vertices, origin, inverse)
    local = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    if not len(local):
        return used[:0], index[:0], local
    out = _collapsed_between(Mesh(index, local), shared, 0.5, collapse)
    release_freed_memory()  # the collapse's, before the next slab's (its own maps)
    still = np.unique(out)
    return used[still], index[still], used[out]


def _collapsed_between(mesh: Mesh, shared: np.ndarray, bound: float, collapse: Collapse):
    """A slab's triangles collapsed within ``bound``, over its vertices: those it
    shares with other slabs (``shared``, (V,) bool), and their neighbours, kept
    where they are, so that the slabs still meet and no two collapses, one on
    either side, join the same two shared vertices."""
    near = shared[mesh.cells].any(axis=1)
    kept = shared.copy()
    kept[mesh.cells[near].reshape(-1)] = True
    return collapse(mesh, bound, kept)


def _coarse_fragments(
    lods: int,
    collapse: Collapse,
    octree: tuple,
    bits: int,
    sizes: tuple[int, int, int],
    slabs: list[tuple],
) -> list[dict[tuple[int, int, int], bytes]]:
    """A large object's coarser levels from its slabs' collapses
    (:func:`_coarse_levels`, ``sizes`` its :data:`LARGE_OBJECT`,
    :data:`SLAB_TRIANGLES` and level 0's triangles), cut and encoded (``octree``:
    its grid origin, finest nodes' shape, ``top``, box, and whether it is cut: else
    each level is one fragment), as many as :func:`coarser_level_fits` allows."""
    levels = []
    previous = None  # the level before's triangles, as cut
    lo, hi = octree[3], octree[4]
    upto = next(
        (k for k in range(1, lods) if not coarser_level_fits(k, float(np.max(hi - lo)))), lods
    )
    for k, mesh in enumerate(_coarse_levels(slabs, upto, collapse, sizes[:2]), start=1):
        if k == 1 and len(mesh.cells) >= sizes[2]:  # level 0's (its rows are cut elsewhere)
            break
        level, triangles = encoded_level(mesh.vertices, mesh.cells, k, octree, bits, dracopy())
        if not levels_go_on(triangles, previous):
            break
        previous = triangles
        levels.append(level)
        del mesh, level  # before the next level is made
        release_freed_memory()
    return levels


def _coarse_levels(
    slabs: list[tuple], lods: int, collapse: Collapse, sizes: tuple[int, int]
) -> Iterator[Mesh]:
    """Levels 1 to ``lods - 1`` of a large object (index coordinates), never
    collapsing its whole mesh: level 1 is collapsed in z-slabs of about
    :data:`SLAB_TRIANGLES` triangles each, within half its bound of its slab
    (:func:`collapse_slab`: ``slabs`` are their results, a list emptied once their
    union is made, so that they are not held beside it; the vertices a slab shares
    with others, and their neighbours, kept, so that the slabs still meet and no
    two collapses join the same two shared vertices); then level k is the slabs'
    union collapsed within the rest of its bound, ``2**(k - 1) - 0.5``
    (:func:`_collapsed_in_slabs`: whole, or in z-slabs again while it is large).
    The bounds add: level k lies within ``2**(k - 1)`` of level 0 both ways, as a
    whole collapse's would. The union is mostly a fraction of the object (1.5 M
    triangles to 60k on the benchmark's bumpy ball), and collapsing level 2 from
    it rather than from level 1 keeps a quarter fewer triangles. Levels come one
    at a time, as asked for."""
    ids, positions, cells = zip(*slabs, strict=True)
    slabs.clear()  # the slabs' results go as the union is made
    # the union, over the vertices its triangles use (a shared one, in two slabs,
    # has one position), in the order of their ids
    every, first = np.unique(np.concatenate(ids), return_index=True)
    union = Mesh(np.concatenate(positions)[first], np.searchsorted(every, np.concatenate(cells)))
    del ids, positions, cells, every, first
    for k in range(1, lods):
        level = _collapsed_in_slabs(union, 2.0 ** (k - 1) - 0.5, collapse, *sizes)
        release_freed_memory()
        yield level


def _collapsed_in_slabs(
    mesh: Mesh, bound: float, collapse: Collapse, large: int, slab_triangles: int
) -> Mesh:
    """``mesh`` collapsed within ``bound`` (index coordinates): whole when it has at
    most ``large`` triangles (:data:`LARGE_OBJECT`), else in z-slabs of about
    ``slab_triangles`` (:data:`SLAB_TRIANGLES`), each within ``bound`` of itself
    with the vertices it shares and their neighbours kept
    (:func:`_collapsed_between`), their bounds
    half a slab off the first collapse's (whose kept vertices are now inside a
    slab). The union of slabs each within ``bound`` of its own triangles, both
    ways, is within ``bound`` of the whole. A union stays that large where the
    first slabs' collapses did little: a binary mask's stair-stepped isosurface,
    1.5 M triangles to 1.2 M at half a voxel, whose collapse whole held 790 MB
    within ``--max-memory 256M``."""
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if len(cells) <= large:
        return _collapsed(mesh, bound, collapse)
    vertices = np.asarray(mesh.vertices)
    low, _ = triangle_extents(vertices, cells, 2)
    count = -(-len(cells) // slab_triangles)
    order, ends, shared, base = slab_split(low, cells, count, offset=0.5)
    del low
    kept = []
    for n in range(len(ends) - 1):
        used, local = np.unique(cells[order[ends[n] : ends[n + 1]]], return_inverse=True)
        if len(used):
            slab = Mesh(vertices[used], local.reshape(-1, 3))
            kept.append(used[_collapsed_between(slab, shared[used - base], bound, collapse)])
            release_freed_memory()
    return _compacted(vertices, np.concatenate(kept))


def _collapsed(mesh: Mesh, bound: float, collapse: Collapse) -> Mesh:
    """``mesh`` collapsed within ``bound``, its vertices those still used, in order."""
    return _compacted(np.asarray(mesh.vertices), collapse(mesh, bound, None))


def _compacted(vertices: np.ndarray, cells: np.ndarray) -> Mesh:
    """Triangles ``cells`` over the vertices they use, in order."""
    used = np.zeros(len(vertices), dtype=bool)
    used[cells.reshape(-1)] = True
    return Mesh(vertices[used], (np.cumsum(used) - 1)[cells])


def index_of(world: np.ndarray, origin: np.ndarray, inverse: np.ndarray) -> np.ndarray:
    """Index coordinates of world points, ``inverse @ (world - origin)``, one
    point at a time in the same operations however many are given (a matrix
    product's kernel may sum a block's rows otherwise than a lone row's), so that
    an object's parts get its whole mesh's coordinates to the bit.

    Parameters
    ----------
    world : (N, 3) float64
    origin : (3,) float64
    inverse : (3, 3) float64

    Returns
    -------
    (N, 3) float64
    """
    d = np.asarray(world, dtype=np.float64) - origin
    return d[:, 0:1] * inverse[:, 0] + d[:, 1:2] * inverse[:, 1] + d[:, 2:3] * inverse[:, 2]


def write_object(target: str | None, layer: str, encode: Callable, *args) -> tuple | dict:
    """A layer's task on a cluster: ``encode(*args)``, :func:`encode_object`,
    :func:`encode_rows`, :func:`encode_node`, :func:`collapse_slab`, a large
    object's coarser levels from its slabs' (:func:`_coarse_fragments`) or
    :func:`assemble_object`. An object's fragment data (:func:`encode_object`'s,
    :func:`assemble_object`'s) is written by the task itself to ``target`` (in the
    layer's part folder) when it sees that folder (a file system shared with the
    client, as a cluster's output usually is), and only the manifest and the data's
    size come back; a task that does not see it sends the data back instead, for
    the client to write. The others' results (``target`` None) go to the task that
    puts them together (kept on the cluster), or come back when that is here: a
    row's or a node's fragments, a slab's collapse, the coarser levels'.

    Parameters
    ----------
    target : str or None
        The file of the object's fragment data; None: sent back.
    layer : str
        The layer's folder, named in errors.
    encode : callable
    *args
        ``encode``'s.

    Returns
    -------
    tuple, dict or list
        An object's manifest and fragment data (bytes, or its size once written
        to ``target``); a row's fragments by node; a slab's collapse; the coarser
        levels' fragments by node, a dict a level.
    """
    result = encode(*args)
    # a row, or the client's part folder not on this machine: sent back
    if target is None or not Path(target).parent.is_dir():
        return result
    manifest, data = result
    try:
        Path(target).write_bytes(data)
    except OSError as exc:  # the client removes the part folder on an error
        if exc.errno in DISK_FULL_ERRNOS:
            raise disk_full_error(layer, 0, why="while a worker wrote an object") from None
        if isinstance(exc, PermissionError) or exc.errno == errno.EROFS:
            # a worker of another user, or a read-only mount: the client writes it
            with contextlib.suppress(OSError):
                Path(target).unlink(missing_ok=True)
            return manifest, data
        raise OutputError(f"{layer}: a worker could not write an object ({exc.strerror})") from None
    return manifest, len(data)


def encode_and_write(target: str, encode: Callable, *args) -> tuple[bytes, int]:
    """``encode(*args)`` (:func:`encode_object`), its fragment data written to
    ``target``: the manifest and the data's size."""
    manifest, data = encode(*args)
    Path(target).write_bytes(data)
    return manifest, len(data)
