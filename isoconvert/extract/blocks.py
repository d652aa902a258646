"""Block-wise extraction: a volume cut into z-slabs, stitched by edge id.

A slab owns the z-layers ``k0 <= k < k1`` and is read with one more layer
(``k1``, its overlap) so that the cubes between its last owned layer and the
next slab exist. It owns every vertex whose edge starts on one of its layers
and every cell whose lowest row of samples is one of its layers, so each
vertex and cell of the whole mesh is made by exactly one slab. The vertices
of the overlap layer belong to the next slab, which makes them first: a
slab's cells that use them are renumbered once the next slab's vertices are
known, by their edge id (ARCHITECTURE.md, Vertex identity), never by position.

The kernels number vertices row of samples by row (``j + Y * k``) and cells by
the row of their lowest samples, so the slabs' vertices and cells, taken in z
order, are the whole mesh's in the whole mesh's order: block-wise extraction
gives the in-memory mesh bit for bit, whatever the slab thickness.

The same :func:`run_block` runs here (:func:`run_local`, the next slab read
ahead by :func:`isoconvert.runner.local.read_ahead`) and as a task of a Dask
cluster (:func:`isoconvert.extract.slabs.dask_runner` hands the slabs to
:func:`isoconvert.runner.run_in_order`); :func:`stitch_blocks` merges results
in either case. How slabs are cut and sent is :mod:`isoconvert.extract.slabs`,
shared with the label net's slabs.

Where a cluster's slabs are read:

* a lazy grid that can be read out of order (a raw file, a TIFF stack) is
  pickled with each task (its file's absolute path and layout, never the
  samples) and every worker reads its own slab: the workers need the same
  files at the same paths (a shared file system);
* an in-memory array, or a grid best read in order by one process (a gzip
  stream), is read here, slab by slab in z order, just before its task is
  sent, and travels with it; the runner keeps the bytes in flight within the
  memory budget.

This module hands tasks to the runner and never imports its Dask code: the
runner knows nothing of slabs, and the block engine nothing of Dask.
"""

from __future__ import annotations

import contextlib
import gc
import mmap
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..atomic import DiskFullError, disk_full_error
from ..errors import IsoconvertError
from ..grid import LazyGrid, SlabReader
from ..memory import FileMap
from ..mesh import Mesh
from ..methods import NO_DEGENERATE_OFFSET, TRILINEAR
from ..runner import TaskFailure, cluster_size
from ..runner.local import read_ahead
from ..threads import kernel_threads
from ..volume import ValueRange, Volume
from . import slabs
from .cubes import FilledNormals, fill_pass_normals, nan_as_exact
from .placement import Allocate, kernel_outputs, mesh_info, reversed_orientation
from .prepare import (
    _replace_nonfinite,
    check_finite_level,
    check_level,
    check_vertex_offset,
    check_volume,
    equal_target,
    kernel_type,
    nonfinite_error,
    resolve_vertex_offset,
)
from .slabs import (
    _SLABS_PER_THREAD,
    DEFAULT_MAX_MEMORY,
    Blocks,
    slab_ranges,
    slab_task,
)
from .tables import DEFAULT_AMBIGUITY
from .trilinear import interior_layer

#: Layers read beyond a slab each way when its filling pass gives normals: one
#: for a central difference, one for a vertex that rounding through world
#: coordinates puts in the neighbouring cell (as isoconvert.attributes.HALO).
NORMALS_HALO = 2

#: Methods that run block-wise, and how many edge directions number their ids.
BLOCK_METHODS = {"cubes": 3, "tetra": 7, "squares": 3}


