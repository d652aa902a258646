"""Neuroglancer precomputed segmentation layers with multi-resolution meshes.

A layer is a folder (Neuroglancer's "precomputed" format, served as static
files):

``info``
    The segmentation volume's metadata: ``type`` segmentation, the label
    ``data_type``, one scale with the volume's ``size``, its ``resolution`` in
    nanometres (the spacing and the volume's unit) and ``voxel_offset`` 0, and
    ``mesh``: the name of the mesh folder.
``mesh/info``
    ``@type`` ``neuroglancer_multilod_draco``, the ``vertex_quantization_bits``
    (10 or 16), the ``transform`` from the stored model space (here the volume's
    index space: sample (i, j, k) at (i, j, k)) to nanometres (the volume's
    index-to-world affine, origin and rotation included, times nanometres per
    unit), and ``lod_scale_multiplier`` 1.
``mesh/<id>.index``, ``mesh/<id>``
    Per object, the manifest (octree chunk shape, grid origin, the levels of
    detail with their scales, the fragments' positions and byte sizes) and the
    fragments: Draco meshes whose integer positions are the vertices quantized
    in their fragment's box.

Levels of detail: level 0 is the mesh as extracted; level k (k >= 1) is it
decimated, by the function the caller passes (the jobs pass isoconvert's bounded
collapse, :func:`isoconvert.post.decimate.collapse`), to within ``2**(k - 1)``
index units both ways. Each level is one fragment whose
octree node starts at the object's bounding box: its node at level k is ``2**k``
boxes wide, so the object lies in the node's first octant and no triangle
crosses the node's 2x2x2 partition, as the format asks. Quantizing in that box
moves a vertex by at most half a step: ``box * 2**k / (2**bits - 1) / 2``
per axis.

With ``chunk`` the octree's finest nodes are that many index units a side instead,
and each level is cut into the nodes it crosses (:func:`_object`, :func:`_cut`).

With ``sharded`` the manifests and fragments go into shard files
(:func:`_write_shards`, the identity hash).

With ``legacy`` the meshes are in the legacy single-resolution format instead
(``neuroglancer_legacy_mesh``, for tools that read no other): per object a JSON
manifest ``<id>:0`` naming one fragment ``<id>:0:0``, which holds the vertex count,
the vertices as float32 nanometres and the triangles as uint32, one level, not
sharded.

With ``volume`` the layer also holds the labels' voxels
(:mod:`isoconvert.writers.precomputed_volume`). A precomputed volume has no origin
or direction: voxel (i, j, k) fills ``[i, i + 1) x resolution`` per axis. The
meshes then go to that same frame (index coordinates plus half a voxel, times the
resolution), so that each surface lies on its voxels in the viewer; the volume's
origin and direction are not stored (a note says so where they are not trivial).

Each object is encoded by :func:`encode_object`, a function of arrays and scalars,
which the caller may run elsewhere (``map_objects``: the jobs send each object to a
Dask cluster's workers with ``--scheduler``, as :func:`write_object`). There each
task writes its object's fragment data into the layer's part folder itself (the
folder is on a file system the workers share) and sends back only the manifest;
the client writes the manifests (or, sharded, the shards from the tasks' files)
and renames the folder into place. A worker that does not see the folder, or may
not write there, sends the data back instead.

An object given in parts (a label's, from the surface net) and cut into fragments
is encoded a z-row of level-0 nodes at a time instead (:func:`encode_row`, one
task each, the fragments sent back and put in order here), never built whole;
when it is large (:data:`LARGE_OBJECT`) its coarser levels are collapsed in slabs
here (:func:`_coarse_levels`).
"""

from __future__ import annotations

import contextlib
import errno
import functools
import json
import shutil
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_folder
from ..errors import FormatError, IsoconvertError, OutputError, extra_hint
from ..geometry import normalized_grid
from ..mesh import Mesh, MeshParts, slab_split
from ..threads import kernel_threads, threaded_in_order
from ..units import meters_per_unit
from ..volume import Volume
from .precomputed_volume import volume_scale, write_chunks

#: The vertex quantization the format allows.
QUANTIZATION_BITS = (10, 16)

#: Label types a precomputed segmentation may hold.
_DATA_TYPES = ("uint8", "uint16", "uint32", "uint64")

#: ``collapse(mesh, bound, locked)``: the triangles of ``mesh`` (index coordinates)
#: collapsed to within ``bound`` of it both ways, over its vertices, ``locked``
#: ((V,) bool or None) kept where they are (:func:`isoconvert.post.decimate.collapse`).
Collapse = Callable[[Mesh, float, np.ndarray | None], np.ndarray]

#: ``map_objects(function, tasks)``: ``function(*args)`` for each ``(what, args)`` of
#: ``tasks`` (``what`` names the task in errors), the results in order.
ObjectMap = Callable[[Callable[..., tuple], Iterable[tuple[str, tuple]]], Iterable]


def not_a_file(mesh: Mesh, fh, ascii: bool) -> None:
    """The registry's writer entry: a layer is a folder of every object, not a stream."""
    raise FormatError(LAYER_ONLY)


#: Where the precomputed format goes.
LAYER_ONLY = (
    "precomputed writes a folder holding every object's mesh: use it with "
    "convert (--labels or --level) -o FOLDER --format precomputed"
)


def data_type_for(largest: int) -> str:
    """The smallest unsigned type of a precomputed segmentation holding ``largest``."""
    for name in _DATA_TYPES:
        if largest <= np.iinfo(name).max:
            return name
    raise IsoconvertError(f"precomputed: label {largest} does not fit in uint64")


def check_layer(
    folder: str | Path,
    force: bool,
    lods: int,
    inputs: Sequence[str | Path] = (),
    chunk: float | None = None,
    *,
    sharded: bool = False,
    legacy: bool = False,
) -> None:
    """Fail before any work when a layer cannot be written: DracoPy or (for more
    than one level of detail) meshoptimizer missing, options the legacy format
    cannot hold, or the folder taken.

    Raises
    ------
    IsoconvertError
        A missing package or bad ``lods``.
    OutputError
        ``folder`` exists (without ``force``), is not a folder, its parent is
        missing, or it holds one of ``inputs`` (replacing it would delete them).
    """
    _check_lods(lods)
    _check_chunk(chunk)
    _check_legacy(legacy, lods, chunk, sharded)
    if not legacy:
        _dracopy()
    if lods > 1:
        try:
            import meshoptimizer  # noqa: F401
        except ImportError:
            raise IsoconvertError(
                f"--lods above 1 decimates: {extra_hint('simplify')}, or --lods 1"
            ) from None
    folder = Path(folder)
    parent = folder.parent if str(folder.parent) else Path(".")
    if not parent.exists():  # worded as for mesh files (atomic.check_output)
        raise OutputError(f"{folder}: the folder {parent} does not exist; create it first")
    if not parent.is_dir():
        raise OutputError(f"{folder}: {parent} is not a folder; give the layer another name")
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder} exists and is not a layer folder; give a folder name")
    if folder.exists() and not force:
        raise OutputError(f"{folder} exists; pass --force to replace it")
    if folder.is_dir():
        inside = folder.resolve()
        for path in inputs:
            resolved = Path(path).resolve()
            if resolved == inside or inside in resolved.parents:
                raise OutputError(
                    f"{folder} holds the input {path}; replacing the layer would delete it: "
                    "write the layer elsewhere"
                )
    _check_replaceable(folder)


