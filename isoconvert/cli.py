"""Command line: a thin shell over the Python API (the only module using typer/rich).

Exit codes: 0 success, 1 a problem with the input or output (one line on
stderr), 2 a usage error, 3 an internal error (a bug), 4 a check named by
``--require`` failed, 130 interrupted.
"""

from __future__ import annotations

import json
import sys
import time
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from . import __version__
from .errors import IsoconvertError, VolumeError
from .extract import EXTRACTORS, NO_DEGENERATE_OFFSET, SQUARE_AMBIGUITY_RULES
from .readers import READERS
from .report import CHECK_NAMES
from .writers import WRITERS

app = typer.Typer(
    name="isoconvert",
    help="Turn scalar volumes (raw, NRRD, TIFF) into isosurface meshes (PLY, OBJ, STL).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

# Options that take several numbers; `--shape 256 256 128` is gathered into one
# value before typer sees it (click options have a fixed number of values, and
# --shape takes 2 or 3).
_MULTI_VALUE = ("--shape", "--spacing", "--origin")

Ambiguity = Enum("Ambiguity", {r.replace("-", "_"): r for r in SQUARE_AMBIGUITY_RULES}, type=str)
Axis = Enum("Axis", {"x": "x", "y": "y", "z": "z"}, type=str)
Endian = Enum("Endian", {"little": "little", "big": "big"}, type=str)

#: Exit code when a check named by --require fails.
EXIT_CHECK_FAILED = 4

RequireOpt = Annotated[
    str | None,
    typer.Option(
        help=f"Comma-separated checks that must pass, else exit code 4: {', '.join(CHECK_NAMES)}.",
        rich_help_panel="Checks",
    ),
]
ExamplesOpt = Annotated[
    int, typer.Option(help="Examples to list per kind of problem.", rich_help_panel="Checks")
]

# Read options shared by convert and info
InputFormatOpt = Annotated[
    str | None,
    typer.Option(
        "--input-format",
        help=f"Input format: {', '.join(READERS.names())}.",
        rich_help_panel="Input",
    ),
]
ShapeOpt = Annotated[
    str | None,
    typer.Option(
        help="Raw: samples along x y [z], e.g. --shape 256 256 128.", rich_help_panel="Input"
    ),
]
DtypeOpt = Annotated[
    str | None,
    typer.Option(help="Raw: sample type (uint8, int16, float32, ...).", rich_help_panel="Input"),
]
EndianOpt = Annotated[Endian, typer.Option(help="Raw: byte order.", rich_help_panel="Input")]
HeaderBytesOpt = Annotated[
    int, typer.Option(help="Raw: bytes to skip before the samples.", rich_help_panel="Input")
]
ChannelOpt = Annotated[
    int | None,
    typer.Option(help="Multi-channel (RGB) images: channel to use.", rich_help_panel="Input"),
]
SpacingOpt = Annotated[
    str | None,
    typer.Option(help="Override the spacing: x y [z].", rich_help_panel="Input"),
]
OriginOpt = Annotated[
    str | None,
    typer.Option(help="Override the origin: x y [z].", rich_help_panel="Input"),
]


def _status(quiet: bool):
    if quiet:
        return None
    return lambda message: print(message, file=sys.stderr, flush=True)


def _numbers(text: str | None, name: str, kind=float) -> tuple | None:
    if text is None:
        return None
    parts = [p for p in text.replace("x", " ").replace(",", " ").split() if p]
    try:
        return tuple(kind(p) for p in parts)
    except ValueError:
        raise VolumeError(f"{name} takes numbers, e.g. {name} 1 1 2.5; got {text!r}") from None


def _read_kwargs(input_format, shape, dtype, endian, header_bytes, channel, spacing, origin):
    kwargs = {
        "input_format": input_format,
        "spacing": _numbers(spacing, "--spacing"),
        "origin": _numbers(origin, "--origin"),
    }
    opts = {
        "shape": _numbers(shape, "--shape", int),
        "dtype": dtype,
        "endian": endian.value if isinstance(endian, Enum) else endian,
        "header_bytes": header_bytes,
        "channel": channel,
    }
    kwargs.update({k: v for k, v in opts.items() if v is not None})
    return kwargs


@app.callback(invoke_without_command=True)
def _main(
    version: Annotated[bool, typer.Option("--version", help="Show the version.")] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show tracebacks (may go anywhere on the line).")
    ] = False,
) -> None:
    if version:
        print(f"isoconvert {__version__}")
        raise typer.Exit()


