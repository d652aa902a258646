"""Command line: a thin shell over the Python API (the only module using typer/rich).

The top layer: it imports the library, nothing imports it. The help, ``formats``
and ``methods`` need only numpy-free tables; each command imports the rest when
it runs. The options ``convert`` and ``batch`` share are declared once, in
groups (``ReadArgs``, ``ExtractArgs``, ...), and both commands build their
:class:`~isoconvert.convert.ConvertOptions` from them through one function.

Exit codes: 0 success, 1 a problem with the input or output (one line on
stderr), 2 a usage error, 3 an internal error (a bug), 4 a check named by
``--require`` failed, 130 interrupted.
"""

from __future__ import annotations

import functools
import inspect
import json
import sys
import time
from contextlib import contextmanager, nullcontext, redirect_stdout
from dataclasses import dataclass, fields, replace
from enum import Enum
from pathlib import Path
from typing import Annotated, get_type_hints

import typer

from . import __version__
from .atomic import check_output
from .checks import CHECK_NAMES
from .errors import IsoconvertError, VolumeError, one_line
from .methods import EXTRACTORS, NO_DEGENERATE_OFFSET, SQUARE_AMBIGUITY_RULES
from .readers import READERS
from .writers import WRITERS, check_attributes

# What the help, `formats` and `methods` need comes from numpy-free tables
# (methods, checks, and the readers' and writers' registries); each command
# imports the rest (numpy, the kernels, the parsers) when it runs, so that
# `isoconvert --help` starts fast.


class _HelpAsFlag:
    """Show ``--help`` as a flag, as our own flags (typer would show ``-h <bool>``)."""

    def get_help_option(self, ctx):
        option = super().get_help_option(ctx)
        if option is not None:
            option.metavar = ""
            # Absent, typer's help option is None, which typer coerces through
            # pydantic (~50 ms to import); False is a bool, which it passes as
            # is, so `formats` and `methods` need no pydantic.
            option.default = False
        return option


class _Command(_HelpAsFlag, typer.core.TyperCommand):
    pass


class _Group(_HelpAsFlag, typer.core.TyperGroup):
    pass


app = typer.Typer(
    name="isoconvert",
    cls=_Group,
    help="Turn scalar volumes and images (raw, NRRD, TIFF, Zarr, DICOM, NIfTI, MetaImage, NumPy, "
    "PNG, JPEG) into isosurface meshes and contours (PLY, OBJ, OFF, VTP, STL, GLB, 3MF, SVG, "
    "GeoJSON), and check and picture meshes.",
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


def _flag(*declarations: str, **kwargs):
    """An on/off option, shown in help as a flag (typer would show ``--force <bool>``)."""
    return typer.Option(*declarations, metavar="", **kwargs)


#: Exit code when a check named by --require fails.
EXIT_CHECK_FAILED = 4

RequireOpt = Annotated[
    str | None,
    typer.Option(
        help=f"Comma-separated checks that must pass, else exit code 4: {', '.join(CHECK_NAMES)}.",
        rich_help_panel="Checks",
    ),
]
VerboseOpt = Annotated[
    bool, _flag("--verbose", "-v", help="Say what happens, step by step, with times.")
]
ExamplesOpt = Annotated[
    int, typer.Option(help="Examples to list per kind of problem.", rich_help_panel="Checks")
]

#: Set by :func:`main`: with --debug, third-party warnings and log lines stay visible.
_show_third_party = False


def _quiet_third_party() -> None:
    """Keep numpy's warnings and tifffile's log lines off stderr, unless --debug.

    Called by the commands that read or compute, not by ``main``: it imports
    numpy, which the help, ``formats`` and ``methods`` do without.
    """
    if not _show_third_party:
        from .quiet import silence_third_party

        silence_third_party()


def _interactive() -> bool:
    """Progress displays only on a terminal, never in pipes, logs or CI."""
    return sys.stderr.isatty()


@contextmanager
def _stage_display(quiet: bool, verbose: bool = False):
    """Yield ``(on_progress, on_status)`` for :func:`isoconvert.convert`.

    On a terminal a spinner names the stage (reading, extracting, writing);
    notices print above it. With
    ``verbose``, a timed line per stage instead (also when not a terminal).
    Otherwise notices are plain lines on stderr.
    """
    if quiet:
        yield None, None
        return
    if verbose or not _interactive():
        clock = _StageClock() if verbose else None
        yield (clock.start if clock else None), _status(quiet)
        if clock:
            clock.finish()
        return
    from rich.console import Console

    console = Console(stderr=True)
    with console.status("starting") as status:

        def on_status(message: str) -> None:
            console.print(message, markup=False, highlight=False)

        yield (lambda stage: status.update(f"{stage}...")), on_status


class _StageClock:
    """--verbose: one line per stage with the time it took, as it ends, then the
    total, so that the lines add up to the run."""

    def __init__(self) -> None:
        self.began = self.since = time.perf_counter()
        self.stage: str | None = None

    def start(self, stage: str) -> None:
        now = time.perf_counter()
        if self.stage is not None:
            print(f"{now - self.since:7.2f} s  {self.stage}", file=sys.stderr)
        self.stage, self.since = stage, now

    def finish(self) -> None:
        self.start("")  # the line of the last stage
        print(f"{time.perf_counter() - self.began:7.2f} s  in all", file=sys.stderr)


def _status(quiet: bool):
    """Notices as plain lines on stderr (None when quiet)."""
    if quiet:
        return None

    def say(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    return say


def _numbers(text: str | None, name: str, kind=float) -> tuple | None:
    if text is None:
        return None
    parts = [p for p in text.replace("x", " ").replace(",", " ").split() if p]
    try:
        return tuple(kind(p) for p in parts)
    except ValueError:
        raise VolumeError(f"{name} takes numbers, e.g. {name} 1 1 2.5; got {text!r}") from None


@app.callback(invoke_without_command=True)
def _main(
    version: Annotated[bool, _flag("--version", help="Show the version.")] = False,
    debug: Annotated[
        bool, _flag("--debug", help="Show tracebacks (may go anywhere on the line).")
    ] = False,
) -> None:
    if version:
        print(f"isoconvert {__version__}")
        raise typer.Exit()


def _check_levels(values: list[str] | None) -> list[str] | None:
    """--level values are numbers or 'auto': a word is a command line that cannot be
    parsed (exit 2, as for every other number option)."""
    for text in values or ():
        if text.strip().lower() != "auto":
            try:
                float(text)
            except ValueError:
                raise typer.BadParameter(f"a number or 'auto', got {text!r}") from None
    return values


LevelOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--level",
        "-l",
        metavar="<number|auto>",
        callback=_check_levels,
        help="Isovalue, or 'auto' (Otsu's threshold; in batch, each file's own); several "
        "--level write one mesh each (NAME_levelL.ply).",
    ),
]


