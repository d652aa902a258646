"""Readers: one module per format and the table of built-ins below."""

from __future__ import annotations

import glob as globlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..errors import FormatError, InputNotFoundError, IsoconvertError, VolumeError, one_line
from ..registry import Registry
from ..volume import Volume
from .image import IMAGE_SUFFIXES, read_image
from .nrrd import read_nrrd
from .options import ReadOptions
from .raw import read_raw
from .tiff import TIFF_SUFFIXES, read_tiff


@dataclass(frozen=True)
class Reader:
    """A volume format: how to recognise it and how to read it."""

    name: str
    summary: str
    suffixes: tuple[str, ...]
    read: Callable[[Path, ReadOptions], Volume]
    #: ReadOptions fields this reader uses; any other given option is an error.
    options: frozenset[str]
    #: True when a folder or glob of files is one volume of this format.
    stacks: bool = False


READERS: Registry[Reader] = Registry("input format")
READERS.register(
    "raw",
    Reader(
        "raw",
        "headerless samples, x fastest; --shape/--dtype or a name_XxYxZ_dtype.raw name",
        (".raw", ".bin", ".dat"),
        read_raw,
        frozenset({"shape", "dtype", "endian", "header_bytes"}),
    ),
)
READERS.register(
    "nrrd",
    Reader(
        "nrrd",
        "NRRD, attached (.nrrd) or detached (.nhdr), raw/gzip/bzip2, multi-file data",
        (".nrrd", ".nhdr"),
        read_nrrd,
        frozenset({"channel"}),
    ),
)
READERS.register(
    "tiff",
    Reader(
        "tiff",
        "multi-page TIFF, or a folder or glob of single-page slices",
        TIFF_SUFFIXES,
        read_tiff,
        frozenset({"channel"}),
        stacks=True,
    ),
)
READERS.register(
    "image",
    Reader(
        "image",
        "2D images (PNG, JPEG, BMP, GIF) via Pillow; colour becomes gray unless --channel",
        IMAGE_SUFFIXES,
        read_image,
        frozenset({"channel"}),
    ),
)


def detect_format(spec: str) -> str:
    """Name of the reader for a path, folder or glob, from its suffix."""
    path = Path(spec)
    if path.is_dir():
        return "tiff"
    suffix = path.suffix.lower()
    if not path.exists() and globlib.has_magic(spec):
        suffix = Path(spec.rstrip("*?]")).suffix.lower() or suffix
        matches = globlib.glob(spec)
        if matches:
            suffix = Path(matches[0]).suffix.lower()
    found = READERS.by_suffix(suffix)
    if found:
        return found[0]
    raise FormatError(
        f"{spec}: cannot tell the format from the name; known input formats: "
        f"{READERS.suffix_listing()}; or name one with --input-format"
    )


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
        The input. A folder or glob is a stack of TIFF slices.
    format : str or None
        Reader name (``raw``, ``nrrd``, ``tiff``); None guesses from the suffix.
    spacing, origin : sequence of float or None
        Override what the file says (x, y[, z]).
    **options
        Fields of :class:`ReadOptions`: ``shape``, ``dtype``, ``endian``,
        ``header_bytes`` (raw), ``channel`` (multi-channel images).

    Returns
    -------
    Volume
    """
    spec = str(path)
    p = Path(spec)
    if not p.exists() and not (globlib.has_magic(spec) and globlib.glob(spec)):
        raise InputNotFoundError(f"{spec}: no such file or folder")
    name = format.lower() if format else detect_format(spec)
    reader = READERS.get(name)
    if (p.is_dir() or not p.exists()) and not reader.stacks:
        raise FormatError(f"{spec}: a folder or glob is read as a stack of TIFF slices, not {name}")
    try:
        opts = ReadOptions(**options)
    except TypeError as exc:
        raise VolumeError(f"unknown read option: {exc}") from None
    stray = opts.given() - reader.options
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
            f"{spec}: not a readable {name} file ({type(exc).__name__}: {one_line(exc)})"
        ) from None
    if volume.data.dtype.kind not in "biuf":
        raise VolumeError(
            f"{spec}: samples of type {volume.data.dtype} are not real numbers; isoconvert "
            "contours scalar volumes (convert to a real type first, e.g. the magnitude)"
        )
    if volume.data.size == 0:
        raise VolumeError(f"{spec}: the volume is empty (shape {volume.shape})")
    if spacing is not None or origin is not None:
        volume = volume.with_placement(spacing, origin)
        volume.notes.append("spacing/origin set on the command line")
    return volume


__all__ = ["READERS", "Reader", "ReadOptions", "detect_format", "read_volume"]
