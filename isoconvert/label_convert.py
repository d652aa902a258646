"""Label volumes (segmentations, atlases) to one closed surface per label."""

from __future__ import annotations

import functools
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from .atomic import check_output, input_file, output_stream, refuse_given_outputs, refuse_stream
from .convert import (
    ConvertOptions,
    ConvertResult,
    bounded_collapse,
    layer_budget_note,
    layer_objects_on,
    read_input,
    refuse_layer_options,
    refuse_outputs_read,
)
from .errors import IsoconvertError
from .grid import grid_slab_zyx
from .methods import DEFAULT_AMBIGUITY
from .post.pipeline import EmptyMeshError, post_process
from .threads import kernel_threads, threaded_in_order
from .volume import Volume
from .writers import check_attributes, output_format
from .writers.precomputed import check_layer, data_type_for, object_file, write_precomputed
from .writers.precomputed.volume import volume_data_type
from .writers.stored import write_mesh


def label_outputs(output: str | Path, labels: Sequence[int]) -> list[Path]:
    """Where each label's surface goes: ``NAME_labelL.SUFFIX`` beside ``output``
    (refused for a stream such as ``/dev/stdout``: ``--single-file`` writes one)."""
    output = Path(output)
    refuse_stream(output, "--labels writes one file per label (--single-file writes one)")
    return [output.with_name(f"{output.stem}_label{label}{output.suffix}") for label in labels]


