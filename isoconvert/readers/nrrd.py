"""NRRD volumes: attached .nrrd, detached .nhdr, multi-file data.

pynrrd parses the header fields; the samples are read here. ascii (where the
file's size bounds the work) has every number checked to fit the sample type,
never wrapped. The binary encodings (raw, gzip, bzip2) and hex are read so that
compressed data is never decompressed past the size the header declares (a gzip
bomb stops after a few MiB) and raw data is memory-mapped.
A 3D volume whose raw or compressed samples are in one file is read lazily,
slab by slab (:class:`~isoconvert.grid.RawGrid`, :class:`CompressedNrrdGrid`),
so that it need not fit in memory; multi-file, hex and ascii data are read whole.
Detached data files must lie in the header's folder or below unless the caller
allows otherwise (``allow_outside_data``): a header from elsewhere must not be
able to make the tool read any file on the machine.
"""

from __future__ import annotations

import bz2
import math
import os
import re
import threading
import weakref
import zlib
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, one_line
from ..grid import LazyGrid, RawGrid, read_exactly
from ..memory import check_fits
from ..volume import Volume
from .options import (
    ReadOptions,
    absolute_files,
    origin_note,
    select_channel,
    spacing_note,
)

# "data file: <format> <min> <max> <step> [<subdim>]" (NRRD spec, detached headers)
_MULTI_FILE = re.compile(r"^(\S*%\S*)\s+(-?\d+)\s+(-?\d+)\s+(-?\d+)(?:\s+(\d+))?$")
# "data file: LIST [<subdim>]": the file names follow, one per line
_LIST_FIELD = re.compile(r"^data ?file\s*:\s*LIST(?:\s+(\S+))?\s*$")

_MAX_LINE = 1 << 20  # bytes of one header line
_MAX_HEADER = 64 << 20  # bytes of a whole header (a LIST of many files included)
_IN_CHUNK = 1 << 20  # compressed bytes read at a time
_OUT_CHUNK = 4 << 20  # decompressed bytes produced at a time
# Compressed volumes up to this size (decompressed) are decoded once when read, to find a
# truncated or corrupt stream before any work is done; larger ones as their slabs are read.
_CHECK_AT_OPEN = 64 << 20
_GUIDE = "convert it with 3D Slicer or unu (teem)"

_ENCODINGS = {
    "raw": "raw",
    "gzip": "gzip",
    "gz": "gzip",
    "bzip2": "bzip2",
    "bz2": "bzip2",
    "ascii": "ascii",
    "text": "ascii",
    "txt": "ascii",
    "hex": "hex",
}


@dataclass
class _Header:
    """A parsed header, where its attached data starts, and the names of a LIST."""

    fields: dict
    data_offset: int
    listed: list[str] | None = None
    list_subdim: str | None = None


def read_nrrd(path: Path, options: ReadOptions) -> Volume:
    """Read a NRRD file with its spacing, origin and axis directions.

    ``space directions`` give spacing (their lengths) and direction (their unit
    vectors); else ``spacings``; ``space origin`` gives the origin. Vertex
    positions are then in the file's world space (e.g. LPS for medical data).
    Detached data (one file, numbered files, or a ``LIST``) must lie in the
    header's folder or below unless ``options.allow_outside_data``.

    A 3D volume of three spatial axes whose samples are raw or gzip/bzip2 in
    one file (attached or detached) is lazy: a :class:`~isoconvert.grid.RawGrid`
    or a :class:`CompressedNrrdGrid`. Compressed data up to 64 MiB is checked
    whole here; beyond, a truncated or corrupt stream is found by the read that
    reaches it (the same one-line :class:`FormatError`).
    """
    parsed = _read_header(path)
    header = parsed.fields
    if str(header.get("type", "")).strip().lower() == "block":
        raise VolumeError(
            f"{path}: NRRD type 'block' holds opaque blocks of {header.get('block size', '?')} "
            "bytes, not numbers; only numeric sample types (uchar, short, float, ...) "
            "can be contoured"
        )
    _check_declared_size(path, header)
    files, subdim = _data_files(path, parsed, options.allow_outside_data)
    data = _read_data(path, parsed, files, subdim)
    data, domain = _domain_axes(path, header, data, options.channel)
    spacing, direction, notes = _placement(header, domain)
    origin = header.get("space origin")
    if origin is not None:
        origin = np.asarray(origin, dtype=np.float64)
        if origin.shape != (len(domain),) or not np.all(np.isfinite(origin)):
            notes.append(origin_note("space origin ignored (does not match the volume's axes)"))
            origin = None
    if "space" in header:
        notes.append(f"coordinates in the file's {header['space']} space")
    units = header.get("space units")
    unit = str(units[0]) if units is not None and len(set(units)) == 1 else None
    return Volume(
        data,
        spacing=spacing,
        origin=origin,
        direction=direction,
        source=str(path),
        notes=notes,
        unit=unit,
        frame=_FRAMES.get(str(header.get("space", "")).strip().lower()),
        files=absolute_files([path, *(files or [])]),
    )