def _check_replaceable(folder: Path) -> None:
    """Refuse to replace a folder that is not a precomputed layer: ``--force``
    replaces a layer (or an empty folder), never a folder of someone's files."""
    if not folder.is_dir() or not any(folder.iterdir()):
        return
    try:
        info = json.loads((folder / "info").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        info = None
    if not (isinstance(info, dict) and info.get("@type") == "neuroglancer_multiscale_volume"):
        raise OutputError(
            f"{folder} is a folder that is not a Neuroglancer layer (no layer info file); "
            "--force replaces only layers: give the layer a new folder name"
        )


def _check_legacy(legacy: bool, lods: int, chunk: float | None, sharded: bool) -> None:
    if legacy and (lods > 1 or chunk is not None or sharded):
        raise IsoconvertError(
            "precomputed: the legacy mesh format has one level of detail, one fragment per "
            "object and no shards: leave out --lods, --fragment-size and --sharded with it"
        )


def _check_chunk(chunk) -> None:
    if chunk is not None and not (np.isfinite(chunk) and chunk >= 1):
        raise IsoconvertError(
            f"--fragment-size: precomputed fragments are 1 voxel a side or more, got {chunk}"
        )


def _check_lods(lods) -> None:
    if isinstance(lods, bool) or not isinstance(lods, int | np.integer) or lods < 1:
        raise IsoconvertError(
            f"--lods: a precomputed layer has 1 level of detail or more (level 0, the mesh "
            f"as extracted, counts), got {lods!r}"
        )


def layer_transform(
    grid: dict, unit: str | None, voxel_frame: bool = False
) -> tuple[np.ndarray, float]:
    """The stored-model-to-nanometre transform of a volume's index space.

    Parameters
    ----------
    grid : dict
        ``shape``, ``origin``, ``affine`` (index offsets to world offsets).
    unit : str or None
        The volume's length unit; None or an unknown name counts as nanometres.
    voxel_frame : bool
        The frame of the layer's own voxels instead of the world: sample (i, j, k)
        at the centre of voxel ``[i, i + 1) x resolution`` (Neuroglancer's), the
        resolution being the spacing along each index axis; no origin, no rotation.

    Returns
    -------
    transform : (3, 4) float64
        ``[A | o]`` in nanometres: world = A @ index + o.
    nm_per_unit : float
    """
    per = meters_per_unit(unit)
    nm = 1.0 if per is None else per * 1e9
    affine = np.asarray(grid["affine"], dtype=np.float64) * nm
    if voxel_frame:
        resolution = np.linalg.norm(affine, axis=0)
        return np.column_stack([np.diag(resolution), 0.5 * resolution]), nm
    origin = np.asarray(grid["origin"], dtype=np.float64) * nm
    return np.column_stack([affine, origin]), nm


def write_precomputed(
    folder: str | Path,
    meshes: Mapping[int, Mesh],
    grid: dict,
    *,
    unit: str | None = None,
    data_type: str = "uint64",
    lods: int = 1,
    collapse: Collapse | None = None,
    bits: int = 16,
    chunk: float | None = None,
    sharded: bool = False,
    legacy: bool = False,
    volume: Volume | None = None,
    background: int = 0,
    force: bool = False,
    on_status: Callable[[str], None] | None = None,
    map_objects: ObjectMap | None = None,
    object_threads: int | None = None,
    parts: Callable[[int], MeshParts] | None = None,
) -> Path:
    """Write meshes as one Neuroglancer precomputed segmentation layer.

    Parameters
    ----------
    folder : str or Path
        The layer's folder; it appears whole or not at all (built beside it and
        renamed into place).
    meshes : mapping of int to Mesh
        Each object's surface, keyed by its segment id (> 0): ``vertices (V, 3)``
        in the world frame of ``grid``, ``cells (C, 3)``.
    grid : dict
        The volume's grid (``shape``, ``origin``, ``affine``).
    unit : str or None
        The volume's length unit (nanometres when None or unknown).
    data_type : str
        The labels' type, one of uint8, uint16, uint32, uint64.
    lods : int
        Levels of detail, 1 or more.
    collapse : callable or None
        ``collapse(mesh, bound, locked)``, the bounded collapse (:data:`Collapse`);
        needed for more than one level. An object of more than
        :data:`LARGE_OBJECT` triangles cut into fragments from its ``parts`` is
        collapsed in slabs (:func:`_coarse_levels`), any other whole.
    bits : int
        Vertex quantization bits, 10 or 16.
    chunk : float or None
        The octree's finest nodes, in index units (cubes): an object larger is cut
        into fragments a viewer can load one by one. None: a fragment per level.
    sharded : bool
        Store the objects in shard files (``neuroglancer_uint64_sharded_v1``)
        instead of two files each.
    legacy : bool
        The legacy single-resolution mesh format (one level, one fragment per
        object, not sharded).
    volume : Volume or None
        Also store this label volume's voxels (the one the meshes came from),
        compressed_segmentation chunks; ``data_type`` is then uint32 or uint64.
    background : int
        The label of ``volume`` stored as 0 (no segment).
    force : bool
        Replace an existing folder.
    on_status : callable or None
        Receives notes.
    map_objects : callable or None
        ``map_objects(write_object, tasks)``: ``write_object(*args)`` for each
        ``(what, args)`` of ``tasks`` (an iterable; ``what``, such as "object 3",
        names the task in errors), the results in their order; where the objects
        (or, with ``parts``, their rows of fragments) are encoded (a Dask cluster's
        workers, say). None: here, objects side by side on threads when there are
        coarser levels to decimate.
    object_threads : int or None
        Objects encoded here at once; None: as many as the kernels' threads when
        there are coarser levels to decimate (each holds its object's collapses),
        else 1.
    parts : callable or None
        ``parts(segment)``: the object of ``meshes[segment]`` in parts, for a layer
        cut into fragments: each z-row of level-0 fragments is made from the
        triangles that reach it, one task each (here, or by ``map_objects``), and
        no object's whole mesh is built (the same bytes); with coarser levels, only
        for objects of more than :data:`LARGE_OBJECT` triangles (the others whole).
        None: every object from its whole mesh.

    Returns
    -------
    Path
        The folder.

    Raises
    ------
    IsoconvertError
        A bad option or mesh, DracoPy or meshoptimizer missing.
    OutputError
        The folder exists (without ``force``) or cannot be written.
    """
    if not legacy:
        _dracopy()  # missing: one line before any work
    if bits not in QUANTIZATION_BITS:
        raise IsoconvertError(f"precomputed: quantization bits must be 10 or 16, got {bits}")
    _check_lods(lods)
    _check_chunk(chunk)
    if lods > 1 and collapse is None:
        raise IsoconvertError("precomputed: levels of detail above 0 need a collapse function")
    _check_legacy(legacy, lods, chunk, sharded)
    if data_type not in _DATA_TYPES:
        raise IsoconvertError(
            f"precomputed: labels of type {data_type} cannot be a segmentation; "
            f"one of {', '.join(_DATA_TYPES)}"
        )
    clean = normalized_grid(grid)
    if clean is None or len(clean["shape"]) != 3:
        raise IsoconvertError("precomputed: needs the 3D grid the meshes were extracted on")
    for segment in meshes:
        if isinstance(segment, bool) or not isinstance(segment, int | np.integer) or segment < 1:
            raise IsoconvertError(f"precomputed: segment ids must be integers > 0, got {segment!r}")
    folder = Path(folder)
    if folder.exists() and not force:
        raise OutputError(f"{folder} exists; pass --force to replace it")
    _check_replaceable(folder)
    transform, nm = layer_transform(clean, unit, voxel_frame=volume is not None)
    if meters_per_unit(unit) is None and on_status:
        on_status("note: the volume's unit is unknown; the layer takes one unit as 1 nm")
    if volume is not None and on_status and not _axis_aligned_at_zero(clean):
        on_status(
            "note: a precomputed volume has no origin or direction; the layer's voxels and "
            "meshes are in the grid's own frame (voxel 0 at 0 nm, axes as stored)"
        )
    inverse = np.linalg.inv(np.asarray(clean["affine"], dtype=np.float64))
    origin = np.asarray(clean["origin"], dtype=np.float64)

    if volume is not None and data_type not in ("uint32", "uint64"):
        raise IsoconvertError(
            f"precomputed: compressed_segmentation voxels are uint32 or uint64, not {data_type}"
        )

    with atomic_folder(folder, force) as work:
        (work / "mesh").mkdir()
        info = _layer_info(clean, nm, data_type)
        if volume is not None:
            scale = volume_scale(info["scales"][0]["size"], info["scales"][0]["resolution"])
            info["scales"] = [scale]
            write_chunks(work / scale["key"], volume, background, data_type)
        _write_json(work / "info", info)
        if legacy:
            _write_json(work / "mesh" / "info", {"@type": "neuroglancer_legacy_mesh"})
            for segment, mesh in meshes.items():
                _check_mesh(int(segment), mesh)
                _write_legacy(work / "mesh", int(segment), mesh, origin, inverse, transform)
            return folder
        mesh_info = {
            "@type": "neuroglancer_multilod_draco",
            "vertex_quantization_bits": bits,
            "transform": [float(x) for x in transform.ravel()],
            "lod_scale_multiplier": 1.0,
        }
        spec = _sharding(len(meshes)) if sharded else None
        if spec is not None:
            mesh_info["sharding"] = spec
        _write_json(work / "mesh" / "info", mesh_info)

        # sharded: each object's bytes wait in one file of the part folder as they
        # come (a layer of millions of objects does not fit in memory), and the
        # shards are put together from it at the end
        with contextlib.ExitStack() as stack:
            spill = None
            if spec is not None:
                spill = stack.enter_context(_ObjectSpill(work / "mesh"))
            where = work / "mesh" if spill is None else spill.fragments
            plans: deque[tuple[int, _Rows | None]] = deque()
            jobs = _tasks(meshes, parts, plans, origin, inverse, lods, bits, chunk, collapse)
            if map_objects is None:
                # objects side by side: the coarser levels' collapses are most of the
                # work, and their kernels leave the interpreter free (one level:
                # Draco's encoder mostly holds it, and 15,625 small objects took as
                # long on two threads as on one). Unsharded, each thread writes its
                # object's fragments; sharded, they wait in the one spill file.
                threads = object_threads or (kernel_threads() if lods > 1 else 1)
                done = threaded_in_order(
                    _call,
                    (
                        (_encode_and_write, str(where / str(segment)), encode, *args)
                        if encode is encode_object and spill is None
                        else (encode, *args)
                        for segment, _, encode, args in jobs
                    ),
                    threads,
                )
                stack.callback(done.close)
            else:
                # elsewhere (a cluster's workers): each object's task writes its
                # fragments into the part folder itself when it sees it, and only
                # the manifest comes back (see write_object); a row's fragments and
                # a slab's collapse come back, to be put together here
                done = map_objects(
                    write_object,
                    (
                        (
                            what,
                            (
                                str(where / str(segment)) if encode is encode_object else None,
                                str(folder),
                                encode,
                                *args,
                            ),
                        )
                        for segment, what, encode, args in jobs
                    ),
                )
                if hasattr(done, "close"):  # stops the work left when this fails
                    stack.callback(done.close)
            for first in done:
                # the plan of the object whose first result this is (queued with its
                # tasks, which were taken before their results came)
                segment, plan = plans.popleft()
                if plan is None:
                    manifest, data = first
                else:
                    level: dict = {}
                    for fragments in [first, *(next(done) for _ in range(plan.rows - 1))]:
                        level.update(fragments)
                    slabs = [next(done) for _ in range(plan.slabs)]
                    coarser = plan.coarse(slabs) if plan.coarse is not None else []
                    manifest, data = _assemble([level, *coarser], plan.shape, plan.grid_origin)
                written = isinstance(data, int)  # its size: the task wrote the data
                if spec is None:
                    (work / "mesh" / f"{segment}.index").write_bytes(manifest)
                    if not written:
                        (work / "mesh" / f"{segment}").write_bytes(data)
                else:
                    spill.add(segment, data, manifest)
            if spill is not None:
                _write_shards(work / "mesh", spill, spec)
    return folder


class _ObjectSpill:
    """Objects' fragment data and manifests in one file, read back one at a time.

    The fragment data of an object a cluster's task wrote itself is in its own
    file of :attr:`fragments` instead, removed once read.

    Parameters
    ----------
    folder : Path
        The layer's part folder's mesh folder (so a failed run leaves nothing).
    """

    def __init__(self, folder: Path) -> None:
        self.path = folder / ".objects"
        self.fragments = folder / ".fragments"
        self.fragments.mkdir()
        self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by __exit__)
        self._at = 0
        #: segment -> (offset, fragment data bytes, manifest bytes, data in fragments)
        self.sizes: dict[int, tuple[int, int, int, bool]] = {}

    def add(self, segment: int, data: bytes | int, manifest: bytes) -> None:
        """The object's bytes, or (an int) the size of those written to its file."""
        self._file.seek(self._at)
        written = isinstance(data, int)
        if not written:
            self._file.write(data)
        self._file.write(manifest)
        size = data if written else len(data)
        self.sizes[segment] = (self._at, size, len(manifest), written)
        self._at += (0 if written else size) + len(manifest)

    def read(self, segment: int) -> bytes:
        """The object's fragment data followed by its manifest."""
        at, data, manifest, written = self.sizes[segment]
        self._file.seek(at)
        if not written:
            return self._file.read(data + manifest)
        path = self.fragments / str(segment)
        fragments = path.read_bytes()
        path.unlink()
        return fragments + self._file.read(manifest)

    def __enter__(self) -> _ObjectSpill:
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()
        self.path.unlink(missing_ok=True)
        shutil.rmtree(self.fragments, ignore_errors=True)


