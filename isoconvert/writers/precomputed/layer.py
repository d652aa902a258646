"""Writing a layer: its checks, its ``info`` files, and its objects' files, made
here or by a caller's ``map_objects`` (a Dask cluster's workers)."""

from __future__ import annotations

import contextlib
import json
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ...atomic import atomic_folder, probe_folder
from ...errors import FormatError, IsoconvertError, OutputError, extra_hint
from ...geometry import normalized_grid
from ...mesh import Mesh, MeshParts
from ...threads import kernel_threads, threaded_in_order
from ...units import meters_per_unit
from ...volume import Volume
from .fragments import dracopy
from .legacy import check_legacy, write_legacy
from .octree import AUTO_CUT, AUTO_FRAGMENT
from .shards import ObjectSpill, sharding, write_shards
from .tasks import (
    Collapse,
    ObjectMap,
    Rows,
    assemble_object,
    check_mesh,
    encode_and_write,
    encode_object,
    object_tasks,
    write_object,
)
from .volume import volume_scale, write_chunks

#: The vertex quantization the format allows.
QUANTIZATION_BITS = (10, 16)

#: Label types a precomputed segmentation may hold.
_DATA_TYPES = ("uint8", "uint16", "uint32", "uint64")

#: Where the precomputed format goes.
LAYER_ONLY = (
    "precomputed writes a folder holding every object's mesh: use it with "
    "convert (--labels or --level) -o FOLDER --format precomputed"
)


def not_a_file(mesh: Mesh, fh, ascii: bool) -> None:
    """The registry's writer entry: a layer is a folder of every object, not a stream."""
    raise FormatError(LAYER_ONLY)


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
    chunk: float | str | None = None,
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
    check_legacy(legacy, lods, chunk, sharded)
    if not legacy:
        dracopy()
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
    probe_folder(folder, parent)  # before any work: the part folder is made there
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder} exists and is not a layer folder; give a folder name")
    # what --force would not replace is said first, so that "pass --force" is
    # given only where it helps
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
    if folder_taken(folder) and not force:
        raise OutputError(f"{folder} exists; pass --force to replace it")


