"""The options the commands share, declared once.

The option groups (``ReadArgs``, ``ExtractArgs``, ``MeshArgs``, ``PostArgs``,
``MemoryArgs``, ``LabelArgs``) that ``convert`` and ``batch`` (and, in part,
``info`` and ``check``) take, the ``_grouped`` decorator that spreads a group
into one typer option per field, the one function turning them into
:class:`~isoconvert.convert.ConvertOptions`, the single options several
commands take (``--level``, ``--require``, ``--quiet``, ...) and the parsers of
their values. Only numpy-free tables are imported here, so that ``--help``
starts fast.
"""

from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass, fields, replace
from enum import Enum
from typing import Annotated, get_type_hints

import typer

from ..checks import CHECK_NAMES
from ..errors import IsoconvertError, VolumeError
from ..methods import ALL_AMBIGUITY_RULES, EXTRACTORS, NO_DEGENERATE_OFFSET
from ..readers import READERS
from ..writers import WRITERS

Ambiguity = Enum("Ambiguity", {r.replace("-", "_"): r for r in ALL_AMBIGUITY_RULES}, type=str)


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


def _numbers(text: str | None, name: str, kind=float) -> tuple | None:
    if text is None:
        return None
    parts = [p for p in text.replace("x", " ").replace(",", " ").split() if p]
    try:
        return tuple(kind(p) for p in parts)
    except ValueError:
        raise VolumeError(f"{name} takes numbers, e.g. {name} 1 1 2.5; got {text!r}") from None


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


def _fragment_size(text: str | None) -> float | str | None:
    """--fragment-size: a number of voxels (inf included) or 'auto' (the default);
    a word is a command line that cannot be parsed (exit 2). The layer checks the
    number's range."""
    if text is None or text.strip().lower() == "auto":
        return None if text is None else "auto"
    try:
        return float(text)
    except ValueError:
        raise typer.BadParameter(f"a number of voxels, 'auto' or 'inf', got {text!r}") from None


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
        from ..readers import ReadOptions

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
        from ..readers import read_volume

        opts = self.read_options()
        given = {name: getattr(opts, name) for name in opts.given()}
        return read_volume(path, format=self.input_format, **self.placement(), **given)


#: Stands for the extraction methods in ``--method``'s help until a help is shown
#: (:func:`with_method_names`): finding the plugins among them reads every installed
#: package's entry points, about 45 ms that a run without ``--help`` need not pay.
METHOD_NAMES = "<the extraction methods>"


def with_method_names(params: list) -> None:
    """Put the extraction methods, plugins included, into the help of ``params``."""
    for param in params:
        text = getattr(param, "help", None)
        if text and METHOD_NAMES in text:
            param.help = text.replace(METHOD_NAMES, ", ".join(EXTRACTORS.names()))


@dataclass(frozen=True)
class ExtractArgs:
    """How to extract the surface (the main panel)."""

    method: Annotated[
        str | None,
        typer.Option(
            help=f"Extraction method: {METHOD_NAMES} "
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
            "scikit-image); asymptotic: squares only; trilinear: cubes with the topology "
            "of the trilinear interpolant."
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
            help="Decimate keeping the result and the original within this distance of each "
            "other, both ways (world units; a Hausdorff bound); alone, as far as it allows."
        ),
    ] = None

    def options(self):
        """The PostOptions these options say."""
        from ..post.pipeline import PostOptions

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
        from ..distributed import scheduler_address
        from ..extract.slabs import Blocks

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
            help="A label volume: one surface per label enclosing its voxels (Surface Nets; "
            "a note counts the places it cannot be manifold), NAME_labelL.ply; --smooth N "
            "sets its relaxation iterations (default 16).",
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


@dataclass(frozen=True)
class LayerArgs:
    """Neuroglancer precomputed layers (``--format precomputed``)."""

    lods: Annotated[
        int | None,
        typer.Option(
            help="Levels of detail --format precomputed stores, the mesh as extracted (level "
            "0) included: 3 is levels 0, 1 and 2, level k decimated to within 2^(k-1) voxels "
            "(needs isoconvert\\[simplify]); default 3 (1 with --legacy-mesh).",
        ),
    ] = None
    fragment_size: Annotated[
        str | None,
        typer.Option(
            metavar="<voxels|auto|inf>",
            callback=_fragment_size,
            help="Cut each object of --format precomputed into fragments of this many voxels "
            "a side (octree nodes a viewer loads one by one); default: 128 for objects of more "
            "than 524,288 triangles (halved, down to 32, while one node holds more than 131,072 "
            "vertices), one fragment a level for smaller ones; inf: one fragment per object "
            "and level of detail.",
        ),
    ] = None
    sharded: Annotated[
        bool,
        _flag(
            "--sharded",
            help="Store --format precomputed objects in shard files (neuroglancer_uint64_"
            "sharded_v1) instead of two files each: for layers of many objects.",
        ),
    ] = False
    legacy_mesh: Annotated[
        bool,
        _flag(
            "--legacy-mesh",
            help="Write --format precomputed meshes in the legacy single-resolution format "
            "(neuroglancer_legacy_mesh) for tools that read no other: one level, no shards.",
        ),
    ] = False
    with_volume: Annotated[
        bool,
        _flag(
            "--with-volume",
            help="Also write the labels themselves into the --format precomputed layer "
            "(compressed_segmentation chunks), so that one folder opens with voxels and meshes.",
        ),
    ] = False

    def options(self) -> dict:
        """The ConvertOptions fields of these options."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


#: The groups, and the help panel of their options (unless an option names its own).
_GROUPS = {
    ReadArgs: "Input",
    ExtractArgs: None,
    MeshArgs: None,
    PostArgs: "Post-processing",
    MemoryArgs: "Large volumes",
    LabelArgs: "Labels",
    LayerArgs: "Output",
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
    layer: LayerArgs,
    level,
    *,
    raw_layout: bool = True,
    **changes,
):
    """The ConvertOptions of convert's and batch's shared option groups; ``changes``
    are a command's own (force, blocks, values).

    ``raw_layout`` False leaves out the raw layout (which batch gives raw files only).
    """
    from ..convert import ConvertOptions

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
        **layer.options(),
    )
    return replace(options, **changes)


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
        # a word where a number goes: a command line that cannot be parsed (exit 2)
        raise typer.BadParameter(
            f"a size such as 8G or 512M, got {text!r}", param_hint="'--max-memory'"
        ) from None
