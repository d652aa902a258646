"""VTP (VTK XML PolyData)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .common import (
    _MAX_HEADER_BYTES,
    _check_indices,
    _mapped,
    _numbers,
    _obj_fan,
    _recorded,
    _tag,
    _Unreadable,
)

_VTK_TYPES = {
    "Int8": "i1",
    "UInt8": "u1",
    "Int16": "i2",
    "UInt16": "u2",
    "Int32": "i4",
    "UInt32": "u4",
    "Int64": "i8",
    "UInt64": "u8",
    "Float32": "f4",
    "Float64": "f8",
    # a string array is its NUL-terminated strings' bytes
    "String": "u1",
}
_XML_COMMENT = re.compile(rb"<!--(.*?)-->", re.DOTALL)
#: The most bytes deflate inflates one compressed byte to (a run of one value
#: costs at least 2 bits per 258 bytes): a header declaring more is corrupt.
_DEFLATE_RATIO = 1032


@dataclass
class _VtkData:
    """How a VTK XML file encodes its binary arrays, and its appended data."""

    order: str  # "<" or ">"
    header: str  # numpy code of the block headers: "u4" or "u8"
    compressor: str | None  # "zlib", "lzma" or None
    appended: bytes | memoryview  # bytes after the "_" of <AppendedData>, or b""
    appended_base64: bool
    path: Path | None = None  # the file, for the messages of a block that inflates too far


def _read_vtp(path: Path) -> Mesh:
    """VTK XML PolyData: every Piece's Points and Polys (triangles; polygons as
    fans) or Lines (polylines as segments); ascii, inline base64 and appended
    (raw or base64) arrays, uncompressed or zlib/lzma-compressed, UInt32 or
    UInt64 block headers, either byte order."""
    from xml.etree import ElementTree

    with open(path, "rb") as fh:
        data = _mapped(fh, 0)
    blob = bytes(data[: min(len(data), _MAX_HEADER_BYTES)])
    start = blob.find(b"<AppendedData")
    appended: bytes | memoryview = b""
    base64_data = False
    if start >= 0:
        # the appended section is not XML: parse what comes before it, closed off
        tag_end = blob.find(b">", start)
        marker = blob.find(b"_", tag_end)
        if tag_end < 0 or marker < 0:
            raise _Unreadable("its AppendedData section has no '_' where its data starts")
        encoding = re.search(rb'encoding\s*=\s*["\'](\w+)["\']', blob[start:tag_end])
        base64_data = bool(encoding) and encoding.group(1) == b"base64"
        appended = data[marker + 1 :]
        # the closing tags after the data: without them the file was cut short
        if b"</VTKFile>" not in bytes(data[max(marker, len(data) - 4096) :]):
            raise _Unreadable("it ends before </VTKFile> (a truncated file?)")
        xml = blob[:start] + b"</VTKFile>"
    else:
        xml = bytes(data)
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError as exc:
        raise _Unreadable(f"not well-formed XML ({exc})") from None
    if _tag(root) != "VTKFile" or root.get("type") != "PolyData":
        raise _Unreadable('not a VTK XML PolyData file (no <VTKFile type="PolyData">)')
    compressor = root.get("compressor")
    known = {None: None, "vtkZLibDataCompressor": "zlib", "vtkLZMADataCompressor": "lzma"}
    if compressor not in known:
        raise _Unreadable(f"compressor {compressor} is not supported (zlib and lzma are)")
    header = {"UInt32": "u4", "UInt64": "u8"}.get(root.get("header_type", "UInt32"))
    if header is None:
        raise _Unreadable(f"unknown header_type {root.get('header_type')!r}")
    order = ">" if root.get("byte_order") == "BigEndian" else "<"
    vtk = _VtkData(order, header, known[compressor], appended, base64_data, path)
    polydata = next((e for e in root if _tag(e) == "PolyData"), None)
    if polydata is None:
        raise _Unreadable("no PolyData element")
    comments = [m.group(1).strip().decode("utf-8", "replace") for m in _XML_COMMENT.finditer(xml)]
    comments += _vtp_field_strings(polydata, vtk)
    points_list, cells_list, kinds = [], [], set()
    labels_list: list[np.ndarray | None] = []
    n = 0
    precision = "float32"
    for piece in (e for e in polydata if _tag(e) == "Piece"):
        count = int(piece.get("NumberOfPoints", "0"))
        points = _vtk_section(piece, "Points")
        if count and points is None:
            raise _Unreadable("a Piece has points but no Points element")
        if count:
            array = next((e for e in points if _tag(e) == "DataArray"), None)
            if array is None:
                raise _Unreadable("its Points element has no DataArray")
            if array.get("type") != "Float32":
                precision = "float64"
            values = _vtk_array(array, vtk, count * 3)
            points_list.append(values.astype(np.float64).reshape(count, 3))
        if int(piece.get("NumberOfStrips", "0")):
            raise _Unreadable("it holds triangle strips, which check does not read")
        for section, size in (("Polys", 3), ("Lines", 2)):
            number = int(piece.get(f"NumberOf{section}", "0"))
            element = _vtk_section(piece, section)
            if not number or element is None:
                continue
            arrays = {e.get("Name"): e for e in element if _tag(e) == "DataArray"}
            if "connectivity" not in arrays or "offsets" not in arrays:
                raise _Unreadable(f"its {section} lack a connectivity or offsets array")
            offsets = _vtk_array(arrays["offsets"], vtk, number).astype(np.int64)
            total = int(offsets[-1])
            indices = _vtk_array(arrays["connectivity"], vtk, total).astype(np.int64)
            sizes = np.diff(np.concatenate([[0], offsets]))
            if (sizes < 0).any():
                raise _Unreadable(f"the offsets of its {section} decrease")
            cells, owner = _obj_fan(path, indices, sizes, size)
            cells_list.append(cells + n)
            kinds.add(size)
            if section == "Polys":
                labels_list.append(_cell_labels(piece, vtk, number, owner))
        n += count
    if not cells_list:
        raise FormatError(f"{path}: holds no triangles or segments")
    if len(kinds) > 1:
        raise _Unreadable("it holds both polygons and lines; check reads one kind")
    vertices = np.concatenate(points_list) if points_list else np.zeros((0, 3))
    cells = np.concatenate(cells_list)
    _check_indices(path, cells, len(vertices), "polygon" if 3 in kinds else "line")
    info: dict = {"source": str(path), "stored_precision": precision}
    info.update(_recorded(comments))
    labels = None
    if labels_list and all(a is not None for a in labels_list):
        labels = np.concatenate(labels_list)
    return Mesh(vertices, cells, info=info, cell_labels=labels)


def _cell_labels(piece, vtk: _VtkData, number: int, owner) -> np.ndarray | None:
    """(T, 2) int64: a label mesh's two labels per triangle, from the 2-component
    cell array ``labels`` our writer gives a Piece of polygons only (cell data runs
    over verts, lines, polys: only then do its rows follow the polygons); else None."""
    cell_data = _vtk_section(piece, "CellData")
    if cell_data is None or any(
        int(piece.get(f"NumberOf{kind}", "0")) for kind in ("Verts", "Lines", "Strips")
    ):
        return None
    array = next((e for e in cell_data if e.get("Name") == "labels"), None)
    if array is None or array.get("NumberOfComponents") != "2":
        return None
    labels = _vtk_array(array, vtk, 2 * number).astype(np.int64).reshape(number, 2)
    return labels if owner is None else labels[owner]


def _vtk_section(piece, name: str):
    return next((e for e in piece if _tag(e) == name), None)


def _vtp_field_strings(polydata, vtk: _VtkData) -> list[str]:
    """The strings of a FieldData String array named ``isoconvert`` (our writer
    records its provenance and grid there too; VTK keeps it when it rewrites
    the file, where the XML comments are lost)."""
    field_data = _vtk_section(polydata, "FieldData")
    if field_data is None:
        return []
    for array in field_data:
        if array.get("type") == "String" and array.get("Name") == "isoconvert":
            try:
                raw = _vtk_array(array, vtk, None)
            except _Unreadable:
                return []  # metadata only: a mesh without it is still a mesh
            return [s.decode("utf-8", "replace") for s in raw.tobytes().split(b"\0") if s]
    return []


def _vtk_array(array, vtk: _VtkData, count: int | None) -> np.ndarray:
    """The values (1D) of a DataArray; ``count`` values expected (None: any)."""
    kind = array.get("type")
    if kind not in _VTK_TYPES:
        raise _Unreadable(f"DataArray type {kind!r} is not supported")
    name = array.get("Name", kind)
    dtype = np.dtype(vtk.order + _VTK_TYPES[kind])
    form = array.get("format", "ascii")
    if form == "ascii":
        text = (array.text or "").encode("ascii", "replace")
        values = _numbers(text)
        if values is None:
            raise _Unreadable(f"its {name} array holds something other than numbers")
        values = values.astype(dtype.newbyteorder("="))
    elif form == "binary":
        values = _vtk_binary(
            _base64_chars((array.text or "").encode("ascii", "replace")), vtk, dtype, name
        )
    elif form == "appended":
        offset = int(array.get("offset", "0"))
        if offset < 0 or offset >= len(vtk.appended):
            raise _Unreadable(f"the file ends before its {name} array")
        source = vtk.appended[offset:]
        if vtk.appended_base64:
            values = _vtk_binary(_base64_chars(bytes(source)), vtk, dtype, name)
        else:
            values = _vtk_raw(source, vtk, dtype, name)
    else:
        raise _Unreadable(f"unknown DataArray format {form!r}")
    if count is not None and len(values) < count:
        raise _Unreadable(f"its {name} array has {len(values)} values, {count} expected")
    return values if count is None else values[:count]


def _base64_chars(text: bytes) -> bytes:
    """Base64 text without the whitespace XML puts around it."""
    return b"".join(text.split())


def _vtk_raw(source, vtk: _VtkData, dtype: np.dtype, name: str) -> np.ndarray:
    """An appended raw array: a header (byte count, or compression blocks) and the data."""
    head = np.dtype(vtk.order + vtk.header)
    truncated = _Unreadable(f"the file ends inside its {name} array")
    if vtk.compressor is None:
        if len(source) < head.itemsize:
            raise truncated
        size = int(np.frombuffer(source, head, 1)[0])
        if head.itemsize + size > len(source):
            raise truncated
        return np.frombuffer(source, dtype, size // dtype.itemsize, head.itemsize)
    if len(source) < 3 * head.itemsize:
        raise truncated
    blocks = int(np.frombuffer(source, head, 1)[0])
    if (3 + blocks) * head.itemsize > len(source):
        raise truncated
    sizes = np.frombuffer(source, head, 3 + blocks).astype(np.int64)
    start = (3 + blocks) * head.itemsize
    if start + int(sizes[3:].sum()) > len(source):
        raise truncated
    return _vtk_inflate(source, start, sizes, vtk, dtype, name)


def _vtk_binary(text: bytes, vtk: _VtkData, dtype: np.dtype, name: str) -> np.ndarray:
    """A base64 array (inline or appended): uncompressed, the count and the data
    are one base64 stream; compressed, the block header is encoded on its own."""
    import base64
    import binascii

    head = np.dtype(vtk.order + vtk.header)
    truncated = _Unreadable(f"the file ends inside its {name} array")
    try:
        if vtk.compressor is None:
            # appended base64 arrays follow each other: decode only this one
            first = base64.b64decode(text[: 4 * -(-head.itemsize // 3)])
            size = int(np.frombuffer(first, head, 1)[0])
            needed = 4 * -(-(head.itemsize + size) // 3)
            if needed > len(text):
                raise truncated
            raw = base64.b64decode(text[:needed])
            return np.frombuffer(raw, dtype, size // dtype.itemsize, head.itemsize)
        first = base64.b64decode(text[: 4 * -(-head.itemsize // 3)])
        blocks = int(np.frombuffer(first, head, 1)[0])
        chars = 4 * -(-(3 + blocks) * head.itemsize // 3)
        if chars > len(text):
            raise truncated
        sizes = np.frombuffer(base64.b64decode(text[:chars]), head, 3 + blocks).astype(np.int64)
        needed = 4 * -(-int(sizes[3:].sum()) // 3)
        if chars + needed > len(text):
            raise truncated
        raw = base64.b64decode(text[chars : chars + needed])
    except (binascii.Error, ValueError) as exc:
        raise _Unreadable(f"its {name} array is not valid base64 ({exc})") from None
    return _vtk_inflate(raw, 0, sizes, vtk, dtype, name)


def _vtk_inflate(
    source, start: int, sizes: np.ndarray, vtk: _VtkData, dtype: np.dtype, name: str
) -> np.ndarray:
    """Decompress the blocks of a compressed array. ``sizes`` is the header:
    number of blocks, block size, size of the last block (0: a full one), the
    compressed size of each block.

    No block is inflated past the size the header declares for it (plus one
    byte, to tell that it goes on): a block that would is a FormatError naming
    the file, and a decompression bomb costs a few bytes more than the header
    declares, never what the data would inflate to. Nor is the header believed
    when it declares more than zlib can inflate from the block's bytes (deflate
    turns a byte into at most 1032): such a file is corrupt.
    """
    import lzma
    import zlib

    blocks, block_size, last = int(sizes[0]), int(sizes[1]), int(sizes[2])
    kind = vtk.compressor
    where = f"{vtk.path}: " if vtk.path is not None else ""
    if block_size < 0 or last < 0 or last > block_size:
        raise _Unreadable(f"the compression header of its {name} array is corrupt")
    parts = []
    for number, size in enumerate(sizes[3:].tolist()):
        expected = last if number == blocks - 1 and last else block_size
        if kind == "zlib" and expected > _DEFLATE_RATIO * size + 64:
            raise FormatError(
                f"{where}a zlib block of its {name} array declares {expected:,} bytes from "
                f"{size:,}, more than zlib can inflate them to; the file is corrupt"
            )
        inflater = zlib.decompressobj() if kind == "zlib" else lzma.LZMADecompressor()
        try:
            # max_length: one byte past the declared size tells that the block goes on
            part = inflater.decompress(bytes(source[start : start + size]), expected + 1)
        except (zlib.error, lzma.LZMAError) as exc:
            raise _Unreadable(f"its {name} array does not decompress ({exc})") from None
        if len(part) > expected:
            raise FormatError(
                f"{where}a {kind} block of its {name} array inflates past the {expected:,} "
                "bytes its header declares; the file is corrupt or a decompression bomb"
            )
        if len(part) != expected:
            raise _Unreadable(f"a block of its {name} array has the wrong size")
        parts.append(part)
        start += size
    raw = b"".join(parts)
    return np.frombuffer(raw, dtype, len(raw) // dtype.itemsize)
