"""Many volumes at once: discovery, scheduling over worker processes, summary.

The library reports progress through a callback and never prints; the CLI
draws the progress bar and the table.
"""

from __future__ import annotations

import csv
import fnmatch
import glob as globlib
import io
import json
import os
import time
import tomllib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from .atomic import finished_outputs, note_finished
from .convert import ConvertOptions, level_outputs
from .errors import InputNotFoundError, IsoconvertError, OutputError, one_line, utf8_text
from .quiet import silence_third_party
from .readers import READERS, format_suffix, is_dicom_file, unsupported_format
from .readers.stacks import TIFF_SUFFIXES, is_zarr_store, natural_key
from .runner import Finished, Task
from .writers.precomputed.layer import is_layer

#: Bytes of working memory a conversion needs per byte of samples (a native-order
#: or NaN-free copy at most, vertex and triangle arrays, the writer's records),
#: plus a fixed part for the interpreter and its libraries.
MEMORY_FACTOR = 3
MEMORY_BASE = 300 * 2**20


@dataclass
class Found:
    """A volume found in the inputs: what to read and the name to mirror."""

    spec: str  # a file, or a folder of TIFF slices or DICOM files
    relative: Path  # its path relative to the input it was found under
    size: int  # bytes of samples, roughly, for scheduling
    options: dict = field(default_factory=dict)  # read options it needs (a DICOM series)
    label: str = ""  # which volume of ``spec`` it is, for the summary ("series 5")

    @property
    def name(self) -> str:
        """``spec``, with ``label`` when it has one: the summary's name for it."""
        return f"{self.spec} ({self.label})" if self.label else self.spec


@dataclass
class Skipped:
    """An input file (or a folder of them, ``files`` > 1) that is not converted, and why."""

    path: str
    reason: str
    files: int = 1


class NoVolumesError(InputNotFoundError):
    """The inputs of a batch hold no volume to convert (every file was skipped)."""

    def __init__(self, inputs: list[str], skipped: list[Skipped]) -> None:
        self.inputs = list(inputs)
        self.skipped = list(skipped)
        super().__init__(no_volumes_message(inputs, skipped))


class BatchOptionError(IsoconvertError):
    """A batch setting (the number of worker processes) cannot be used."""


@dataclass
class Job:
    """One conversion to run."""

    input: str
    output: str
    level: float | str
    options: dict = field(default_factory=dict)  # read options and flip
    estimate: int = 0  # bytes of memory it is expected to need
    name: str = ""  # the summary's name for the input (``input`` when empty)
    layer: bool = False  # ``output`` is a precomputed layer (a folder) of the file's meshes

    def __post_init__(self) -> None:
        self.name = self.name or self.input


@dataclass
class Outcome:
    """What happened to one input (a row of the summary)."""

    input: str
    output: str
    status: str  # ok, failed, check-failed, skipped, interrupted
    level: float | None = None
    vertices: int | None = None
    cells: int | None = None
    seconds: float = 0.0
    checks: dict | None = None
    message: str = ""


# --- discovery --------------------------------------------------------------------------

#: Why a 2D image is not converted by a batch unless asked for.
IMAGE_REASON = "a 2D image; pass --images to contour 2D images"
#: Why a file of no known format is not converted.
UNKNOWN_REASON = "not a volume format isoconvert reads"


def discover(
    inputs: list[str],
    recursive: bool = False,
    exclude: Path | None = None,
    images: bool = False,
) -> tuple[list[Found], list[Skipped]]:
    """Find the volumes in files, folders and globs.

    A folder holding only single-image TIFF slices of one shape is one volume
    (a stack); a ``.nhdr`` header and the data files it names count once;
    files of unknown formats are skipped with a reason, those of formats not
    read yet with what ``readers.unsupported_format`` says; the DICOM files of
    a folder (``.dcm``, ``.dicom`` or the DICOM magic) are one volume, the folder.
    Symbolic links to folders are followed once (a loop is cut where it closes);
    a file reached twice is converted once. ``exclude`` (the output folder) is not
    searched when met inside an input folder (its files are skipped, as one entry
    saying so); when it is an input folder itself, that folder is searched, as
    asked (meshes there are never taken for volumes: no mesh format is a volume
    format). Preview pictures ``batch --previews`` wrote are skipped, saying so,
    never taken for images.

    Parameters
    ----------
    inputs : list of str
        Files, folders and glob patterns.
    recursive : bool
        Search sub-folders of folders (and ``**`` in globs).
    exclude : Path or None
        The output folder: not searched inside an input folder.
    images : bool
        Keep 2D images. Without it, image files (the ``image`` reader's
        suffixes), single-page 2D TIFFs that form no slice stack and 2D NRRD
        files are skipped with :data:`IMAGE_REASON` (from their headers only).

    Returns
    -------
    found : list of Found
    skipped : list of Skipped

    Raises
    ------
    InputNotFoundError
        An input does not exist, or a pattern matches nothing.
    """
    found: list[Found] = []
    skipped: list[Skipped] = []
    excluded = exclude.resolve() if exclude else None
    for spec in inputs:
        path = Path(spec)
        if path.is_file():
            _add_files([path], path.parent, found, skipped, images)
        elif is_zarr_store(path):
            found.append(_zarr_found(path, path.parent))
        elif path.is_dir():
            _walk(path, recursive, excluded, found, skipped, images)
        elif globlib.has_magic(spec):
            matches = sorted(
                globlib.glob(spec, recursive=recursive), key=lambda p: natural_key(Path(p))
            )
            if not matches:
                raise InputNotFoundError(f"{spec}: the pattern matches nothing")
            files = [Path(m) for m in matches if Path(m).is_file()]
            root = Path(os.path.commonpath([str(Path(m).parent) for m in matches]))
            _add_files(files, root, found, skipped, images)
            for m in matches:
                if is_zarr_store(Path(m)):
                    found.append(_zarr_found(Path(m), root))
                elif Path(m).is_dir():
                    _walk(Path(m), recursive, excluded, found, skipped, images)
        else:
            raise InputNotFoundError(f"{spec}: no such file, folder or pattern")
    return _once(found, skipped), skipped


