"""Readers: one module per format and the table of built-ins below."""

from __future__ import annotations

import glob as globlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import (
    DAMAGED_FILE,
    FormatError,
    InputNotFoundError,
    IsoconvertError,
    VolumeError,
    one_line,
)
from ..lazy import LazyFunction
from ..registry import Registry
from .options import ReadOptions, without_overridden
from .stacks import TIFF_SUFFIXES, is_zarr_store, natural_key

if TYPE_CHECKING:
    from ..volume import Volume

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".gif")


@dataclass(frozen=True)
class Reader:
    """A volume format: how to recognise it and how to read it.

    The built-ins' ``read`` is a :class:`~isoconvert.lazy.LazyFunction`: the
    table describes every format without importing numpy or any parser.
    """

    name: str
    summary: str
    suffixes: tuple[str, ...]
    read: Callable[[Path, ReadOptions], Volume]
    #: ReadOptions fields this reader uses; any other given option is an error.
    options: frozenset[str]
    #: True when a folder or glob of files is one volume of this format.
    stacks: bool = False
    #: True when the input is a folder (a Zarr store), not a file.
    folder: bool = False


READERS: Registry[Reader] = Registry("input format")
READERS.register(
    "raw",
    Reader(
        "raw",
        "headerless samples, x fastest; --shape/--dtype or a name_XxYxZ_dtype.raw name",
        (".raw", ".bin", ".dat"),
        LazyFunction("isoconvert.readers.raw:read_raw"),
        frozenset({"shape", "dtype", "endian", "header_bytes"}),
    ),
)
READERS.register(
    "nrrd",
    Reader(
        "nrrd",
        "NRRD, attached (.nrrd) or detached (.nhdr), raw/gzip/bzip2, multi-file data",
        (".nrrd", ".nhdr"),
        LazyFunction("isoconvert.readers.nrrd:read_nrrd"),
        frozenset({"channel", "allow_outside_data"}),
    ),
)
READERS.register(
    "tiff",
    Reader(
        "tiff",
        "multi-page TIFF, or a folder or glob of single-page slices",
        TIFF_SUFFIXES,
        LazyFunction("isoconvert.readers.tiff:read_tiff"),
        frozenset({"channel"}),
        stacks=True,
    ),
)
READERS.register(
    "zarr",
    Reader(
        "zarr",
        "Zarr 2/3 store (a folder), plain (z, y, x) array or OME-Zarr (--scale picks the level)",
        (".zarr",),
        LazyFunction("isoconvert.readers.zarr:read_zarr"),
        frozenset({"scale", "channel", "allow_missing_chunks"}),
        folder=True,
    ),
)
READERS.register(
    "numpy",
    Reader(
        "numpy",
        "NumPy .npy (memory-mapped; (z, y, x) C order or (x, y, z) Fortran order) or .npz "
        "(--key picks the array)",
        (".npy", ".npz"),
        LazyFunction("isoconvert.readers.numpy:read_numpy"),
        frozenset({"key"}),
    ),
)
READERS.register(
    "metaimage",
    Reader(
        "metaimage",
        "MetaImage .mhd (+ raw/zraw data, LIST or numbered files) or .mha (ITK, VTK, Slicer)",
        (".mhd", ".mha"),
        LazyFunction("isoconvert.readers.metaimage:read_metaimage"),
        frozenset({"channel", "allow_outside_data"}),
    ),
)
READERS.register(
    "nifti",
    Reader(
        "nifti",
        "NIfTI-1/NIfTI-2 .nii or .nii.gz via nibabel (sform/qform placement, RAS; "
        "--volume-index picks a volume of a 4D image)",
        (".nii", ".nii.gz"),
        LazyFunction("isoconvert.readers.nifti:read_nifti"),
        frozenset({"volume_index"}),
    ),
)
READERS.register(
    "dicom",
    Reader(
        "dicom",
        "DICOM via pydicom: a folder of slices or one .dcm file of it, or an enhanced "
        "multi-frame file (sorted by position, rescaled to HU, LPS; --series UID picks one "
        "of several)",
        (".dcm", ".dicom"),
        LazyFunction("isoconvert.readers.dicom:read_dicom"),
        frozenset({"series"}),
        stacks=True,
        folder=True,
    ),
)
READERS.register(
    "image",
    Reader(
        "image",
        "2D images (PNG, JPEG, BMP, GIF) via Pillow; colour becomes gray unless --channel",
        IMAGE_SUFFIXES,
        LazyFunction("isoconvert.readers.image:read_image"),
        frozenset({"channel"}),
    ),
)


# Formats recognised but not read yet (a later issue): what to call them in messages.
_NOT_READ_YET: dict[str, str] = {}
# Files that are a whole volume by themselves: a folder holding one is not a TIFF stack.
_HEADER_SUFFIXES = {
    ".mhd": "MetaImage header",
    ".mha": "MetaImage file",
    ".nii": "NIfTI file",
    ".nii.gz": "NIfTI file",
}
# Suffixes of two parts that a reader claims (the last part alone means something else).
_DOUBLE_SUFFIXES = (".nii.gz",)


