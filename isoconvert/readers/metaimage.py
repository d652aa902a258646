"""MetaImage volumes (ITK, VTK, 3D Slicer): ``.mhd`` header + data, ``.mha`` in one file.

The header is ``Key = Value`` lines ending with ``ElementDataFile``: ``LOCAL``
(the samples follow the header, as in every ``.mha``), one file name, a
printf pattern ``name%03d.raw first last step [subdim]``, or ``LIST [subdim]``
followed by one file name per line. Samples are x fastest, as isoconvert
holds them.

Placement: ``ElementSpacing`` (else ``ElementSize``) is the spacing, ``Offset``
(or ``Origin``, ``Position``) the origin, and ``TransformMatrix`` (or
``Rotation``, ``Orientation``) the axis directions. ITK writes that matrix as
the direction vectors of the grid axes one after the other (its reader sets
the direction of axis ``i`` to values ``i*N .. i*N+N-1``): the file's rows are
the columns of :attr:`Volume.direction`.

Uncompressed 3D samples of one channel in one file are a lazy
:class:`~isoconvert.grid.RawGrid`. Compressed data (``CompressedData = True``,
a zlib stream) is read into memory, never decoded past the size the header
declares. Data files must lie in the header's folder or below unless the
caller allows otherwise (``allow_outside_data``).
"""

from __future__ import annotations

import math
import os
import re
import zlib
from pathlib import Path

import numpy as np

from ..errors import FormatError, one_line
from ..grid import RawGrid, read_exactly
from ..memory import check_fits
from ..volume import Volume
from .nrrd import _data_path, _Inflater, numbered_names
from .options import (
    ReadOptions,
    absolute_files,
    check_channel,
    origin_note,
    spacing_note,
)

_MAX_HEADER = 1 << 20  # bytes of header before ElementDataFile (a LIST's names excluded)
_MAX_LIST = 64 << 20  # bytes of a LIST of file names

#: MetaIO's element types and their sizes (MET_LONG is 4 bytes in MetaIO, as in ITK)
_TYPES = {
    "MET_CHAR": "i1",
    "MET_UCHAR": "u1",
    "MET_SHORT": "i2",
    "MET_USHORT": "u2",
    "MET_INT": "i4",
    "MET_UINT": "u4",
    "MET_LONG": "i4",
    "MET_ULONG": "u4",
    "MET_LONG_LONG": "i8",
    "MET_ULONG_LONG": "u8",
    "MET_FLOAT": "f4",
    "MET_DOUBLE": "f8",
}
_PATTERN = re.compile(r"^(\S*%\S*)\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)(?:\s+(\d+)D?)?$", re.IGNORECASE)
_LIST = re.compile(r"^LIST(?:\s+(\d+)D?)?$", re.IGNORECASE)
_TRUE = ("true", "1", "yes", "t")


class _Header:
    """The fields (keys lower-case), where attached data starts, and a LIST's names."""

    def __init__(self, path: Path, fields: dict[str, str], offset: int, listed: list[str] | None):
        self.path, self.fields, self.offset, self.listed = path, fields, offset, listed

    def get(self, *keys: str) -> str | None:
        for key in keys:
            if key.lower() in self.fields:
                return self.fields[key.lower()]
        return None

    def numbers(self, keys: tuple[str, ...], count: int, kind=float) -> list | None:
        text = self.get(*keys)
        if text is None:
            return None
        try:
            values = [kind(v) for v in text.split()]
        except ValueError:
            values = []
        if len(values) != count:
            raise FormatError(
                f"{self.path}: {keys[0]} = {text!r} needs {count} numbers for NDims "
                f"{self.get('NDims')}; fix the MetaImage header"
            )
        return values

    def flag(self, *keys: str) -> bool:
        text = self.get(*keys)
        return text is not None and text.strip().lower() in _TRUE