def _once(found: list[Found], skipped: list[Skipped]) -> list[Found]:
    """Each volume once, however many inputs (or ``..`` paths, or links) reach it."""
    first: dict[tuple, Found] = {}
    for f in found:
        key = (os.path.realpath(f.spec), f.options.get("series"))
        if key not in first:
            first[key] = f
        elif f.spec != first[key].spec:
            skipped.append(Skipped(f.spec, f"the same file as {first[key].spec}; converted once"))
    return list(first.values())


def no_volumes_message(inputs: list[str], skipped: list[Skipped]) -> str:
    """``no volumes found in INPUTS (N files skipped: ...)``, the reasons counted.

    Parameters
    ----------
    inputs : list of str
        The batch's inputs, as given.
    skipped : list of Skipped
        What discovery skipped.

    Returns
    -------
    str
        One line.
    """
    total = sum(s.files for s in skipped)
    by_reason: dict[str, int] = {}
    for s in skipped:
        by_reason[s.reason] = by_reason.get(s.reason, 0) + s.files
    if not by_reason:
        detail = "no files"
    elif len(by_reason) == 1:
        (reason,) = by_reason
        detail = f"{total} file{'s' if total != 1 else ''} skipped: {reason}"
    else:
        common = sorted(by_reason.items(), key=lambda item: -item[1])
        listed = " | ".join(
            f"{n} file{'s' if n != 1 else ''}: {reason}" for reason, n in common[:4]
        )
        more = f" | {len(common) - 4} other reasons" if len(common) > 4 else ""
        detail = f"{total} files skipped: {listed}{more}"
    return f"no volumes found in {' '.join(inputs)} ({detail})"


def check_found(inputs: list[str], found: list[Found], skipped: list[Skipped]) -> None:
    """Fail when discovery found no volume to convert.

    Raises
    ------
    NoVolumesError
        ``found`` is empty; the message is :func:`no_volumes_message`.
    """
    if not found:
        raise NoVolumesError(inputs, skipped)


#: Why the output folder's files, met inside an input folder, are not converted.
OUTPUT_FOLDER_REASON = "the output folder (-o), which is not searched for volumes"
#: Why a preview picture (``batch --previews``) is not converted.
PREVIEW_REASON = "a preview picture isoconvert wrote (batch --previews), not a volume"
#: Why a Neuroglancer precomputed layer (an earlier batch's output, say) is not searched.
LAYER_REASON = "a Neuroglancer precomputed layer (isoconvert writes these, it does not read them)"


def _walk(root: Path, recursive: bool, excluded, found, skipped, images: bool) -> None:
    seen: set[str] = set()
    top = Path(os.path.realpath(root))
    for folder, dirs, files in os.walk(root, followlinks=True):
        real = os.path.realpath(folder)
        # the output folder inside an input: its meshes and pictures are outputs, not
        # inputs; the output folder named as an input is searched, as asked
        output = excluded is not None and Path(real) == excluded and Path(real) != top
        if real in seen or output:
            dirs[:] = []
            if real in seen:
                skipped.append(Skipped(folder, "a link back to a folder already searched"))
            elif count := sum(len(f) for _, _, f in os.walk(folder)):
                skipped.append(Skipped(folder, OUTPUT_FOLDER_REASON, count))
            continue
        seen.add(real)
        dirs.sort(key=lambda d: natural_key(Path(d)))
        stores = [d for d in dirs if is_zarr_store(Path(folder) / d)]
        for d in stores:  # a Zarr store is one volume, whatever depth: never searched
            found.append(_zarr_found(Path(folder) / d, root))
        dirs[:] = [d for d in dirs if d not in stores]
        layers = [d for d in dirs if recursive and is_layer(Path(folder) / d)]
        for d in layers:  # one entry each, not a row for each of its files
            count = sum(len(f) for _, _, f in os.walk(Path(folder) / d))
            skipped.append(Skipped(str(Path(folder) / d), LAYER_REASON, count))
        dirs[:] = [d for d in dirs if d not in layers]
        if not recursive:
            dirs[:] = []
        paths = sorted((Path(folder) / f for f in files), key=natural_key)
        stack = _tiff_stack(paths)
        if stack:
            rel = Path(folder).relative_to(root)
            name = rel if str(rel) != "." else Path(root.resolve().name)
            found.append(Found(folder, name, sum(p.stat().st_size for p in stack)))
            paths = [p for p in paths if p not in stack]
        _add_files(paths, root, found, skipped, images)


def _zarr_found(store: Path, root: Path) -> Found:
    """A Zarr store as one volume, named by its path under ``root`` (without
    the ``.zarr`` suffix), its size that of its files."""
    rel = store.relative_to(root) if store.is_relative_to(root) else Path(store.name)
    size = sum(f.stat().st_size for f in store.rglob("*") if f.is_file())
    return Found(str(store), rel.with_suffix("") if rel.suffix == ".zarr" else rel, size)


def _tiff_stack(paths: list[Path]) -> list[Path]:
    """The TIFF files of a folder when they are 2+ single images of one shape."""
    tiffs = [p for p in paths if p.suffix.lower() in TIFF_SUFFIXES]
    if len(tiffs) < 2:
        return []
    import tifffile

    shapes = set()
    try:
        for p in tiffs:
            with tifffile.TiffFile(p) as tif:
                if len(tif.pages) != 1:
                    return []
                page = tif.pages[0]
                shapes.add((page.shape, str(page.dtype)))
    except Exception:  # an unreadable TIFF: let each file fail on its own
        return []
    return tiffs if len(shapes) == 1 else []


