"""The commands that look and write no mesh: ``check`` and ``preview`` (a mesh
file), ``info`` (a volume), ``formats`` and ``methods`` (what isoconvert reads,
writes and extracts with), and the hidden ``warmup``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from ..atomic import check_output, input_file
from ..errors import IsoconvertError, VolumeError
from ..methods import EXTRACTORS
from ..readers import READERS
from ..writers import WRITERS
from .display import _quiet_third_party
from .options import ExamplesOpt, ReadArgs, RequireOpt, _flag, _grouped
from .reports import _emit_report

#: check's and preview's --format: the mesh's format, where its name does not tell
MeshFormatOpt = Annotated[
    str | None,
    typer.Option(
        "--format",
        help="The mesh's format by its usual extension (ply, stl, vtu, ...): for - "
        "(standard input) or a name that does not tell.",
    ),
]


@_grouped("channel", "scale", "allow_missing_chunks", "key", "volume_index", "series")
def check(
    mesh_file: Annotated[
        Path,
        typer.Argument(
            help="PLY, OBJ, OFF, STL, VTP, GLB or 3MF file to check, or any surface file "
            "meshio reads (VTU, VTK, MSH, XDMF, INP, ...); - reads standard input "
            "(with --format)."
        ),
    ],
    mesh_format: MeshFormatOpt = None,
    require: RequireOpt = None,
    as_json: Annotated[bool, _flag("--json", help="Print JSON instead of a table.")] = False,
    report: Annotated[
        str | None,
        typer.Option(
            help="Also write the report to FILE: JSON for FILE.json, else the table it prints.",
            rich_help_panel="Checks",
        ),
    ] = None,
    examples: ExamplesOpt = 5,
    force: Annotated[bool, _flag("--force", "-f", help="Overwrite the report file.")] = False,
    quiet: Annotated[bool, _flag("--quiet", "-q", help="Print only errors.")] = False,
    grid: Annotated[
        str | None,
        typer.Option(
            help="The volume the mesh came from: boundary edges on its grid are not holes "
            "(default: the grid the file records; an isoconvert STL's bounding box; "
            "else every open boundary is a hole).",
            rich_help_panel="Checks",
        ),
    ] = None,
    read: ReadArgs = ReadArgs(),
) -> None:
    """Report on a mesh file: degenerate elements, holes, manifoldness, orientation, topology."""
    _quiet_third_party()
    from ..meshfile import read_mesh
    from ..report import check_mesh, grid_from_volume, parse_requirements

    required = parse_requirements(require)
    frame = grid_files = None
    if grid is not None:
        grid_volume = read.read(grid)
        grid_files = grid_volume.files
        frame = grid_from_volume(grid_volume)
    if report is not None and report != "-":  # before reading: a bad name must not cost a check
        sources = [mesh_file, *(grid_files or ())]
        check_output(report, force, "report.txt", inputs=sources)
    mesh = read_mesh(mesh_file, format=mesh_format)
    checked = check_mesh(mesh, examples=examples, source=str(mesh_file), grid=frame)
    if report is not None and report != "-":
        _emit_report(checked, report, [], as_json=False, force=force, quiet=True, inputs=sources)
    _emit_report(checked, "-", required, as_json=as_json, force=force, quiet=quiet)


def preview(
    mesh_file: Annotated[
        Path,
        typer.Argument(
            help="PLY, OBJ, OFF, STL, VTP, GLB or 3MF file, or any surface file meshio "
            "reads; - reads standard input (with --format)."
        ),
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
    mesh_format: MeshFormatOpt = None,
    size: Annotated[str, typer.Option(help="Picture size in pixels, WIDTHxHEIGHT.")] = "1024x768",
    background: Annotated[
        str, typer.Option(help="Background colour: a name or #rrggbb.")
    ] = "white",
    force: Annotated[bool, _flag("--force", "-f", help="Overwrite the output.")] = False,
    quiet: Annotated[bool, _flag("--quiet", "-q", help="Print only errors.")] = False,
) -> None:
    """Picture a mesh from four views, with holes and non-manifold parts marked
    (needs isoconvert\\[render])."""
    _quiet_third_party()
    from ..preview import parse_colour, parse_size, preview_file

    start = time.perf_counter()
    picture = preview_file(
        mesh_file,
        output,
        size=parse_size(size),
        background=parse_colour(background),
        force=force,
        format=mesh_format,
    )
    if not quiet:  # what the picture's footer says, so as the report says
        print(f"wrote {output}: {picture.describe()} ({time.perf_counter() - start:.2f} s)")


@_grouped()
def info(
    input: Annotated[str, typer.Argument(help="Volume file, folder of TIFF slices, or glob.")],
    as_json: Annotated[bool, _flag("--json", help="Print JSON instead of text.")] = False,
    plot: Annotated[
        Path | None,
        typer.Option(
            "--plot",
            help="Also write a picture (.png, .svg or .pdf, as the name ends): the histogram "
            "with the suggested levels, and the middle slices with the contour at --level "
            "(needs isoconvert\\[plot]).",
        ),
    ] = None,
    plot_level: Annotated[
        str | None,
        typer.Option(
            "--level",
            "-l",
            help="--plot: the level to contour: a number, or otsu, p50, p90, p99, auto "
            "(default: the first suggested level, otsu).",
        ),
    ] = None,
    force: Annotated[bool, _flag("--force", "-f", help="Overwrite the --plot file.")] = False,
    read: ReadArgs = ReadArgs(),
) -> None:
    """Describe a volume (size, spacing, value range, histogram) and suggest isovalues."""
    _quiet_third_party()
    if plot is not None:
        from ..infoplot import plot_format, require_matplotlib

        # before reading: a missing extra, a format not written or an unwritable
        # --plot fails at once
        require_matplotlib()
        plot_format(plot)
        check_output(plot, force, "info.png", inputs=input_file(input))
    elif plot_level is not None:
        raise VolumeError("--level is for --plot (the contour drawn on the slices); add --plot")
    from ..stats import histogram, no_levels_reason, suggested_levels, text_histogram

    volume = read.read(input)
    hist = histogram(volume.samples)
    levels = suggested_levels(hist)  # empty when no level gives a surface
    if plot is not None:
        from ..infoplot import write_info_plot

        # the same histogram and levels as printed below, so the marks equal --json's
        write_info_plot(volume, plot, plot_level, hist=hist, levels=levels, force=force)
        print(f"wrote {plot}: histogram and middle slices", file=sys.stderr)
    summary = {
        "source": volume.source,
        "shape": list(volume.shape),
        "dtype": volume.dtype.name,
        "spacing": volume.spacing.tolist(),
        "origin": volume.origin.tolist(),
        "direction": volume.direction.tolist(),
        "unit": volume.unit,
        # null without finite samples: no range is made up
        "min": hist.low if hist.finite else None,
        "max": hist.high if hist.finite else None,
        "nonfinite": hist.nonfinite,
        "suggested_levels": levels,
        "no_levels_reason": no_levels_reason(hist),
        "notes": volume.notes,
    }
    if as_json:
        print(json.dumps(summary, indent=2))
        return
    unit = f" {volume.unit}" if volume.unit else ""
    print(f"{volume.source}")
    print(f"  shape     {' x '.join(map(str, volume.shape))}  ({volume.dtype.name})")
    print(f"  spacing   {' '.join(f'{s:g}' for s in volume.spacing)}{unit}")
    print(f"  origin    {' '.join(f'{s:g}' for s in volume.origin)}{unit}")
    if not (volume.direction == _identity(volume.ndim)).all():
        for r, row in enumerate(volume.direction):
            label = "direction" if r == 0 else ""
            print(f"  {label:<9} {' '.join(f'{v: .4f}' for v in row)}")
    if hist.finite:
        print(f"  range     {summary['min']:g} .. {summary['max']:g}")
    else:
        print("  range     none (no finite samples)")
    if hist.nonfinite and hist.finite:
        print(f"  NaN/Inf   {hist.nonfinite:,} samples (use --nan-as VALUE to contour)")
    for note in volume.notes:
        print(f"  note      {note}")
    rows = text_histogram(hist)
    if rows:
        print("  histogram")
    for line in rows:
        print("    " + line)
    if summary["no_levels_reason"]:
        print(f"  levels    none: {summary['no_levels_reason']}")
    if levels:
        suggestions = ", ".join(f"{k} {v:g}" for k, v in levels.items())
        print(f"  suggested levels: {suggestions}")


def _identity(n: int):
    import numpy as np

    return np.eye(n)


def warmup() -> None:
    """Kept so scripts written for isoconvert 0.1 still run: there is nothing to warm up."""
    print(
        "isoconvert warmup has nothing to do: the kernels are compiled when isoconvert is "
        "installed (you can drop this command)",
        file=sys.stderr,
    )


def formats() -> None:
    """List input formats, output formats and extraction methods."""
    tables = {"input formats": list(READERS.items()), "output formats": list(WRITERS.items())}
    rows = [(n, " ".join(e.suffixes)) for entries in tables.values() for n, e in entries]
    # one column width for both tables, from the longest name and suffix list
    name_width = max(len(n) for n, _ in rows)
    suffix_width = max(len(s) for _, s in rows)
    for title, entries in tables.items():
        print(f"{title}:")
        for name, entry in entries:
            suffixes = " ".join(entry.suffixes)
            print(f"  {name:<{name_width}} {suffixes:<{suffix_width}} {entry.summary}")
    print("methods:")
    _print_methods()


def methods() -> None:
    """List extraction methods (built-in and installed plugins)."""
    _print_methods()


def _print_methods() -> None:
    # What is installed now: the plugins found when the help was built may have
    # changed since in a long-lived process (a notebook calling main()).
    EXTRACTORS.reload_plugins()
    for name in EXTRACTORS.names():
        try:
            summary = EXTRACTORS.summary(name)
        except IsoconvertError as exc:
            summary = f"(broken plugin: {exc})"
        print(f"  {name:<8} {summary}")