def read_metaimage(path: Path, options: ReadOptions) -> Volume:
    """Read a MetaImage ``.mhd``/``.mha`` with its spacing, origin and directions.

    Parameters
    ----------
    path : Path
        The header (``.mhd``) or the whole image (``.mha``).
    options : ReadOptions
        ``channel`` (``ElementNumberOfChannels`` > 1), ``allow_outside_data``.
    """
    header = _read_header(path)
    ndims = _ndims(header)
    sizes = header.numbers(("DimSize",), ndims, int)
    if sizes is None or any(n <= 0 for n in sizes):
        raise FormatError(
            f"{path}: the MetaImage header needs DimSize with {ndims} positive sizes, got "
            f"{header.get('DimSize')!r}; fix the header"
        )
    name = (header.get("ElementType") or "").strip().upper()
    if name not in _TYPES:
        raise FormatError(
            f"{path}: MetaImage ElementType {name or 'missing'!s} is not a known numeric type; "
            f"use one of {', '.join(_TYPES)}"
        )
    if header.get("BinaryData") is not None and not header.flag("BinaryData"):
        raise FormatError(
            f"{path}: BinaryData = False (samples as text) is not supported; write the image "
            "as binary (e.g. with SimpleITK or 3D Slicer)"
        )
    msb = header.flag("BinaryDataByteOrderMSB", "ElementByteOrderMSB")
    dtype = np.dtype(_TYPES[name]).newbyteorder(">" if msb else "<")
    text = (header.get("ElementNumberOfChannels") or "1").strip()
    if not text.isdigit() or int(text) < 1:
        raise FormatError(
            f"{path}: ElementNumberOfChannels = {text!r} must be a whole number >= 1; fix the "
            "MetaImage header"
        )
    channels = int(text)
    channel = check_channel(
        channels if channels > 1 else None, options.channel, path, "values per sample (channels)"
    )
    described = f"DimSize {' '.join(map(str, sizes))} of {name}" + (
        f" x {channels} channels" if channels > 1 else ""
    )
    names, subdim = _data_names(header, ndims)
    files = (
        None
        if names is None
        else [_checked_path(header, n, options.allow_outside_data) for n in names]
    )
    data = _read_samples(header, files, subdim, sizes, channels, dtype, described)
    if channel is not None:
        data = np.ascontiguousarray(data[..., channel])
    notes = []
    spacing = _spacing(header, ndims, notes)
    origin = header.numbers(("Offset", "Origin", "Position"), ndims)
    if origin is not None and not all(np.isfinite(v) for v in origin):
        notes.append(
            origin_note(f"Offset {origin} in the MetaImage header ignored; using 0; set --origin")
        )
        origin = None
    direction = _direction(header, ndims, notes)
    orientation = header.get("AnatomicalOrientation")
    if orientation and orientation.strip() and set(orientation.strip()) != {"?"}:
        notes.append(f"anatomical orientation {orientation.strip()} (as the file states)")
    # ITK's world frame, which MetaImage files are written in, is LPS
    placement = {
        "spacing": spacing,
        "origin": origin,
        "direction": direction,
        "source": str(path),
        "notes": notes,
        "frame": "LPS",
        "files": absolute_files([path, *(files or [])]),
    }
    if isinstance(data, RawGrid):
        return Volume(data, **placement)
    return Volume.from_zyx(data, **placement)


def metaimage_data_files(path: Path) -> list[Path]:
    """The files a ``.mhd`` names as its data, resolved; [] for LOCAL or an unreadable header."""
    try:
        header = _read_header(path)
        names = _data_names(header, _ndims(header))[0]
    except Exception:  # an unreadable header names no files
        return []
    return [(path.parent / n).resolve() for n in names or []]


def image_ndim(path: Path) -> int | None:
    """``NDims`` of a MetaImage header (for batch, which skips 2D images); None when
    the header is unreadable."""
    try:
        return _ndims(_read_header(Path(path)))
    except Exception:  # an unreadable header: reading it says what is wrong
        return None


# --- header ---------------------------------------------------------------------------------


def _read_header(path: Path) -> _Header:
    fields: dict[str, str] = {}
    with open(path, "rb") as fh:
        while True:
            raw = fh.readline(_MAX_HEADER)
            if not raw:
                raise FormatError(
                    f"{path}: not a readable MetaImage header (no ElementDataFile line ends it); "
                    "fix the header"
                )
            if fh.tell() > _MAX_HEADER:
                raise FormatError(
                    f"{path}: not a readable MetaImage header (no ElementDataFile line within "
                    f"{_MAX_HEADER >> 20} MiB)"
                )
            text = raw.decode("utf-8", "replace").strip()
            if not text or text.startswith("#"):
                continue
            key, eq, value = text.partition("=")
            if not eq or not key.strip() or " " in key.strip():
                raise FormatError(
                    f"{path}: not a readable MetaImage header (line {one_line(text, 60)!r} is not "
                    "'Key = Value')"
                )
            key, value = key.strip().lower(), value.strip()
            fields[key] = value
            if key == "elementdatafile":
                break
        offset = fh.tell()
        listed = None
        if _LIST.match(fields["elementdatafile"]):
            rest = fh.read(_MAX_LIST + 1)
            if len(rest) > _MAX_LIST:
                raise FormatError(f"{path}: the LIST of data files is longer than 64 MiB")
            listed = [n.strip() for n in rest.decode("utf-8", "replace").splitlines() if n.strip()]
    object_type = fields.get("objecttype")
    if object_type is not None and object_type.lower() != "image":
        raise FormatError(
            f"{path}: MetaImage ObjectType {object_type} is not an image; only images are read"
        )
    return _Header(path, fields, offset, listed)