def _add_files(paths: list[Path], root: Path, found, skipped, images: bool = False) -> None:
    # data files named by a header beside them (.nhdr, .mhd) are read through it
    consumed: dict[Path, Path] = {}
    for folder in {p.parent for p in paths}:
        for header in folder.glob("*.nhdr"):
            consumed.update({data: header for data in _nhdr_data_files(header)})
        for header in folder.glob("*.[mM][hH][dD]"):
            consumed.update({data: header for data in _mhd_data_files(header)})
    given = {q.resolve() for q in paths}
    dicom: dict[Path, list[Path]] = {}  # folder: its DICOM files
    for p in paths:
        header = consumed.get(p.resolve())
        if header is not None:
            if header.resolve() in given:
                continue  # read through its header, or skipped with it
            if READERS.by_suffix(format_suffix(header)) is not None:
                skipped.append(Skipped(str(p), f"the data of {header.name}; convert that header"))
                continue
            # the header's format is not read yet: the file may still be read as raw
        match = READERS.by_suffix(format_suffix(p))
        if (match and match[0] == "dicom") or (match is None and is_dicom_file(p)):
            dicom.setdefault(p.parent, []).append(p)
            continue
        if match is None:
            skipped.append(Skipped(str(p), unsupported_format(p) or UNKNOWN_REASON))
            continue
        if match[0] == "image" and _is_preview(p):
            skipped.append(Skipped(str(p), PREVIEW_REASON))
            continue
        if not images and _is_2d_image(p, match[0]):
            skipped.append(Skipped(str(p), IMAGE_REASON))
            continue
        try:
            rel = p.relative_to(root)
        except ValueError:
            rel = Path(p.name)
        found.append(Found(str(p), rel, _sample_bytes(p)))
    for folder, files in dicom.items():
        # the DICOM files of a folder are one volume per series (the reader sorts the
        # files of a series into slices): the folder, or the file when it is alone
        spec = files[0] if len(files) == 1 else folder
        try:
            rel = spec.relative_to(root)
        except ValueError:
            rel = Path(spec.name)
        if str(rel) == ".":
            rel = Path(root.resolve().name)
        size = sum(p.stat().st_size for p in files)
        if len(files) == 1:
            found.append(Found(str(spec), rel, size))
        else:
            _add_dicom_series(folder, rel, size, found, skipped)


#: Why a DICOM series of one single-frame file is not converted by a batch.
LONE_SLICE_REASON = "a DICOM series of one slice (a localizer?): an image, not a volume"


def _add_dicom_series(folder: Path, rel: Path, size: int, found, skipped) -> None:
    """One volume per image series among a folder's DICOM files, as dcm2niix does:
    ``NAME_seriesN`` (N its SeriesNumber; its UID where numbers are missing or repeat)."""
    try:
        from .readers.dicom import folder_series

        series = folder_series(folder)
    except IsoconvertError:  # pydicom missing: the job says how to install it
        series = []
    if len(series) < 2:
        found.append(Found(str(folder), rel, size))
        return
    numbers = [s.number for s in series]
    by_number = None not in numbers and len(set(numbers)) == len(numbers)
    total = sum(s.files for s in series)
    for s in series:
        # no dots in the name: the part after one would be taken for a file suffix
        suffix = f"series{s.number}" if by_number else (s.uid or "no-uid").replace(".", "-")
        shown = f"series {s.number}" if by_number else f"series {s.uid}"
        if s.frames == 1:
            skipped.append(Skipped(f"{folder} ({shown})", LONE_SLICE_REASON))
            continue
        part = size * s.files // total
        name = rel.with_name(f"{rel.name}_{suffix}")
        found.append(Found(str(folder), name, part, {"series": s.uid}, shown))


def _is_preview(path: Path) -> bool:
    """Whether ``path`` is a preview PNG isoconvert wrote (it records its summary)."""
    if path.suffix.lower() != ".png":
        return False
    from .preview.sheet import read_summary

    return read_summary(path) is not None


def _is_2d_image(path: Path, reader: str) -> bool:
    """Whether a file the ``reader`` reads holds a 2D image (from its header only).

    Unreadable headers count as not 2D: the conversion then says what is wrong.
    """
    if reader == "image":
        return True
    if reader == "raw":  # a 2D shape in the name (figure_2_4_5x5_uint8.raw)
        from .readers.raw import layout_from_filename

        layout = layout_from_filename(path)
        return layout is not None and len(layout[0]) == 2
    try:
        if reader == "tiff":
            import tifffile

            from .readers.tiff import check_complete, kept_axes

            with tifffile.TiffFile(path) as tif:
                check_complete(tif, path)  # a truncated stack is not "a 2D image"
                series = tif.series[0]
                axes = kept_axes(series.axes, series.shape)
            return len(axes) - any(a in "CS" for a in axes) == 2  # less a channel axis
        if reader == "nrrd":
            import nrrd

            from .readers.nrrd import spatial_axes

            header = nrrd.read_header(str(path))
            return len(spatial_axes(header.get("kinds"), int(header["dimension"]))) == 2
        if reader == "numpy":
            from .readers.numpy import array_ndim

            return array_ndim(path) == 2
        if reader == "metaimage":
            from .readers.metaimage import image_ndim

            return image_ndim(path) == 2
        if reader == "nifti":
            from .readers.nifti import nifti_ndim

            return nifti_ndim(path) == 2
    except Exception:  # pynrrd and tifffile raise many kinds on a bad header
        return False
    return False


def _mhd_data_files(header: Path) -> set[Path]:
    """The data file a MetaImage header names (``ElementDataFile = name``), if one."""
    try:
        with open(header, "rb") as fh:
            text = fh.read(64 * 1024).decode("utf-8", errors="replace")
    except OSError:
        return set()
    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key.strip() == "ElementDataFile":
            value = value.strip()
            if not value or value.upper() == "LOCAL" or value.upper().startswith("LIST"):
                return set()
            if "%" in value:
                return set()  # a numbered set: left to each file's own reason
            return {(header.parent / value).resolve()}
    return set()