QuietOpt = Annotated[bool, _flag("--quiet", "-q", help="Print only errors.")]
ForceOpt = Annotated[bool, _flag("--force", "-f", help="Overwrite existing outputs.")]

# --- option groups -----------------------------------------------------------------------
# Each group of options that convert and batch share is declared once, as the
# fields of a dataclass whose types carry the typer option (help text; the help
# panel is the group's, in _GROUPS, unless the option names its own). A command
# names a group as one parameter (``read: ReadArgs``, its default setting the
# defaults); `_grouped` spreads it into one option per field, so that `--help`
# lists them as before, and gathers them back into one value when the command
# runs. Both commands turn the groups into ConvertOptions through
# `_convert_options`, so a new option is one field and one line there (and
# tests/test_cli_shared_options.py fails until both commands have it, or it is
# listed there as one command's own).


@dataclass(frozen=True)
class ReadArgs:
    """How to read a volume: convert, batch, info; check, in part."""

    input_format: Annotated[
        str | None, typer.Option(help=f"Input format: {', '.join(READERS.names())}.")
    ] = None
    shape: Annotated[
        str | None,
        typer.Option(help="Raw: samples along x and y (and z), e.g. --shape 256 256 128."),
    ] = None
    dtype: Annotated[
        str | None, typer.Option(help="Raw: sample type (uint8, int16, float32, ...).")
    ] = None
    endian: Annotated[Endian, typer.Option(help="Raw: byte order.")] = Endian.little
    header_bytes: Annotated[int, typer.Option(help="Raw: bytes to skip before the samples.")] = 0
    channel: Annotated[
        int | None, typer.Option(help="Multi-channel (RGB) images: channel to use.")
    ] = None
    spacing: Annotated[
        str | None, typer.Option(help="Override the spacing: x y (z), e.g. --spacing 0.5 0.5 2.")
    ] = None
    origin: Annotated[str | None, typer.Option(help="Override the origin: x y (z).")] = None
    allow_outside_data: Annotated[
        bool,
        _flag(
            "--allow-outside-data",
            help="Let a header (detached NRRD) name data files outside its own folder.",
        ),
    ] = False
    scale: Annotated[
        int, typer.Option(help="OME-Zarr: resolution level to read (0 = full resolution).")
    ] = 0
    allow_missing_chunks: Annotated[
        bool,
        _flag(
            "--allow-missing-chunks",
            help="Zarr: read chunks missing from the store as the fill value (stores whose "
            "writer skips empty chunks; else a missing chunk is an error).",
        ),
    ] = False
    key: Annotated[
        str | None, typer.Option(help="NumPy .npz: the array to read (when it holds several).")
    ] = None
    volume_index: Annotated[
        int | None, typer.Option(help="4D NIfTI: the volume to read (0 = the first).")
    ] = None
    series: Annotated[
        str | None,
        typer.Option(help="DICOM folder holding several series: the SeriesInstanceUID to read."),
    ] = None

    def read_options(self, raw_layout: bool = True):
        """The ReadOptions these options say (without the raw layout: shape,
        dtype, endian and header bytes, which batch gives raw files only)."""
        from .readers import ReadOptions

        layout = self.raw_layout() if raw_layout else {}
        return ReadOptions(
            **layout,
            channel=self.channel,
            allow_outside_data=self.allow_outside_data,
            scale=self.scale,
            allow_missing_chunks=self.allow_missing_chunks,
            key=self.key,
            volume_index=self.volume_index,
            series=self.series,
        )

    def raw_layout(self) -> dict:
        """The raw file layout given (shape, dtype, endian, header bytes)."""
        layout = {
            "shape": _numbers(self.shape, "--shape", int),
            "dtype": self.dtype,
            "endian": self.endian.value if isinstance(self.endian, Enum) else self.endian,
            "header_bytes": self.header_bytes,
        }
        return {k: v for k, v in layout.items() if v is not None}

    def placement(self) -> dict:
        """``spacing`` and ``origin`` as numbers (None where not given)."""
        return {
            "spacing": _numbers(self.spacing, "--spacing"),
            "origin": _numbers(self.origin, "--origin"),
        }

    def read(self, path: str):
        """The volume at ``path``, read as these options say (info, check --grid)."""
        from .readers import read_volume

        opts = self.read_options()
        given = {name: getattr(opts, name) for name in opts.given()}
        return read_volume(path, format=self.input_format, **self.placement(), **given)