def _ndims(header: _Header) -> int:
    text = header.get("NDims")
    if text is None or not text.strip().isdigit() or int(text) not in (2, 3):
        raise FormatError(
            f"{header.path}: the MetaImage header needs NDims = 2 or 3, got {text!r}; "
            "fix the header"
        )
    return int(text)


def _spacing(header: _Header, ndims: int, notes: list[str]):
    keys = ("ElementSpacing",) if header.get("ElementSpacing") else ("ElementSize",)
    values = header.numbers(keys, ndims)
    if values is None:
        notes.append(spacing_note("no spacing in the file; using 1 (set --spacing)"))
        return None
    if not all(np.isfinite(v) and v > 0 for v in values):
        notes.append(
            spacing_note(
                f"{keys[0]} {values} in the MetaImage header ignored; using 1; set --spacing"
            )
        )
        return None
    return values


def _direction(header: _Header, ndims: int, notes: list[str]):
    keys = ("TransformMatrix", "Rotation", "Orientation")
    values = header.numbers(keys, ndims * ndims)
    if values is None:
        return None
    # ITK: values i*N .. i*N+N-1 are the direction of grid axis i (a column of ours)
    direction = np.asarray(values, dtype=np.float64).reshape(ndims, ndims).T
    if not np.all(np.isfinite(direction)) or abs(np.linalg.det(direction)) < 1e-6:
        notes.append("TransformMatrix in the MetaImage header ignored (degenerate)")
        return None
    lengths = np.linalg.norm(direction, axis=0)
    return direction / lengths


# --- samples --------------------------------------------------------------------------------


def _data_names(header: _Header, ndims: int) -> tuple[list[str] | None, int | None]:
    """Data file names (None: LOCAL) and how many axes each file holds (None: all)."""
    path = header.path
    value = header.get("ElementDataFile") or ""
    if value.upper() == "LOCAL":
        return None, None
    listed = _LIST.match(value)
    if listed:
        if not header.listed:
            raise FormatError(
                f"{path}: ElementDataFile = LIST names no files; list them one per line after it"
            )
        return header.listed, _subdim(path, listed.group(1), ndims)
    multi = _PATTERN.match(value)
    if multi:
        fmt, lo, hi, step, sub = multi.groups()
        names = numbered_names(path, "ElementDataFile", fmt, int(lo), int(hi), int(step))
        return names, _subdim(path, sub, ndims)
    return [value], None


def _subdim(path: Path, text: str | None, ndims: int) -> int:
    if text is None:
        return ndims - 1
    if not 1 <= int(text) <= ndims:
        raise FormatError(
            f"{path}: ElementDataFile gives {text} axes per file; it must be 1..{ndims}"
        )
    return int(text)


def _checked_path(header: _Header, name: str, allow_outside: bool) -> Path:
    try:
        return _data_path(header.path, name, allow_outside)
    except FormatError as err:  # the NRRD wording, made MetaImage's
        raise FormatError(str(err).replace("'data file'", "ElementDataFile")) from None