#: NRRD ``space`` values that name an anatomical frame isoconvert converts between.
_FRAMES = {
    "left-posterior-superior": "LPS",
    "lps": "LPS",
    "right-anterior-superior": "RAS",
    "ras": "RAS",
}


def detached_data_files(path: Path) -> list[Path]:
    """The files a detached NRRD header names as its data, resolved; [] when attached.

    For tools that need to know which files belong to a header (batch). Names
    outside the header's folder are listed too; reading refuses them.

    Parameters
    ----------
    path : Path
        The header (.nhdr or .nrrd).

    Returns
    -------
    list of Path
        One path per data file, in order; empty for attached data or an
        unreadable header.
    """
    try:
        parsed = _read_header(path)
        files, _ = _data_files(path, parsed, allow_outside=True, check=False)
    except Exception:  # an unreadable header names no files
        return []
    return [f.resolve() for f in files or []]


# --- header ---------------------------------------------------------------------------------


def _read_header(path: Path) -> _Header:
    """Parse the header with pynrrd, after taking a ``data file: LIST`` apart.

    pynrrd reads ``key: value`` lines only, so the file names of a LIST (one per
    line after the LIST field) are split off here.
    """
    import nrrd

    try:
        with open(path, "rb") as fh:
            first = fh.readline(_MAX_LINE)
            if not first.startswith(b"NRRD"):
                raise FormatError(
                    f"{path}: not a readable NRRD header (the file does not start with 'NRRD')"
                )
            lines = [first.decode("ascii", "replace").rstrip()]
            listed: list[str] | None = None
            subdim = None
            total = len(first)
            while True:
                raw = fh.readline(_MAX_LINE)
                if not raw:
                    break
                total += len(raw)
                if total > _MAX_HEADER or (len(raw) == _MAX_LINE and not raw.endswith(b"\n")):
                    raise FormatError(
                        f"{path}: not a readable NRRD header (no blank line ends it within "
                        f"{_MAX_HEADER >> 20} MiB, or a line is longer than 1 MiB)"
                    )
                text = raw.decode("utf-8", "surrogateescape").rstrip()
                if not text:
                    break
                if listed is not None:
                    listed.append(text)
                    continue
                match = _LIST_FIELD.match(text)
                if match:
                    listed, subdim = [], match.group(1)
                else:
                    lines.append(text)
    except FormatError:
        raise
    except OSError as exc:
        raise FormatError(f"{path}: cannot read the NRRD header ({one_line(exc)})") from None
    try:
        fields = nrrd.read_header(lines)
    except (nrrd.NRRDError, UnicodeError, ValueError, IndexError, KeyError, TypeError) as exc:
        raise FormatError(f"{path}: not a readable NRRD header ({one_line(exc)})") from None
    if listed is not None and ("data file" in fields or "datafile" in fields):
        raise FormatError(f"{path}: the NRRD header has two 'data file' fields; keep one")
    fields = dict(fields)
    exact = _exact_sizes(lines)
    if exact is not None:
        fields["sizes"] = exact
    return _Header(fields, total, listed, subdim)


def _exact_sizes(lines: list[str]) -> list[int] | None:
    """The ``sizes`` field as Python integers: pynrrd parses it through 64-bit
    numbers, which round sizes past 2**53 and wrap those past 2**63, so a
    message would name a size the header never declared. None when the field
    is absent or not whole numbers (pynrrd's reading then stands)."""
    for line in lines[1:]:
        key, sep, value = line.partition(":")
        if sep and key.strip() == "sizes" and not line.startswith("#"):
            try:
                return [int(word) for word in value.split()]
            except ValueError:
                return None
    return None