@dataclass(frozen=True)
class ExtractArgs:
    """How to extract the surface (the main panel)."""

    method: Annotated[
        str | None,
        typer.Option(
            help=f"Extraction method: {', '.join(EXTRACTORS.names())} "
            "(default: squares for 2D images, cubes for 3D; see `isoconvert methods`)."
        ),
    ] = None
    axis: Annotated[
        Axis | None,
        typer.Option(help="squares on a 3D volume: contour every slice across this axis."),
    ] = None
    flip: Annotated[
        bool, _flag("--flip", help="Reverse orientation (normals toward higher values).")
    ] = False
    ambiguity: Annotated[
        Ambiguity | None,
        typer.Option(
            help="Rule for ambiguous faces (default separate-positive, as VTK and "
            "scikit-image); asymptotic: squares only."
        ),
    ] = None
    nan_as: Annotated[
        float | None, typer.Option(help="Treat NaN/Inf samples as this value (else an error).")
    ] = None
    no_degenerate: Annotated[
        bool,
        _flag(
            "--no-degenerate",
            help=f"Keep every vertex {NO_DEGENERATE_OFFSET:g} of an edge away from grid "
            "vertices (the default only when the level equals some sample values).",
        ),
    ] = False
    exact_placement: Annotated[
        bool,
        _flag(
            "--exact-placement",
            help="Place vertices exactly by linear interpolation even when the level equals "
            "sample values (zero-length edges and degenerate triangles there).",
        ),
    ] = False

    def vertex_offset(self) -> float | None:
        """--no-degenerate always offsets, --exact-placement never; neither: automatic (None)."""
        if self.no_degenerate and self.exact_placement:
            raise typer.BadParameter("--no-degenerate and --exact-placement contradict each other")
        if self.no_degenerate:
            return NO_DEGENERATE_OFFSET
        return 0.0 if self.exact_placement else None


@dataclass(frozen=True)
class MeshArgs:
    """What the mesh file holds: its format, text or binary, frame and normals."""

    format: Annotated[
        str | None,
        typer.Option(
            help=f"Output format: {', '.join(WRITERS.names())} (default: from the output's "
            "extension; batch: ply)."
        ),
    ] = None
    ascii: Annotated[bool, _flag("--ascii", help="Text PLY/STL/VTP instead of binary.")] = False
    space: Annotated[
        str | None,
        typer.Option(
            help="World frame of the mesh: lps (NRRD, DICOM, ITK) or ras (NIfTI); converts "
            "from the frame the file states (default: keep it).",
            rich_help_panel="Input",
        ),
    ] = None
    normals: Annotated[
        bool,
        _flag(
            "--normals",
            help="Write per-vertex normals from the volume's gradient (PLY, OBJ, VTP, GLB).",
            rich_help_panel="Output",
        ),
    ] = False