def convert_labels(
    input: str | Path,
    output: str | Path,
    labels: Sequence[int] = (),
    options: ConvertOptions | None = None,
    *,
    on_status: Callable[[str], None] | None = None,
    on_progress: Callable[[str], None] | None = None,
    also_writes: Sequence[str | Path] = (),
    **changes,
) -> list[ConvertResult]:
    """The surfaces of the labels of a label volume (segmentation, atlas), by
    Surface Nets (:func:`isoconvert.extract.labels.label_surfaces`), each closed
    and sharing its boundary with its neighbours exactly.

    Parameters
    ----------
    input, output : str or Path
        Without ``single_file``, label L goes to :func:`label_outputs`
        (``atlas_label3.ply``); with it, everything goes to ``output``, each
        triangle with the labels on its two sides (PLY, VTP).
    labels : sequence of int
        The labels to extract; empty: every label but the background.
    options : ConvertOptions or None
        ``label_smoothing`` is the number of Surface Nets relaxation iterations
        (default 16; 0 gives the voxel faces). The post-processing steps but
        closing and smoothing (label surfaces are closed and smoothed already)
        run on each label's surface, which then no longer shares its boundary
        exactly; not with ``single_file``.
    on_status, on_progress, also_writes, **changes
        As :func:`convert_levels`.
    """
    from .extract.labels import label_surfaces

    opts = (options or ConvertOptions()).updated(labels=tuple(labels), **changes)
    progress = on_progress or (lambda stage: None)
    writer = output_format(output, opts.format)
    if opts.method is not None:
        # there is no label path through Marching Cubes or tetrahedra: saying
        # nothing would give Surface Nets under another method's name
        raise IsoconvertError(
            f"--method {opts.method} extracts an isosurface; label surfaces are always "
            "Surface Nets: leave out --method, or --labels for an isosurface with --level"
        )
    if opts.normals or opts.values is not None:
        raise IsoconvertError(
            "--normals and --values sample an isosurface's volume; label surfaces have "
            "neither: leave them out with --labels"
        )
    post = replace(opts.post, close=False, smooth=0)  # label surfaces are closed and smoothed
    refuse_layer_options(opts, writer)
    if writer.layer:
        if opts.single_file:
            raise IsoconvertError(
                f"{writer.name} is a layer of every label already; leave out --single-file"
            )
        check_layer(output, opts.force, opts.layer_lods, [input], opts.fragment_size,
                    sharded=opts.sharded, legacy=opts.legacy_mesh)  # fmt: skip
    elif opts.single_file:
        check_output(output, opts.force, inputs=input_file(input))
        check_attributes(writer, output, labels=True)
        if post.steps:
            raise IsoconvertError(
                f"{', '.join(post.steps)} would break the shared boundaries of "
                "--single-file; write one file per label instead"
            )
    elif opts.labels:
        for n, path in enumerate(label_outputs(output, opts.labels)):
            check_output(path, opts.force, inputs=input_file(input), probe=n == 0)
    known = [output] if opts.single_file or writer.layer else label_outputs(output, opts.labels)
    refuse_given_outputs(input, [*known, *also_writes])
    progress("reading")
    volume = read_input(input, opts)
    refuse_outputs_read([*known, *also_writes], volume)
    if not opts.labels:
        _check_label_volume(volume, opts.background)
    progress("extracting")
    blocks = opts.blocks
    if blocks.spill_dir is None:
        # slabs over the budget wait beside the output (a stream's, in the temporary folder)
        folder = tempfile.gettempdir() if output_stream(output) is not None else Path(output).parent
        blocks = replace(blocks, spill_dir=Path(folder).resolve())
    surfaces = label_surfaces(
        volume,
        opts.labels or None,
        background=opts.background,
        smoothing=opts.label_smoothing,
        on_status=on_status,
        blocks=blocks,
    )
    if opts.single_file:
        mesh = surfaces.combined
        mesh.cell_labels = surfaces.boundary_labels
        progress("writing")
        path = write_mesh(mesh, output, format=writer.name, ascii=opts.ascii, force=opts.force)
        return [ConvertResult(volume, mesh, path, writer.name, opts.ascii)]
    count = len(surfaces.labels)
    outputs = (
        [
            Path(output)
            / "mesh"
            / object_file(label, count, sharded=opts.sharded, legacy=opts.legacy_mesh)  # fmt: skip
            for label in surfaces.labels
        ]
        if writer.layer
        else label_outputs(output, surfaces.labels)
    )
    if writer.layer:
        check_layer(output, opts.force, opts.layer_lods, volume.files, opts.fragment_size,
                    sharded=opts.sharded, legacy=opts.legacy_mesh)  # fmt: skip
    else:
        for n, path in enumerate(outputs):  # every name before the first file is written
            # one folder: a file made there once shows the others can be too
            check_output(path, opts.force, inputs=volume.files, probe=n == 0)
    # each label's surface is built when it is written and let go after: only the
    # few in flight are held (post-processing holds every label's, see below)
    meshes = list(surfaces.meshes.values()) if post.steps else None
    if post.steps:
        progress("post-processing")
        # every label before the first file: a step emptying one label's surface
        # fails the run with no file written, not half of the files
        for n, label in enumerate(surfaces.labels):
            try:
                meshes[n] = post_process(meshes[n], volume, post, ambiguity=DEFAULT_AMBIGUITY,
                                         flip=False, nan_as=None, on_status=on_status)  # fmt: skip
            except EmptyMeshError as exc:  # say which label's surface it was
                text = str(exc).removeprefix(f"{volume.source}: ")
                raise EmptyMeshError(f"{volume.source}: label {label}: {text}") from None
    if writer.layer:
        progress("writing")
        if on_status is not None and (note := layer_budget_note(opts)):
            on_status(note)
        largest = max(surfaces.labels)
        if opts.with_volume:  # every label of the volume is stored, not only those meshed
            largest = max(largest, int(surfaces.value_range[1]))
        write_precomputed(
            output,
            surfaces.meshes if meshes is None else dict(zip(surfaces.labels, meshes, strict=True)),
            surfaces.grid,
            unit=volume.unit,
            data_type=volume_data_type(largest) if opts.with_volume else data_type_for(largest),
            lods=opts.layer_lods,
            collapse=bounded_collapse,
            chunk=opts.layer_fragment_size,
            sharded=opts.sharded,
            legacy=opts.legacy_mesh,
            volume=volume if opts.with_volume else None,
            background=opts.background,
            force=opts.force,
            on_status=on_status,
            map_objects=layer_objects_on(opts, volume.source),
            # within --max-memory, one object's coarser levels at a time
            object_threads=1 if opts.blocks.max_memory else None,
            # one level cut into fragments: each label's rows from the net, never its
            # whole surface (post-processed surfaces are whole already)
            parts=surfaces.parts if meshes is None else None,
            # the cut planes midway between samples, where an unsmoothed net's
            # vertices lie: at --smooth 0 no triangle crosses them
            phase=0.5,
        )
    made = surfaces.labels  # the labels extracted (``labels`` may name none)
    if not writer.layer:  # (a layer's object files are the outputs named above)
        progress("writing")

        def write(n: int, label: int, path: Path) -> Path:
            # in a worker thread: the label's mesh is built and written there, the
            # kernels and the file leaving the interpreter to the next label's
            mesh = meshes[n] if meshes is not None else surfaces.meshes[label]
            return write_mesh(mesh, path, format=writer.name, ascii=opts.ascii, force=opts.force)

        jobs = zip(range(len(made)), made, outputs, strict=True)
        outputs = list(threaded_in_order(write, jobs, kernel_threads()))
    if meshes is not None:  # post-processed: each result holds its label's mesh, both ways
        return [
            ConvertResult(
                volume,
                mesh,
                path,
                writer.name,
                opts.ascii and not writer.layer,
                surfaces[label],
                layer=(Path(output), label) if writer.layer else None,
            )  # fmt: skip
            for label, mesh, path in zip(made, meshes, outputs, strict=True)
        ]
    # each result builds its label's mesh again when asked for (a report, a picture):
    # held by the results, every label's mesh would be the peak of a large volume's run
    return [
        ConvertResult(
            volume,
            functools.partial(surfaces.__getitem__, label),
            path,
            writer.name,
            opts.ascii and not writer.layer,
            summary=surfaces.summary(label),
            layer=(Path(output), label) if writer.layer else None,
        )  # fmt: skip
        for label, path in zip(made, outputs, strict=True)
    ]


