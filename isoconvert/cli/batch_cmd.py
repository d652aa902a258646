"""``isoconvert batch``: many volumes, in parallel (here or on a Dask cluster)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from ..atomic import check_output
from ..errors import FormatError, IsoconvertError, VolumeError
from ..writers import WRITERS, check_attributes
from .display import _batch_display, _print_batch_table, _quiet_third_party
from .options import (
    EXIT_CHECK_FAILED,
    ExtractArgs,
    ForceOpt,
    LabelArgs,
    LayerArgs,
    LevelOpt,
    MemoryArgs,
    MeshArgs,
    PostArgs,
    QuietOpt,
    ReadArgs,
    RequireOpt,
    VerboseOpt,
    _bytes,
    _convert_options,
    _flag,
    _grouped,
    _level,
)


@_grouped("input_format", "series")
def batch(
    inputs: Annotated[list[str], typer.Argument(help="Files, folders or globs of volumes.")],
    out_dir: Annotated[Path, typer.Option("-o", "--output", help="Folder for the meshes.")],
    level: LevelOpt = None,
    levels: Annotated[
        Path | None,
        typer.Option(help="TOML or CSV mapping of path patterns to level and read options."),
    ] = None,
    recursive: Annotated[bool, _flag("--recursive", "-r", help="Search sub-folders.")] = False,
    extract: ExtractArgs = ExtractArgs(),
    jobs: Annotated[
        int | None, typer.Option("--jobs", "-j", help="Worker processes (default: cores).")
    ] = None,
    skip_existing: Annotated[
        bool, _flag("--skip-existing", help="Keep outputs that exist; convert the rest.")
    ] = False,
    force: ForceOpt = False,
    summary: Annotated[
        Path | None, typer.Option(help="Write a summary table as FILE.json or FILE.csv.")
    ] = None,
    require: RequireOpt = None,
    quiet: QuietOpt = False,
    verbose: VerboseOpt = False,
    images: Annotated[
        bool,
        _flag(
            "--images",
            help="Also contour 2D images (PNG, JPEG, 2D TIFF and NRRD); skipped otherwise "
            "(implied by --method squares).",
        ),
    ] = False,
    previews: Annotated[
        bool,
        _flag(
            "--previews",
            help="Also a thumbnail (NAME.png) beside each mesh and an index.html contact sheet "
            "in the output folder (needs isoconvert\\[render]).",
        ),
    ] = False,
    read: ReadArgs = ReadArgs(),
    mesh: MeshArgs = MeshArgs(),
    post: PostArgs = PostArgs(),
    memory: MemoryArgs = MemoryArgs(),
    labels: LabelArgs = LabelArgs(),
    layer: LayerArgs = LayerArgs(),
) -> None:
    """Convert many volumes: files, folders (--recursive) and globs, in parallel."""
    _quiet_third_party()
    from .. import batch as batching
    from ..checks import parse_requirements
    from ..readers.stacks import natural_text_key

    required = parse_requirements(require)
    writer = WRITERS.get(mesh.format or "ply")
    if writer.layer and previews:
        raise FormatError(
            f"--previews pictures mesh files; a {writer.name} layer is viewed in "
            "Neuroglancer: leave out --previews"
        )
    if writer.layer and level and len(level) > 1:
        raise FormatError(
            f"batch writes one {writer.name} layer per volume, of its labels or of one "
            "--level; for several levels in one layer, convert each volume with --level "
            "given once per level"
        )
    check_attributes(writer, "--format", normals=mesh.normals, labels=labels.single_file)
    # the raw layout goes to raw files only (plan); every other option to every file
    options = _convert_options(
        read, extract, mesh, post, labels, layer, level, raw_layout=False, format=writer.name
    )
    from ..convert import refuse_layer_options

    refuse_layer_options(options, writer)  # --lods without a layer: once, not per file
    by_label = options.labels is not None
    batching.check_jobs(jobs)
    if previews:  # before the work: without a renderer there would be no pictures
        from ..preview import require_renderer
        from ..preview.sheet import check_contact_sheet

        require_renderer()
        check_contact_sheet(out_dir)  # and never over a page of the user's own
    if not level and levels is None and not by_label:
        raise VolumeError("batch needs --level (a number or auto), --levels FILE or --labels")
    if out_dir.exists() and not out_dir.is_dir():
        raise VolumeError(f"{out_dir}: exists and is not a folder; choose another -o")
    budget = _bytes(memory.max_memory) if memory.max_memory else _default_budget()
    early: list[Path] = []
    if summary is not None:  # a bad summary name fails now, not at the end
        if summary.suffix.lower() not in (".json", ".csv"):
            raise VolumeError(f"{summary}: --summary takes a .json or .csv file name")
        if summary.resolve().parent.is_relative_to(out_dir.resolve()):
            early = batching.make_folders(summary.parent)  # inside -o, which batch makes
        try:
            # never over the --levels table or an input given as a file (a zarr.json)
            given = [f for f in (levels, *map(Path, inputs)) if f is not None and f.is_file()]
            check_output(summary, force or skip_existing, "summary.json", inputs=given)
        except IsoconvertError:
            batching.remove_empty_folders(early)
            raise
    rules = batching.read_mapping(levels) if levels else None
    found, skipped = batching.discover(
        inputs, recursive=recursive, exclude=out_dir, images=images or extract.method == "squares"
    )
    batching.check_found(inputs, found, skipped)
    numeric_level = None
    if level:
        from ..convert import level_outputs

        numeric_level = [lv if lv == "auto" else _level(lv) for lv in level]
        level_outputs(out_dir / "x", numeric_level)  # the same level twice is an error
    work, outcomes = batching.plan(
        found,
        out_dir,
        writer.suffixes[0] if writer.suffixes else "",  # a layer: a folder per volume
        numeric_level,
        rules,
        skip_existing=skip_existing,
        force=force,
        raw_options=read.raw_layout(),
        labels=by_label,
        layer=writer.layer,
    )
    # a batch into its own input folder meets its earlier outputs: not inputs skipped
    written = [out_dir / "index.html"] if previews else []
    written += [summary] if summary is not None else []
    for item in batching.drop_outputs(skipped, work, outcomes, previews, written):
        outcomes.append(batching.Outcome(item.path, "", "skipped", message=item.reason))
    from ..distributed import scheduler_address
    from ..extract.slabs import Blocks

    workers = batching.check_jobs(jobs, files=len(work))
    # the files running at once share the budget
    share = max(1, budget // workers) if budget else None
    settings = batching.BatchSettings(
        replace(options, blocks=Blocks(size=memory.block_size, max_memory=share)),
        tuple(required),
        scheduler=scheduler_address(memory.scheduler),
        previews=previews,
    )
    created = early + (batching.make_folders(out_dir) if work else [])
    try:
        with _batch_display(quiet, len(work), verbose) as on_done:
            try:
                outcomes += batching.run_jobs(work, settings, workers, budget, on_done)
            except KeyboardInterrupt:
                raise typer.Exit(130) from None  # main() says so
        # by file, then by output (NAME_level60.5 before NAME_level128.5)
        outcomes.sort(key=lambda o: (natural_text_key(o.input), natural_text_key(o.output)))
        if summary is not None:
            from ..atomic import atomic_output

            with atomic_output(summary, force=True) as fh:
                fh.write(batching.summary_bytes(outcomes, summary.suffix.lower()))
        if previews and out_dir.is_dir():
            from dataclasses import asdict

            from ..preview import SheetEntry, write_contact_sheet

            fields = ("input", "output", "status", "level", "vertices", "cells", "message")
            entries = [SheetEntry(**{k: asdict(o)[k] for k in fields}) for o in outcomes]
            write_contact_sheet(entries, out_dir)
    finally:
        batching.remove_empty_folders(created)  # a run that made nothing leaves no folder
    if not quiet:
        _print_batch_table(outcomes)
    statuses = [o.status for o in outcomes]
    if "failed" in statuses or "interrupted" in statuses:
        raise typer.Exit(1)
    if "check-failed" in statuses:
        raise typer.Exit(EXIT_CHECK_FAILED)


def _default_budget() -> int | None:
    from ..memory import available_memory

    available = available_memory()
    return int(0.8 * available) if available else None