def is_layer(folder: str | Path) -> bool:
    """Whether ``folder`` holds a Neuroglancer precomputed layer (its ``info``
    file names the multiscale volume type)."""
    try:
        info = json.loads((Path(folder) / "info").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and info.get("@type") == "neuroglancer_multiscale_volume"


def _check_replaceable(folder: Path) -> None:
    """Refuse to replace a folder that is not a precomputed layer, or a layer
    holding more than a layer's files: ``--force`` replaces a layer (an empty
    folder is written into without it), never someone's files kept beside one."""
    if not folder_taken(folder):
        return
    if not is_layer(folder):
        raise OutputError(
            f"{folder} is a folder that is not a Neuroglancer layer (no layer info file); "
            "--force replaces only layers: give the layer a new folder name"
        )
    foreign = sorted(p.name for p in folder.iterdir() if p.name not in _layer_entries(folder))
    if foreign:
        shown = ", ".join(foreign[:3]) + (
            f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        )
        them = "them" if len(foreign) > 1 else "it"
        raise OutputError(
            f"{folder} holds {shown} beside its layer, which replacing the layer would "
            f"delete: move {them} out of the folder, or give the layer a new folder name"
        )


def folder_taken(folder: Path) -> bool:
    """Whether ``folder`` is there and not an empty folder (which a layer is
    written into as if it were not there)."""
    if folder.is_symlink() or not folder.is_dir():
        return folder.exists() or folder.is_symlink()
    return any(folder.iterdir())


def _layer_entries(folder: Path) -> set[str]:
    """The names a layer's folder holds as a layer: its info and provenance, its
    mesh folder and its scales' chunk folders, as its info names them."""
    info = json.loads((folder / "info").read_text(encoding="utf-8"))
    names = {"info", "provenance", str(info.get("mesh", "mesh"))}
    names |= {str(scale.get("key")) for scale in info.get("scales", []) if isinstance(scale, dict)}
    return names


def _check_chunk(chunk) -> None:
    if chunk is None or chunk == "auto":
        return
    if isinstance(chunk, str) or not (chunk >= 1):  # inf: one fragment a level
        raise IsoconvertError(
            f"--fragment-size: precomputed fragments are 1 voxel a side or more (inf: one "
            f"per object and level; auto, the default: {AUTO_FRAGMENT:g} for objects of "
            f"more than {AUTO_CUT:,} triangles), got {chunk}"
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
    chunk: float | str | None = "auto",
    sharded: bool = False,
    legacy: bool = False,
    volume: Volume | None = None,
    background: int = 0,
    force: bool = False,
    on_status: Callable[[str], None] | None = None,
    map_objects: ObjectMap | None = None,
    object_threads: int | None = None,
    parts: Callable[[int], MeshParts] | None = None,
    phase: float = 0.0,
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
    chunk : float, "auto" or None
        The octree's finest nodes, in index units (cubes): an object larger is cut
        into fragments a viewer can load one by one. "auto": :data:`AUTO_FRAGMENT`
        (halved while a node holds too many vertices) for objects of more than
        :data:`AUTO_CUT` triangles, one fragment a level for the others
        (:func:`.octree.fragment_size`). None or infinity: one fragment a level.
    phase : float
        Where the cut planes lie in the voxel grid, in index units past the
        samples (:func:`.octree.object_frame`): 0 (isosurfaces, whose triangles
        each lie in one cell between samples) or 0.5 (surface nets).
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
        ``(what, args, kept)`` of ``tasks`` (an iterable; ``what``, such as "object
        3", names the task in errors), the results in their order (a ``kept`` one's
        is a later task's :class:`~.tasks.Preceding` argument alone); where the
        objects (or, with ``parts``, their rows of fragments, and a large object's
        slabs and coarser levels) are encoded (a Dask cluster's workers, say).
        None: here, objects side by side on threads when there are coarser levels
        to decimate.
    object_threads : int or None
        Objects encoded here at once; None: as many as the kernels' threads when
        there are coarser levels to decimate (each holds its object's collapses),
        else 1.
    parts : callable or None
        ``parts(segment)``: the object of ``meshes[segment]`` in parts, for a layer
        cut into fragments: each row of level-0 fragments (along x) is made from the
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
        dracopy()  # missing: one line before any work
    if bits not in QUANTIZATION_BITS:
        raise IsoconvertError(f"precomputed: quantization bits must be 10 or 16, got {bits}")
    _check_lods(lods)
    _check_chunk(chunk)
    if lods > 1 and collapse is None:
        raise IsoconvertError("precomputed: levels of detail above 0 need a collapse function")
    check_legacy(legacy, lods, chunk, sharded)
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
            raise IsoconvertError(
                f"precomputed: segment ids must be integers > 0 (Neuroglancer's 0 is no "
                f"object), got {segment!r}; with --labels, label 0 is left out with "
                "--background 0 (the default)"
            )
    folder = Path(folder)
    _check_replaceable(folder)  # first, as check_layer does
    if folder_taken(folder) and not force:
        raise OutputError(f"{folder} exists; pass --force to replace it")
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
                check_mesh(int(segment), mesh)
                write_legacy(work / "mesh", int(segment), mesh, origin, inverse, transform)
            return folder
        mesh_info = {
            "@type": "neuroglancer_multilod_draco",
            "vertex_quantization_bits": bits,
            "transform": [float(x) for x in transform.ravel()],
            "lod_scale_multiplier": 1.0,
        }
        spec = sharding(len(meshes)) if sharded else None
        if spec is not None:
            mesh_info["sharding"] = spec
        _write_json(work / "mesh" / "info", mesh_info)

        # sharded: each object's bytes wait in one file of the part folder as they
        # come (a layer of millions of objects does not fit in memory), and the
        # shards are put together from it at the end
        with contextlib.ExitStack() as stack:
            spill = None
            if spec is not None:
                spill = stack.enter_context(ObjectSpill(work / "mesh"))
            where = work / "mesh" if spill is None else spill.fragments
            plans: deque[tuple[int, Rows | None]] = deque()
            # on a cluster, an object made in rows is put together by a task too,
            # given its rows' fragments and its slabs' collapses by the workers
            elsewhere = map_objects is not None
            jobs = object_tasks(
                meshes, parts, plans, origin, inverse, lods, bits, chunk, collapse, elsewhere, phase
            )
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
                        (encode_and_write, str(where / str(segment)), encode, *args)
                        if encode is encode_object and spill is None
                        else (encode, *args)
                        for segment, _, encode, args in jobs
                    ),
                    threads,
                )
                stack.callback(done.close)
            else:
                writing = (encode_object, assemble_object)
                # elsewhere (a cluster's workers): each object's task (or the last
                # of an object made in rows, which the others' results go to) writes
                # its fragments into the part folder itself when it sees it, and only
                # the manifest comes back (see write_object)
                done = map_objects(
                    write_object,
                    (
                        (
                            what,
                            (
                                str(where / str(segment)) if encode in writing else None,
                                str(folder),
                                encode,
                                *args,
                            ),
                            encode not in writing,
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
                elif plan.elsewhere:  # the tasks before the last are kept there
                    for _ in range(plan.kept - 1):
                        next(done)
                    manifest, data = next(done)
                else:  # put together here, as the last task does there
                    rows = [first, *(next(done) for _ in range(plan.rows - 1))]
                    slabs = [next(done) for _ in range(plan.slabs)]
                    coarser = [plan.coarse(slabs)] if plan.coarse is not None else None
                    del slabs
                    manifest, data = assemble_object(rows, coarser, plan.shape, plan.grid_origin)
                written = isinstance(data, int)  # its size: the task wrote the data
                if spec is None:
                    (work / "mesh" / f"{segment}.index").write_bytes(manifest)
                    if not written:
                        (work / "mesh" / f"{segment}").write_bytes(data)
                else:
                    spill.add(segment, data, manifest)
            if spill is not None:
                write_shards(work / "mesh", spill, spec)
    return folder


def _call(function: Callable, *args):
    """``function(*args)``: a pair of a function and its arguments run on a thread."""
    return function(*args)


def _axis_aligned_at_zero(grid: dict) -> bool:
    """Whether a grid's world frame is its voxel frame already: origin 0, no rotation."""
    affine = np.asarray(grid["affine"], dtype=np.float64)
    return not np.any(grid["origin"]) and np.array_equal(affine, np.diag(np.diag(affine)))


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


def _write_json(path: Path, value: dict) -> None:
    path.write_text(json.dumps(value, indent=1) + "\n", encoding="utf-8")