def encode_object(
    vertices: np.ndarray,
    cells: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    lods: int,
    bits: int,
    chunk: float | None,
    collapse: Collapse | None,
) -> tuple[bytes, bytes]:
    """One object's manifest and fragment data: its levels of detail (the coarser
    ones by ``collapse``), cut and Draco-encoded (:func:`_object`). A module-level
    function of arrays and scalars, so that a cluster's worker can run it.

    Parameters
    ----------
    vertices : (V, 3) float64
        World positions.
    cells : (C, 3) int64
    origin : (3,) float64
    inverse : (3, 3) float64
        The grid's origin and the inverse of its affine: index = inverse @ (world - origin).
    lods, bits, chunk, collapse
        As :func:`write_precomputed`.
    """
    full = Mesh(_index_of(vertices, origin, inverse), np.asarray(cells, dtype=np.int64))
    levels = [full] + [_collapsed(full, float(2 ** (k - 1)), collapse) for k in range(1, lods)]
    return _object(levels, bits, _dracopy(), chunk)


#: Triangles of an object above which its coarser levels are collapsed in z-slabs
#: of about :data:`SLAB_TRIANGLES` each (:func:`_coarse_levels`), not whole: the
#: bounded collapse holds about 290 bytes a triangle of its input.
LARGE_OBJECT = 1 << 19
SLAB_TRIANGLES = 1 << 18