@dataclass(frozen=True)
class BlockJob:
    """Everything a worker needs to extract one slab, besides its samples.

    Attributes
    ----------
    method : str
        ``cubes``, ``tetra`` or ``squares``.
    level : float
    k0, k1 : int
        Owned layers ``k0 <= k < k1``; samples ``k0 .. min(k1, Z - 1)`` are read.
    offset : float
        Vertex offset.
    ambiguity : str
    axis : str
        squares: the axis the slices are across.
    reverse : bool
        Cells in reverse orientation.
    nan_as : float or None
    affine : (3, 3) float64
    origin : (3,) float64
    grid_shape : (3,) int
        (X, Y, Z) of the whole grid.
    threads : int
        Kernel threads.
    source : str
        For messages.
    auto_offset : bool
        See the attribute's comment.
    """

    method: str
    level: float
    k0: int
    k1: int
    offset: float
    ambiguity: str
    axis: str
    reverse: bool
    nan_as: float | None
    affine: np.ndarray
    origin: np.ndarray
    grid_shape: tuple[int, int, int]
    threads: int
    source: str
    #: the vertex offset is the automatic one: a slab with a sample equal to
    #: the level takes NO_DEGENERATE_OFFSET instead of ``offset`` 0
    auto_offset: bool = False
    #: cubes: the filling pass also gives the normals, pointing this way (-1.0,
    #: or 1.0 with flip), and the slab is read with a halo (samples_range);
    #: None: no normals
    normals_sign: float | None = None

    @property
    def last(self) -> bool:
        return self.k1 >= self.grid_shape[2]

    @property
    def read_range(self) -> tuple[int, int]:
        """Layers to read, ``[k0, k1 + 1)`` but for the last slab."""
        return self.k0, self.k1 if self.last else self.k1 + 1

    @property
    def samples_range(self) -> tuple[int, int]:
        """Layers a local run reads: :attr:`read_range`, and when the filling
        pass gives normals the :data:`NORMALS_HALO` layers each way (within
        the grid) that their stencils reach."""
        lo, hi = self.read_range
        if self.normals_sign is None:
            return lo, hi
        return max(0, lo - NORMALS_HALO), min(self.grid_shape[2], hi + NORMALS_HALO)


@dataclass
class BlockResult:
    """One slab's vertices and cells, numbered within the slab.

    Attributes
    ----------
    k0 : int
        The slab's first layer.
    vertices : (V, 3) float64 or None
        World positions; None when the kernel wrote them straight into the
        mesh being built (:meth:`MeshSink.allocate`), as do the next two.
    edge_ids : (V,) int64 or None
        Global edge ids.
    cells : (C, 3) or (C, 2) int64 or None
        Indices into the slab's vertices; the first ``owned_cells`` are the slab's.
    owned_vertices : int
        The first ``owned_vertices`` vertices are the slab's; the others lie on
        its overlap layer and are the next slab's.
    owned_cells : int
    first_ids : (F,) int64
        Edge ids of the vertices on layer ``k0`` (the first ones): the slab
        before finds its overlap vertices among them.
    overlap_ids : (V - owned_vertices,) int64
        Edge ids of the overlap vertices.
    min, max : float
        Range of the slab's samples (after NaN replacement).
    equal : int
        Owned samples equal to the level.
    offset : float
        The vertex offset the slab's vertices were placed with.
    normals : FilledNormals or None
        The filling pass's normals, when the job asked for them.
    """

    k0: int
    vertices: np.ndarray | None
    edge_ids: np.ndarray | None
    cells: np.ndarray | None
    owned_vertices: int
    owned_cells: int
    first_ids: np.ndarray
    overlap_ids: np.ndarray
    min: float
    max: float
    equal: int
    offset: float = 0.0
    normals: FilledNormals | None = None


