"""The main job: read a volume, extract a surface, write it.

The extraction (:mod:`isoconvert.extract.dispatch`, :mod:`isoconvert.attributes`)
is imported by the functions that extract: :mod:`isoconvert.label_convert`
shares this module's options, reading and checks, and a label run needs none
of the isosurface kernels (about 15 ms of its start, measured on the atlas).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from .atomic import (
    check_output,
    input_file,
    output_stream,
    refuse_given_outputs,
    refuse_inputs,
    refuse_stream,
)
from .errors import FormatError, IsoconvertError, OutputError
from .extract.slabs import Blocks
from .mesh import Mesh, MeshSummary
from .meshfile import READ_SUFFIXES
from .methods import DEFAULT_AMBIGUITY
from .post.pipeline import PostOptions, post_process
from .readers import READERS, ReadOptions, format_suffix, read_volume
from .volume import Volume
from .writers import WRITERS, Writer, check_attributes, output_format
from .writers.stored import stored_mesh, write_mesh

_READ_FIELDS = frozenset(f.name for f in fields(ReadOptions))
_POST_FIELDS = frozenset(f.name for f in fields(PostOptions))


@dataclass(frozen=True)
class ConvertOptions:
    """Everything about one conversion except the paths and the level.

    One value that the Python API, ``isoconvert convert`` and ``isoconvert
    batch`` (per file, with a level mapping's overrides) share, instead of
    loose keywords threaded through every layer.

    Attributes
    ----------
    read : ReadOptions
        Raw layout (shape, dtype, endian, header bytes), channel, and whether a
        header may name data outside its folder.
    input_format : str or None
        Reader name; None guesses from the suffix.
    spacing, origin : tuple of float or None
        Override what the file says (x, y[, z]).
    method : str or None
        Extractor name; None picks squares for 2D and cubes for 3D.
    flip : bool
        Reverse the orientation.
    ambiguity : str or None
        Rule for ambiguous faces; None is the method's default.
    axis : str or None
        squares on a 3D volume: the slice axis.
    vertex_offset : float or None
        Fraction of an edge vertices keep from grid vertices; None: 0.001 only
        when samples equal the level (see :func:`isoconvert.extract`).
    nan_as : float or None
        Value NaN/Inf samples stand for; None makes them an error.
    format : str or None
        Writer name; None takes it from the output suffix.
    ascii : bool
        Text PLY/STL/VTP.
    force : bool
        Overwrite an existing output.
    blocks : Blocks
        Block-wise extraction: slab size, memory budget, Dask scheduler.
    space : str or None
        "lps" or "ras": convert world coordinates to that anatomical frame
        (the file must state its own); None keeps the file's.
    source_name : str or None
        What the mesh records as its source (file headers, reports); None:
        the input as given. (A cluster worker opens the absolute path but
        records the user's spelling, as a local run does.)
    normals : bool
        Write per-vertex normals: the volume's gradient at each vertex
        (:func:`~isoconvert.attributes.vertex_normals`).
    values : str, Path or None
        A volume sampled at each vertex (trilinear, in world coordinates) and
        written as its value (:func:`~isoconvert.attributes.vertex_values`);
        read with the same options as the input.
    post : PostOptions
        Closing, clean-up, smoothing and decimation after extraction.
    labels : tuple of int or None
        A label volume: the labels whose surfaces to extract (empty: every
        label); see :func:`convert_labels`. None: an isosurface.
    single_file : bool
        Labels: one mesh with every boundary once and each triangle's two
        labels, instead of one file per label.
    background : int
        Labels: the value of no label.
    label_smoothing : int or None
        Labels: Surface Nets relaxation iterations (None: 16; 0: the voxel faces).
    lods : int or None
        Levels of detail of a precomputed layer (1: the meshes as extracted;
        None: 3, or 1 with ``legacy_mesh``).
    fragment_size : float, "auto" or None
        A precomputed layer's octree fragments, in voxels a side (None or "auto": 128
        for objects of more than 524,288 triangles, one fragment a level for the
        others; infinity: one fragment per object and level).
    sharded : bool
        A precomputed layer's objects in shard files.
    legacy_mesh : bool
        A precomputed layer's meshes in the legacy single-resolution format.
    with_volume : bool
        A precomputed layer also holds the labels' voxels.
    """

    read: ReadOptions = field(default_factory=ReadOptions)
    input_format: str | None = None
    spacing: tuple[float, ...] | None = None
    origin: tuple[float, ...] | None = None
    method: str | None = None
    flip: bool = False
    ambiguity: str | None = None
    axis: str | None = None
    vertex_offset: float | None = None
    nan_as: float | None = None
    format: str | None = None
    ascii: bool = False
    force: bool = False
    blocks: Blocks = field(default_factory=Blocks)
    space: str | None = None
    source_name: str | None = None
    normals: bool = False
    values: str | Path | None = None
    post: PostOptions = field(default_factory=PostOptions)
    labels: tuple[int, ...] | None = None
    single_file: bool = False
    background: int = 0
    label_smoothing: int | None = None
    lods: int | None = None
    fragment_size: float | str | None = None
    sharded: bool = False
    legacy_mesh: bool = False
    with_volume: bool = False

    @property
    def layer_lods(self) -> int:
        """The precomputed layer's levels of detail, the default resolved."""
        return self.lods if self.lods is not None else (1 if self.legacy_mesh else 3)

    @property
    def layer_fragment_size(self) -> float | str:
        """The precomputed layer's fragment size, the default (``"auto"``) resolved."""
        return self.fragment_size if self.fragment_size is not None else "auto"

    def updated(self, **changes) -> ConvertOptions:
        """A copy with ``changes``; names of :class:`ReadOptions` fields go to
        ``read``, those of :class:`PostOptions` to ``post``.

        Raises
        ------
        IsoconvertError
            A name that is no option.
        """
        read = {k: changes.pop(k) for k in list(changes) if k in _READ_FIELDS}
        post = {k: changes.pop(k) for k in list(changes) if k in _POST_FIELDS}
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise IsoconvertError(f"unknown conversion option(s): {', '.join(sorted(unknown))}")
        if read:
            changes["read"] = replace(self.read, **read)
        if post:
            changes["post"] = replace(self.post, **post)
        return replace(self, **changes)


class ConvertResult:
    """What :func:`convert` made; ``volume.notes`` says what the reader assumed.

    Attributes
    ----------
    volume : Volume
    mesh : Mesh
        The mesh written (extracted and post-processed), in float64. Given as a
        function (a label's surface, rebuilt from the surface net when asked for),
        it is built on each access and held only by whoever asked: a run over
        many labels does not keep every label's mesh after its file is written.
    summary : MeshSummary
        The mesh's counts and ``info``, for a one-line account without the mesh.
    output : Path
    format : str
        The writer used.
    ascii : bool
        Whether the file is text.
    extracted : Mesh or None
        The mesh as extracted, before post-processing (None when no step ran).
    layer : (Path, int) or None
        The layer folder and segment id, when ``output`` is an object of a layer.
    """

    def __init__(
        self,
        volume: Volume,
        mesh: Mesh | Callable[[], Mesh],
        output: Path,
        format: str,
        ascii: bool = False,
        extracted: Mesh | None = None,
        summary: MeshSummary | None = None,
        layer: tuple[Path, int] | None = None,
    ) -> None:
        if summary is None:
            if not isinstance(mesh, Mesh):
                raise TypeError("ConvertResult: a mesh given as a function needs its summary")
            summary = MeshSummary.of(mesh)
        self.volume, self._mesh, self.summary = volume, mesh, summary
        self.output, self.format, self.ascii, self.extracted = output, format, ascii, extracted
        self.layer = layer

    @property
    def mesh(self) -> Mesh:
        mesh = self._mesh
        return mesh if isinstance(mesh, Mesh) else mesh()

    @cached_property
    def written(self) -> Mesh:
        """The mesh as the file holds it (vertices at the file's precision, STL
        with three vertices per triangle): what ``convert --report`` checks,
        against the volume's grid, so that it agrees with ``isoconvert check
        FILE`` (``check FILE --grid VOLUME`` for STL, which records no grid). A
        layer's object: its level 0 read back from the layer
        (:func:`.writers.precomputed.readback.stored_level`), which a cut can have
        left with fewer triangles than the mesh."""
        if self.layer is not None:
            from .writers.precomputed.readback import stored_level

            stored = stored_level(*self.layer)
            if stored is not None:
                index, cells = stored
                grid = self.summary.info["grid"]
                world = np.asarray(grid["origin"]) + index @ np.asarray(grid["affine"]).T
                return stored_mesh(Mesh(world, cells, None, dict(self.summary.info)), self.format)
        return stored_mesh(self.mesh, self.format, self.ascii)

    def stored_counts(self) -> tuple[int, int]:
        """How many vertices and cells the output holds: a layer object's level 0
        as stored (a fragment decoded at a time), else the mesh's."""
        if self.layer is not None:
            from .writers.precomputed.readback import stored_counts

            counts = stored_counts(*self.layer)
            if counts is not None:
                return counts
        return self.summary.n_vertices, self.summary.n_cells

    def forget_written(self) -> None:
        """Let :attr:`written` go (built again if asked for): a run over a layer's
        many objects holds one object's at a time."""
        self.__dict__.pop("written", None)

    def __repr__(self) -> str:
        s = self.summary
        return (
            f"ConvertResult({self.output}, {self.format}: {s.n_vertices} vertices, "
            f"{s.n_cells} cells)"
        )


def convert(
    input: str | Path,
    output: str | Path,
    level: float | str,
    options: ConvertOptions | None = None,
    *,
    on_status: Callable[[str], None] | None = None,
    on_progress: Callable[[str], None] | None = None,
    **changes,
) -> ConvertResult:
    """Read ``input``, extract the isosurface at ``level``, write it to ``output``.

    Everything that can be checked before the work is checked first (output
    folder, existing file, output format), so a mistake costs no extraction time.

    Parameters
    ----------
    input, output : str or Path
    level : float or "auto"
    options : ConvertOptions or None
        How to read, extract, post-process and write; None for the defaults.
    on_status : callable or None
        Receives one-line notices (compiling, levels equal to samples, precision).
    on_progress : callable or None
        Called with the stage starting: "reading", "extracting", then those that
        run ("post-processing", "normals", "values"), "writing".
    **changes
        Fields of :class:`ConvertOptions`, :class:`ReadOptions` or
        :class:`~isoconvert.post.pipeline.PostOptions` to change, e.g.
        ``convert("a.raw", "a.ply", 80.5, shape=(256, 256, 128), dtype="uint8")``.
    """
    (result,) = convert_levels(
        input,
        output,
        [level],
        options,
        on_status=on_status,
        on_progress=on_progress,
        **changes,
    )
    return result


def level_outputs(output: str | Path, levels: Sequence[float | str]) -> list[Path]:
    """Where each level's mesh goes: ``output`` itself for one level, else
    ``NAME_levelL.SUFFIX`` beside it (``engine_level80.5.ply``).

    Raises
    ------
    OutputError
        The same level twice, or ``output`` is a stream (``/dev/stdout``).
    """
    output = Path(output)
    if len(levels) == 1:
        return [output]
    refuse_stream(output, "several --level write one file each")
    texts = [f"{level:g}" if not isinstance(level, str) else level.strip() for level in levels]
    if len(set(texts)) < len(texts):
        raise OutputError(f"--level {' '.join(texts)}: a level is given twice")
    return [output.with_name(f"{output.stem}_level{t}{output.suffix}") for t in texts]


def convert_levels(
    input: str | Path,
    output: str | Path,
    levels: Sequence[float | str],
    options: ConvertOptions | None = None,
    *,
    on_status: Callable[[str], None] | None = None,
    on_progress: Callable[[str], None] | None = None,
    also_writes: Sequence[str | Path] = (),
    **changes,
) -> list[ConvertResult]:
    """:func:`convert` at several levels, reading the volume once: one mesh per
    level, named by :func:`level_outputs`.

    ``also_writes`` names the other files the caller will write from the
    results (reports, pictures): like the meshes, each is refused before any
    work when it is one of the files being read.

    A volume read from its file that fits the memory budget (``--max-memory``)
    is read into memory once for all levels; a larger one is read slab by slab
    for each level.
    """
    opts = (options or ConvertOptions()).updated(**changes)
    progress = on_progress or (lambda stage: None)
    refuse_layer_options(opts, WRITERS.get(opts.format) if opts.format else None)
    if opts.format and WRITERS.get(opts.format).layer:
        return _convert_levels_to_layer(
            input, output, levels, opts, on_status, progress, also_writes
        )
    outputs = level_outputs(output, levels)
    for path in outputs:  # first: a folder given as -o is "a folder", not a format
        check_output(path, opts.force, inputs=input_file(input))  # the input: not "exists"
    writer = output_format(output, opts.format)
    check_attributes(writer, output, normals=opts.normals, values=opts.values is not None)
    by_suffix = WRITERS.by_suffix(Path(output).suffix)
    if on_status and by_suffix and by_suffix[0] != writer.name:
        on_status(f"note: writing {writer.name} into {output}, whose extension says {by_suffix[0]}")
    refuse_given_outputs(input, [*outputs, *also_writes])
    from .attributes import check_3d
    from .extract.dispatch import default_method

    progress("reading")
    volume = read_input(input, opts)
    opts.post.check_method(opts.method or default_method(volume))
    if opts.normals:
        check_3d(volume, "normals")
    value_volume = None if opts.values is None else _value_volume(opts, volume)
    refuse_outputs_read([*outputs, *also_writes], volume, value_volume)
    if len(levels) > 1 and volume.grid is not None and volume.grid.nbytes <= opts.blocks.budget:
        volume = _in_memory(volume)
    return [
        _extract_and_write(volume, value_volume, level, path, writer, opts, on_status, progress)
        for level, path in zip(levels, outputs, strict=True)
    ]


def _convert_levels_to_layer(
    input: str | Path,
    output: str | Path,
    levels: Sequence[float | str],
    opts: ConvertOptions,
    on_status: Callable[[str], None] | None,
    progress: Callable[[str], None],
    also_writes: Sequence[str | Path],
) -> list[ConvertResult]:
    """:func:`convert_levels` into one precomputed layer: level n (in the order
    given) is the layer's object n + 1, all written once every level is extracted."""
    from .writers.precomputed import check_layer, data_type_for, object_file, write_precomputed

    writer = WRITERS.get(opts.format)
    if opts.normals or opts.values is not None or opts.with_volume:
        flag = "--normals" if opts.normals else "--values" if opts.values else "--with-volume"
        why = "label voxels" if opts.with_volume else "vertex attributes"
        raise FormatError(
            f"{flag}: a precomputed layer of isosurfaces holds no {why}; leave it out"
        )
    level_outputs(output, levels)  # the same level twice is an error here too
    check_layer(output, opts.force, opts.layer_lods, [input], opts.fragment_size,
                sharded=opts.sharded, legacy=opts.legacy_mesh)  # fmt: skip
    refuse_given_outputs(input, also_writes, folder=output)
    from .extract.dispatch import default_method

    progress("reading")
    volume = read_input(input, opts)
    opts.post.check_method(opts.method or default_method(volume))
    check_layer(output, opts.force, opts.layer_lods, volume.files, opts.fragment_size,
                sharded=opts.sharded, legacy=opts.legacy_mesh)  # fmt: skip
    refuse_outputs_read(also_writes, volume)
    if len(levels) > 1 and volume.grid is not None and volume.grid.nbytes <= opts.blocks.budget:
        volume = _in_memory(volume)
    meshes, extracted = {}, {}
    for n, level in enumerate(levels, start=1):
        meshes[n], extracted[n] = _extract(volume, level, opts, on_status, progress)
    progress("writing")
    if on_status is not None and (note := layer_budget_note(opts)):
        on_status(note)
    grid = meshes[1].info["grid"]
    write_precomputed(
        output,
        meshes,
        grid,
        unit=volume.unit,
        data_type=data_type_for(len(levels)),
        lods=opts.layer_lods,
        collapse=bounded_collapse,
        chunk=opts.layer_fragment_size,
        sharded=opts.sharded,
        legacy=opts.legacy_mesh,
        force=opts.force,
        on_status=on_status,
        map_objects=layer_objects_on(opts, volume.source),
        # within --max-memory, one object's coarser levels at a time
        object_threads=1 if opts.blocks.max_memory else None,
    )

    def where(n: int) -> Path:
        return Path(output) / "mesh" / object_file(n, len(meshes), sharded=opts.sharded,
                                                   legacy=opts.legacy_mesh)  # fmt: skip

    return [
        ConvertResult(
            volume, meshes[n], where(n), writer.name, False, extracted[n], layer=(Path(output), n)
        )  # fmt: skip
        for n in meshes
    ]


def refuse_layer_options(opts: ConvertOptions, writer: Writer | None) -> None:
    """Refuse the flags only a precomputed layer takes when ``writer`` writes none
    (None: the format comes from the output's name, which is no layer's)."""
    if writer and writer.layer:
        return
    given = {
        "--with-volume": opts.with_volume,
        "--legacy-mesh": opts.legacy_mesh,
        "--lods": opts.lods is not None,
        "--fragment-size": opts.fragment_size is not None,
        "--sharded": opts.sharded,
    }
    for flag, on in given.items():
        if on:  # said, not silently ignored
            raise IsoconvertError(f"{flag} is an option of --format precomputed")


def layer_budget_note(opts: ConvertOptions) -> str | None:
    """The note for a layer made within ``--max-memory`` that an option takes out
    of it: with ``--fragment-size inf`` each object's level 0 is one Draco fragment
    of its whole surface, encoded at once (the 1.5 M-triangle ball of bench_pipeline
    peaks at 394 MB within 256M, its rows cut in 128-voxel fragments at 208 MB)."""
    if opts.blocks.max_memory and opts.layer_fragment_size == float("inf"):
        return (
            "note: --fragment-size inf encodes each object's whole surface as one fragment, "
            "which --max-memory does not bound; leave it out to cut large objects"
        )
    return None


def layer_objects_on(opts: ConvertOptions, source: str):
    """Where a layer's objects are encoded (``write_precomputed``'s ``map_objects``):
    with ``--scheduler``, each object is one task of the cluster (its coarser levels
    decimated, everything Draco-encoded and the fragments written by a worker, the
    manifest sent back and written here, in order), or, for a label cut into
    fragments from its parts, each row of its level-0 fragments is, and so are a
    large label's slabs, collapsed, its coarser levels made from them, and a last
    task that puts the label together and writes it (the others' results go to it
    from worker to worker, and only the manifest comes back); otherwise None,
    here."""
    address = opts.blocks.scheduler
    if address is None:
        return None
    import uuid

    from .runner import Earlier, Task, run_in_order
    from .writers.precomputed import Preceding

    token = uuid.uuid4().hex[:12]

    def key(n: int) -> str:
        return f"isoconvert-object-{token}-{n}"

    def on_cluster(function, layer_tasks):
        tasks = (
            Task(
                _object_task,
                (
                    function,
                    *(
                        Earlier(tuple(key(m) for m in range(n - a.skip - a.count, n - a.skip)))
                        if isinstance(a, Preceding)
                        else a
                        for a in args
                    ),
                ),
                key=key(n),
                what=f"{source}: {what}",
                nbytes=sum(a.nbytes for a in args if isinstance(a, np.ndarray)),
                kept=kept,
            )
            for n, (what, args, kept) in enumerate(layer_tasks, start=1)
        )
        return run_in_order(
            address,
            tasks,
            budget=opts.blocks.budget,
            died=lambda task: (
                f"{task.what}: a Dask worker died while encoding it (out of memory?), also "
                "when retried on other workers; nothing was written. Give the workers more memory"
            ),
            tail="; nothing was written",
            memory_hint="Give the workers more memory",
        )

    return on_cluster


def _object_task(function, *args):
    """A layer's object as a cluster's task: ``function(*args)``, or the
    ``TaskFailure`` of a user's error (never retried), also one of the earlier
    tasks whose results it takes."""
    from .runner import TaskFailure, failure_among

    earlier = failure_among(args)
    if earlier is not None:
        return earlier
    try:
        return function(*args)
    except IsoconvertError as exc:
        return TaskFailure.of(exc)


def bounded_collapse(mesh: Mesh, bound: float, locked: np.ndarray | None = None) -> np.ndarray:
    """A precomputed layer's coarser level: the bounded collapse to within ``bound``,
    its triangles over ``mesh``'s vertices, ``locked`` ones kept."""
    from .post.decimate import collapse

    return collapse(mesh, max_error=bound, locked=locked)[0]


def refuse_outputs_read(outputs: Sequence[str | Path], *volumes: Volume | None) -> None:
    """Raise OutputError when an output is one of the files ``volumes`` are read
    from (a detached header's data file, a slice of a TIFF folder, ...), or a
    file inside a store they are read from (a Zarr folder's chunks); a new
    mesh beside the slices of a TIFF folder or in a DICOM folder is fine."""
    files = [f for volume in volumes if volume is not None for f in volume.files]
    for path in outputs:
        refuse_inputs(path, files)


def refuse_mesh_input(input: str | Path, input_format: str | None) -> None:
    """A mesh file given where a volume goes is said to be one (a file whose suffix
    only a mesh format claims, no --input-format), not a name with no format."""
    suffix = format_suffix(input)
    if input_format is None and READERS.by_suffix(suffix) is None and suffix in READ_SUFFIXES:
        if not Path(input).is_dir():
            raise FormatError(
                f"{input}: a mesh file ({suffix}), not a volume: convert and batch read "
                "volumes; `isoconvert check` and `isoconvert preview` read meshes"
            )


def read_input(input: str | Path, opts: ConvertOptions) -> Volume:
    """The input volume, in the frame ``opts.space`` asks for."""
    refuse_mesh_input(input, opts.input_format)
    volume = read_volume(
        input,
        format=opts.input_format,
        spacing=opts.spacing,
        origin=opts.origin,
        **{name: getattr(opts.read, name) for name in opts.read.given()},
    )
    if opts.space is not None:
        volume = volume.in_frame(opts.space)
    if opts.source_name is not None:
        volume.source = opts.source_name
    return volume


def _in_memory(volume: Volume) -> Volume:
    """The same volume with its samples read into memory once."""
    return replace(volume, data=volume.data)


def _extract_and_write(
    volume: Volume,
    value_volume: Volume | None,
    level: float | str,
    output: Path,
    writer: Writer,
    opts: ConvertOptions,
    on_status: Callable[[str], None] | None,
    progress: Callable[[str], None],
) -> ConvertResult:
    """Extract one level, post-process, sample attributes, write."""
    from .attributes import vertex_normals, vertex_values

    blocks = opts.blocks
    if writer.streams and blocks.spill_dir is None:
        # a block-wise mesh larger than the budget waits for the writer on disk
        # (a stream's, standard output's, in the temporary folder)
        folder = tempfile.gettempdir() if output_stream(output) is not None else output.parent
        blocks = replace(blocks, spill_dir=Path(folder).resolve())
    mesh, extracted = _extract(volume, level, replace(opts, blocks=blocks), on_status, progress)
    if opts.normals and len(mesh.cells):
        if mesh.normals is None:  # not from the filling pass: sample them
            progress("normals")
            mesh.normals = vertex_normals(mesh, volume, flip=opts.flip, nan_as=opts.nan_as)
        mesh.info["normals"] = "volume gradient"
    if value_volume is not None:
        progress("values")
        mesh.values = vertex_values(mesh, value_volume)
        mesh.info["values"] = value_volume.source
        outside = int(np.isnan(mesh.values).sum())
        if outside and on_status:
            on_status(
                f"note: {outside} of {len(mesh.values)} vertices lie outside {value_volume.source} "
                "(or on NaN samples): their value is NaN"
            )
    progress("writing")
    path = write_mesh(
        mesh, output, format=writer.name, ascii=opts.ascii, force=opts.force, on_status=on_status
    )
    return ConvertResult(volume, mesh, path, writer.name, opts.ascii, extracted)


def _extract(
    volume: Volume,
    level: float | str,
    opts: ConvertOptions,
    on_status: Callable[[str], None] | None,
    progress: Callable[[str], None],
) -> tuple[Mesh, Mesh | None]:
    """Extract one level and post-process it: the mesh, and the mesh as extracted
    when post-processing changed it (else None)."""
    from .extract.dispatch import extract

    method_options = {} if opts.axis is None else {"axis": opts.axis}
    if opts.vertex_offset is not None:
        method_options["vertex_offset"] = opts.vertex_offset
    progress("extracting")
    mesh = extract(
        volume,
        level,
        method=opts.method,
        flip=opts.flip,
        ambiguity=opts.ambiguity,
        nan_as=opts.nan_as,
        on_status=on_status,
        blocks=opts.blocks,
        # from the filling pass where extract can (Marching Cubes in memory),
        # unless post-processing moves the vertices before the normals are due
        normals=opts.normals and not opts.post.steps,
        **method_options,
    )
    extracted = None
    if opts.post.steps:
        progress("post-processing")
        extracted = mesh
        mesh = post_process(
            mesh,
            volume,
            opts.post,
            ambiguity=opts.ambiguity or DEFAULT_AMBIGUITY,
            flip=opts.flip,
            nan_as=opts.nan_as,
            on_status=on_status,
        )
    return mesh, extracted


def _value_volume(opts: ConvertOptions, volume: Volume) -> Volume:
    """The volume of ``--values``, in the world frame of ``volume``."""
    from .attributes import check_3d

    values = read_volume(
        opts.values, **{name: getattr(opts.read, name) for name in opts.read.given()}
    )
    if volume.frame is not None and values.frame is not None and values.frame != volume.frame:
        values = values.in_frame(volume.frame)
    check_3d(values, "values")
    return values
