"""``isoconvert convert``: one volume to one mesh per level (or per label)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from ..atomic import check_output, input_file
from ..errors import IsoconvertError
from .display import _quiet_third_party, _stage_display
from .options import (
    EXIT_CHECK_FAILED,
    ExamplesOpt,
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
    _convert_options,
    _grouped,
)
from .reports import _report_result


@_grouped()
def convert(
    input: Annotated[str, typer.Argument(help="Volume file, folder of TIFF slices, or glob.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Mesh file to write.")],
    level: LevelOpt = None,
    extract: ExtractArgs = ExtractArgs(),
    force: ForceOpt = False,
    report: Annotated[
        str | None,
        typer.Option(
            help="Check the mesh and print a report; --report FILE.json writes it as JSON, "
            "--report FILE.txt as the table it prints.",
            rich_help_panel="Checks",
        ),
    ] = None,
    require: RequireOpt = None,
    examples: ExamplesOpt = 5,
    preview: Annotated[
        Path | None,
        typer.Option(
            help="Also write a picture of the mesh with its problems marked, as FILE.png "
            "(needs isoconvert\\[render]).",
            rich_help_panel="Output",
        ),
    ] = None,
    quiet: QuietOpt = False,
    verbose: VerboseOpt = False,
    read: ReadArgs = ReadArgs(),
    mesh: MeshArgs = MeshArgs(),
    values: Annotated[
        str | None,
        typer.Option(
            help="Write the value of this volume (read like the input) at each vertex, by "
            "trilinear interpolation in world coordinates (PLY, VTP, GLB).",
            rich_help_panel="Output",
        ),
    ] = None,
    post: PostArgs = PostArgs(),
    memory: MemoryArgs = MemoryArgs(),
    labels: LabelArgs = LabelArgs(),
    layer: LayerArgs = LayerArgs(),
) -> None:
    """Extract an isosurface from a volume and write it as a mesh."""
    _quiet_third_party()
    from ..checks import parse_requirements

    required = parse_requirements(require)
    from ..convert import convert_levels, level_outputs
    from ..label_convert import convert_labels

    options = _convert_options(
        read,
        extract,
        mesh,
        post,
        labels,
        layer,
        level,
        force=force,
        values=values,
        blocks=memory.blocks(),
    )
    by_label = options.labels is not None
    if not by_label and not level:
        raise IsoconvertError(
            "convert needs --level (a number, or auto), or --labels for a label volume"
        )
    reports = None
    if report not in (None, "-") and not by_label:
        reports = level_outputs(report, level)
        for path in reports:
            check_output(path, force, "report.json", inputs=input_file(input))  # before a mesh
    elif report not in (None, "-") and not options.single_file and len(options.labels or ()) != 1:
        from ..atomic import refuse_stream

        refuse_stream(report, "--labels writes a report per label")
    if preview is not None:  # before the work: no renderer or a bad name must not cost a mesh
        from ..preview import check_picture_output, require_renderer

        require_renderer()
        check_picture_output(preview, force, inputs=input_file(input))
    # reports and pictures must not replace an input's file either
    also_writes = [*(reports or ()), *([preview] if preview is not None else ())]
    if by_label and report not in (None, "-"):
        also_writes.append(report)
    start = time.perf_counter()
    with _stage_display(quiet, verbose) as (on_progress, on_status):
        run, first = (convert_labels, options.labels) if by_label else (convert_levels, level)
        results = run(
            input,
            output,
            first,
            options,
            also_writes=also_writes,
            on_status=on_status,
            on_progress=on_progress,
        )
    if not quiet:
        for note in results[0].volume.notes:
            print(f"note: {note}", file=sys.stderr)
    if by_label and report not in (None, "-"):
        name = Path(report)
        reports = [name.with_name(f"{name.stem}_{r.output.stem}{name.suffix}")
                   for r in results] if len(results) > 1 else [report]  # fmt: skip
    failed = []
    steps = options.post.steps
    for n, result in enumerate(results):
        if not quiet:
            made = result.summary
            counts = result.stored_counts()  # a cut layer's level can hold fewer
            kind = "triangles" if made.is_triangles else "segments"
            kind = f"{kind}, {made.info['method']}"
            slabs = made.info.get("blocks", 1)
            if slabs > 1:
                kind += f" in {slabs} slabs"
            done = f", {', '.join(steps)}" if steps and not by_label else ""
            what = made.info["level"]
            if by_label and options.single_file:
                what = f"labels {what}"
            else:
                what = f"label {what:g}" if by_label else f"level {what:g}"
            # the run's time once: on each of many lines it read as each file's
            took = f", {time.perf_counter() - start:.2f} s" if len(results) == 1 else ""
            if result.layer is not None:
                what = f"level 0 as stored, {what}"
            print(
                f"wrote {result.output}: {counts[0]:,} vertices, {counts[1]:,} {kind} "
                f"({what}{done}{took})"
            )
        if report is not None or required:
            target = reports[n] if reports else report
            failed += _report_result(result, target, required, examples, force, quiet)
        if preview is not None:
            _write_preview(result, preview, output, len(results), force, quiet)
        result.forget_written()
    if not quiet and len(results) > 1:
        from ..writers import WRITERS

        layer = options.format is not None and WRITERS.get(options.format).layer
        where = f" into {output}" if layer else ""
        print(f"{len(results)} meshes written{where} in {time.perf_counter() - start:.2f} s")
    if failed:
        raise typer.Exit(EXIT_CHECK_FAILED)


def _write_preview(
    result, preview: Path, output: Path, count: int, force: bool, quiet: bool
) -> None:
    """The picture of one mesh convert wrote: ``preview`` itself for one mesh,
    else named like the mesh (``-o em.ply --preview pic.png`` with two levels:
    ``pic_level80.5.png``, ``pic_level180.5.png``)."""
    from ..preview import render_preview, write_preview

    target = preview
    if count > 1:
        stem, base = result.output.stem, Path(output).stem
        tail = stem[len(base) :] if stem.startswith(base) else f"_{stem}"
        target = preview.with_name(f"{preview.stem}{tail}.png")
    mesh = result.mesh  # a label's is built again: the results do not hold them
    picture = render_preview(mesh, checked=result.written, grid=result.summary.info.get("grid"))
    write_preview(picture, target, force)
    if not quiet:
        print(f"wrote {target}: preview", file=sys.stderr)