def _read_samples(header, files, subdim, sizes, channels, dtype, described):
    """(Z, Y, X[, C]) / (Y, X[, C]) array, or a RawGrid for plain 3D samples in one file.

    ``files`` are the checked data files (None: LOCAL), each holding ``subdim`` axes.
    """
    path = header.path
    ndims = len(sizes)
    # Python integers: a header may declare sizes whose product overflows 64 bits
    total = math.prod(sizes) * channels
    nbytes = total * dtype.itemsize
    shape_zyx = tuple(sizes[::-1]) + ((channels,) if channels > 1 else ())
    compressed = header.flag("CompressedData")
    skip = _header_size(header)
    if skip < -1:
        raise FormatError(f"{path}: HeaderSize {skip} is invalid (>= 0, or -1 for the file's end)")
    if files is not None and len(files) > 1:
        if compressed:
            raise FormatError(
                f"{path}: compressed data in several files is not supported; write the image "
                "as one .mha or one .zraw"
            )
        return _read_parts(header, files, subdim, sizes, shape_zyx, dtype, described)
    source = (path, header.offset) if files is None else (files[0], 0)
    where = "the file" if files is None else f"its data file {files[0].name}"
    if compressed:
        check_fits(nbytes, "the declared volume", str(path))
        out = np.empty(total, dtype=dtype)
        start = source[1] + (max(skip, 0) if files is not None else 0)
        _inflate(header, source[0], start, out, where, described)
        return out.reshape(shape_zyx)
    size = os.path.getsize(source[0])
    if files is None:
        begin = source[1]
    elif skip == -1:
        begin = size - nbytes
    else:
        begin = skip
    have = size - begin
    if have != nbytes and not (files is not None and skip == -1 and have >= nbytes):
        raise FormatError(
            f"{path}: the MetaImage data cannot be read: {where} holds {max(have, 0)} bytes of "
            f"samples, but {described} need {nbytes}; the file is truncated, or check DimSize, "
            "ElementType and HeaderSize"
        )
    if ndims == 3 and channels == 1:
        return RawGrid(source[0], dtype, tuple(sizes), begin)
    if begin % dtype.itemsize == 0:
        return np.asarray(
            np.memmap(source[0], dtype=dtype, mode="c", offset=begin, shape=shape_zyx)
        )
    out = np.empty(shape_zyx, dtype=dtype)
    with open(source[0], "rb") as fh:
        fh.seek(begin)
        read_exactly(fh, out)
    return out


def _header_size(header: _Header) -> int:
    text = (header.get("HeaderSize") or "0").strip()
    try:
        return int(text)
    except ValueError:
        raise FormatError(
            f"{header.path}: HeaderSize = {text!r} is not a whole number (bytes before the "
            "samples, -1 for the file's end); fix the MetaImage header"
        ) from None


def _read_parts(header, files, subdim, sizes, shape_zyx, dtype, described):
    """Samples split over several files (a LIST or a pattern), each holding ``subdim`` axes."""
    path = header.path
    outer = math.prod(sizes[subdim:])
    if len(files) > outer or outer % len(files):
        raise FormatError(
            f"{path}: {len(files)} data files cannot split {outer} slices evenly; check "
            "ElementDataFile and DimSize"
        )
    total = math.prod(shape_zyx)
    check_fits(total * dtype.itemsize, "the declared volume", str(path))
    out = np.empty(total, dtype=dtype)
    per = total // len(files)
    skip = _header_size(header)
    for i, file in enumerate(files):
        part = out[i * per : (i + 1) * per]
        size = os.path.getsize(file)
        begin = size - part.nbytes if skip == -1 else skip
        if size - begin != part.nbytes:
            raise FormatError(
                f"{path}: the MetaImage data cannot be read: its data file {file.name} holds "
                f"{max(size - begin, 0)} bytes, but one of {len(files)} parts of {described} "
                f"needs {part.nbytes}; check DimSize, ElementType and the file list"
            )
        with open(file, "rb") as fh:
            fh.seek(begin)
            read_exactly(fh, part)
    return out.reshape(shape_zyx)


def _inflate(header, file: Path, start: int, out: np.ndarray, where: str, described: str):
    """Decode the zlib stream at ``start`` of ``file`` into ``out``, never past its size.

    ``CompressedDataSize`` is not needed: the stream's own end marker ends it.
    """
    path = header.path
    try:
        with open(file, "rb") as fh:
            fh.seek(start)
            inflater = _Inflater(fh, "gzip")  # zlib or gzip, told apart by its header
            got = inflater.readinto(memoryview(out.reshape(-1).view(np.uint8)))
            extra = got == out.nbytes and bool(inflater.chunk(1))
    except (zlib.error, EOFError, OSError) as exc:
        raise FormatError(
            f"{path}: the MetaImage data cannot be read: the compressed data in {where} is "
            f"corrupt or truncated ({one_line(exc)}); write the image again"
        ) from None
    if got < out.nbytes:
        raise FormatError(
            f"{path}: the MetaImage data cannot be read: the compressed data in {where} holds "
            f"{got} bytes, fewer than the {out.nbytes} of {described}; the file is truncated "
            "or DimSize/ElementType are wrong"
        )
    if extra:
        raise FormatError(
            f"{path}: the compressed data in {where} holds more than the {out.nbytes} bytes of "
            f"{described}; the file is corrupt or DimSize/ElementType are wrong"
        )