@dataclass(frozen=True)
class PostArgs:
    """Post-processing: closing, clean-up, smoothing, decimation."""

    close: Annotated[
        bool,
        _flag(
            "--close",
            help="Cap the surface where the object meets the grid's faces, so it comes out "
            "watertight (cubes).",
        ),
    ] = False
    largest: Annotated[bool, _flag("--largest", help="Keep only the largest component.")] = False
    keep: Annotated[
        int | None, typer.Option(help="Keep the K largest components (by triangles).")
    ] = None
    min_size: Annotated[
        int | None, typer.Option(help="Drop components of fewer than N triangles.")
    ] = None
    min_volume: Annotated[
        float | None,
        typer.Option(help="Drop closed components enclosing less than V (world units cubed)."),
    ] = None
    fill_cavities: Annotated[
        bool,
        _flag(
            "--fill-cavities",
            help="Drop closed surfaces inside other closed surfaces (internal bubbles).",
        ),
    ] = False
    smooth: Annotated[
        int | None,
        typer.Option(
            help="Smoothing iterations (default 0: none; with --labels, relaxation iterations, "
            "default 16); keeps the volume, grid-face vertices stay on it."
        ),
    ] = None
    smooth_method: Annotated[
        str,
        typer.Option(
            help="sinc (windowed sinc, as VTK), taubin, or laplacian (shrinks the surface)."
        ),
    ] = "sinc"
    passband: Annotated[
        float, typer.Option(help="Smoothing pass band in (0, 2); smaller smooths more.")
    ] = 0.1
    decimate: Annotated[
        float | None,
        typer.Option(
            help="Remove this fraction of the triangles, e.g. 0.9 (needs isoconvert\\[simplify])."
        ),
    ] = None
    max_error: Annotated[
        float | None,
        typer.Option(
            help="Decimate moving the surface at most this far (world units); alone, as far as "
            "it allows."
        ),
    ] = None

    def options(self):
        """The PostOptions these options say."""
        from .post.pipeline import PostOptions

        if self.largest and self.keep is not None:
            raise IsoconvertError("--largest is --keep 1; give one of them")
        return PostOptions(
            close=self.close,
            keep=1 if self.largest else self.keep,
            min_size=self.min_size,
            min_volume=self.min_volume,
            fill_cavities=self.fill_cavities,
            smooth=self.smooth or 0,
            smooth_method=self.smooth_method,
            passband=self.passband,
            decimate=self.decimate,
            max_error=self.max_error,
        )


@dataclass(frozen=True)
class MemoryArgs:
    """Large volumes: slabs, the memory budget, a Dask cluster."""

    block_size: Annotated[
        int | None,
        typer.Option(
            help="Extract block-wise, this many z-layers per block (default: as "
            "--max-memory allows, and only for volumes larger than it)."
        ),
    ] = None
    max_memory: Annotated[
        str | None,
        typer.Option(
            help="Memory for samples at once, e.g. 2G (default 1G; batch: 80% of what is "
            "available, shared by the files converted at once): a volume read from its "
            "file that is larger is extracted block-wise."
        ),
    ] = None
    scheduler: Annotated[
        str | None,
        typer.Option(
            help="Run on a Dask cluster: its scheduler's address, e.g. tcp://host:8786 "
            "(default: $DASK_SCHEDULER_ADDRESS; none: here). Needs isoconvert\\[dask]."
        ),
    ] = None

    def blocks(self):
        """The Blocks of one conversion (convert; batch shares its budget out itself)."""
        from .distributed import scheduler_address
        from .extract.blocks import Blocks

        return Blocks(
            size=self.block_size,
            max_memory=_bytes(self.max_memory) if self.max_memory else None,
            scheduler=scheduler_address(self.scheduler),
        )


@dataclass(frozen=True)
class LabelArgs:
    """Label volumes: one surface per label."""

    labels: Annotated[
        bool,
        _flag(
            "--labels",
            help="A label volume: one closed surface per label (Surface Nets), "
            "NAME_labelL.ply; --smooth N sets its relaxation iterations (default 16).",
        ),
    ] = False
    label: Annotated[
        str | None, typer.Option(help="Only these labels, e.g. 3,7 (implies --labels).")
    ] = None
    single_file: Annotated[
        bool,
        _flag(
            "--single-file",
            help="Labels: one mesh, each triangle with the labels on its two sides (PLY, VTP).",
        ),
    ] = False
    background: Annotated[int, typer.Option(help="Labels: the value of no label.")] = 0

    def chosen(self, level) -> tuple[int, ...] | None:
        """The labels wanted (empty: every label), or None for an isosurface."""
        wanted = _label_list(self.label)
        labels = self.labels or wanted is not None
        if self.background and not labels:
            raise IsoconvertError("--background is the value of no label; it goes with --labels")
        if self.single_file and not labels:
            raise IsoconvertError("--single-file writes the surfaces of --labels; add --labels")
        if labels and level:
            raise IsoconvertError("--labels extracts every label's boundary: leave out --level")
        return (wanted or ()) if labels else None


#: The groups, and the help panel of their options (unless an option names its own).
_GROUPS = {
    ReadArgs: "Input",
    ExtractArgs: None,
    MeshArgs: None,
    PostArgs: "Post-processing",
    MemoryArgs: "Large volumes",
    LabelArgs: "Labels",
}
_KEYWORD = inspect.Parameter.KEYWORD_ONLY


@functools.cache
def _group_types(kind: type) -> dict:
    """The annotated types of a group's fields (evaluated once for all commands), each
    option in its group's help panel unless it names its own."""
    types = get_type_hints(kind, include_extras=True)
    for annotated in types.values():
        option = annotated.__metadata__[0]
        option.rich_help_panel = option.rich_help_panel or _GROUPS[kind]
    return types