def run_block(job: BlockJob, zyx: np.ndarray, allocate: Allocate | None = None) -> BlockResult:
    """Extract one slab: the kernels' first pass and count-and-fill on its samples.

    Parameters
    ----------
    job : BlockJob
    zyx : (layers, Y, X) array
        :func:`~isoconvert.extract.slabs.read_block` of ``job``.
    allocate : callable or None
        Where the kernel writes (:meth:`MeshSink.allocate`); the result then
        holds no arrays but the ids it needs. None: fresh arrays, kept in the
        result (a Dask task sends them back).

    Raises
    ------
    VolumeError
        NaN/Inf samples and no ``nan_as``; unsupported sample type.
    """
    from .. import _native

    zyx = kernel_type(zyx, job.source)
    # with normals, zyx comes with its halo (samples_range): the slab is a view
    # into it
    with_halo = job.normals_sign is not None
    halo_lo, _ = job.samples_range
    read_lo, read_hi = job.read_range
    halo = zyx
    if with_halo:
        zyx = halo[read_lo - halo_lo : read_hi - halo_lo]
    equal_to = equal_target(zyx.dtype, job.level)

    def scan(samples: np.ndarray):
        return _native.scan_rows(
            samples, job.level, equal_to is not None, equal_to or 0.0, job.threads
        )

    rows = scan(zyx)
    if rows.nonfinite:
        if job.nan_as is None:
            lo, hi = job.read_range
            whole = lo == 0 and hi == job.grid_shape[2]
            raise nonfinite_error(
                job.source, rows.nonfinite, "" if whole else f" (z {lo}..{hi - 1})"
            )
        halo = _replace_nonfinite(halo, rows.nonfinite, job.nan_as, job.source)
        zyx = halo[read_lo - halo_lo : read_hi - halo_lo] if with_halo else halo
        rows = scan(zyx)
    elif with_halo and job.nan_as is not None and not np.isfinite(halo).all():
        # NaN/Inf in the halo only: the stencils read them as nan_as too
        halo = _replace_nonfinite(halo, 1, job.nan_as, job.source)
        zyx = halo[read_lo - halo_lo : read_hi - halo_lo]
    if job.auto_offset and not job.offset and rows.equal:
        job = replace(job, offset=NO_DEGENERATE_OFFSET)
    equal = rows.equal
    if equal and not job.last:  # the overlap layer's samples are the next slab's
        equal -= int(np.count_nonzero(zyx[-1] == zyx.dtype.type(equal_to)))
    normals = None
    if job.normals_sign is None:
        verts, ids, cells = _block_kernel(job).extract(
            zyx, rows, (0, 0, job.k0), allocate or kernel_outputs
        )
    else:
        verts, ids, cells, normals = _block_kernel(job).extract_with_normals(
            zyx, rows, job.normals_sign, allocate or kernel_outputs, halo, halo_lo, job.k0
        )
    if job.ambiguity == TRILINEAR and job.method == "cubes":
        # vertices inside cubes have ids past the edge ids, numbered by cube
        layer = interior_layer(ids, job.grid_shape)
    else:
        layer = ids // (BLOCK_METHODS[job.method] * job.grid_shape[0] * job.grid_shape[1])
    # layer is non-decreasing: vertices come row by row
    owned = len(ids) if job.last else int(np.searchsorted(layer, job.k1))
    owned_cells = len(cells)
    if job.method == "squares" and job.axis == "z" and not job.last and len(cells):
        # slices across z are the only cells on the overlap layer; all their
        # vertices lie on it, and they come last
        owned_cells = int(np.searchsorted(cells[:, 0] >= owned, True))
    kept = allocate is None
    return BlockResult(
        k0=job.k0,
        vertices=verts if kept else None,
        edge_ids=ids if kept else None,
        cells=cells if kept else None,
        owned_vertices=owned,
        owned_cells=owned_cells,
        first_ids=ids[: int(np.searchsorted(layer, job.k0 + 1))].copy(),
        overlap_ids=ids[owned:].copy(),
        min=float(rows.min),
        max=float(rows.max),
        equal=int(equal),
        offset=job.offset,
        normals=normals,
    )


def _block_kernel(job: BlockJob):
    """The method's block extractor for ``job``."""
    common = {
        "affine": job.affine,
        "origin": job.origin,
        "grid_shape": job.grid_shape,
        "offset": job.offset,
        "reverse": job.reverse,
        "threads": job.threads,
    }
    if job.method == "cubes":
        from .cubes import CubesBlock

        return CubesBlock(ambiguity=job.ambiguity, **common)
    if job.method == "tetra":
        from .tetra import TetraBlock

        return TetraBlock(**common)
    from .squares import SquaresBlock

    return SquaresBlock(axis=job.axis, ambiguity=job.ambiguity, **common)


#: What a spill file's disk-full message says it was for, and what else helps.
_SPILL_WHY = (
    "for the mesh being built, larger than a quarter of --max-memory (a larger one keeps "
    "more of it in memory)"
)


def _close_map(mapped: mmap.mmap) -> None:
    """Close a memory map now, or, while a view still holds it, once the last
    view goes (the collector first gets a chance to drop forgotten ones)."""
    try:
        mapped.close()
    except BufferError:
        gc.collect()
        with contextlib.suppress(BufferError):
            mapped.close()