@app.command()
def convert(
    input: Annotated[str, typer.Argument(help="Volume file, folder of TIFF slices, or glob.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Mesh file to write.")],
    level: Annotated[
        str, typer.Option("--level", "-l", help="Isovalue, or 'auto' for Otsu's threshold.")
    ],
    method: Annotated[
        str | None,
        typer.Option(
            help=f"Extraction method: {', '.join(EXTRACTORS.names())} "
            "(default: squares for 2D images, cubes for 3D; see `isoconvert methods`)."
        ),
    ] = None,
    axis: Annotated[
        Axis | None,
        typer.Option(help="squares on a 3D volume: contour every slice across this axis."),
    ] = None,
    format: Annotated[
        str | None,
        typer.Option(
            help=f"Output format: {', '.join(WRITERS.names())} (default: from the extension)."
        ),
    ] = None,
    ascii: Annotated[bool, typer.Option("--ascii", help="Text PLY/STL instead of binary.")] = False,
    force: Annotated[bool, typer.Option("--force", "-f", help="Overwrite the output.")] = False,
    flip: Annotated[
        bool, typer.Option("--flip", help="Reverse orientation (normals toward higher values).")
    ] = False,
    ambiguity: Annotated[
        Ambiguity | None,
        typer.Option(
            help="Rule for ambiguous faces (default separate-positive, as VTK and "
            "scikit-image); asymptotic: squares only."
        ),
    ] = None,
    nan_as: Annotated[
        float | None, typer.Option(help="Treat NaN/Inf samples as this value (else an error).")
    ] = None,
    no_degenerate: Annotated[
        bool,
        typer.Option(
            "--no-degenerate",
            help=f"Keep vertices {NO_DEGENERATE_OFFSET:g} of an edge away from grid vertices: "
            "no zero-length edges when the level equals sample values.",
        ),
    ] = False,
    report: Annotated[
        str | None,
        typer.Option(
            help="Check the mesh and print a report; --report FILE.json writes it as JSON.",
            rich_help_panel="Checks",
        ),
    ] = None,
    require: RequireOpt = None,
    examples: ExamplesOpt = 5,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print only errors.")] = False,
    input_format: InputFormatOpt = None,
    shape: ShapeOpt = None,
    dtype: DtypeOpt = None,
    endian: EndianOpt = Endian.little,
    header_bytes: HeaderBytesOpt = 0,
    channel: ChannelOpt = None,
    spacing: SpacingOpt = None,
    origin: OriginOpt = None,
) -> None:
    """Extract an isosurface from a volume and write it as a mesh."""
    from .report import parse_requirements

    required = parse_requirements(require)
    from .convert import convert as run_convert

    start = time.perf_counter()
    result = run_convert(
        input,
        output,
        level,
        method=method,
        format=format,
        ascii=ascii,
        force=force,
        flip=flip,
        ambiguity=ambiguity.value if ambiguity else None,
        axis=axis.value if axis else None,
        vertex_offset=NO_DEGENERATE_OFFSET if no_degenerate else 0.0,
        nan_as=nan_as,
        on_status=_status(quiet),
        **_read_kwargs(input_format, shape, dtype, endian, header_bytes, channel, spacing, origin),
    )
    if not quiet:
        for note in result.volume.notes:
            print(f"note: {note}", file=sys.stderr)
        mesh = result.mesh
        kind = "triangles" if mesh.is_triangles else "segments"
        kind = f"{kind}, {mesh.info['method']}"
        print(
            f"wrote {result.output}: {mesh.n_vertices:,} vertices, {mesh.n_cells:,} {kind} "
            f"(level {mesh.info['level']:g}, {time.perf_counter() - start:.2f} s)"
        )
    if report is not None or required:
        from .report import check_mesh

        checked = check_mesh(result.mesh, examples=examples, source=str(result.output))
        _emit_report(checked, report, required, as_json=False, force=force, quiet=quiet)