def _grouped(*omit: str):
    """Spread a command's option-group parameters into typer options, one per field
    (but those named in ``omit``), and gather them back when the command runs."""

    def decorate(command):
        hints = get_type_hints(command, include_extras=True)
        params, groups = [], {}
        for param in inspect.signature(command).parameters.values():
            kind = hints[param.name]
            if kind not in _GROUPS:
                params.append(param.replace(annotation=kind, kind=param.KEYWORD_ONLY))
                continue
            types = _group_types(kind)
            names = [f.name for f in fields(kind) if f.name not in omit]
            given = param.default  # the group's defaults (a command may set its own)
            params += [
                inspect.Parameter(n, _KEYWORD, default=getattr(given, n), annotation=types[n])
                for n in names
            ]
            groups[param.name] = (given, names)

        @functools.wraps(command)
        def run(**kwargs):
            for name, (given, names) in groups.items():
                kwargs[name] = replace(given, **{n: kwargs.pop(n) for n in names})
            return command(**kwargs)

        run.__signature__ = inspect.Signature(params)
        run.__annotations__ = {p.name: p.annotation for p in params}
        return run

    return decorate


def _convert_options(
    read: ReadArgs,
    extract: ExtractArgs,
    mesh: MeshArgs,
    post: PostArgs,
    labels: LabelArgs,
    level,
    *,
    raw_layout: bool = True,
    **changes,
):
    """The ConvertOptions of convert's and batch's shared option groups; ``changes``
    are a command's own (force, blocks, values).

    ``raw_layout`` False leaves out the raw layout (which batch gives raw files only).
    """
    from .convert import ConvertOptions

    chosen = labels.chosen(level)
    options = ConvertOptions(
        read=read.read_options(raw_layout),
        input_format=read.input_format,
        **read.placement(),
        method=extract.method,
        flip=extract.flip,
        ambiguity=extract.ambiguity.value if extract.ambiguity else None,
        axis=extract.axis.value if extract.axis else None,
        vertex_offset=extract.vertex_offset(),
        nan_as=extract.nan_as,
        format=mesh.format,
        ascii=mesh.ascii,
        space=mesh.space,
        normals=mesh.normals,
        post=post.options(),
        labels=chosen,
        single_file=labels.single_file,
        background=labels.background,
        label_smoothing=post.smooth if chosen is not None else None,
    )
    return replace(options, **changes)