def format_suffix(path: str | Path) -> str:
    """The suffix that names a file's format, lower-case: ``.nii.gz`` for
    ``scan.nii.gz`` (not ``.gz``), else the last suffix (``.nrrd``).

    Use it with ``READERS.by_suffix`` instead of ``Path.suffix``.
    """
    name = Path(path).name.lower()
    for double in _DOUBLE_SUFFIXES:
        if name.endswith(double) and len(name) > len(double):
            return double
    return Path(name).suffix


_TOOLS = "(e.g. with 3D Slicer or SimpleITK)"
_CONVERT = f"convert it to NRRD first {_TOOLS}"
_DICOM_CHECKS = 16  # files of a folder looked at for the DICOM magic


def is_dicom_file(path: str | Path) -> bool:
    """True when the file has the DICOM magic "DICM" after its 128-byte preamble
    (reads 132 bytes; DICOM files often have no suffix, or a number)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(132)
    except OSError:
        return False
    return head[128:132] == b"DICM"


def _kind_not_read(path: Path, look_inside: bool = True) -> str | None:
    return _NOT_READ_YET.get(format_suffix(path))


def _is_dicom_folder(folder: Path) -> bool:
    """True when a folder (not a Zarr store) holds no TIFF slices but DICOM files: ``.dcm``
    or ``.dicom`` files, or, among its first files whose suffix no reader claims, one
    with the DICOM magic (DICOM files often have no suffix, or a number)."""
    if is_zarr_store(folder):
        return False
    try:
        files = sorted((p for p in folder.iterdir() if p.is_file()), key=natural_key)
    except OSError:
        return False
    if any(p.suffix.lower() in TIFF_SUFFIXES for p in files):
        return False
    if any(format_suffix(p) in (".dcm", ".dicom") for p in files):
        return True
    unknown = [p for p in files if READERS.by_suffix(format_suffix(p)) is None]
    return any(is_dicom_file(p) for p in unknown[:_DICOM_CHECKS])


def unsupported_format(path: Path) -> str | None:
    """Why ``path`` cannot be read yet, when it is a format isoconvert knows but does not read.

    Recognises folders that hold no TIFF slices but a volume file of another
    format (a MetaImage or NIfTI header: give that file). DICOM files and
    folders of them are read (the ``dicom`` reader). Cheap enough to call on
    every file of a folder.

    Parameters
    ----------
    path : Path
        A file or folder.

    Returns
    -------
    str or None
        A one-line reason naming the format and what to do, without the path
        (a batch skip reason; :func:`read_volume` raises it as
        ``"PATH: REASON"``), or None when the path is not such a format.
    """
    path = Path(path)
    try:
        if path.is_dir():
            return _unsupported_folder(path)
        if not path.is_file():
            return None
    except OSError:
        return None
    kind = _kind_not_read(path)
    if kind is None:
        return None
    return f"{kind} is not read yet; {_CONVERT}"


def _unsupported_folder(folder: Path) -> str | None:
    """A folder that holds no TIFF slices (nor DICOM files) but files of a format not read yet."""
    if is_zarr_store(folder):
        return None
    try:
        files = sorted((p for p in folder.iterdir() if p.is_file()), key=natural_key)
    except OSError:
        return None
    if any(p.suffix.lower() in TIFF_SUFFIXES for p in files) or _is_dicom_folder(folder):
        return None
    for p in files:
        kind = _kind_not_read(p, look_inside=False)
        if kind:
            return (
                "a folder is read as a stack of TIFF slices and this one holds none; "
                f"it holds {kind} ({p.name}), which is not read yet; {_CONVERT}"
            )
    headers = [p for p in files if format_suffix(p) in _HEADER_SUFFIXES]
    if headers:
        return (
            "a folder is read as a stack of TIFF slices and this one holds none; it holds "
            f"a {_HEADER_SUFFIXES[format_suffix(headers[0])]} ({headers[0].name}): give that "
            "file instead"
        )
    return None


def detect_format(spec: str) -> str:
    """Name of the reader for a path, folder or glob, from its suffix.

    A folder is a Zarr store when named ``*.zarr`` or holding Zarr metadata
    (``zarr.json``, ``.zarray``, ``.zgroup``, ``.zattrs``), a DICOM series when it
    holds DICOM files and no TIFF slices, else a stack of TIFF slices. A file
    whose suffix no reader claims is DICOM when it has the DICOM magic.
    """
    path = Path(spec)
    if path.is_dir():
        if path.suffix.lower() == ".zarr" or is_zarr_store(path):
            return "zarr"
        return "dicom" if _is_dicom_folder(path) else "tiff"
    suffix = format_suffix(path)
    if path.is_file() and READERS.by_suffix(suffix) is None and is_dicom_file(path):
        return "dicom"
    if not path.exists() and globlib.has_magic(spec):
        suffix = format_suffix(spec.rstrip("*?]")) or suffix
        matches = globlib.glob(spec)
        if matches:
            suffix = format_suffix(matches[0])
    found = READERS.by_suffix(suffix)
    if found:
        return found[0]
    raise FormatError(
        f"{spec}: cannot tell the format from the name; known input formats: "
        f"{READERS.suffix_listing()}; or name one with --input-format"
    )


_PERMISSIONS = frozenset({"allow_outside_data", "allow_missing_chunks"})


def read_volume(
    path: str | Path,
    *,
    format: str | None = None,
    spacing: tuple[float, ...] | None = None,
    origin: tuple[float, ...] | None = None,
    **options,
) -> Volume:
    """Read a volume from a file, a folder of slices or a glob.

    Parameters
    ----------
    path : str or Path
        The input. A folder or glob is a stack of TIFF slices, unless the
        folder is a Zarr store or holds DICOM files.
    format : str or None
        Reader name (``raw``, ``nrrd``, ``tiff``, ``zarr``, ``numpy``, ``metaimage``,
        ``nifti``, ``dicom``, ``image``); None
        guesses from the suffix (see :func:`detect_format`).
    spacing, origin : sequence of float or None
        Override what the file says (x, y[, z]).
    **options
        Fields of :class:`ReadOptions`: ``shape``, ``dtype``, ``endian``,
        ``header_bytes`` (raw), ``channel`` (multi-channel images),
        ``allow_outside_data`` (detached NRRD or MetaImage data outside the
        header's folder),
        ``scale`` (OME-Zarr resolution level), ``allow_missing_chunks`` (Zarr),
        ``key`` (the array of a NumPy ``.npz``), ``volume_index`` (the volume of a
        4D NIfTI image), ``series`` (the SeriesInstanceUID of a DICOM folder
        holding several).

    Raises
    ------
    FormatError
        Among others, for a format recognised but not read yet (see
        :func:`unsupported_format`), unless ``format`` names a reader.

    Returns
    -------
    Volume
    """
    spec = str(path)
    p = Path(spec)
    if not p.exists() and not (globlib.has_magic(spec) and globlib.glob(spec)):
        raise InputNotFoundError(f"{spec}: no such file or folder")
    if format is None:
        # a glob is judged by its first match, as detect_format does
        first = p if p.exists() else Path(sorted(globlib.glob(spec))[0])
        reason = unsupported_format(first)
        if reason:
            raise FormatError(f"{spec}: {reason}")
    name = format.lower() if format else detect_format(spec)
    reader = READERS.get(name)
    if (p.is_dir() and not (reader.stacks or reader.folder)) or (
        not p.exists() and not reader.stacks
    ):
        raise FormatError(
            f"{spec}: a folder or glob is read as a stack of TIFF slices (a folder also as a "
            f"Zarr store or a DICOM series), not {name}"
        )
    try:
        opts = ReadOptions(**options)
    except TypeError as exc:
        raise VolumeError(f"unknown read option: {exc}") from None
    # permissions (to read companion files, to read missing Zarr chunks as the fill
    # value) are harmless where a format has no use for them, so one flag can apply
    # to a whole batch
    stray = opts.given() - reader.options - _PERMISSIONS
    if stray:
        flags = ", ".join("--" + s.replace("_", "-") for s in sorted(stray))
        raise VolumeError(f"{spec}: {flags} do(es) not apply to {name} input")
    try:
        volume = reader.read(p, opts)
    except IsoconvertError:
        raise
    except PermissionError:
        raise InputNotFoundError(
            f"{spec}: permission denied; check the file's permissions"
        ) from None
    except IsADirectoryError:
        raise FormatError(f"{spec}: is a folder, expected a {name} file") from None
    except MemoryError:
        raise VolumeError(f"{spec}: the volume does not fit in memory") from None
    except Exception as exc:
        # The parsers (pynrrd, tifffile, Pillow) raise many kinds of exceptions on
        # corrupt input; each is a fact about the file, not a bug of ours.
        raise FormatError(
            f"{spec}: not a readable {name} file ({type(exc).__name__}: {one_line(exc)}); "
            f"{DAMAGED_FILE}"
        ) from None
    if volume.dtype.kind not in "biuf":
        raise VolumeError(
            f"{spec}: samples of type {volume.dtype} are not real numbers; isoconvert "
            "contours scalar volumes (convert to a real type first, e.g. the magnitude)"
        )
    if 0 in volume.shape:
        raise VolumeError(f"{spec}: the volume is empty (shape {volume.shape})")
    if spacing is not None or origin is not None:
        volume = volume.with_placement(spacing, origin)
        # what the reader said about the spacing (or origin) it found is moot now
        given = {name for name, v in (("spacing", spacing), ("origin", origin)) if v is not None}
        volume.notes = without_overridden(volume.notes, given)
        volume.notes.append("spacing/origin set on the command line")
    return volume


__all__ = [
    "READERS",
    "Reader",
    "ReadOptions",
    "detect_format",
    "format_suffix",
    "is_dicom_file",
    "read_volume",
    "unsupported_format",
]