@app.command()
def check(
    mesh_file: Annotated[Path, typer.Argument(help="OBJ, PLY or STL file to check.")],
    require: RequireOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    report: Annotated[
        str | None,
        typer.Option(help="Also write the report as JSON to FILE.json.", rich_help_panel="Checks"),
    ] = None,
    examples: ExamplesOpt = 5,
    force: Annotated[
        bool, typer.Option("--force", "-f", help="Overwrite the report file.")
    ] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print only errors.")] = False,
) -> None:
    """Report on a mesh file: degenerate elements, holes, manifoldness, orientation, topology."""
    from .meshfile import read_mesh
    from .report import check_mesh, parse_requirements

    required = parse_requirements(require)
    checked = check_mesh(read_mesh(mesh_file), examples=examples, source=str(mesh_file))
    if report is not None and report != "-":
        _emit_report(checked, report, [], as_json=False, force=force, quiet=True)
    _emit_report(checked, "-", required, as_json=as_json, force=force, quiet=quiet)


def _emit_report(checked, target, required, *, as_json, force, quiet) -> None:
    """Print the report (target "-") or write it as JSON; exit 4 when a required check fails."""
    from .report import format_report

    if target is not None and target != "-":
        from .atomic import atomic_output

        with atomic_output(target, force) as fh:
            fh.write((json.dumps(checked.to_dict(), indent=2) + "\n").encode("utf-8"))
    elif target == "-" and not quiet:
        print(json.dumps(checked.to_dict(), indent=2) if as_json else format_report(checked))
    failed = checked.failures(required)
    if failed:
        print(f"isoconvert: required check failed: {', '.join(failed)}", file=sys.stderr)
        raise typer.Exit(EXIT_CHECK_FAILED)


@app.command()
def info(
    input: Annotated[str, typer.Argument(help="Volume file, folder of TIFF slices, or glob.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of text.")] = False,
    input_format: InputFormatOpt = None,
    shape: ShapeOpt = None,
    dtype: DtypeOpt = None,
    endian: EndianOpt = Endian.little,
    header_bytes: HeaderBytesOpt = 0,
    channel: ChannelOpt = None,
    spacing: SpacingOpt = None,
    origin: OriginOpt = None,
) -> None:
    """Describe a volume (size, spacing, value range, histogram) and suggest isovalues."""
    from .readers import read_volume
    from .stats import histogram, suggested_levels

    kwargs = _read_kwargs(
        input_format, shape, dtype, endian, header_bytes, channel, spacing, origin
    )
    volume = read_volume(input, format=kwargs.pop("input_format"), **kwargs)
    hist = histogram(volume.data)
    levels = suggested_levels(hist) if hist.counts.sum() else {}
    summary = {
        "source": volume.source,
        "shape": list(volume.shape),
        "dtype": volume.data.dtype.name,
        "spacing": volume.spacing.tolist(),
        "origin": volume.origin.tolist(),
        "direction": volume.direction.tolist(),
        "unit": volume.unit,
        "min": float(hist.edges[0]),
        "max": float(hist.edges[-2] if hist.integer else hist.edges[-1]),
        "nonfinite": hist.nonfinite,
        "suggested_levels": levels,
        "notes": volume.notes,
    }
    if as_json:
        print(json.dumps(summary, indent=2))
        return
    unit = f" {volume.unit}" if volume.unit else ""
    print(f"{volume.source}")
    print(f"  shape     {' x '.join(map(str, volume.shape))}  ({volume.data.dtype.name})")
    print(f"  spacing   {' '.join(f'{s:g}' for s in volume.spacing)}{unit}")
    print(f"  origin    {' '.join(f'{s:g}' for s in volume.origin)}{unit}")
    if not (volume.direction == _identity(volume.ndim)).all():
        for r, row in enumerate(volume.direction):
            label = "direction" if r == 0 else ""
            print(f"  {label:<9} {' '.join(f'{v: .4f}' for v in row)}")
    print(f"  range     {summary['min']:g} .. {summary['max']:g}")
    if hist.nonfinite:
        print(f"  NaN/Inf   {hist.nonfinite:,} samples (use --nan-as VALUE to contour)")
    for note in volume.notes:
        print(f"  note      {note}")
    print("  histogram")
    for line in _text_histogram(hist):
        print("    " + line)
    if levels:
        suggestions = ", ".join(f"{k} {v:g}" for k, v in levels.items())
        print(f"  suggested levels: {suggestions}")