def _check_declared_size(path: Path, header: dict) -> None:
    """The header's sizes must be positive and name a known sample type."""
    from nrrd.reader import _determine_datatype

    try:
        sizes = [int(s) for s in header["sizes"]]
        # the byte order does not change the size (and 1-byte types may omit it)
        _determine_datatype({**header, "endian": "little"})
    except Exception as exc:  # pynrrd raises several kinds for a bad header
        raise FormatError(
            f"{path}: the NRRD header has no usable sizes or type ({one_line(exc)})"
        ) from None
    if any(s <= 0 for s in sizes):
        raise VolumeError(f"{path}: the NRRD header declares sizes {sizes}; all must be >= 1")
    if int(header.get("dimension", len(sizes))) != len(sizes):
        raise FormatError(
            f"{path}: the NRRD header says dimension {header.get('dimension')} but gives "
            f"{len(sizes)} sizes; make them agree"
        )


# --- which files hold the data --------------------------------------------------------------


def _data_files(
    path: Path, parsed: _Header, allow_outside: bool, check: bool = True
) -> tuple[list[Path] | None, int | None]:
    """The data files (None: attached) and how many axes each holds (None: all)."""
    header = parsed.fields
    sizes = [int(s) for s in header["sizes"]]
    if parsed.listed is not None:
        names = parsed.listed
        subdim = _subdim(path, parsed.list_subdim, len(sizes))
        if not names:
            raise FormatError(
                f"{path}: 'data file: LIST' names no files; list them one per line after it"
            )
        _check_split(path, len(names), sizes, subdim)
    else:
        value = str(header.get("data file", header.get("datafile", ""))).strip()
        if not value:
            return None, None
        multi = _MULTI_FILE.match(value)
        if multi:
            fmt, lo, hi, step, sub = multi.groups()
            subdim = _subdim(path, sub, len(sizes))
            names = numbered_names(path, "'data file'", fmt, int(lo), int(hi), int(step))
            _check_split(path, len(names), sizes, subdim)
        else:
            names, subdim = [value], None
    return [_data_path(path, name, allow_outside, check) for name in names], subdim


def numbered_names(path: Path, field: str, fmt: str, lo: int, hi: int, step: int) -> list[str]:
    """The file names of a numbered data-file pattern (``slice%03d.raw 1 93 1``:
    NRRD's ``data file``, MetaImage's ``ElementDataFile``), ``hi`` included."""
    numbers = range(lo, hi + (1 if step > 0 else -1), step) if step else range(0)
    if not numbers:
        raise FormatError(f"{path}: {field} range {lo}..{hi} step {step} is empty")
    try:
        return [fmt % n for n in numbers]
    except (TypeError, ValueError) as exc:
        raise FormatError(
            f"{path}: {field} pattern {fmt!r} is not a printf pattern for one number "
            f"({one_line(exc)})"
        ) from None


def _subdim(path: Path, text: str | None, ndim: int) -> int:
    if text is None:
        return ndim - 1
    if not text.isdigit() or not 1 <= int(text) <= ndim:
        raise FormatError(f"{path}: 'data file' gives {text!r} axes per file; it must be 1..{ndim}")
    return int(text)


def _check_split(path: Path, n_files: int, sizes: list[int], subdim: int) -> None:
    outer = math.prod(sizes[subdim:])
    if n_files > outer or outer % n_files:
        raise FormatError(
            f"{path}: {n_files} data files cannot split {outer} slices evenly; "
            "check the 'data file' line"
        )


def _data_path(header: Path, name: str, allow_outside: bool, check: bool = True) -> Path:
    """The file ``name`` (relative to the header's folder), checked to be safe to read."""
    if "\x00" in name or not name:
        raise FormatError(f"{header}: 'data file' name {name!r} is not a file name")
    candidate = header.parent / name
    if not check:
        return candidate
    try:
        resolved = candidate.resolve()
        root = header.parent.resolve()
    except (OSError, RuntimeError) as exc:
        raise FormatError(
            f"{header}: its data file {name} cannot be resolved ({one_line(exc)})"
        ) from None
    if not allow_outside and not resolved.is_relative_to(root):
        raise FormatError(
            f"{header}: its data file {name} resolves to {resolved}, outside the header's "
            f"folder {root}; move the data beside the header, or pass --allow-outside-data "
            "(allow_outside_data=True) if you trust this header"
        )
    if not resolved.exists():
        raise FormatError(
            f"{header}: its data file {name} is missing; put it beside the header or fix "
            "the 'data file' line"
        )
    if not resolved.is_file():
        raise FormatError(f"{header}: its data file {name} is not a regular file")
    return candidate