class _Growing:
    """An array that grows along its first axis without copying what it holds.

    It lives in a memory map, which grows by remapping its pages
    (``mmap.resize``), not by copying them, and whose new pages cost nothing
    until written: anonymous memory at first, a temporary file once
    :meth:`spill` is called (the file has no name, so nothing is left behind
    whatever happens). Views from :meth:`view` must be dropped before the
    next :meth:`reserve` (a map with views cannot move).
    """

    def __init__(self, width: tuple[int, ...], dtype) -> None:
        self.width = width
        self.dtype = np.dtype(dtype)
        self.row = self.dtype.itemsize * int(np.prod(width, dtype=np.int64))
        self.size = 0  # rows committed
        self._map = mmap.mmap(-1, 1 << 16, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
        self._file = None
        self._folder: str | None = None  # of the spill file, once spilled

    @property
    def nbytes(self) -> int:
        return len(self._map)

    def reserve(self, rows: int) -> None:
        """Room for ``rows`` more rows after the committed ones."""
        need = (self.size + rows) * self.row
        if need <= len(self._map):
            return
        try:
            self._grow(need)
        except BufferError:
            # a view of the map outlived its use, held by a reference cycle (an
            # exception's frames, a task's result on another thread) until the
            # collector runs: collect, then grow; failing that, move to a new map
            gc.collect()
            try:
                self._grow(need)
            except BufferError:
                self._move(max(need, 2 * len(self._map)))

    def _grow(self, need: int) -> None:
        if self._file is None:
            self._map.resize(max(need, 2 * len(self._map)))
            if hasattr(mmap, "MADV_HUGEPAGE"):
                self._map.madvise(mmap.MADV_HUGEPAGE)
            return
        try:  # on disk: its blocks first (FileMap.grow), and no more than fits
            self._map.grow(max(need, 2 * len(self._map)))
        except DiskFullError:
            self._map.grow(need)

    def _move(self, size: int) -> None:
        """Copy what the map holds into a new, larger one (views still held keep
        the old one alive, and see none of what is written from now on)."""
        if self._file is not None:
            fh = tempfile.TemporaryFile(dir=Path(self._folder), prefix=".isoconvert-mesh-")
            try:
                moved = FileMap.create(fh.fileno(), size, Path(self._folder), _SPILL_WHY)
            except BaseException:
                fh.close()
                raise
        else:
            fh = None
            moved = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
        used = self.size * self.row
        step = 1 << 24
        for a in range(0, used, step):  # piece by piece: no copy of the whole
            moved[a : min(a + step, used)] = self._map[a : min(a + step, used)]
        old_file = self._file
        self._map, self._file = moved, fh
        if old_file is not None:
            old_file.close()  # its pages stay mapped while old views live

    def spill(self, folder: Path) -> None:
        """Move the array into a temporary file in ``folder``; from now on its
        committed pages can be given back (:meth:`release`)."""
        if self._file is not None:
            return
        self._folder = str(folder)
        fh = tempfile.TemporaryFile(dir=folder, prefix=".isoconvert-mesh-")
        size = len(self._map)
        try:
            mapped = FileMap.create(fh.fileno(), size, folder, _SPILL_WHY)
        except BaseException:
            fh.close()
            raise
        step = 1 << 24
        for a in range(0, size, step):  # piece by piece: no copy of the whole
            mapped[a : a + step] = self._map[a : a + step]
        _close_map(self._map)
        self._map, self._file = mapped, fh

    def release(self, stop: int) -> None:
        """Give back the pages of rows before ``stop`` (spilled arrays only)."""
        if self._file is None or not hasattr(mmap, "MADV_DONTNEED"):
            return
        end = stop * self.row
        end -= end % mmap.PAGESIZE
        if end > 0:
            self._map.madvise(mmap.MADV_DONTNEED, 0, end)

    def view(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start <= r < stop`` (reserved or committed), writable."""
        count = (stop - start) * int(np.prod(self.width, dtype=np.int64))
        flat = np.frombuffer(self._map, dtype=self.dtype, count=count, offset=start * self.row)
        return flat.reshape(stop - start, *self.width)

    def final(self) -> np.ndarray:
        """The committed rows; the map (and its file) is then the array's."""
        if self.size == 0:
            return np.empty((0, *self.width), dtype=self.dtype)
        try:
            self._map.resize(self.size * self.row)
        except BufferError:  # a view outlived its use (see reserve)
            gc.collect()
            with contextlib.suppress(BufferError):  # else the map keeps its spare rows
                self._map.resize(self.size * self.row)
        out = self.view(0, self.size)
        self._map = self._file = None  # the view keeps both open
        return out

    def wanted(self, rows: int) -> int:
        """Bytes of the map once it has room for ``rows`` more rows."""
        return max(len(self._map), (self.size + rows) * self.row)

    def close(self) -> None:
        """Drop the memory (and the file) of an array that will not be finished."""
        if self._map is not None:
            with contextlib.suppress(BufferError, ValueError):  # views left: they keep it
                self._map.close()
        if self._file is not None:
            self._file.close()
        self._map = self._file = None


class MeshSink:
    """The mesh being stitched (see :func:`stitch_blocks`).

    A local slab's kernel writes straight into it (:meth:`allocate`); a
    remote slab's arrays are copied in (:meth:`put`). Once it holds more
    than ``spill_above`` bytes it moves into temporary files in
    ``spill_dir`` (None: it stays in memory) and gives back the pages of
    finished slabs, so memory holds a few slabs, not the mesh.
    """

    def __init__(
        self, arity: int = 3, spill_dir: Path | None = None, spill_above: int | None = None
    ) -> None:
        self._vertices = _Growing((3,), np.float64)
        self._ids = _Growing((), np.int64)
        self._cells = _Growing((arity,), np.int64)
        self._parts = (self._vertices, self._ids, self._cells)
        self._spill_dir = spill_dir
        self._spill_above = spill_above
        self.spilled = False
        # (first vertex, first cell, vertices on the first layer) of each slab
        self.starts: list[tuple[int, int, int]] = []
        #: the filling pass's normals of each slab's own vertices, when asked for
        self.normals: list[np.ndarray] = []
        self.flat_normals = 0

    @property
    def counts(self) -> tuple[int, int]:
        """Vertices and cells committed."""
        return self._vertices.size, self._cells.size

    def allocate(
        self, n_vertices: int, n_cells: int, arity: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrays for a slab's kernel, after what is committed; valid until the
        next call (see :class:`_Growing`)."""
        sizes = (n_vertices, n_vertices, n_cells)
        try:
            for part, n in zip(self._parts, sizes, strict=True):
                part.reserve(n)
            if (
                not self.spilled
                and self._spill_dir is not None
                and sum(part.nbytes for part in self._parts) > (self._spill_above or 0)
            ):
                for part in self._parts:
                    part.spill(self._spill_dir)
                self.spilled = True
        except DiskFullError:
            # say what the spilled mesh needs in all, against what is free once
            # its files are given back
            wanted = sum(part.wanted(n) for part, n in zip(self._parts, sizes, strict=True))
            self.close()
            raise disk_full_error(self._spill_dir, wanted, more=True, why=_SPILL_WHY) from None
        return tuple(
            part.view(part.size, part.size + n) for part, n in zip(self._parts, sizes, strict=True)
        )

    def put(self, result: BlockResult) -> None:
        """Copy a slab's arrays in, where :meth:`allocate` would have put them."""
        verts, ids, cells = self.allocate(len(result.vertices), len(result.cells), 0)
        verts[:] = result.vertices
        ids[:] = result.edge_ids
        cells[:] = result.cells

    def commit(self, n_vertices: int, n_cells: int, first_layer: int = 0) -> None:
        """Keep the first ``n_vertices`` and ``n_cells`` of the last slab's, of
        which the first ``first_layer`` vertices lie on its first layer."""
        self.starts.append((*self.counts, first_layer))
        self._vertices.size += n_vertices
        self._ids.size += n_vertices
        self._cells.size += n_cells
        if self.spilled:  # the slab's cells wait for the next slab: keep them
            self._vertices.release(self._vertices.size)
            self._ids.release(self._ids.size)
            self._cells.release(self.starts[-1][1])

    def renumber(self, start: int, stop: int, number: np.ndarray) -> None:
        """Replace committed cells ``start .. stop - 1`` (slab-local) by ``number`` of them."""
        step = 1 << 16  # small pieces: the temporary stays in cache
        for a in range(start, stop, step):
            piece = self._cells.view(a, min(a + step, stop))
            piece[:] = number[piece]
            del piece

    def mesh(self, info: dict) -> Mesh:
        if self.spilled:
            self._cells.release(self._cells.size)
        parts = [part.final() for part in self._parts]
        if not self.spilled:
            return Mesh(parts[0], parts[2], parts[1], info)
        return BlockMesh(parts[0], parts[2], parts[1], info, slab_starts=list(self.starts))

    def close(self) -> None:
        """Give up the mesh (an error or a restart)."""
        for part in self._parts:
            part.close()


@dataclass
class BlockMesh(Mesh):
    """A mesh built block-wise that outgrew memory: its arrays are memory maps
    of temporary files (writers stream them, see
    :func:`isoconvert.memory.row_chunks`), and it knows where each
    slab's vertices and cells start.

    Attributes
    ----------
    slab_starts : list of (int, int, int)
        (first vertex, first cell, vertices on its first layer) of each slab.
    """

    slab_starts: list[tuple[int, int, int]] = field(default_factory=list)

    def float32_windows(self):
        """Pieces that together answer "does float32 lose anything?" as the
        whole mesh would, or None when they cannot.

        Yields, per slab, its cells (renumbered from its first vertex) with its
        vertices and those of the next slab's first layer: a cell uses only
        those. Rounding to float32 can only merge vertices closer than
        ``sqrt(3) 2**-23 m`` (m the largest coordinate). A slab's vertices lie
        below its last layer, the next slab's beyond its first layer lie above
        the layer after it: more than one grid step apart. So every merge and
        every triangle made degenerate is seen in some piece, when a grid step
        is longer than that.
        """
        if not self.slab_starts or not len(self.vertices):
            return None
        grid = self.info.get("grid")
        if not grid:
            return None
        affine = np.asarray(grid["affine"], dtype=np.float64)
        # every vertex lies in the grid's box, so its corners bound the coordinates
        corners = np.array(np.meshgrid(*[[0, n - 1] for n in grid["shape"]])).reshape(3, -1)
        m = float(np.abs(affine @ corners + np.asarray(grid["origin"])[:, None]).max())
        step = float(np.linalg.svd(affine, compute_uv=False).min())
        if not step > 4 * np.sqrt(3) * 2.0**-23 * m:
            return None
        starts = [*self.slab_starts, (len(self.vertices), len(self.cells), 0)]

        from ..memory import release

        def pieces():
            for s in range(len(starts) - 1):
                (v0, c0, _), (v1, c1, first) = starts[s], starts[s + 1]
                yield self.vertices[v0 : v1 + first], self.cells[c0:c1] - v0
                release(self.vertices[max(0, v0 - 1) : v1])
                release(self.cells[max(0, c0 - 1) : c1])

        return pieces()


@dataclass
class _Pending:
    """A stitched slab whose cells wait for the next slab's first layer."""

    vertex_start: int
    owned_vertices: int
    overlap_ids: np.ndarray
    cell_start: int
    owned_cells: int


def stitch_blocks(results: Iterable[BlockResult], sink: MeshSink) -> None:
    """Merge slab results, given in z order, into one numbering in ``sink``:
    each slab's own vertices as it arrives, its cells renumbered once the next
    slab's first-layer vertices (its overlap vertices) are known.

    Raises
    ------
    IsoconvertError
        When a slab's overlap vertices are not the next slab's first-layer
        vertices (slabs out of order or extracted differently): a bug, never a
        weld.
    """
    pending: _Pending | None = None
    for result in results:
        if result.vertices is not None:
            sink.put(result)
        if result.normals is not None:  # those of the slab's own vertices, in their order
            sink.normals.append(result.normals.normals[: result.owned_vertices])
            sink.flat_normals += result.normals.flat  # overlap vertices too: an upper bound
        vertex_start, cell_start = sink.counts
        if pending is not None:
            _renumber(sink, pending, result.first_ids, vertex_start)
        sink.commit(result.owned_vertices, result.owned_cells, len(result.first_ids))
        pending = _Pending(
            vertex_start,
            result.owned_vertices,
            result.overlap_ids,
            cell_start,
            result.owned_cells,
        )
        del result  # a local result may hold views of the sink
    if pending is not None:
        _renumber(sink, pending, np.empty(0, dtype=np.int64), sink.counts[0])


def _renumber(sink: MeshSink, block: _Pending, following: np.ndarray, following_start: int) -> None:
    """Give ``block``'s cells global numbers; its overlap vertices are found
    among the following slab's first-layer vertices by edge id."""
    own = block.owned_vertices
    shared = block.overlap_ids
    number = np.empty(own + len(shared), dtype=np.int64)
    number[:own] = np.arange(block.vertex_start, block.vertex_start + own)
    if len(shared):
        if len(following) < len(shared):
            raise IsoconvertError("internal error: a slab's overlap vertices have no owner")
        order = np.argsort(following, kind="stable")
        at = order[np.minimum(np.searchsorted(following, shared, sorter=order), len(following) - 1)]
        if not np.array_equal(following[at], shared):
            raise IsoconvertError("internal error: a slab's overlap vertices have no owner")
        number[own:] = following_start + at
    sink.renumber(block.cell_start, block.cell_start + block.owned_cells, number)


def run_local(
    source: np.ndarray | LazyGrid,
    jobs: list[BlockJob],
    allocate: Allocate | None = None,
    adjust: Callable[[BlockJob], BlockJob] | None = None,
) -> Iterator[BlockResult]:
    """Run ``jobs`` here, in order, reading the next slab while one is extracted
    (a chunked store's chunks are decoded once, see :class:`SlabReader`).
    ``adjust`` may change a job just before it runs (the offset the slabs
    before it chose)."""
    if not jobs:
        return
    slabs = SlabReader(source)

    def read(job: BlockJob) -> np.ndarray:
        return slabs.read(*job.samples_range)

    def ready(job: BlockJob) -> bool:
        # read ahead, unless that decodes a new chunk row while this one is in use
        return slabs.ready(*job.samples_range)

    for job, zyx in read_ahead(jobs, read, ready):
        result = run_block(adjust(job) if adjust else job, zyx, allocate)
        del zyx
        yield result


Runner = Callable[[list[BlockJob]], Iterator[BlockResult]]


def extract_blocks(
    volume: Volume,
    level: float,
    *,
    method: str = "cubes",
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float | None = None,
    axis: str = "z",
    blocks: Blocks | None = None,
    on_status: Callable[[str], None] | None = None,
    sink: MeshSink | None = None,
    normals: bool = False,
) -> Mesh:
    """Extract the isosurface of a 3D volume slab by slab; the same mesh as the
    in-memory path (:func:`isoconvert.extract`), bit for bit.

    The samples are read one slab at a time (from ``volume.grid`` when the
    volume is lazy), so memory holds a few slabs and the mesh, not the volume.
    Validation that needs every sample (level inside the data range) happens
    when the last slab is done; a NaN without ``nan_as`` stops at its slab.
    When the vertex offset is left to choose and a slab finds a sample equal
    to the level, the extraction starts again with the offset (the mesh must
    not depend on where that sample lies).

    Parameters
    ----------
    volume : Volume
        3D.
    level : float
    method : str
        ``cubes``, ``tetra`` or ``squares`` (slices across ``axis``).
    flip, ambiguity, nan_as, vertex_offset, axis, on_status
        As for :func:`isoconvert.extract`.
    blocks : Blocks or None
        Slab size, memory budget, and a Dask scheduler to run on.
    sink : MeshSink or None
        Receives the stitched pieces; None keeps them in memory.
    normals : bool
        Give ``mesh.normals`` from the filling pass where it can: Marching
        Cubes with a fixed ambiguity rule, slabs run here (each read with
        :data:`NORMALS_HALO` more layers each way, which the gradients'
        stencils reach). The trilinear rule, tetrahedra, slabs on a cluster and
        a ``nan_as`` with no exact twin in the sample type
        (:func:`~isoconvert.extract.cubes.nan_as_exact`) leave ``mesh.normals``
        None, for :func:`isoconvert.vertex_normals`.

    Returns
    -------
    Mesh
        With ``info["blocks"]`` the number of slabs.
    """
    if method not in BLOCK_METHODS:
        raise IsoconvertError(
            f"{method} does not run block-wise; use --method {', '.join(BLOCK_METHODS)}"
        )
    blocks = blocks or Blocks()
    check_volume(volume, 3, method, nan_as)
    level = check_finite_level(level, volume.source)
    source = volume.samples
    dtype = kernel_type(np.empty((0, 0, 0), dtype=volume.dtype), volume.source).dtype
    layers = blocks.layers(volume.shape, dtype.itemsize)
    ranges = slab_ranges(volume.shape[2], layers)
    grid = volume.grid
    if grid is not None and grid.z_chunk > 1 and on_status:
        row = grid.shape[0] * grid.shape[1] * grid.z_chunk * grid.dtype.itemsize
        if row > blocks.budget // 2:
            on_status(
                f"note: {volume.source} stores {grid.z_chunk} z-layers per chunk, so a row of "
                f"chunks ({row / 2**20:.0f} MiB) is decoded at once, more than --max-memory "
                "allows for samples"
            )
    can_equal = equal_target(dtype, level) is not None
    auto = vertex_offset is None
    offset = 0.0 if auto or vertex_offset == 0 else check_vertex_offset(vertex_offset)
    arity = 2 if method == "squares" else 3
    if blocks.scheduler is not None:
        runner: Runner | None = slabs.dask_runner(
            blocks.scheduler, source, volume.source, extract_slab, max_bytes=blocks.budget
        )
        if blocks.size is None:  # enough slabs to keep every thread of the cluster busy
            per_thread = -(
                -volume.shape[2] // (_SLABS_PER_THREAD * max(1, cluster_size(blocks.scheduler)))
            )
            layers = max(1, min(layers, per_thread))
            ranges = slab_ranges(volume.shape[2], layers)
    else:
        runner = None
    # normals in the filling pass (slabs read here, with their halo; not the
    # trilinear rule's interior vertices, which would need the samples again)
    fill_normals = (
        normals
        and method == "cubes"
        and ambiguity != TRILINEAR
        and runner is None
        and nan_as_exact(dtype, nan_as)
    )
    threads = kernel_threads()
    while True:
        template = BlockJob(
            method=method,
            level=level,
            k0=0,
            k1=0,
            offset=offset,
            ambiguity=ambiguity,
            axis=axis,
            reverse=reversed_orientation(volume, flip),
            nan_as=nan_as,
            affine=np.ascontiguousarray(volume.affine, dtype=np.float64),
            origin=np.ascontiguousarray(volume.origin, dtype=np.float64),
            grid_shape=tuple(int(n) for n in volume.shape),
            threads=threads,
            source=volume.source,
            auto_offset=auto and can_equal and not offset,
            normals_sign=(1.0 if flip else -1.0) if fill_normals else None,
        )
        jobs = [replace(template, k0=k0, k1=k1) for k0, k1 in ranges]
        out = sink or MeshSink(arity, blocks.spill_dir, blocks.budget // 4)
        stats = _Stats(offset)
        if runner:
            results = runner(jobs)
        else:  # slabs after the first take the offset it chose
            results = run_local(source, jobs, out.allocate, stats.adjust)
        try:
            stitch_blocks(stats.tally(results), out)
        except _Restart:
            out.close()
            offset = NO_DEGENERATE_OFFSET
            continue
        except BaseException:
            out.close()
            raise
        finally:
            results.close()
        break
    check_level(level, ValueRange(stats.min, stats.max, 0), volume.source)
    _, note = resolve_vertex_offset(dtype, level, vertex_offset, stats.equal)
    info = mesh_info(
        volume, method, level, flip, stats.offset, None if method == "tetra" else ambiguity
    )
    info["blocks"] = len(ranges)
    pieces, flat = out.normals, out.flat_normals
    mesh = out.mesh(info)
    if fill_normals and mesh.n_cells:  # as vertex_normals: only with triangles
        filled = FilledNormals(pieces[0] if len(pieces) == 1 else np.concatenate(pieces), flat)
        assert len(filled.normals) == mesh.n_vertices
        mesh.normals = fill_pass_normals(
            mesh, filled, None, _block_kernel(template), template.normals_sign, threads
        )
    if method == "squares" and mesh.n_cells == 0:
        raise IsoconvertError(f"{volume.source}: no slice crosses level {level:g}")
    if note and on_status:
        on_status(note)
    return mesh


# --- slabs as tasks of a cluster -----------------------------------------------------------------


def extract_slab(job: BlockJob, samples: np.ndarray | LazyGrid) -> BlockResult | TaskFailure:
    """One slab, as a task of a cluster: read it (unless sent), extract it
    (:func:`slab_task` of :func:`run_block`).

    Parameters
    ----------
    job : BlockJob
        Its ``threads`` is replaced by :func:`isoconvert.runner.worker_threads`
        (the mesh is the same for any number).
    samples : LazyGrid or (layers, Y, X) array
        The grid to read the slab from (on the worker), or the slab itself
        (:func:`~isoconvert.extract.slabs.read_block` of ``job``, read by the client).

    Returns
    -------
    BlockResult or TaskFailure
        The result with its arrays; a failure for an ``IsoconvertError``.
    """
    return slab_task(run_block, job, samples)


class _Restart(Exception):
    """A slab chose another vertex offset than the slabs before it."""


class _Stats:
    """Range, equal count and vertex offset over the slabs seen."""

    def __init__(self, offset: float) -> None:
        self.min, self.max, self.equal = np.inf, -np.inf, 0
        self.offset = offset
        self.seen = 0

    def adjust(self, job: BlockJob) -> BlockJob:
        """``job`` with the offset the slabs so far chose."""
        if self.seen and self.offset != job.offset:
            return replace(job, offset=self.offset, auto_offset=False)
        return job

    def tally(self, results: Iterator[BlockResult]) -> Iterator[BlockResult]:
        """Pass ``results`` on, counting; raise :class:`_Restart` when a slab
        placed its vertices with another offset than the slabs before it (a
        sample equal to the level found late: the mesh must not depend on
        where that sample lies)."""
        for result in results:
            self.min = min(self.min, result.min)
            self.max = max(self.max, result.max)
            self.equal += result.equal
            if result.offset != self.offset:
                if self.seen:
                    raise _Restart
                self.offset = result.offset  # the first slab chose it: no slab before it
            self.seen += 1
            yield result


__all__ = [
    "BLOCK_METHODS",
    "DEFAULT_MAX_MEMORY",
    "BlockJob",
    "BlockResult",
    "Blocks",
    "MeshSink",
    "extract_blocks",
    "extract_slab",
    "run_block",
    "run_local",
    "slab_ranges",
    "stitch_blocks",
]