def _identity(n: int):
    import numpy as np

    return np.eye(n)


def _text_histogram(hist, rows: int = 12, width: int = 40) -> list[str]:
    """Bars of sample counts in ``rows`` equal value ranges (log scale, as CT is skewed)."""
    import numpy as np

    lo, hi = float(hist.edges[0]), float(hist.edges[-1])
    bounds = np.linspace(lo, hi, rows + 1)
    which = np.clip(np.searchsorted(bounds, hist.centers, side="right") - 1, 0, rows - 1)
    counts = np.bincount(which, weights=hist.counts, minlength=rows)
    scale = np.log1p(counts) / max(np.log1p(counts).max(), 1e-12)
    bars = ["#" * int(round(s * width)) for s in scale]
    return [
        f"{bounds[r]:>10.4g} .. {bounds[r + 1]:<10.4g} {bars[r]:<{width}} {int(counts[r]):,}"
        for r in range(rows)
    ]


@app.command()
def formats() -> None:
    """List input formats, output formats and extraction methods."""
    print("input formats:")
    for name, reader in READERS.items():
        print(f"  {name:<6} {' '.join(reader.suffixes):<18} {reader.summary}")
    print("output formats:")
    for name, writer in WRITERS.items():
        print(f"  {name:<6} {' '.join(writer.suffixes):<18} {writer.summary}")
    print("methods:")
    _print_methods()


@app.command()
def methods() -> None:
    """List extraction methods (built-in and installed plugins)."""
    _print_methods()


def _print_methods() -> None:
    for name in EXTRACTORS.names():
        try:
            summary = EXTRACTORS.get(name).summary
        except IsoconvertError as exc:
            summary = f"(broken plugin: {exc})"
        print(f"  {name:<8} {summary}")


def gather_multi_values(argv: list[str]) -> list[str]:
    """Join ``--shape 256 256 128`` into ``--shape 256,256,128`` (also spacing,
    origin), and give a bare ``--report`` the value "-" (print) unless a
    ``.json`` file name follows it."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        out.append(token)
        i += 1
        if token == "--report":
            if i < len(argv) and argv[i].lower().endswith(".json"):
                out.append(argv[i])
                i += 1
            else:
                out.append("-")
            continue
        if token in _MULTI_VALUE:
            values = []
            while i < len(argv) and len(values) < 3 and _is_number(argv[i]):
                values.append(argv[i])
                i += 1
            if values:
                out.append(",".join(values))
    return out


def _is_number(text: str) -> bool:
    try:
        float(text.replace("x", "e") if "x" in text else text)
        return "x" not in text
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``isoconvert`` command; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    args = gather_multi_values([a for a in args if a != "--debug"])
    try:
        app(args=args, prog_name="isoconvert", standalone_mode=True)
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except IsoconvertError as exc:
        if debug:
            raise
        print(f"isoconvert: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if debug:
            raise
        print("isoconvert: interrupted; no output was written", file=sys.stderr)
        return 130
    except MemoryError:
        if debug:
            raise
        print("isoconvert: error: out of memory; try a smaller volume", file=sys.stderr)
        return 1
    except Exception as exc:  # a bug, not a user mistake: say so in one line
        if debug:
            raise
        print(
            f"isoconvert: internal error: {type(exc).__name__}: {exc} "
            "(rerun with --debug and report it)",
            file=sys.stderr,
        )
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())