# --- reading the samples --------------------------------------------------------------------


def _read_data(
    path: Path, parsed: _Header, files: list[Path] | None, subdim: int | None
) -> np.ndarray | LazyGrid:
    """All samples as an (x, y, z, ...) Fortran-ordered view of a C-ordered array,
    or a lazy grid for a 3D volume of spatial axes held in one raw or compressed file."""
    from nrrd.reader import _determine_datatype

    header = parsed.fields
    sizes = [int(s) for s in header["sizes"]]
    # Python integers: a header may declare sizes whose product overflows 64 bits
    total = math.prod(sizes)
    key = str(header.get("encoding", "")).strip()
    encoding = _ENCODINGS.get(key.lower())
    if encoding is None:
        raise FormatError(
            f"{path}: NRRD encoding {key!r} is not supported; use raw, gzip, bzip2, ascii or hex "
            f"({_GUIDE})"
        )
    try:
        dtype = _determine_datatype(header)
    except Exception as exc:
        raise FormatError(
            f"{path}: the NRRD header has no usable type or endian ({one_line(exc)})"
        ) from None
    line_skip = int(header.get("line skip", header.get("lineskip", 0)))
    byte_skip = int(header.get("byte skip", header.get("byteskip", 0)))
    if line_skip < 0 or byte_skip < -1:
        raise FormatError(
            f"{path}: line skip {line_skip} / byte skip {byte_skip} are invalid "
            "(line skip >= 0, byte skip >= -1)"
        )
    if byte_skip == -1 and encoding != "raw":
        raise FormatError(
            f"{path}: byte skip -1 (data at the end of the file) applies only to raw encoding, "
            f"not {key}; give the number of bytes to skip"
        )
    sources: list[tuple[Path, int]] = (
        [(path, parsed.data_offset)] if files is None else [(f, 0) for f in files]
    )
    per_part = total // len(sources)
    described = f"sizes {' '.join(map(str, sizes))} of {header['type']}"
    # a volume of three spatial axes (no channel to pick) in one file is read slab by slab
    lazy = (
        len(sources) == 1 and len(sizes) == 3 and spatial_axes(header.get("kinds"), 3) == [0, 1, 2]
    )
    if len(sources) == 1 and encoding == "raw":
        nbytes = total * dtype.itemsize
        begin = _raw_begin(path, sources[0], nbytes, line_skip, byte_skip, described)
        if lazy:
            return RawGrid(sources[0][0], dtype, tuple(sizes), begin)
        if begin % dtype.itemsize == 0:
            # unaligned samples would slow down or upset the kernels: those are read as a copy
            mapped = np.memmap(sources[0][0], dtype=dtype, mode="c", offset=begin, shape=(total,))
            return np.asarray(mapped).reshape(sizes[::-1]).T
    if lazy and encoding in ("gzip", "bzip2"):
        grid = CompressedNrrdGrid(
            path, sources[0], encoding, dtype, tuple(sizes), line_skip, byte_skip, described
        )
        # a slab-wise read holds at least two z-layers (one block and its overlap)
        check_fits(2 * sizes[0] * sizes[1] * dtype.itemsize, "a slab of two z-layers", str(path))
        if grid.nbytes <= _CHECK_AT_OPEN:
            grid.check()
        return grid
    check_fits(total * dtype.itemsize, "the declared volume", str(path))
    out = np.empty(total, dtype=dtype)
    for i, source in enumerate(sources):
        part = out[i * per_part : (i + 1) * per_part]
        args = (path, source, part, line_skip, byte_skip, described)
        if encoding == "raw":
            _read_raw_part(*args)
        elif encoding in ("gzip", "bzip2"):
            _read_compressed_part(*args, encoding)
        elif encoding == "hex":
            _read_hex_part(*args)
        else:
            _read_ascii_part(*args, header)
    return out.reshape(sizes[::-1]).T


def _where(path: Path, source: tuple[Path, int]) -> str:
    return "the file" if source[0] == path else f"its data file {source[0].name}"


def _open_at_data(source: tuple[Path, int], line_skip: int):
    """Open a data source positioned after the header and the skipped lines."""
    fh = open(source[0], "rb")  # the caller closes it
    try:
        fh.seek(source[1])
        for _ in range(line_skip):
            while True:  # a "line" of binary data may be long: read it in pieces
                piece = fh.readline(65536)
                if not piece or piece.endswith(b"\n"):
                    break
    except BaseException:
        fh.close()
        raise
    return fh