def _nhdr_data_files(header: Path) -> set[Path]:
    """Files a detached NRRD header names as its data (one, numbered, or a LIST)."""
    from .readers.nrrd import detached_data_files

    return set(detached_data_files(header))


def _sample_bytes(path: Path) -> int:
    """Rough in-memory size of a file's samples, for scheduling."""
    size = path.stat().st_size
    suffix = path.suffix.lower()
    if suffix in (".nrrd", ".nhdr"):
        try:
            import nrrd
            import numpy as np

            header = nrrd.read_header(str(path))
            from nrrd.reader import _determine_datatype

            item = _determine_datatype({**header, "endian": "little"}).itemsize
            return int(np.prod([int(s) for s in header["sizes"]], dtype=np.float64)) * item
        except Exception:
            return size
    if suffix in (".png", ".jpg", ".jpeg", ".bmp", ".gif"):
        return 8 * size  # compressed
    return size


# --- levels and per-file options ------------------------------------------------------------

_OPTION_KEYS = (
    "shape",
    "dtype",
    "endian",
    "header_bytes",
    "channel",
    "spacing",
    "origin",
    "flip",
    "scale",
    "key",
    "volume_index",
    "series",
)


@dataclass
class Rule:
    """One entry of a level mapping: a path pattern and what applies to matches."""

    pattern: str
    level: float | str | None = None
    options: dict = field(default_factory=dict)

    def matches(self, relative: Path) -> bool:
        posix = relative.as_posix()
        return fnmatch.fnmatch(posix, self.pattern) or fnmatch.fnmatch(relative.name, self.pattern)