#: Of the face-neighbouring sample pairs inside labels (neither background), the
#: share with different labels above which a volume is taken for an intensity
#: image: a segmentation's labels fill regions (a few % of pairs straddle a
#: wall), a scan's values change from sample to sample (the engine: 80 %).
INTENSITY_SHARE = 0.3


def _check_label_volume(volume: Volume, background: int) -> None:
    """Refuse, before a long extraction, a volume that looks like an intensity
    image (every value a "label"), judging from its middle layers."""
    if volume.ndim != 3:
        return
    z = volume.shape[2]
    # only the middle layers: a large scan refused here is not read whole first
    middle = grid_slab_zyx(volume.samples, max(0, z // 2 - 4), min(z, z // 2 + 4)).T
    if not np.issubdtype(middle.dtype, np.integer) and not np.issubdtype(middle.dtype, np.bool_):
        return  # label_surfaces says whether float samples are whole numbers
    inside = pairs = 0
    for axis in range(3):
        a = np.moveaxis(middle, axis, 0)
        lo, hi = a[:-1], a[1:]
        both = (lo != background) & (hi != background)
        inside += int(np.count_nonzero(both))
        pairs += int(np.count_nonzero(both & (lo != hi)))
    if inside > 1000 and pairs > INTENSITY_SHARE * inside:
        raise IsoconvertError(
            f"{volume.source}: looks like an intensity image, not a label volume "
            f"({pairs / inside:.0%} of neighbouring samples differ); extract an isosurface "
            "with --level, or name the labels with --label 3,7"
        )


__all__ = ["INTENSITY_SHARE", "convert_labels", "label_outputs"]