def _raw_span(path, source, fh, nbytes, byte_skip, described) -> int:
    """Offset of the raw samples in the open file, after checking their size."""
    start = fh.tell()
    size = os.fstat(fh.fileno()).st_size
    if byte_skip == -1:
        begin = size - nbytes
        have = size - start
    else:
        begin = start + byte_skip
        have = size - begin
    # byte skip -1 means "the last nbytes of the file"; else the sizes must match exactly
    if (have < nbytes) if byte_skip == -1 else (have != nbytes):
        raise FormatError(
            f"{path}: the NRRD data cannot be read: {_where(path, source)} holds {max(have, 0)} "
            f"bytes of samples, but {described} need {nbytes}; check sizes, type, byte skip "
            "and line skip"
        )
    return begin


def _raw_begin(path, source, nbytes, line_skip, byte_skip, described) -> int:
    """Offset of the ``nbytes`` raw samples of a data source, checked to be all there."""
    with _open_at_data(source, line_skip) as fh:
        return _raw_span(path, source, fh, nbytes, byte_skip, described)


def _read_raw_part(path, source, out, line_skip, byte_skip, described) -> None:
    with _open_at_data(source, line_skip) as fh:
        begin = _raw_span(path, source, fh, out.nbytes, byte_skip, described)
        fh.seek(begin)
        got = read_exactly(fh, out)
    if got != out.nbytes:
        raise FormatError(
            f"{path}: the NRRD data cannot be read: {_where(path, source)} ended after {got} of "
            f"{out.nbytes} bytes (it changed while being read?)"
        )


class _Inflater:
    """Decompress a gzip or bzip2 stream in bounded pieces, member after member."""

    def __init__(self, fh, encoding: str) -> None:
        self._fh = fh
        self._bz2 = encoding == "bzip2"
        self._magic = b"BZh" if self._bz2 else b"\x1f\x8b"
        self._pending = b""
        self._exhausted = False
        self._dec = self._new(first=True)

    def _new(self, first: bool = False):
        if self._bz2:
            return bz2.BZ2Decompressor()
        # the first member may also be a zlib stream, as some writers make
        return zlib.decompressobj(zlib.MAX_WBITS | (32 if first else 16))

    def _feed(self) -> None:
        if not self._pending and not self._exhausted:
            self._pending = self._fh.read(_IN_CHUNK)
            self._exhausted = not self._pending

    def chunk(self, limit: int) -> bytes:
        """Up to ``limit`` decompressed bytes; b"" at the end of the data."""
        while True:
            if self._dec.eof:
                rest = self._dec.unused_data + self._pending
                self._pending = b""
                if len(rest) < len(self._magic) and not self._exhausted:
                    more = self._fh.read(_IN_CHUNK)
                    self._exhausted = not more
                    rest += more
                if not rest.startswith(self._magic):
                    return b""  # the end (any bytes after the last member are ignored)
                self._dec, self._pending = self._new(), rest
            self._feed()
            if self._bz2 and not self._dec.needs_input:
                data = b""
            else:
                data, self._pending = self._pending, b""
            out = self._dec.decompress(data, limit)
            if not self._bz2:
                self._pending = self._dec.unconsumed_tail
            if out:
                return out
            stuck = self._bz2 and not self._dec.needs_input
            if self._exhausted and not self._pending and not self._dec.eof and not stuck:
                raise EOFError("the compressed stream ends before its end marker")

    def readinto(self, view: memoryview) -> int:
        """Fill ``view``; the count is short only when the data ends."""
        got = 0
        while got < len(view):
            piece = self.chunk(min(_OUT_CHUNK, len(view) - got))
            if not piece:
                break
            view[got : got + len(piece)] = piece
            got += len(piece)
        return got

    def skip(self, n: int) -> int:
        """Drop ``n`` decompressed bytes; returns how many there were."""
        done = 0
        while done < n:
            piece = self.chunk(min(_OUT_CHUNK, n - done))
            if not piece:
                break
            done += len(piece)
        return done