def read_mapping(path: str | Path) -> list[Rule]:
    """Rules from a TOML (``[[volume]]`` tables) or CSV (a header row) file.

    Keys: ``pattern`` (required; matched against the path relative to its
    input, or the file name), ``level`` (number or "auto"), and the read
    options ``shape``, ``dtype``, ``endian``, ``header_bytes``, ``channel``,
    ``spacing``, ``origin``, plus ``flip``. In CSV, several numbers go in one
    cell separated by spaces or ``x`` ("256x256x128").
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(f"{path}: no such level mapping file")
    text = path.read_text(encoding="utf-8")
    try:
        if path.suffix.lower() == ".toml":
            rows = tomllib.loads(text).get("volume", [])
        elif path.suffix.lower() == ".csv":
            rows = [
                {k.strip(): v.strip() for k, v in r.items() if k and v and v.strip()}
                for r in csv.DictReader(io.StringIO(text))
            ]
        else:
            raise IsoconvertError(f"{path}: a level mapping is a .toml or .csv file")
    except (tomllib.TOMLDecodeError, csv.Error) as exc:
        raise IsoconvertError(f"{path}: not a readable level mapping ({exc})") from None
    rules = []
    for n, row in enumerate(rows, start=1):
        if not isinstance(row, dict) or "pattern" not in row:
            raise IsoconvertError(f"{path}: entry {n} has no 'pattern'")
        unknown = set(row) - {"pattern", "level", *_OPTION_KEYS}
        if unknown:
            raise IsoconvertError(
                f"{path}: entry {n} has unknown key(s) {', '.join(sorted(unknown))}; "
                f"known: pattern, level, {', '.join(_OPTION_KEYS)}"
            )
        options = {k: _parse_option(k, row[k], path, n) for k in _OPTION_KEYS if k in row}
        level = row.get("level")
        if isinstance(level, str) and level.strip().lower() != "auto":
            level = _parse_option("level", level, path, n)
        rules.append(Rule(str(row["pattern"]), level, options))
    return rules


def _parse_option(key: str, value, path: Path, n: int):
    try:
        if key in ("shape", "spacing", "origin"):
            parts = (
                value.replace("x", " ").replace(",", " ").split()
                if isinstance(value, str)
                else value
            )
            kind = int if key == "shape" else float
            return tuple(kind(p) for p in parts)
        if key in ("header_bytes", "channel", "scale", "volume_index"):
            return int(value)
        if key == "level":
            return float(value)
        if key == "flip":
            return value if isinstance(value, bool) else str(value).lower() in ("1", "true", "yes")
        return str(value)
    except (TypeError, ValueError):
        raise IsoconvertError(f"{path}: entry {n}: bad value {value!r} for {key}") from None


# --- planning ---------------------------------------------------------------------------------


def plan(
    found: list[Found],
    out_dir: Path,
    suffix: str,
    level: float | str | Sequence[float | str] | None,
    rules: list[Rule] | None = None,
    skip_existing: bool = False,
    force: bool = False,
    options: dict | None = None,
    raw_options: dict | None = None,
    labels: bool = False,
    layer: bool = False,
) -> tuple[list[Job], list[Outcome]]:
    """Jobs for the found volumes; outcomes for those skipped because done.

    ``options`` (e.g. spacing) apply to every file, ``raw_options`` (shape,
    dtype, endian, header bytes) to raw files only; a mapping entry overrides both.

    Output names mirror the input paths under ``out_dir`` with ``suffix``. Two
    inputs that would give the same name (``a.nrrd`` and ``a.tif``) keep their
    input suffix in it (``a.nrrd.ply``, ``a.tif.ply``). Names never leave
    ``out_dir``: a relative path that would (``..`` parts, an absolute path, a
    link out of it) gives way to the input's own name, at the top of
    ``out_dir``; a name still taken gets a number (``x-2.ply``).

    Several levels give each file one job per level, ``NAME_levelL.ply`` (a
    mapping entry's level overrides them with its one). With ``labels`` a file
    needs no level: its job writes ``NAME_labelL.ply`` per label (its output
    counts as existing when one of those does). With ``layer`` (``suffix`` empty) each
    file's output is a precomputed layer, a folder: its labels' meshes, or its one
    level's as object 1.
    """
    levels = list(level) if isinstance(level, list | tuple) else [level]
    out_dir = Path(out_dir)
    base = out_dir.resolve()
    relatives = [_inside(base, f.relative) or _fallback_name(f) for f in found]
    names = [_output_name(rel, suffix) for rel in relatives]
    clashes = {n for n in names if names.count(n) > 1}
    taken: set[Path] = set()
    jobs, done = [], []
    for f, rel, name in zip(found, relatives, names, strict=True):
        if name in clashes:
            name = Path(str(rel) + suffix)
        name = _unique(name, taken)
        taken.add(name)
        output = out_dir / name
        rule = next((r for r in rules or [] if r.matches(f.relative)), None)
        reader = READERS.by_suffix(format_suffix(f.spec))
        is_raw = reader is not None and reader[0] == "raw"
        job_options = {
            **(options or {}),
            **((raw_options or {}) if is_raw else {}),
            **f.options,
            **(rule.options if rule else {}),
        }
        if rule and rule.level is not None:
            file_levels = [(rule.level, output)]
        elif len(levels) > 1:
            named = level_outputs(name, levels)
            file_levels = [(lv, out_dir / path) for lv, path in zip(levels, named, strict=True)]
        else:
            file_levels = [(levels[0], output)]
        if labels:
            file_levels = [("labels", output)]
        for job_level, output in file_levels:
            _add_job(f, output, job_level, job_options, jobs, done, skip_existing, force, layer)
    return jobs, done


def _add_job(
    f: Found,
    output: Path,
    job_level: float | str | None,
    job_options: dict,
    jobs: list[Job],
    done: list[Outcome],
    skip_existing: bool,
    force: bool,
    layer: bool = False,
) -> None:
    """The job converting ``f`` at ``job_level`` into ``output``, or the outcome
    saying why there is none (no level, output there)."""
    if job_level is None:
        done.append(
            Outcome(
                f.name,
                str(output),
                "failed",
                message=f"{f.name}: no level; give --level or a mapping entry",
            )
        )
        return
    exists, shown = output.exists(), output
    if job_level == "labels" and not layer:  # the job writes NAME_labelL.ply files
        shown = output.with_name(f"{output.stem}_label*{output.suffix}")
        exists = any(output.parent.glob(f"{globlib.escape(output.stem)}_label*{output.suffix}"))
    if exists and skip_existing:
        done.append(Outcome(f.name, str(output), "skipped", message="output exists"))
        return
    if exists and not force:
        done.append(
            Outcome(
                f.name,
                str(output),
                "failed",
                message=f"{shown}: already exists; pass --force or --skip-existing",
            )
        )
        return
    estimate = MEMORY_FACTOR * f.size + MEMORY_BASE
    jobs.append(Job(f.spec, str(output), job_level, job_options, estimate, f.name, layer))


def drop_outputs(
    skipped: list[Skipped],
    jobs: Sequence[Job],
    done: Sequence[Outcome],
    previews: bool = False,
    also: Sequence[str | Path] = (),
) -> list[Skipped]:
    """``skipped`` without the files this batch writes: its meshes (label meshes
    included), their thumbnails with ``previews``, and ``also`` (the contact sheet,
    the summary). A batch writing into its own input folder finds its earlier
    outputs there; they are outputs, not inputs skipped.

    Parameters
    ----------
    skipped : list of Skipped
        What :func:`discover` skipped.
    jobs, done : sequences of Job and Outcome
        What :func:`plan` returned (the outputs to write, and those not rewritten).

    Returns
    -------
    list of Skipped
    """
    names: set[str] = {os.path.realpath(p) for p in also}
    patterns: list[str] = []
    for item in [*jobs, *done]:
        if not item.output:
            continue
        out = Path(item.output)
        names.add(os.path.realpath(out))
        if previews:
            names.add(os.path.realpath(out.with_suffix(".png")))
        if isinstance(item, Job) and item.layer:  # the layer's files
            patterns.append(globlib.escape(os.path.realpath(out)) + os.sep + "*")
        elif isinstance(item, Job) and item.level == "labels":
            stem = os.path.realpath(out.with_suffix(""))
            patterns.append(globlib.escape(stem) + "_label*" + out.suffix)
            if previews:
                patterns.append(globlib.escape(stem) + "_label*.png")
    return [
        s
        for s in skipped
        if os.path.realpath(s.path) not in names
        and not any(fnmatch.fnmatchcase(os.path.realpath(s.path), p) for p in patterns)
    ]


def _output_name(relative: Path, suffix: str) -> Path:
    """``relative`` with its format's suffix (two parts for ``.nii.gz``) replaced by ``suffix``."""
    kept = format_suffix(relative)
    if not relative.suffix:
        return Path(str(relative) + suffix)
    return relative.with_name(relative.name[: -len(kept)] + suffix)


def _inside(base: Path, relative: Path) -> Path | None:
    """``relative`` normalised, or None where ``base / relative`` would leave ``base``
    (the output folder, resolved)."""
    text = os.path.normpath(str(relative))
    rel = Path(text)
    if rel.is_absolute() or rel.drive or rel.anchor or not rel.name or rel.parts[0] == "..":
        return None
    if text in (".", "") or any(part in ("", ".", "..") for part in rel.parts):
        return None
    if not (base / rel).resolve().is_relative_to(base):  # a link inside base leading out
        return None
    return rel


def _fallback_name(found: Found) -> Path:
    """A plain file name for ``found``, for the top of the output folder."""
    for name in (Path(found.spec).name, Path(os.path.abspath(found.spec)).name):
        if name not in ("", ".", ".."):
            return Path(name)
    return Path("volume")


def _unique(name: Path, taken: set[Path]) -> Path:
    """``name``, or ``stem-2.ext``, ``stem-3.ext``, ... where it is taken."""
    n = 2
    candidate = name
    while candidate in taken:
        candidate = name.with_name(f"{name.stem}-{n}{name.suffix}")
        n += 1
    return candidate


# --- output folders -----------------------------------------------------------------------------


def make_folders(folder: str | Path) -> list[Path]:
    """Create ``folder`` and its missing parents; return those this call created.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    list of Path
        The folders created, outermost first (empty when ``folder`` existed).
        A folder another process creates at the same moment is not included.

    Raises
    ------
    OutputError
        A part of the path is a file, or a folder cannot be created.
    """
    folder = Path(folder)
    missing = []
    part = folder
    while not part.exists() and not part.is_symlink() and part.parent != part:
        missing.append(part)
        part = part.parent
    if missing and not part.is_dir():
        raise OutputError(f"{part}: exists and is not a folder; choose another -o")
    created: list[Path] = []
    for part in reversed(missing):
        try:
            part.mkdir()
        except FileExistsError:
            continue  # made meanwhile by someone else: not ours to remove
        except OSError as exc:
            remove_empty_folders(created)
            raise OutputError(
                f"{part}: cannot create the output folder ({exc.strerror or exc}); "
                "choose another -o"
            ) from None
        created.append(part)
    if not folder.is_dir():
        remove_empty_folders(created)
        raise OutputError(f"{folder}: exists and is not a folder; choose another -o")
    return created


def remove_empty_folders(created: list[Path]) -> None:
    """Remove the folders of ``created`` that are empty, innermost first.

    Parameters
    ----------
    created : list of Path
        Folders as :func:`make_folders` returns them (outermost first). A folder
        that is not empty stays, and so do those holding it.
    """
    for folder in sorted(created, key=lambda f: len(Path(f).parts), reverse=True):
        try:
            Path(folder).rmdir()
        except OSError:  # not empty, gone already, or not ours to remove: leave it
            continue


# --- running ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchSettings:
    """What applies to every file of a batch.

    Attributes
    ----------
    options : ConvertOptions
        How to read, extract and write; a job's own options (from a level
        mapping or the raw layout) are applied on top.
    require : tuple of str
        Checks each mesh must pass (``--require``).
    scheduler : str or None
        A Dask scheduler address (``tcp://host:8786``): each file is converted
        by a task on that cluster (:func:`run_on_cluster`),
        whose workers must see the inputs and the output folder at the same
        paths. None runs here, in worker processes.
    previews : bool
        Write a thumbnail beside each mesh (:func:`isoconvert.preview.batch_thumbnail`),
        in the worker that made it, so the mesh is not read again.
    """

    options: ConvertOptions = field(default_factory=ConvertOptions)
    require: tuple[str, ...] = ()
    scheduler: str | None = None
    previews: bool = False


def run_one(job: Job, settings: BatchSettings) -> Outcome:
    """Convert one volume; every failure becomes an outcome, never an exception."""
    from .convert import convert
    from .preview.marks import MAX_MARKS
    from .report import check_mesh

    start = time.perf_counter()

    def failed(message: str) -> Outcome:
        return Outcome(
            job.name, job.output, "failed", seconds=time.perf_counter() - start, message=message
        )

    require = list(settings.require)
    created: list[Path] = []
    try:
        options = settings.options.updated(force=True, **job.options)
        created = make_folders(Path(job.output).parent)
        try:
            if options.labels is not None:
                from .label_convert import convert_labels

                results = convert_labels(job.input, job.output, options.labels, options)
            else:
                results = [convert(job.input, job.output, job.level, options)]
        except BaseException:
            remove_empty_folders(created)  # a failed file leaves no empty folder behind
            raise
    except IsoconvertError as exc:
        return failed(str(exc))
    except MemoryError:
        return failed(f"{job.name}: out of memory; convert it alone or lower --jobs")
    except Exception as exc:  # a bug: report it for this file, keep the others going
        return failed(f"{job.name}: internal error {type(exc).__name__}: {exc}")
    labels = settings.options.labels is not None
    counts = [r.stored_counts() for r in results]
    outcome = Outcome(
        job.name,
        job.output,
        "ok",
        level=None if labels else float(results[0].summary.info["level"]),
        # as stored: a layer's cut level can hold fewer triangles than the mesh
        vertices=sum(stored[0] for stored in counts),
        cells=sum(stored[1] for stored in counts),
        message=_made(len(results), labels, job.layer) if labels or job.layer else "",
    )
    notes = [outcome.message] if outcome.message else []
    checks: dict = {}
    for result in results if require or settings.previews else ():
        mesh = result.mesh  # a label's is built again here: results do not hold them
        grid = mesh.info.get("grid")
        report = None
        if require:
            # one check for --require and the thumbnail's marks (which want more examples)
            more = {"examples": MAX_MARKS} if settings.previews else {}
            report = check_mesh(result.written, source=str(result.output), grid=grid, **more)
            for name in require:  # a check passes when it passes for every file
                checks[name] = checks.get(name, True) and report.checks[name]
            failed = report.failures(require)
            if failed:
                outcome.status = "check-failed"
                notes.append(f"{result.output}: required check failed: {', '.join(failed)}")
        if settings.previews and mesh.is_triangles:
            from .preview import batch_thumbnail

            # a thumbnail that cannot be made costs the picture, not the mesh
            why = batch_thumbnail(mesh, result.written, str(result.output), grid, report)
            notes += [why] if why else []
        result.forget_written()  # a layer's objects held one at a time
    if require:
        outcome.checks = checks
    outcome.message = "; ".join(notes)
    outcome.seconds = time.perf_counter() - start
    return outcome


def _made(count: int, labels: bool, layer: bool) -> str:
    """What a file's job made, for its summary row: "40 label surfaces", "a layer of
    1 isosurface"."""
    what = f"{count} label surface{'s' if count != 1 else ''}" if labels else "1 isosurface"
    return f"a layer of {what}" if layer else what


def _run_one_dict(job: dict, settings: BatchSettings) -> tuple[dict, list[str]]:
    """:func:`run_one` in a worker process of ``--jobs`` (one file at a time),
    pickle-friendly, and the outputs it renamed into place
    (:func:`isoconvert.atomic.finished_outputs`): the batch names them when it is
    interrupted, as a run of one process does. A cluster's worker may run files
    side by side on threads, which one list of the process cannot tell apart: its
    files are not named."""
    finished_outputs(forget=True)  # a file's before, on this worker
    outcome = run_one(Job(**job), settings)
    return asdict(outcome), [str(path) for path in finished_outputs(forget=True)]


def run_jobs(
    jobs: list[Job],
    settings: BatchSettings,
    workers: int = 1,
    max_memory: int | None = None,
    on_done: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Run the jobs, ``workers`` at a time, within ``max_memory`` bytes of estimates.

    A job whose estimate alone exceeds the budget runs with nothing else beside
    it. One failure never stops the others: a worker that dies (killed, out of
    memory) breaks the pool, so each job that was running is run again alone,
    which fails only the one that kills its worker; the pool then starts again
    for the rest. On
    KeyboardInterrupt, jobs not finished are reported as interrupted (their
    outputs are written atomically, so none is left half-written).

    Output sub-folders are created as jobs start; those left empty by failed
    jobs are removed (with worker processes, by this process, once no running
    job writes there). Worker processes run :func:`silence_third_party` first.
    They stop with this process (:func:`isoconvert.signals.worker_init`): on
    KeyboardInterrupt or SIGTERM/SIGHUP here they are terminated, removing their
    partial files, and a worker whose parent died stops by itself.

    With ``settings.scheduler`` set, the jobs run on that Dask cluster instead
    (:func:`run_on_cluster`; ``workers`` and ``max_memory`` are then the
    cluster's business).

    The files are tasks of the task runner (:func:`isoconvert.runner.local.run_in_processes`);
    what a task's value means (an :class:`Outcome`) and which folders to tidy
    are decided here.
    """
    if settings.scheduler:
        return run_on_cluster(settings.scheduler, jobs, settings, on_done)
    outcomes: list[Outcome] = []

    def done(outcome: Outcome) -> None:
        outcomes.append(outcome)
        if on_done:
            on_done(outcome)

    if workers <= 1:
        for n, job in enumerate(jobs):
            try:
                done(run_one(job, settings))
            except KeyboardInterrupt:
                for rest in jobs[n:]:
                    done(Outcome(rest.input, rest.output, "interrupted", message="interrupted"))
                raise
        return outcomes

    from .runner.local import run_in_processes

    # Folders are made here, not in the workers: a worker removing the empty folder
    # of its failed file could otherwise pull it from under a neighbour writing there.
    files = _FileTasks(jobs, _run_one_dict, lambda job: (asdict(job), settings))
    runs = run_in_processes(
        files.tasks, workers, budget=max_memory, initializer=silence_third_party
    )
    try:
        for finished in runs:
            job = files.finish(finished)
            if not finished.started:  # its output folder could not be made
                done(Outcome(job.name, job.output, "failed", message=str(finished.error)))
                continue
            if finished.died:
                result = Outcome(
                    job.name,
                    job.output,
                    "failed",
                    message=f"{job.name}: the worker process died (out of memory?); "
                    "convert it alone or lower --jobs",
                )
            elif finished.error is not None:
                exc = finished.error
                message = f"{job.name}: {type(exc).__name__}: {exc}"
                result = Outcome(job.name, job.output, "failed", message=message)
            else:
                value, written = finished.value
                result = Outcome(**value)
                note_finished(written)
            if result.status == "failed":
                files.tidy()
            done(result)
    except KeyboardInterrupt as exc:
        _stop(runs, exc)
        for job in files.unfinished():
            done(Outcome(job.name, job.output, "interrupted", message="interrupted"))
        raise
    finally:
        runs.close()
        files.running.clear()
        files.tidy()
    return outcomes


def _stop(runs: Iterator, exc: KeyboardInterrupt) -> None:
    """Pass an interrupt met here, between two results, to the runner (which
    then stops its workers at once); one met there has closed it already."""
    try:
        runs.throw(exc)
    except KeyboardInterrupt:
        pass


class _FileTasks:
    """The files of a batch as tasks of the runner (:class:`isoconvert.runner.Task`),
    which of them are running, and the output folders made for them.

    A task's ``load`` makes the output folder of its file just before the file
    starts (here, not in a worker: a worker removing the empty folder of its
    failed file could pull it from under a neighbour writing there).

    Parameters
    ----------
    jobs : list of Job
    function : callable
        What a worker runs.
    arguments : callable
        ``arguments(job)``: the task's arguments.
    where : callable
        ``where(job)``: the job as the workers see it (its output's folder is
        made and tidied there).
    key : callable
        ``key(n)``: the task key of the n-th job.
    """

    def __init__(self, jobs, function, arguments, where=None, key=str) -> None:
        self.jobs = list(jobs)
        self.where = where or (lambda job: job)
        self.made: list[Path] = []
        self.running: list[Job] = []  # started, not finished, in the order they started
        self._finished: set[int] = set()
        self.tasks = [
            Task(
                function,
                key=key(n),
                what=job.input,
                nbytes=job.estimate,
                load=self._starter(job, arguments),
                item=job,
            )
            for n, job in enumerate(self.jobs)
        ]

    def _starter(self, job: Job, arguments) -> Callable[[], tuple]:
        def start() -> tuple:
            self.made.extend(make_folders(Path(self.where(job).output).parent))
            self.running.append(job)
            return arguments(job)

        return start

    def finish(self, finished: Finished) -> Job:
        """Note that ``finished``'s job is done; the job."""
        job = finished.task.item
        self._finished.add(id(job))
        self.running = [j for j in self.running if j is not job]
        return job

    def unfinished(self) -> list[Job]:
        """The jobs running, then those not started."""
        started = {id(j) for j in self.running} | self._finished
        return [*self.running, *(j for j in self.jobs if id(j) not in started)]

    def tidy(self) -> None:
        """Remove the folders made that are empty, but those a running job writes to."""
        writing = [Path(self.where(j).output).parent for j in self.running]
        remove_empty_folders(
            [f for f in self.made if not any(w == f or w.is_relative_to(f) for w in writing)]
        )
        self.made[:] = [f for f in self.made if f.is_dir()]


def run_on_cluster(
    address: str,
    jobs: list[Job],
    settings: BatchSettings,
    on_done: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Convert the files of a batch on the Dask cluster at ``address``, one task each.

    The cluster's workers run :func:`run_one`; they must see the input files
    and the output folder at the same paths (which are made absolute here;
    outcomes name them as given). Output folders are made here before the
    tasks are submitted, and those left empty by failed files are removed, as
    :func:`run_jobs` does. The tasks are run by
    :func:`isoconvert.runner.dask.run_as_completed`.

    Parameters
    ----------
    address : str
    jobs : list of Job
    settings : BatchSettings
        Sent to each task, without its scheduler (a file's blocks run on the
        worker that converts it).
    on_done : callable or None
        Called with each outcome as its file finishes.

    Returns
    -------
    list of Outcome
        In the order the files finished. A file whose workers kept dying
        fails alone, with a one-line message.

    Raises
    ------
    IsoconvertError
        As :func:`isoconvert.runner.dask.connect`.
    KeyboardInterrupt
        After reporting the files not finished as ``interrupted`` and
        cancelling their tasks (one already running on a worker finishes,
        its output written whole or not at all).
    """
    from .runner.dask import connect, new_token, run_as_completed

    connect(address)  # an unreachable scheduler fails before any folder is made
    options = settings.options
    if options.blocks.scheduler is not None:
        options = replace(options, blocks=replace(options.blocks, scheduler=None))
    remote = replace(settings, options=options, scheduler=None)
    token = new_token()
    outcomes: list[Outcome] = []

    def done(outcome: Outcome) -> None:
        outcomes.append(outcome)
        if on_done:
            on_done(outcome)

    def sent(job: Job) -> Job:
        return replace(
            job,
            input=os.path.abspath(job.input),
            output=os.path.abspath(job.output),
            # the header records the input as given, as a local run does
            options={**job.options, "source_name": job.input},
        )

    files = _FileTasks(
        jobs,
        run_one,
        lambda job: (sent(job), remote),
        where=sent,
        key=lambda n: f"isoconvert-file-{token}-{n}",
    )
    runs = run_as_completed(address, files.tasks)
    try:
        for finished in runs:
            job = files.finish(finished)
            if not finished.started:  # its output folder could not be made
                done(Outcome(job.name, job.output, "failed", message=str(finished.error)))
                continue
            outcome = _file_outcome(finished, job, sent(job))
            if outcome.status == "failed":
                files.tidy()
            done(outcome)
    except KeyboardInterrupt:
        runs.close()  # cancels the tasks still running
        for job in files.unfinished():
            done(Outcome(job.name, job.output, "interrupted", message="interrupted"))
        raise
    finally:
        runs.close()
        files.running.clear()
        files.tidy()
    return outcomes


def _file_outcome(finished: Finished, job: Job, sent: Job) -> Outcome:
    """The outcome of one file's task on a cluster, naming the file as the user gave it."""

    def failed(message: str) -> Outcome:
        return Outcome(job.name, job.output, "failed", seconds=finished.seconds, message=message)

    if isinstance(finished.error, IsoconvertError):
        return failed(str(finished.error))
    if finished.error is not None:  # a bug: report it for this file, keep the others going
        exc = finished.error
        return failed(f"{job.name}: internal error {type(exc).__name__}: {one_line(exc)}")
    if finished.died:
        return failed(
            f"{job.name}: the Dask worker converting it died (out of memory?), also when "
            "retried on other workers; give the workers more memory or convert it alone"
        )
    result = finished.value
    result.message = result.message.replace(sent.input, job.input).replace(sent.output, job.output)
    result.input, result.output = job.name, job.output
    return result


def check_jobs(jobs: int | None, files: int | None = None) -> int:
    """The number of worker processes for ``--jobs``.

    Parameters
    ----------
    jobs : int or None
        What the user asked for; None means one per core.
    files : int or None
        The number of files to convert, if known: no more workers than files.

    Returns
    -------
    int
        At least 1.

    Raises
    ------
    BatchOptionError
        ``jobs`` is 0 or negative.
    """
    if jobs is not None and jobs < 1:
        raise BatchOptionError(
            f"--jobs must be 1 or more (worker processes), got {jobs}; "
            "leave it out to use one per core"
        )
    count = jobs if jobs is not None else (os.cpu_count() or 1)
    if files is not None:
        count = min(count, max(files, 1))
    return max(count, 1)


# --- summary ----------------------------------------------------------------------------------

SUMMARY_FIELDS = (
    "input",
    "output",
    "status",
    "level",
    "vertices",
    "cells",
    "seconds",
    "checks",
    "message",
)


def summary_bytes(outcomes: list[Outcome], suffix: str) -> bytes:
    """The summary as JSON (``.json``) or CSV (``.csv``)."""
    rows = [asdict(o) for o in outcomes]
    if suffix == ".json":
        totals = {
            s: sum(o.status == s for o in outcomes)
            for s in ("ok", "failed", "check-failed", "skipped", "interrupted")
        }
        text = json.dumps({"files": rows, "totals": totals}, indent=2, ensure_ascii=False)
        return utf8_text(text + "\n")
    if suffix == ".csv":
        out = io.StringIO()
        writer = csv.DictWriter(out, fieldnames=SUMMARY_FIELDS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            row["checks"] = ";".join(
                f"{k}={'pass' if v else 'fail'}" for k, v in (row["checks"] or {}).items()
            )
            writer.writerow(row)
        return utf8_text(out.getvalue())
    raise IsoconvertError(f"--summary takes a .json or .csv file name, got {suffix or 'none'}")