@dataclass(frozen=True)
class _Rows:
    """An object made a z-row of level-0 nodes at a time: its octree, its rows'
    count, and, with coarser levels, its slabs' count and what makes the levels
    from their collapses (:func:`_coarse_fragments`)."""

    shape: np.ndarray
    grid_origin: np.ndarray
    rows: int
    slabs: int = 0
    coarse: Callable[[list[tuple]], list[dict]] | None = None


def _tasks(
    meshes: Mapping[int, Mesh],
    parts: Callable[[int], MeshParts] | None,
    plans: deque,
    origin: np.ndarray,
    inverse: np.ndarray,
    lods: int,
    bits: int,
    chunk: float | None,
    collapse: Collapse | None,
) -> Iterator[tuple[int, str, Callable, tuple]]:
    """Each object's tasks, ``(segment, what, encode, args)``, an object at a time,
    its plan put in ``plans`` before them: ``(segment, None)`` for one
    :func:`encode_object` task (its whole mesh), or ``(segment, _Rows)`` for an
    object given in parts that is cut into fragments with one level, or for one
    large (:data:`LARGE_OBJECT` triangles) with more, given in parts or whole
    (:class:`_WholeParts`): level 0 is one :func:`encode_row`
    task per z-row of nodes its box reaches, each made of the triangles that reach
    the row, so that no object's whole mesh is built (the same bytes, as
    :func:`_cut_level` makes each row from those triangles alone), or, held by one
    node, one :func:`encode_node` task; then a large one's coarser levels are one
    :func:`collapse_slab` task per z-slab of it (:func:`_coarse_levels`)."""
    top = float(2**bits - 1)

    def to_index(world: np.ndarray) -> np.ndarray:
        return _index_of(world, origin, inverse)

    for key in meshes:  # a mapping that builds each mesh when asked for is asked once
        segment = int(key)
        mesh = pieces = None
        if parts is not None:
            pieces = parts(segment)
        else:
            mesh = meshes[key]
            _check_mesh(segment, mesh)
            if lods > 1 and len(mesh.cells) > LARGE_OBJECT:  # coarser levels from slabs too
                pieces = _WholeParts(mesh)
        large = pieces is not None and lods > 1 and pieces.n_cells > LARGE_OBJECT
        if pieces is not None and (chunk is not None or large):
            lo, hi = pieces.extent(to_index)
            grid_origin, shape, cut = _frame(lo, hi, chunk)
            if large or (cut and lods == 1):
                frame = _level_frame(grid_origin, shape, 0, top, lo, hi)
                rows = _rows(frame) if cut else range(1)
                plan = _Rows(shape, grid_origin, len(rows))
                if large:  # and its slabs, collapsed for its coarser levels
                    octree = (grid_origin, shape, top, lo, hi, cut)
                    coarse = functools.partial(_coarse_fragments, lods, collapse, octree, bits)
                    plan = replace(plan, slabs=-(-pieces.n_cells // SLAB_TRIANGLES), coarse=coarse)
                plans.append((segment, plan))
                if not cut:  # level 0 is one fragment: the whole mesh
                    whole = pieces.whole()
                    args = (whole.vertices, whole.cells, origin, inverse, grid_origin, shape, bits)
                    del whole
                    yield segment, f"object {segment}, level 0", encode_node, args
                for row in rows if cut else ():
                    part = pieces.reaching(to_index, *_row_span(frame, row))
                    args = (part.vertices, part.cells, origin, inverse, frame, row, bits)
                    yield segment, f"object {segment}, z-row {row} of fragments", encode_row, args
                for n, (slab, used, shared) in enumerate(pieces.slabs(to_index, plan.slabs)):
                    args = (slab.vertices, slab.cells, used, shared, origin, inverse, collapse)
                    yield segment, f"object {segment}, slab {n} of its levels", collapse_slab, args
                continue
        if mesh is None:
            mesh = pieces.whole()
            _check_mesh(segment, mesh)
        plans.append((segment, None))
        args = (mesh.vertices, mesh.cells, origin, inverse, lods, bits, chunk, collapse)
        yield segment, f"object {segment}", encode_object, args


class _WholeParts:
    """An object given whole as :class:`~isoconvert.mesh.MeshParts` (a large
    isosurface, a post-processed label), so that its coarser levels come from
    slabs as a label's do: each triangle's slab by its lowest corner."""

    def __init__(self, mesh: Mesh) -> None:
        self._mesh = mesh
        self._cells = np.asarray(mesh.cells, dtype=np.int64)
        self._low = self._high = self._box = None

    @property
    def n_cells(self) -> int:
        return len(self._cells)

    def _extents(self, to_index: Callable) -> None:
        if self._low is None:
            index = to_index(np.asarray(self._mesh.vertices, dtype=np.float64))
            self._box = index.min(axis=0), index.max(axis=0)
            self._low, self._high = _extent(index, self._cells, 2)

    def extent(self, to_index: Callable) -> tuple[np.ndarray, np.ndarray]:
        self._extents(to_index)
        return self._box

    def reaching(self, to_index: Callable, low: float, high: float) -> Mesh:
        self._extents(to_index)
        return self._part((self._high >= low) & (self._low <= high))[0]

    def slabs(
        self, to_index: Callable, count: int
    ) -> Iterator[tuple[Mesh, np.ndarray, np.ndarray]]:
        self._extents(to_index)
        order, ends, shared, base = slab_split(self._low, self._cells, count)
        for n in range(count):
            mesh, used = self._part(order[ends[n] : ends[n + 1]])
            yield mesh, used, shared[used - base]

    def _part(self, taken: np.ndarray) -> tuple[Mesh, np.ndarray]:
        """The triangles ``taken`` selects, over the vertices they use, in order."""
        used, local = np.unique(self._cells[taken], return_inverse=True)
        return Mesh(np.asarray(self._mesh.vertices)[used], local.reshape(-1, 3)), used

    def whole(self) -> Mesh:
        return self._mesh


def _coarse_fragments(
    lods: int, collapse: Collapse, octree: tuple, bits: int, slabs: list[tuple]
) -> list[dict[tuple[int, int, int], bytes]]:
    """A large object's coarser levels from its slabs' collapses
    (:func:`_coarse_levels`), cut and encoded (``octree``: its grid origin, finest
    nodes' shape, ``top``, box, and whether it is cut: else each level is one
    fragment)."""
    grid_origin, shape, top, lo, hi, cut = octree
    levels = []
    for k, mesh in enumerate(_coarse_levels(slabs, lods, collapse), start=1):
        if cut:
            frame = _level_frame(grid_origin, shape, k, top, lo, hi)
            level = _cut_level(mesh.vertices, mesh.cells, frame)
        else:
            level = _one_node(mesh.vertices, mesh.cells, grid_origin, shape * 2.0**k, top)
        levels.append(_encoded(level, bits, _dracopy()))
    return levels


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
    ``shape``), Draco-encoded: a task of arrays and scalars, as :func:`encode_row`.
    ``vertices`` are world positions, the rest as :func:`encode_object`'s."""
    index = _index_of(vertices, origin, inverse)
    level = _one_node(index, np.asarray(cells, np.int64), grid_origin, shape, float(2**bits - 1))
    return _encoded(level, bits, _dracopy())


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
    index = _index_of(vertices, origin, inverse)
    local = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    if not len(local):
        return used[:0], index[:0], local
    near = shared[local].any(axis=1)
    kept = shared.copy()
    kept[local[near].reshape(-1)] = True
    out = collapse(Mesh(index, local), 0.5, kept)
    still = np.unique(out)
    return used[still], index[still], used[out]


def _coarse_levels(slabs: list[tuple], lods: int, collapse: Collapse) -> list[Mesh]:
    """Levels 1 to ``lods - 1`` of a large object (index coordinates), never
    collapsing its whole mesh: level 1 is collapsed in z-slabs of about
    :data:`SLAB_TRIANGLES` triangles each, within half its bound of its slab
    (:func:`collapse_slab`: ``slabs`` are their results; the vertices a slab shares
    with others, and their neighbours, kept, so that the slabs still meet and no
    two collapses join the same two shared vertices); then level k is the slabs'
    union collapsed whole within the rest of its bound, ``2**(k - 1) - 0.5``. The
    bounds add: level k lies within ``2**(k - 1)`` of level 0 both ways, as a
    whole collapse's would. The union is a fraction of the object (1.5 M
    triangles to 60k on the benchmark's bumpy ball), and collapsing level 2 from
    it rather than from level 1 keeps a quarter fewer triangles."""
    ids, positions, cells = zip(*slabs, strict=True)
    # the union, over the vertices its triangles use (a shared one, in two slabs,
    # has one position), in the order of their ids
    every, first = np.unique(np.concatenate(ids), return_index=True)
    union = Mesh(np.concatenate(positions)[first], np.searchsorted(every, np.concatenate(cells)))
    return [_collapsed(union, 2.0 ** (k - 1) - 0.5, collapse) for k in range(1, lods)]


def _collapsed(mesh: Mesh, bound: float, collapse: Collapse) -> Mesh:
    """``mesh`` collapsed within ``bound``, its vertices those still used, in order."""
    out = collapse(mesh, bound, None)
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[out.reshape(-1)] = True
    return Mesh(np.asarray(mesh.vertices)[used], (np.cumsum(used) - 1)[out])


def encode_row(
    vertices: np.ndarray,
    cells: np.ndarray,
    origin: np.ndarray,
    inverse: np.ndarray,
    frame: _Octree,
    row: int,
    bits: int,
) -> dict[tuple[int, int, int], bytes]:
    """One z-row of nodes of an object's level 0, cut (:func:`_cut_level`) and
    Draco-encoded: a task of arrays and scalars, which a cluster's worker can run.

    Parameters
    ----------
    vertices : (V, 3) float64
        World positions of the triangles that reach the row (and its snapping
        distance), in the object's order, over its vertices in theirs.
    cells : (C, 3) int64
    origin, inverse
        As :func:`encode_object`.
    frame : _Octree
        The object's level 0.
    row : int
    bits : int

    Returns
    -------
    dict
        Each node's position and its Draco fragment.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    level = _cut_level(_index_of(vertices, origin, inverse), cells, frame, [row])
    return _encoded(level, bits, _dracopy())


def _index_of(world: np.ndarray, origin: np.ndarray, inverse: np.ndarray) -> np.ndarray:
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
    :func:`encode_row`, :func:`encode_node` or :func:`collapse_slab`. An object's
    fragment data is written by the task itself to ``target`` (in the layer's part
    folder) when it sees that folder (a file system shared with the client, as a
    cluster's output usually is), and only the manifest and the data's size come
    back; a task that does not see it sends the data back instead, for the client
    to write. The others' results (``target`` None) always come back: a row's or
    a node's fragments, to be put in the object's order, and a slab's collapse.

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
    tuple or dict
        An object's manifest and fragment data (bytes, or its size once written
        to ``target``); a row's fragments by node; a slab's collapse.
    """
    from ..atomic import DISK_FULL_ERRNOS, disk_full_error

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


def _encode_and_write(target: str, encode: Callable, *args) -> tuple[bytes, int]:
    """``encode(*args)`` (:func:`encode_object`), its fragment data written to
    ``target``: the manifest and the data's size."""
    manifest, data = encode(*args)
    Path(target).write_bytes(data)
    return manifest, len(data)


def _call(function: Callable, *args):
    """``function(*args)``: a pair of a function and its arguments run on a thread."""
    return function(*args)


def _axis_aligned_at_zero(grid: dict) -> bool:
    """Whether a grid's world frame is its voxel frame already: origin 0, no rotation."""
    affine = np.asarray(grid["affine"], dtype=np.float64)
    return not np.any(grid["origin"]) and np.array_equal(affine, np.diag(np.diag(affine)))


def _write_legacy(
    folder: Path,
    segment: int,
    mesh: Mesh,
    origin: np.ndarray,
    inverse: np.ndarray,
    transform: np.ndarray,
) -> None:
    """One object in the legacy format: its manifest ``<id>:0`` and its one fragment
    ``<id>:0:0`` (vertex count, float32 nanometres in the layer's frame, uint32
    triangles, all little-endian)."""
    index = (np.asarray(mesh.vertices, dtype=np.float64) - origin) @ inverse.T
    nm = index @ transform[:, :3].T + transform[:, 3]
    fragment = f"{segment}:0:0"
    _write_json(folder / f"{segment}:0", {"fragments": [fragment]})
    (folder / fragment).write_bytes(
        b"".join(
            [
                np.uint32(len(nm)).astype("<u4").tobytes(),
                nm.astype("<f4").tobytes(),
                np.asarray(mesh.cells).astype("<u4").tobytes(),
            ]
        )
    )


def object_file(segment: int, objects: int, *, sharded: bool = False, legacy: bool = False) -> str:
    """The file of a layer's mesh folder that holds ``segment``, one of ``objects``:
    its fragments (multi-resolution), its manifest (legacy) or its shard."""
    if legacy:
        return f"{segment}:0"
    if not sharded:
        return str(segment)
    spec = _sharding(objects)
    return _shard_name(_shard_of(segment, spec)[0], spec)


def _shard_of(segment: int, spec: dict) -> tuple[int, int]:
    """(shard, minishard) of ``segment``: the identity hash, no preshift."""
    minishard = segment & ((1 << spec["minishard_bits"]) - 1)
    return (segment >> spec["minishard_bits"]) & ((1 << spec["shard_bits"]) - 1), minishard


def _shard_name(shard: int, spec: dict) -> str:
    digits = max(1, -(-spec["shard_bits"] // 4))
    return f"{shard:0{digits}x}.shard"


def _sharding(objects: int) -> dict:
    """A sharding specification for ``objects`` segments: the identity hash (segment
    ids are the labels, spread over the low bits already), about 64 objects per
    minishard and 64 minishards per shard."""
    bits = max(0, int(np.ceil(np.log2(max(objects, 1) / 64))))
    minishard_bits = min(bits, 6)
    return {
        "@type": "neuroglancer_uint64_sharded_v1",
        "preshift_bits": 0,
        "hash": "identity",
        "minishard_bits": minishard_bits,
        "shard_bits": bits - minishard_bits,
        "minishard_index_encoding": "gzip",
        "data_encoding": "raw",
    }


def _write_shards(folder: Path, objects: _ObjectSpill, spec: dict) -> None:
    """The shard files of sharded.md: per shard, the shard index, then each object's
    fragment data followed by its manifest (the minishard index points at the
    manifest, as meshes.md asks), then the gzip-encoded minishard indices. The
    layout comes from the objects' sizes; their bytes are copied one at a time."""
    import gzip

    minishards = 1 << spec["minishard_bits"]
    shards: dict[int, dict[int, list[int]]] = {}
    for segment in sorted(objects.sizes):
        shard, minishard = _shard_of(segment, spec)
        shards.setdefault(shard, {}).setdefault(minishard, []).append(segment)
    for shard, by_minishard in shards.items():
        order, indices, at = [], [], 0
        for minishard in range(minishards):
            ids = by_minishard.get(minishard, [])
            starts, sizes = [], []
            for segment in ids:
                _, data, manifest, _ = objects.sizes[segment]
                order.append(segment)
                starts.append(at + data)
                sizes.append(manifest)
                at += data + manifest
            indices.append((ids, starts, sizes))
        index, tail, place = [], [], at
        for ids, starts, sizes in indices:
            if not ids:
                index.append((place, place))
                continue
            starts_, sizes_ = np.array(starts, np.int64), np.array(sizes, np.int64)
            ends = starts_ + sizes_
            # ids delta-encoded; starts relative to the end of the chunk before
            table = np.array(
                [np.diff(ids, prepend=0), starts_ - np.r_[0, ends[:-1]], sizes_], dtype="<u8"
            )
            encoded = gzip.compress(table.tobytes(), mtime=0)
            index.append((place, place + len(encoded)))
            tail.append(encoded)
            place += len(encoded)
        with open(folder / _shard_name(shard, spec), "wb") as out:
            out.write(np.array(index, dtype="<u8").tobytes())
            for segment in order:
                out.write(objects.read(segment))
            for encoded in tail:
                out.write(encoded)


def _check_mesh(segment: int, mesh: Mesh) -> None:
    cells = np.asarray(mesh.cells)
    vertices = np.asarray(mesh.vertices)
    if cells.ndim != 2 or cells.shape[1] != 3 or not len(cells):
        raise IsoconvertError(f"precomputed: segment {segment} has no triangles")
    if cells.min() < 0 or cells.max() >= len(vertices):
        raise IsoconvertError(f"precomputed: a triangle of segment {segment} refers to no vertex")
    if not np.isfinite(vertices).all():
        raise IsoconvertError(f"precomputed: segment {segment} has non-finite vertices")


def _dracopy():
    try:
        import DracoPy
    except ImportError:
        raise IsoconvertError(
            f"the precomputed format needs DracoPy: {extra_hint('precomputed')}"
        ) from None
    return DracoPy


def _layer_info(grid: dict, nm: float, data_type: str) -> dict:
    """The segmentation layer's ``info``: one scale, the volume's size and spacing."""
    affine = np.asarray(grid["affine"], dtype=np.float64)
    resolution = [float(x) for x in np.linalg.norm(affine, axis=0) * nm]
    size = [int(x) for x in grid["shape"]]
    return {
        "@type": "neuroglancer_multiscale_volume",
        "type": "segmentation",
        "data_type": data_type,
        "num_channels": 1,
        "scales": [
            {
                "key": "_".join(f"{r:g}" for r in resolution),
                "size": size,
                "resolution": resolution,
                "voxel_offset": [0, 0, 0],
                "chunk_sizes": [[min(64, s) for s in size]],
                "encoding": "raw",
            }
        ],
        "mesh": "mesh",
    }


def _object(
    levels: list[Mesh], bits: int, draco, chunk: float | None = None
) -> tuple[bytes, bytes]:
    """One object's manifest and fragment data.

    The octree's finest nodes are ``chunk`` index units wide (cubes), or, when
    ``chunk`` is None or the object fits in one, the object's bounding box: then
    every level is a single fragment. Otherwise each level's mesh is cut at the
    planes of its nodes' 2x2x2 partition and its triangles go to the node holding
    their centroid, one z-row of nodes at a time (:func:`_cut_level`).
    """
    lo = np.min([m.vertices.min(axis=0) for m in levels], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in levels], axis=0)
    grid_origin, shape, cut = _frame(lo, hi, chunk)
    top = float(2**bits - 1)
    nodes = []
    for k, mesh in enumerate(levels):
        vertices, cells = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.cells, np.int64)
        if cut:
            nodes.append(
                _cut_level(vertices, cells, _level_frame(grid_origin, shape, k, top, lo, hi))
            )
            continue
        # the level lies in the first node (its box is the object's): one fragment
        nodes.append(_one_node(vertices, cells, grid_origin, shape * 2.0**k, top))
    return _assemble([_encoded(level, bits, draco) for level in nodes], shape, grid_origin)


def _one_node(
    vertices: np.ndarray, cells: np.ndarray, grid_origin: np.ndarray, node: np.ndarray, top: float
) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    """A level held by its octree's first node (of shape ``node``): its quantized
    vertices and triangles."""
    if np.bincount(cells.reshape(-1), minlength=len(vertices)).all():
        # every vertex used (as extracted and decimated meshes are): what
        # np.unique would give, without sorting 3C indices
        used, local = np.arange(len(vertices)), cells
    else:
        used, local = np.unique(cells, return_inverse=True)
    q = np.clip(np.rint((vertices[used] - grid_origin) / node * top), 0, top)
    return {(0, 0, 0): (q.astype(np.uint32), local.reshape(-1, 3).astype(np.uint32))}


def _level_frame(
    grid_origin: np.ndarray, shape: np.ndarray, k: int, top: float, lo: np.ndarray, hi: np.ndarray
) -> _Octree:
    """Level ``k``'s nodes, ``2**k`` finest nodes wide, cut at their halves
    (level 0's at their own planes)."""
    node = shape * 2.0**k
    return _Octree(grid_origin, node, node / 2.0 if k else node, top, lo, hi)


def _frame(
    lo: np.ndarray, hi: np.ndarray, chunk: float | None
) -> tuple[np.ndarray, np.ndarray, bool]:
    """An object's octree: its grid origin, its finest nodes' shape, and whether
    it is cut (``chunk`` given and the object larger than one node)."""
    # float32 in the manifest: the box is widened so that float32 rounding of its
    # origin and shape cannot leave a vertex outside it
    origin32 = np.nextafter(lo.astype(np.float32), np.float32(-np.inf))
    grid_origin = origin32.astype(np.float64)
    box32 = np.nextafter(
        np.maximum(hi - grid_origin, 1e-6).astype(np.float32), np.float32(np.inf)
    ).astype(np.float64)
    cut = not (chunk is None or (box32 <= chunk).all())
    return grid_origin, (np.full(3, float(np.float32(chunk))) if cut else box32), cut


def _assemble(
    levels: list[dict[tuple[int, int, int], bytes]], shape: np.ndarray, grid_origin: np.ndarray
) -> tuple[bytes, bytes]:
    """The manifest and the fragment data of an object's levels, each a dict of
    node position to its Draco fragment (:func:`_encoded`)."""
    # every node's parent is listed too (empty when the coarser level has no
    # triangles there), as the viewer walks the octree down from the top
    for k in range(len(levels) - 1):
        for x, y, z in list(levels[k]):
            levels[k + 1].setdefault((x // 2, y // 2, z // 2), b"")
    table, data = [], []
    for level in levels:
        positions = sorted(level, key=_morton)
        table.append((positions, [len(level[p]) for p in positions]))
        data.extend(level[p] for p in positions)
    return _manifest(shape, grid_origin, table), b"".join(data)


def _encoded(level: dict, bits: int, draco) -> dict[tuple[int, int, int], bytes]:
    """A level's (or a row's) nodes' Draco fragments."""
    top = float(2**bits - 1)
    return {position: _encode(draco, *f, bits, top) for position, f in level.items()}


def _manifest(
    shape: np.ndarray, grid_origin: np.ndarray, levels: Sequence[tuple[Sequence, Sequence[int]]]
) -> bytes:
    """An object's manifest: its octree's finest nodes' ``shape`` and grid origin,
    and for each level its nodes' positions, in Z-curve order, with the sizes of
    their fragments."""
    parts = [
        shape.astype("<f4").tobytes(),
        grid_origin.astype("<f4").tobytes(),
        np.uint32(len(levels)).astype("<u4").tobytes(),
        np.array([2.0**k for k in range(len(levels))], "<f4").tobytes(),  # lod_scales
        np.zeros((len(levels), 3), "<f4").tobytes(),  # vertex_offsets
        np.array([len(positions) for positions, _ in levels], "<u4").tobytes(),
    ]
    for positions, sizes in levels:
        parts.append(np.array(positions, "<u4").reshape(-1, 3).T.copy().tobytes())
        parts.append(np.array(sizes, "<u4").tobytes())
    return b"".join(parts)


@dataclass(frozen=True)
class _Octree:
    """One level's nodes: ``origin + index * node`` (index units), the planes of
    their partition every ``split``, the quantization's ``top`` (``2**bits - 1``),
    and the object's box ``lo``..``hi`` (every level's vertices)."""

    origin: np.ndarray
    node: np.ndarray
    split: np.ndarray
    top: float
    lo: np.ndarray
    hi: np.ndarray


def _cut_level(
    vertices: np.ndarray, cells: np.ndarray, frame: _Octree, rows: Iterable[int] | None = None
) -> dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]:
    """One level's fragments: for each node its quantized vertices and triangles.

    The level is cut one z-row of nodes at a time: the triangles reaching the row
    (or within a snapping distance of it) are cut at every plane of the partition
    (:func:`_cut_at_planes`) and the pieces whose centroid lies in the row are
    kept. A triangle is cut the same way in each row that takes it (the same
    planes in the same order, each new vertex from the same two ends), so the rows
    meet exactly; the peak holds one row's pieces, not the whole level's (an
    object of 1.5 million triangles in 64-voxel fragments within ``--max-memory
    256M``: 476 MB cut whole, 344 MB a row at a time, see bench/RESULTS.md).

    Parameters
    ----------
    vertices : (V, 3) float64
        Index coordinates.
    cells : (C, 3) int64
    frame : _Octree
    rows : iterable of int or None
        The z-rows of nodes to make (``vertices`` and ``cells`` then need hold only
        the triangles that reach them, in the level's order, their vertices in
        theirs: :func:`encode_parts`); None: every row of the object.
    """
    level: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
    low, high = _extent(vertices, cells, 2)
    for row in _rows(frame) if rows is None else rows:
        start, end = _row_span(frame, row)
        taken = (high >= start) & (low <= end)
        if not taken.any():
            continue
        # the row's vertices in their order in the level (so that each cut takes
        # an edge's ends in the same order in every row)
        used, local = np.unique(cells[taken], return_inverse=True)
        part, pieces = _cut_at_planes(vertices[used], local.reshape(-1, 3), frame)
        centroid = part[pieces].mean(axis=1)
        where = np.maximum(np.floor((centroid - frame.origin) / frame.node).astype(np.int64), 0)
        mine = where[:, 2] == row
        if not mine.any():  # the row's triangles are all in the rows beside it
            continue
        where, pieces = where[mine], pieces[mine]
        order = np.lexsort(where.T[::-1])
        where, pieces = where[order], pieces[order]
        starts = np.flatnonzero(np.r_[True, (where[1:] != where[:-1]).any(axis=1)])
        for a, b in zip(starts, np.r_[starts[1:], len(pieces)], strict=True):
            kept, corners = np.unique(pieces[a:b], return_inverse=True)
            origin = frame.origin + where[a] * frame.node
            q = np.clip(np.rint((part[kept] - origin) / frame.node * frame.top), 0, frame.top)
            # corners the cuts left within a step of each other share a quantized
            # position: one vertex, and the triangles between them (no area) go;
            # on a seam both fragments see the same positions, so they merge alike
            # and the seam stays closed
            # (one key per position, in the order np.unique(q, axis=0) gives, faster)
            keys = q.astype(np.int64)
            keys, same = np.unique(keys[:, 0] << 32 | keys[:, 1] << 16 | keys[:, 2],
                                   return_inverse=True)  # fmt: skip
            q = np.stack([keys >> 32, (keys >> 16) & 0xFFFF, keys & 0xFFFF], axis=1)
            corners = same.reshape(-1)[corners.reshape(-1, 3)]
            corners = corners[(corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2])
                              & (corners[:, 0] != corners[:, 2])]  # fmt: skip
            position = tuple(int(x) for x in where[a])
            level[position] = (q.astype(np.uint32), corners.astype(np.uint32))
    return level


def _rows(frame: _Octree) -> range:
    """The z-rows of nodes an object's box reaches."""
    span = np.floor((np.array([frame.lo[2], frame.hi[2]]) - frame.origin[2]) / frame.node[2])
    return range(max(int(span[0]), 0), int(span[1]) + 1)


def _row_span(frame: _Octree, row: int) -> tuple[float, float]:
    """The z-range whose triangles a row of nodes takes: the row, and a snapping
    distance (a quantization step) beyond it each way."""
    start = frame.origin[2] + row * frame.node[2]
    reach = frame.node[2] / frame.top
    return start - reach, start + frame.node[2] + reach


def _cut_at_planes(
    vertices: np.ndarray, cells: np.ndarray, frame: _Octree
) -> tuple[np.ndarray, np.ndarray]:
    """Cut triangles at every plane of the partition inside the object's box, x
    planes first, each axis's in increasing order (:func:`_cut`).

    Parameters
    ----------
    vertices : (V, 3) float64
        Changed in place (the snapping, see below).
    cells : (C, 3) int64
    frame : _Octree

    Returns
    -------
    vertices : (V', 3) float64
    cells : (C', 3) int64
    """
    for axis in range(3):
        step = frame.split[axis]
        first = int(np.floor((frame.lo[axis] - frame.origin[axis]) / step)) + 1
        last = int(np.ceil((frame.hi[axis] - frame.origin[axis]) / step)) - 1
        low, high = _extent(vertices, cells, axis)
        for m in range(max(first, 1), last + 1):
            plane = frame.origin[axis] + m * step
            # vertices within a quantization step of the plane go onto it first
            # (igneous snaps too): cut there, they would leave slivers whose
            # corners quantize to one position
            near = np.abs(vertices[:, axis] - plane) < frame.node[axis] / frame.top
            vertices[near, axis] = plane
            # snapping moves a vertex towards this plane only from within a step,
            # never across another: the extents before it still hold every
            # triangle that crosses the plane
            maybe = np.flatnonzero((low < plane) & (high > plane))
            if not len(maybe):
                continue
            count = len(cells)
            vertices, cells, kept = _cut(vertices, cells, axis, plane, maybe)
            if len(kept) != count:  # cut: the pieces' extents after the others'
                pieces = cells[len(kept) :]
                new_low, new_high = _extent(vertices, pieces, axis)
                low = np.concatenate([low[kept], new_low])
                high = np.concatenate([high[kept], new_high])
    return vertices, cells


def _extent(vertices: np.ndarray, cells: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's lowest and highest coordinate along ``axis``: (C,) each."""
    x = vertices[:, axis]
    a, b, c = x[cells[:, 0]], x[cells[:, 1]], x[cells[:, 2]]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def _encode(draco, q: np.ndarray, cells: np.ndarray, bits: int, top: float) -> bytes:
    """One Draco fragment, by Draco's edgebreaker (about 5x smaller than its
    sequential encoding on the atlas's labels) when every vertex has a position of
    its own. The edgebreaker merges vertices quantized to one position and drops the
    triangles that become degenerate (a few on half of the atlas's labels, where
    smoothing brings vertices within a step): a fragment with such vertices is
    encoded in its own order instead, every triangle kept (cut fragments merged
    them already, see :func:`_object`)."""
    q = np.asarray(q)
    keys = (q[:, 0].astype(np.int64) << 32) | (q[:, 1].astype(np.int64) << 16) | q[:, 2]
    keys.sort()
    own_positions = not len(keys) or bool((keys[1:] != keys[:-1]).all())
    return draco.encode(
        q,
        cells,
        quantization_bits=bits,
        quantization_range=top,
        quantization_origin=[0.0, 0.0, 0.0],
        compression_level=7,
        preserve_order=not own_positions,
    )


def _morton(position: tuple[int, int, int]) -> int:
    """The Z-curve key of an octree node, x in the lowest bit (meshes.md)."""
    key = 0
    for bit in range(21):
        for axis in range(3):
            key |= ((position[axis] >> bit) & 1) << (3 * bit + axis)
    return key


def _cut(
    vertices: np.ndarray, cells: np.ndarray, axis: int, plane: float, maybe: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split the triangles that cross the plane ``x[axis] = plane`` (strictly) so
    that none does, keeping orientation.

    Each crossing edge gets one new vertex exactly on the plane, computed from its
    ends in increasing index order, so the two triangles beside it share it and
    the surface stays closed. A triangle with a corner on the plane becomes two,
    any other crossing one three.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int64
    maybe : (M,) int64
        The triangles that may cross it (every other one is left as it is).

    Returns
    -------
    vertices : (V + N, 3) float64
    cells : (C', 3) int64
        The triangles that do not cross, in their order, then the pieces.
    kept : (K,) int64
        Where the triangles that do not cross were in ``cells``.
    """
    side = np.sign(vertices[cells[maybe], axis] - plane).astype(np.int8)  # (M, 3)
    through = (side.min(axis=1) < 0) & (side.max(axis=1) > 0)
    if not through.any():
        return vertices, cells, np.arange(len(cells))
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
    u, w = vertices[unique[:, 0]], vertices[unique[:, 1]]
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
    return np.vstack([vertices, new]), np.vstack([cells[kept], two, three]), kept


def _write_json(path: Path, value: dict) -> None:
    path.write_text(json.dumps(value, indent=1) + "\n", encoding="utf-8")