@app.command(cls=_Command)
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
) -> None:
    """Extract an isosurface from a volume and write it as a mesh."""
    _quiet_third_party()
    from .report import parse_requirements

    required = parse_requirements(require)
    from .convert import convert_levels, level_outputs
    from .label_convert import convert_labels

    options = _convert_options(
        read,
        extract,
        mesh,
        post,
        labels,
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
            check_output(path, force, "report.json")  # a bad report name must not cost a mesh
    elif report not in (None, "-") and not options.single_file and len(options.labels or ()) != 1:
        from .atomic import refuse_stream

        refuse_stream(report, "--labels writes a report per label")
    if preview is not None:  # before the work: no renderer or a bad name must not cost a mesh
        from .preview import check_picture_output, require_renderer

        require_renderer()
        check_picture_output(preview, force)
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
            made = result.mesh
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
            print(
                f"wrote {result.output}: {made.n_vertices:,} vertices, {made.n_cells:,} {kind} "
                f"({what}{done}, {time.perf_counter() - start:.2f} s)"
            )
        if report is not None or required:
            target = reports[n] if reports else report
            failed += _report_result(result, target, required, examples, force, quiet)
        if preview is not None:
            _write_preview(result, preview, output, len(results), force, quiet)
    if failed:
        raise typer.Exit(EXIT_CHECK_FAILED)


def _write_preview(
    result, preview: Path, output: Path, count: int, force: bool, quiet: bool
) -> None:
    """The picture of one mesh convert wrote: ``preview`` itself for one mesh,
    else named like the mesh (``-o em.ply --preview pic.png`` with two levels:
    ``pic_level80.5.png``, ``pic_level180.5.png``)."""
    from .preview import render_preview, write_preview

    target = preview
    if count > 1:
        stem, base = result.output.stem, Path(output).stem
        tail = stem[len(base) :] if stem.startswith(base) else f"_{stem}"
        target = preview.with_name(f"{preview.stem}{tail}.png")
    picture = render_preview(result.mesh, checked=result.written, grid=result.mesh.info.get("grid"))
    write_preview(picture, target, force)
    if not quiet:
        print(f"wrote {target}: preview", file=sys.stderr)


def _label_list(text: str | None) -> tuple[int, ...] | None:
    """The labels of --label 3,7 (None when not given)."""
    if text is None:
        return None
    try:
        return tuple(int(p) for p in text.replace(",", " ").split())
    except ValueError:
        raise IsoconvertError(
            f"--label takes whole numbers, e.g. --label 3,7; got {text!r}"
        ) from None


def _report_result(result, target, required, examples, force, quiet) -> list[str]:
    """Check what ``result`` wrote, against its volume's grid; with
    post-processing, also the mesh as extracted, and say what changed.
    Returns the required checks that failed."""
    from .report import check_mesh

    grid = result.mesh.info.get("grid")
    checked = check_mesh(result.written, examples=examples, source=str(result.output), grid=grid)
    changed = None
    if result.extracted is not None and not (quiet and target in (None, "-")):
        from .post.pipeline import changes
        from .writers.stored import stored_mesh

        # both as the file stores them (STL: three vertices per triangle)
        extracted = stored_mesh(result.extracted, result.format, result.ascii)
        before = check_mesh(extracted, examples=0, grid=grid).to_dict()
        changed = changes(before, checked.to_dict()) or ["nothing the report measures"]
        if not quiet:
            print(f"{result.output}: post-processing changed:", file=sys.stderr)
            for line in changed:
                print(f"  {line}", file=sys.stderr)
    try:
        _emit_report(
            checked, target, required, as_json=False, force=force, quiet=quiet, changed=changed
        )
    except typer.Exit:
        return checked.failures(required)
    return []


@app.command(cls=_Command)
@_grouped("channel", "scale", "allow_missing_chunks", "key", "volume_index", "series")
def check(
    mesh_file: Annotated[
        Path, typer.Argument(help="PLY, OBJ, OFF, STL, VTP, GLB or 3MF file to check.")
    ],
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
    from .meshfile import read_mesh
    from .report import check_mesh, grid_from_volume, parse_requirements

    required = parse_requirements(require)
    frame = grid_files = None
    if grid is not None:
        grid_volume = read.read(grid)
        grid_files = grid_volume.files
        frame = grid_from_volume(grid_volume)
    if report is not None and report != "-":  # before reading: a bad name must not cost a check
        sources = [mesh_file, *(grid_files or ())]
        check_output(report, force, "report.txt", inputs=sources)
    mesh = read_mesh(mesh_file)
    checked = check_mesh(mesh, examples=examples, source=str(mesh_file), grid=frame)
    if report is not None and report != "-":
        _emit_report(checked, report, [], as_json=False, force=force, quiet=True, inputs=sources)
    _emit_report(checked, "-", required, as_json=as_json, force=force, quiet=quiet)


@app.command(cls=_Command)
def preview(
    mesh_file: Annotated[Path, typer.Argument(help="PLY, OBJ, STL, OFF, VTP, GLB or 3MF file.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write.")],
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
    from .preview import parse_colour, parse_size, preview_file

    start = time.perf_counter()
    picture = preview_file(
        mesh_file, output, size=parse_size(size), background=parse_colour(background), force=force
    )
    if not quiet:  # what the picture's footer says, so as the report says
        print(f"wrote {output}: {picture.describe()} ({time.perf_counter() - start:.2f} s)")


def _emit_report(
    checked, target, required, *, as_json, force, quiet, changed=None, inputs=()
) -> None:
    """Print the report (target "-") or write it to a file (JSON when its name ends in
    .json, else the printed table), with what post-processing ``changed`` (lines) in
    the file; exit 4 when a required check fails."""
    from .report import format_report

    if target is not None and target != "-":
        from .atomic import atomic_output

        if str(target).lower().endswith(".json"):
            data = checked.to_dict()
            if changed is not None:
                data["post_processing"] = {"changed": list(changed)}
            text = json.dumps(data, indent=2)
        else:
            text = format_report(checked)
            if changed is not None:
                text += "\n\npost-processing changed:\n" + "\n".join(f"  {c}" for c in changed)
        with atomic_output(target, force, "report.txt", inputs) as fh:
            fh.write((text + "\n").encode("utf-8"))
    elif target == "-" and not quiet:
        print(json.dumps(checked.to_dict(), indent=2) if as_json else format_report(checked))
    failed = checked.failures(required)
    if failed:
        print(
            f"isoconvert: {checked.source}: required check failed: {', '.join(failed)}",
            file=sys.stderr,
        )
        raise typer.Exit(EXIT_CHECK_FAILED)


@app.command(cls=_Command)
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
) -> None:
    """Convert many volumes: files, folders (--recursive) and globs, in parallel."""
    _quiet_third_party()
    from . import batch as batching
    from .readers.stacks import natural_text_key
    from .report import parse_requirements

    required = parse_requirements(require)
    writer = WRITERS.get(mesh.format or "ply")
    check_attributes(writer, "--format", normals=mesh.normals, labels=labels.single_file)
    # the raw layout goes to raw files only (plan); every other option to every file
    options = _convert_options(
        read, extract, mesh, post, labels, level, raw_layout=False, format=writer.name
    )
    by_label = options.labels is not None
    batching.check_jobs(jobs)
    if previews:  # before the work: without a renderer there would be no pictures
        from .preview import require_renderer
        from .preview.sheet import check_contact_sheet

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
        from .convert import level_outputs

        numeric_level = [lv if lv == "auto" else _level(lv) for lv in level]
        level_outputs(out_dir / "x", numeric_level)  # the same level twice is an error
    work, outcomes = batching.plan(
        found,
        out_dir,
        writer.suffixes[0],
        numeric_level,
        rules,
        skip_existing=skip_existing,
        force=force,
        raw_options=read.raw_layout(),
        labels=by_label,
    )
    # a batch into its own input folder meets its earlier outputs: not inputs skipped
    written = [out_dir / "index.html"] if previews else []
    written += [summary] if summary is not None else []
    for item in batching.drop_outputs(skipped, work, outcomes, previews, written):
        outcomes.append(batching.Outcome(item.path, "", "skipped", message=item.reason))
    from .distributed import scheduler_address
    from .extract.blocks import Blocks

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
            from .atomic import atomic_output

            with atomic_output(summary, force=True) as fh:
                fh.write(batching.summary_bytes(outcomes, summary.suffix.lower()))
        if previews and out_dir.is_dir():
            from dataclasses import asdict

            from .preview import SheetEntry, write_contact_sheet

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


def _level(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise VolumeError(f"--level must be a number or 'auto', got {text!r}") from None


def _bytes(text: str) -> int:
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    t = text.strip().upper().removesuffix("B").removesuffix("I")
    try:
        if t and t[-1] in units:
            return int(float(t[:-1]) * units[t[-1]])
        return int(float(t))
    except ValueError:
        raise VolumeError(f"--max-memory takes a size such as 8G or 512M, got {text!r}") from None


def _default_budget() -> int | None:
    from .memory import available_memory

    available = available_memory()
    return int(0.8 * available) if available else None


@contextmanager
def _batch_display(quiet: bool, total: int, verbose: bool = False):
    """Files done of total with ETA on a terminal; failures as lines on stderr
    (with ``verbose``, every file as it finishes)."""
    count = [0]

    def report_failure(outcome, console=None):
        count[0] += 1
        line = None
        if outcome.status in ("failed", "check-failed"):  # errors, even with --quiet
            line = f"isoconvert: {outcome.message}"
        elif verbose and not quiet:
            line = (
                f"[{count[0]}/{total}] {outcome.status} {outcome.input} -> {outcome.output} "
                f"({outcome.cells or 0:,} cells, {outcome.seconds:.2f} s)"
            )
        if line:
            if console is not None:
                console.print(line, markup=False, highlight=False)
            else:
                print(line, file=sys.stderr)

    if quiet or verbose or not _interactive() or total == 0:
        yield report_failure
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    console = Console(stderr=True)
    columns = [
        TextColumn("converting"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.description}"),
    ]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("", total=total)

        def on_done(outcome):
            report_failure(outcome, progress.console)
            progress.update(task, advance=1, description=Path(outcome.input).name)

        yield on_done


def _collapse_skipped(outcomes, limit: int = 3):
    """Skipped files of one folder, suffix and reason as one row when there are many."""
    groups: dict = {}
    for o in outcomes:
        if o.status == "skipped" and not o.output:
            p = Path(o.input)
            groups.setdefault((str(p.parent), p.suffix, o.message), []).append(o)
    shown, done = [], set()
    for o in outcomes:
        p = Path(o.input)
        key = (str(p.parent), p.suffix, o.message)
        group = groups.get(key) if o.status == "skipped" and not o.output else None
        if group is None or len(group) <= limit:
            shown.append(o)
        elif key not in done:
            done.add(key)
            name = f"{p.parent / ('*' + p.suffix)} ({len(group)} files)"
            shown.append(type(o)(name, "", "skipped", message=o.message))
    return shown


def _print_batch_table(outcomes) -> None:
    rows = [("file", "level", "vertices", "cells", "seconds", "checks", "status")]
    for o in _collapse_skipped(outcomes):
        checks = (
            ""
            if o.checks is None
            else ",".join(f"{k}{'' if v else '!'}" for k, v in o.checks.items())
        )
        rows.append(
            (
                o.input,
                "" if o.level is None else f"{o.level:g}",
                "" if o.vertices is None else f"{o.vertices:,}",
                "" if o.cells is None else f"{o.cells:,}",
                f"{o.seconds:.2f}" if o.status not in ("skipped",) else "",
                checks,
                o.status if not o.message or o.status == "ok" else f"{o.status}: {o.message}"[:80],
            )
        )
    widths = [max(len(r[c]) for r in rows) for c in range(6)]
    for r in rows:
        print(
            "  ".join(r[c].ljust(widths[c]) if c == 0 else r[c].rjust(widths[c]) for c in range(6))
            + "  "
            + r[6]
        )
    totals = {}
    for o in outcomes:
        totals[o.status] = totals.get(o.status, 0) + 1
    print(", ".join(f"{n} {s}" for s, n in totals.items()))


@app.command(cls=_Command)
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
        from .infoplot import plot_format, require_matplotlib

        # before reading: a missing extra, a format not written or an unwritable
        # --plot fails at once
        require_matplotlib()
        plot_format(plot)
        check_output(plot, force, "info.png", inputs=[input] if Path(input).is_file() else [])
    elif plot_level is not None:
        raise VolumeError("--level is for --plot (the contour drawn on the slices); add --plot")
    from .stats import histogram, no_levels_reason, suggested_levels, text_histogram

    volume = read.read(input)
    hist = histogram(volume.samples)
    levels = suggested_levels(hist)  # empty when no level gives a surface
    if plot is not None:
        from .infoplot import write_info_plot

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


@app.command(cls=_Command, hidden=True)
def warmup() -> None:
    """Kept so scripts written for isoconvert 0.1 still run: there is nothing to warm up."""
    print(
        "isoconvert warmup has nothing to do: the kernels are compiled when isoconvert is "
        "installed (you can drop this command)",
        file=sys.stderr,
    )


@app.command(cls=_Command)
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


@app.command(cls=_Command)
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


#: File names that a bare ``--report`` takes as its value (other names after it are
#: read as inputs; ``--report=NAME`` takes any).
REPORT_SUFFIXES = (".json", ".txt")


def gather_multi_values(argv: list[str]) -> list[str]:
    """Join ``--shape 256 256 128`` into ``--shape 256,256,128`` (also spacing,
    origin), and give convert's bare ``--report`` the value "-" (print) unless a
    ``.json`` or ``.txt`` file name follows it (check's ``--report`` always takes
    the next word)."""
    out: list[str] = []
    command = next((a for a in argv if not a.startswith("-")), None)
    i = 0
    while i < len(argv):
        token = argv[i]
        out.append(token)
        i += 1
        if token == "--report" and command == "convert":
            if i < len(argv) and argv[i].lower().endswith(REPORT_SUFFIXES):
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


#: options whose value is a file isoconvert writes
_OUTPUT_OPTIONS = ("-o", "--output", "--report", "--plot", "--preview", "--summary")


def _writes_to_stdout(args: list[str]) -> bool:
    """Whether an output option names standard output (``-o /dev/stdout``)."""
    from .atomic import output_stream

    for n, token in enumerate(args):
        name, _, value = token.partition("=")
        if name in _OUTPUT_OPTIONS:
            value = value or (args[n + 1] if n + 1 < len(args) else "")
            if value and output_stream(value) == 1:
                return True
    return False


def _is_number(text: str) -> bool:
    try:
        float(text.replace("x", "e") if "x" in text else text)
        return "x" not in text
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``isoconvert`` command; returns the exit code.

    SIGTERM and SIGHUP stop a run as Ctrl-C does (:mod:`isoconvert.signals`):
    partial output is removed, one line says so, and the exit code is 128 +
    the signal number (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP).
    """
    from . import signals

    with signals.handled():
        return _main(argv)


def _interrupted() -> int:
    """Say that the run was stopped, in one line; the exit code, 128 + the signal."""
    import contextlib
    import signal

    from . import signals

    signum = signals.received()
    by = f" ({signals.signal_name(signum)})" if signum and signum != signal.SIGINT else ""
    with contextlib.suppress(OSError, ValueError):  # SIGHUP: the terminal may be gone
        print(f"isoconvert: interrupted{by}; no partial output was left", file=sys.stderr)
    return 128 + (signum or signal.SIGINT)


def _main(argv: list[str] | None) -> int:
    global _show_third_party
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    _show_third_party = debug  # numpy warnings and tifffile's log lines are not for users
    args = gather_multi_values([a for a in args if a != "--debug"])
    # a mesh sent to standard output must not have messages mixed into it
    talk = redirect_stdout(sys.stderr) if _writes_to_stdout(args) else nullcontext()
    try:
        with talk:
            result = app(args=args, prog_name="isoconvert", standalone_mode=False)
        code = result if isinstance(result, int) else 0
        if code == 130:  # click turns Ctrl-C into exit code 130
            return _interrupted()
        return code
    except SystemExit as exc:
        code = exc.code
        code = code if isinstance(code, int) else (0 if code is None else 1)
        if code == 130:  # click turns Ctrl-C into exit code 130, and batch Ctrl-C, SIGTERM too
            return _interrupted()
        return code
    except IsoconvertError as exc:
        if debug:
            raise
        print(f"isoconvert: error: {one_line(exc, limit=2000)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C, and SIGTERM or SIGHUP (signals.Interrupted)
        if debug:
            raise
        return _interrupted()
    except MemoryError:
        if debug:
            raise
        print("isoconvert: error: out of memory; try a smaller volume", file=sys.stderr)
        return 1
    except Exception as exc:
        if _is_usage_error(exc):
            message = exc.format_message()
            if not message:  # `isoconvert` alone: the help was the answer
                return 2
            # one line, as for every other mistake (click draws a box of several)
            ctx = getattr(exc, "ctx", None)
            command = ctx.command_path if ctx is not None else "isoconvert"
            print(
                f"isoconvert: error: {one_line(message, limit=500)} (see {command} --help)",
                file=sys.stderr,
            )
            return 2
        if type(exc).__name__ == "Abort":  # click's Ctrl-C (or SIGTERM, SIGHUP)
            return _interrupted()
        # a bug, not a user mistake: say so in one line
        if debug:
            raise
        print(
            f"isoconvert: internal error: {type(exc).__name__}: {exc} "
            "(rerun with --debug and report it)",
            file=sys.stderr,
        )
        return 3
    return 0


def _is_usage_error(exc: Exception) -> bool:
    """A command line click could not parse (its UsageError, which typer vendors
    under a private name): exit code 2 and a message."""
    return getattr(exc, "exit_code", None) == 2 and hasattr(exc, "format_message")


if __name__ == "__main__":
    sys.exit(main())


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())