class _CompressedStream:
    """One gzip or bzip2 data source, open and decoded as far as read, with checked reads.

    Every read or skip that finds the stream shorter than the header declares,
    or corrupt, raises a one-line :class:`FormatError` naming the header, and
    nothing is ever decoded past the declared size (plus one byte, to tell
    that there is more): a compression bomb costs a few MiB at most.

    Parameters
    ----------
    path : Path
        The header, for messages.
    source : (Path, int)
        The file holding the stream and where its data part starts.
    encoding : str
        "gzip" or "bzip2".
    line_skip, byte_skip : int
        Lines skipped in the file; decompressed bytes skipped before the samples.
    nbytes : int
        Bytes of the samples the header declares.
    described : str
        The header's sizes and type, for messages.
    """

    def __init__(self, path, source, encoding, line_skip, byte_skip, nbytes, described) -> None:
        self._path, self._encoding, self._described = path, encoding, described
        self._where = "the file" if source[0] == path else f"data file {source[0].name}"
        self._declared = byte_skip + nbytes
        self.got = 0  # decompressed bytes passed so far, byte skip included
        with self._decoding():
            fh = _open_at_data(source, line_skip)
        # the file closes with the stream, even when the stream is dropped unclosed
        self._closer = weakref.finalize(self, fh.close)
        self._inflater = _Inflater(fh, encoding)
        self.skip(byte_skip)

    def __enter__(self) -> _CompressedStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._closer()

    @contextmanager
    def _decoding(self):
        try:
            yield
        except (zlib.error, OSError, EOFError) as exc:
            raise FormatError(
                f"{self._path}: not a readable NRRD file: the {self._encoding} data in "
                f"{self._where} is corrupt or truncated ({one_line(exc)})"
            ) from None

    def _ended(self, wanted: int, done: int) -> None:
        self.got += done
        if done < wanted:
            raise FormatError(
                f"{self._path}: the NRRD data cannot be read: the compressed data in "
                f"{self._where} holds {self.got} bytes, fewer than the {self._declared} its "
                f"header declares ({self._described}); the file is truncated or its sizes are "
                "wrong"
            )

    def skip(self, n: int) -> None:
        """Decode and drop ``n`` bytes."""
        with self._decoding():
            done = self._inflater.skip(n)
        self._ended(n, done)

    def readinto(self, out: np.ndarray) -> None:
        """Fill the contiguous array ``out`` with the next ``out.nbytes`` bytes."""
        with self._decoding():
            done = self._inflater.readinto(memoryview(out.reshape(-1).view(np.uint8)))
        self._ended(out.nbytes, done)

    def check_end(self) -> None:
        """After the declared bytes: the stream must hold no more."""
        with self._decoding():
            extra = bool(self._inflater.chunk(1))
        if extra:
            raise FormatError(
                f"{self._path}: the compressed data in {self._where} holds more than the "
                f"{self._declared} bytes its header declares ({self._described}); the file is "
                "corrupt or its sizes are wrong"
            )


def _read_compressed_part(path, source, out, line_skip, byte_skip, described, encoding) -> None:
    args = (path, source, encoding, line_skip, byte_skip, out.nbytes, described)
    with _CompressedStream(*args) as stream:
        stream.readinto(out)
        stream.check_end()


class CompressedNrrdGrid(LazyGrid):
    """A 3D NRRD volume stored as one gzip or bzip2 stream, decoded slab by slab.

    A compressed stream can only be decoded from its start, so the grid keeps
    its open stream between reads, and a copy of the last layer it read: a
    read that starts at or after that layer decodes on from where the last
    one stopped (reads in increasing z, block-wise extraction's slabs that
    overlap by one layer included, decode the stream once in all), while a
    read of earlier layers opens the stream again and decodes, dropping, up
    to its first layer. Hence ``sequential``. The open stream is this
    process's cache: pickling drops it, and an unpickled grid (a Dask
    worker's) opens its own on its first read.

    The checks of a whole read hold for every slab: a stream shorter than
    declared, or corrupt, fails the read that reaches the gap, and the read of
    the last layer checks that the stream holds nothing more; nothing is
    decoded past the declared size.

    Parameters
    ----------
    path : Path
        The header (named in messages).
    source : (Path, int)
        The file holding the stream (the header itself when attached) and the
        offset where its data part starts.
    encoding : str
        "gzip" or "bzip2".
    dtype : numpy dtype
        Of the samples, with their byte order.
    shape : (3,) tuple of int
        (X, Y, Z), the header's sizes.
    line_skip, byte_skip : int
        Lines skipped in the file; decompressed bytes skipped before the samples.
    described : str
        The header's sizes and type, for messages.

    Attributes
    ----------
    opened : int
        How many times this process opened the stream for a read, to decode it
        from its start (1 after any number of reads in increasing z).
    """

    sequential = True

    def __init__(self, path, source, encoding, dtype, shape, line_skip, byte_skip, described):
        self.path = Path(path)
        self.source = (Path(source[0]), int(source[1]))
        self.encoding = encoding
        self.dtype = np.dtype(dtype)
        self.shape = tuple(int(n) for n in shape)
        self.line_skip, self.byte_skip = int(line_skip), int(byte_skip)
        self.described = described
        self._reset()

    def _reset(self) -> None:
        self.opened = 0
        self._stream: _CompressedStream | None = None
        self._next = 0  # the first layer the open stream has not passed
        self._last: np.ndarray | None = None  # layer _next - 1, kept for overlapping reads
        self._lock = threading.Lock()  # one read at a time moves the stream

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        for name in ("opened", "_stream", "_next", "_last", "_lock"):
            del state[name]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._reset()

    def _open(self) -> _CompressedStream:
        return _CompressedStream(
            self.path,
            self.source,
            self.encoding,
            self.line_skip,
            self.byte_skip,
            self.nbytes,
            self.described,
        )

    def check(self) -> None:
        """Decode the whole stream once, dropping the samples, with the checks of a read.

        Raises
        ------
        FormatError
            The stream is corrupt, or holds fewer or more bytes than declared.
        """
        with self._open() as stream:
            stream.skip(self.nbytes)
            stream.check_end()

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        out = self._empty_slab(k0, k1)
        nx, ny, nz = self.shape
        layer = nx * ny * self.dtype.itemsize
        if k1 == k0:
            return out
        with self._lock:
            stream, self._stream = self._stream, None  # put back only after a good read
            kept = 0  # leading layers of ``out`` taken from the kept last layer
            if stream is not None and k0 == self._next - 1:
                out[0] = self._last
                kept = 1
            elif stream is None or self._next > k0:
                if stream is not None:
                    stream.close()
                stream, self._next = self._open(), 0
                self.opened += 1
            self._last = None
            try:
                stream.skip((k0 + kept - self._next) * layer)
                stream.readinto(out[kept:])
                if k1 == nz:
                    stream.check_end()
                    stream.close()
                else:
                    self._stream, self._next, self._last = stream, k1, out[-1].copy()
            except BaseException:
                stream.close()
                raise
        return out


def _read_hex_part(path, source, out, line_skip, byte_skip, described) -> None:
    """Hex encoding: two hex digits per byte, whitespace anywhere (the file bounds the work)."""
    with _open_at_data(source, line_skip) as fh:
        fh.seek(byte_skip, os.SEEK_CUR)
        text = fh.read()
    digits = b"".join(text.split())
    try:
        values = bytes.fromhex(digits.decode("ascii"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise FormatError(
            f"{path}: not a readable NRRD file: the hex data in {_where(path, source)} is not "
            f"pairs of hex digits ({one_line(exc)})"
        ) from None
    if len(values) != out.nbytes:
        raise FormatError(
            f"{path}: the NRRD data cannot be read: the hex data in {_where(path, source)} holds "
            f"{len(values)} bytes, but {described} need {out.nbytes}"
        )
    out.view(np.uint8)[:] = np.frombuffer(values, np.uint8)


def _read_ascii_part(path, source, out, line_skip, byte_skip, described, header) -> None:
    """ascii encoding: numbers separated by whitespace (or commas), in file order.

    Every number must be one the sample type holds: a value outside an integer
    type's range, text that is not a whole number for an integer type, or a
    finite number beyond a float type's range is refused, naming the first such
    value and its sample index (numpy's parsers would wrap 300 to 44 in uint8).
    The text's size bounds the work.
    """
    with _open_at_data(source, line_skip) as fh:
        fh.seek(byte_skip, os.SEEK_CUR)
        text = fh.read()
    tokens = text.replace(b",", b" ").split()
    if len(tokens) != out.size:
        raise FormatError(
            f"{path}: the NRRD data cannot be read: the ascii data in {_where(path, source)} "
            f"holds {len(tokens)} numbers, but {described} need {out.size}"
        )
    kind = str(header["type"]).strip()

    def refuse(index: int, why: str) -> FormatError:
        shown = one_line(tokens[index].decode("ascii", "replace"), 40)
        return FormatError(
            f"{path}: the NRRD data cannot be read: the ascii data in {_where(path, source)} "
            f"holds {shown} at sample index {index} (0-based, in file order), {why}; fix the "
            "value, or declare a type that holds it"
        )

    if out.dtype.kind in "iu":
        info = np.iinfo(out.dtype)
        span = f"outside the range {info.min}..{info.max} of type {kind}"
        try:
            values = np.array(tokens).astype(np.int64)
        except (ValueError, OverflowError):
            # not whole numbers, or beyond int64: find the first bad one the slow way
            numbers = []
            for i, token in enumerate(tokens):
                try:
                    number = int(token)
                except ValueError:
                    raise refuse(i, f"not a whole number, as type {kind} needs") from None
                if not info.min <= number <= info.max:
                    raise refuse(i, span) from None
                numbers.append(number)
            out[:] = np.array(numbers, dtype=object).astype(out.dtype)
            return
        outside = (values < info.min) | (values > info.max)
        if outside.any():
            raise refuse(int(np.argmax(outside)), span)
        out[:] = values
        return
    try:
        values = np.array(tokens).astype(np.float64)
    except ValueError:
        for i, token in enumerate(tokens):
            try:
                float(token)
            except ValueError:
                raise refuse(i, f"not a number, as type {kind} needs") from None
        raise
    # a finite number past the type's range would become infinite; "inf" spelt out is fine
    limit = np.finfo(out.dtype).max
    with np.errstate(invalid="ignore"):
        beyond = np.abs(values) > limit
    spelt = np.array([b"inf" in t.lower() for t in tokens]) if beyond.any() else None
    if spelt is not None and (beyond & ~spelt).any():
        raise refuse(int(np.argmax(beyond & ~spelt)), f"beyond the range of type {kind}")
    out[:] = values


# --- axes and placement ---------------------------------------------------------------------


def spatial_axes(kinds: list[str] | None, ndim: int) -> list[int]:
    """The axes that are the grid's: kinds domain, space or time (every one of
    the ``ndim`` axes when the header gives no kinds)."""
    if kinds is None:
        return list(range(ndim))
    return [a for a, k in enumerate(kinds) if k in ("domain", "space", "time")]


def _domain_axes(path: Path, header: dict, data: np.ndarray, channel: int | None):
    """Pick the spatial axes; a non-spatial axis (RGB, vector) needs ``channel``."""
    kinds = header.get("kinds")
    spatial = spatial_axes(kinds, data.ndim)
    other = [a for a in range(data.ndim) if a not in spatial]
    if len(other) > 1 or len(spatial) not in (2, 3):
        raise VolumeError(
            f"{path}: NRRD axes of kinds {kinds} cannot be read as a 2D or 3D scalar volume"
        )
    axis = other[0] if other else None
    what = f"values per sample ({kinds[axis]})" if other else ""
    return select_channel(data, axis, channel, path, what), spatial


def _placement(header: dict, domain: list[int]):
    """Spacing, direction and notes; invalid values are ignored with a note saying so."""
    notes = []
    nd = len(domain)
    directions = header.get("space directions")
    if directions is not None:
        try:
            rows = np.asarray(directions, dtype=np.float64)[domain]
        except (ValueError, IndexError, TypeError):
            rows = None
        if rows is not None and rows.shape == (nd, nd) and np.all(np.isfinite(rows)):
            spacing = np.linalg.norm(rows, axis=1)
            if np.all(spacing > 0) and abs(np.linalg.det(rows / spacing[:, None])) > 1e-6:
                return spacing, (rows / spacing[:, None]).T, notes
            # what replaces the spacing is said below (a note --spacing removes)
            notes.append(
                "space directions in the NRRD header ignored (a zero-length or parallel "
                "vector); the axes are taken as x, y, z"
            )
        else:
            notes.append(
                "space directions in the NRRD header ignored (not one finite vector per "
                "spatial axis); the axes are taken as x, y, z"
            )
    spacings = header.get("spacings")
    if spacings is not None:
        try:
            values = np.asarray(spacings, dtype=np.float64)[domain]
        except (ValueError, IndexError, TypeError):
            values = np.full(nd, np.nan)
        spacing = np.ones(nd)
        for axis, value in enumerate(values):
            if np.isfinite(value) and value > 0:
                spacing[axis] = value
            else:
                notes.append(
                    spacing_note(
                        f"spacings {value:g} for axis {'xyz'[axis]} in the NRRD header ignored; "
                        "using 1; set --spacing"
                    )
                )
        return spacing, None, notes
    notes.append(spacing_note("no spacing in the file; using 1 (set --spacing)"))
    return None, None, notes
