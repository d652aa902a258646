"""PLY: ascii, binary_little_endian and binary_big_endian."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import FormatError, one_line
from ..mesh import Mesh
from .common import (
    _MAX_HEADER_BYTES,
    _as_stored,
    _fans,
    _mapped,
    _numbers,
    _recorded,
    _Unreadable,
    _why,
)

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


@dataclass
class _Property:
    name: str
    dtype: str  # numpy code, e.g. "f4"
    count_dtype: str | None = None  # list properties: the type of the count


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property] = field(default_factory=list)


@dataclass
class _PlyHeader:
    format: str  # "ascii", "binary_little_endian" or "binary_big_endian"
    elements: list[_Element]
    comments: list[str]
    size: int  # bytes up to and including the end_header line


#: Header keywords other than format, element, property, comment and end_header that
#: PLY files use (ignored).
_PLY_OTHER_KEYWORDS = ("obj_info",)


def _ply_header(path: Path, fh) -> _PlyHeader:
    first = fh.readline(64)
    if first.strip() != b"ply":
        raise _Unreadable("not a PLY file: its first line is not 'ply'")
    size = len(first)
    fmt = None
    elements: list[_Element] = []
    comments: list[str] = []
    while True:
        raw = fh.readline(_MAX_HEADER_BYTES)
        size += len(raw)
        if not raw or size > _MAX_HEADER_BYTES:
            raise _Unreadable("the PLY header has no end_header line")
        line = raw.decode("ascii", errors="replace").rstrip("\r\n")
        words = line.split()
        if not words:
            continue
        keyword = words[0]
        if keyword == "end_header":
            break
        if keyword == "comment":
            comments.append(line.split("comment", 1)[1].lstrip(" \t"))
        elif keyword == "format" and len(words) >= 2:
            fmt = words[1]
        elif keyword == "element" and len(words) == 3:
            try:
                count = int(words[2])
            except ValueError:
                raise _Unreadable(f"PLY header line {line!r} has no count") from None
            if count < 0:
                raise _Unreadable(f"PLY header line {line!r} has a negative count")
            elements.append(_Element(words[1], count))
        elif keyword == "property" and elements:
            if len(words) == 5 and words[1] == "list":
                count_type, item_type, name = words[2], words[3], words[4]
                if count_type not in _PLY_TYPES or item_type not in _PLY_TYPES:
                    raise _Unreadable(f"unknown type in PLY header line {line!r}")
                prop = _Property(name, _PLY_TYPES[item_type], _PLY_TYPES[count_type])
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                prop = _Property(words[2], _PLY_TYPES[words[1]])
            else:
                raise _Unreadable(f"cannot read PLY header line {line!r}")
            elements[-1].properties.append(prop)
        elif keyword not in _PLY_OTHER_KEYWORDS:
            # a misspelt "element" would otherwise lose its element silently
            raise _Unreadable(f"unknown PLY header line {line!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _Unreadable(f"unknown PLY format {fmt!r}")
    return _PlyHeader(fmt, elements, comments, size)


def _read_ply(path: Path) -> Mesh:
    with open(path, "rb") as fh:
        header = _ply_header(path, fh)
        body = fh.read() if header.format == "ascii" else _mapped(fh, header.size)
    by_name = {e.name: e for e in header.elements}
    vertex = by_name.get("vertex")
    props = {p.name: p for p in vertex.properties} if vertex else {}
    if vertex is None or not all(a in props and props[a].count_dtype is None for a in "xyz"):
        raise _Unreadable("the PLY file has no vertex element with x, y and z")
    precision = "float32" if any(props[a].dtype == "f4" for a in "xyz") else "float64"
    face = by_name.get("face")
    edge = by_name.get("edge")
    wanted = {"vertex"}
    if face is not None and face.count:
        wanted.add("face")
    elif edge is not None and edge.count:
        wanted.add("edge")
    else:
        raise FormatError(f"{path}: holds no triangles or segments")
    if header.format == "ascii":
        data = _ply_ascii(path, header, body, wanted)
    else:
        data = _ply_binary(path, header, body, wanted)
    # one converting copy per column, straight from the file's records
    columns = [data["vertex"][a] for a in "xyz"]
    vertices = np.empty((len(columns[0]), 3), np.float64)
    for axis, column in enumerate(columns):
        vertices[:, axis] = column
    if precision == "float32" and any(props[a].dtype != "f4" for a in "xyz"):
        vertices = _as_stored(vertices, precision)  # float beside double coordinates
    n = len(vertices)
    if "face" in wanted:
        cells, owner = _fans(path, data["face"], "face")
        kind = "face"
    else:
        cells = np.column_stack([data["edge"]["vertex1"], data["edge"]["vertex2"]]).astype(np.int64)
        owner = None
        kind = "edge"
    if cells.size and (cells.min() < 0 or cells.max() >= n):
        bad = (cells < 0) | (cells >= n)
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(cells[row][bad[row]][0])
        cell = row if owner is None else int(owner[row])
        raise FormatError(f"{path}: {kind} {cell} refers to vertex {index}, {_why(index, n)}")
    info: dict = {"source": str(path), "stored_precision": precision}
    info.update(_recorded(header.comments))
    labels = None
    if kind == "face" and {"inside_label", "outside_label"} <= set(data["face"]):
        # a label mesh (convert --labels --single-file): the labels on each side
        faces = data["face"]
        labels = np.column_stack([faces["inside_label"], faces["outside_label"]]).astype(np.int64)
        labels = labels if owner is None else labels[owner]
    return Mesh(vertices, cells, info=info, cell_labels=labels)


def _face_list(element: _Element) -> str:
    """Name of the vertex index list of a face element."""
    lists = [p.name for p in element.properties if p.count_dtype is not None]
    for name in ("vertex_indices", "vertex_index"):
        if name in lists:
            return name
    if lists:
        return lists[0]
    raise _Unreadable(f"the PLY face element has no list of vertex indices ({element.name})")


def _ply_binary(path: Path, header: _PlyHeader, body: bytes, wanted: set[str]) -> dict:
    """Arrays of the wanted elements: {element: {property: (N,) array}}; a face
    element's index lists under ``"__lists__"``, (N, k) or a list of arrays."""
    order = "<" if header.format == "binary_little_endian" else ">"
    offset = 0
    out: dict = {}
    for element in header.elements:
        if not wanted - set(out):
            break
        if all(p.count_dtype is None for p in element.properties):
            dtype = np.dtype([(p.name, order + p.dtype) for p in element.properties])
            end = offset + dtype.itemsize * element.count
            if end > len(body):
                raise _Unreadable(f"the file ends inside its {element.name} element")
            if element.name in wanted:
                records = np.frombuffer(body, dtype, element.count, offset)
                out[element.name] = {p.name: records[p.name] for p in element.properties}
            offset = end
            continue
        records, offset = _binary_lists(path, element, body, offset, order)
        if element.name in wanted:
            out[element.name] = {**records, "__lists__": records[_face_list(element)]}
    missing = wanted - set(out)
    if missing:
        raise _Unreadable(f"no {' or '.join(sorted(missing))} data in the file")
    return out


def _binary_lists(
    path: Path, element: _Element, body: bytes, offset: int, order: str
) -> tuple[dict, int]:
    """Read an element with list properties: one structured view when every
    record has the lists of the first, else record by record."""
    truncated = _Unreadable(f"the file ends inside its {element.name} element")
    if element.count == 0:
        return {p.name: np.zeros((0, 3), np.int64) for p in element.properties}, offset
    # each record has at least its fixed properties and its lists' counts: a count
    # the rest of the file cannot hold is refused before any record is read
    least = sum(np.dtype(p.count_dtype or p.dtype).itemsize for p in element.properties)
    if offset + least * element.count > len(body):
        raise _Unreadable(
            f"its {element.name} element declares {element.count:,} records of at least "
            f"{least} bytes, but the file has {len(body) - offset:,} bytes left"
        )
    # the sizes of the first record's lists give a candidate fixed layout
    fields, cursor = [], offset
    for p in element.properties:
        if p.count_dtype is None:
            fields.append((p.name, order + p.dtype))
            cursor += np.dtype(p.dtype).itemsize
            continue
        ctype = np.dtype(order + p.count_dtype)
        if cursor + ctype.itemsize > len(body):
            raise truncated
        n = int(np.frombuffer(body, ctype, 1, cursor)[0])
        fields.append(("__n_" + p.name, ctype))
        fields.append((p.name, np.dtype(order + p.dtype), (n,)))
        cursor += ctype.itemsize + n * np.dtype(p.dtype).itemsize
    dtype = np.dtype(fields)
    end = offset + dtype.itemsize * element.count
    if end <= len(body):
        records = np.frombuffer(body, dtype, element.count, offset)
        lists = [p for p in element.properties if p.count_dtype is not None]
        first = [int(records["__n_" + p.name][0]) for p in lists]
        if all((records["__n_" + p.name] == n).all() for p, n in zip(lists, first, strict=True)):
            out = {p.name: records[p.name] for p in element.properties}
            for p in lists:
                out[p.name] = out[p.name].reshape(element.count, -1)
            return out, end
    # record by record (mixed polygon sizes)
    out_lists: dict = {p.name: [] for p in element.properties}
    for _ in range(element.count):
        for p in element.properties:
            size = np.dtype(p.dtype).itemsize
            if p.count_dtype is None:
                if offset + size > len(body):
                    raise truncated
                out_lists[p.name].append(np.frombuffer(body, order + p.dtype, 1, offset)[0])
                offset += size
                continue
            csize = np.dtype(p.count_dtype).itemsize
            if offset + csize > len(body):
                raise truncated
            n = int(np.frombuffer(body, order + p.count_dtype, 1, offset)[0])
            offset += csize
            if offset + n * size > len(body):
                raise truncated
            out_lists[p.name].append(np.frombuffer(body, order + p.dtype, n, offset))
            offset += n * size
    return out_lists, offset


def _ply_ascii(path: Path, header: _PlyHeader, body: bytes, wanted: set[str]) -> dict:
    """As :func:`_ply_binary`, from the text body (one record per line)."""
    lines = [line for line in body.split(b"\n") if line.strip()]
    start = 0
    out: dict = {}
    for element in header.elements:
        if not wanted - set(out):
            break
        block = lines[start : start + element.count]
        if len(block) < element.count:
            raise _Unreadable(f"the file ends inside its {element.name} element")
        start += element.count
        if element.name not in wanted:
            continue
        values = _numbers(b" ".join(block)) if block else np.zeros(0)
        width = len(values) // element.count if values is not None and element.count else 0
        if values is not None and element.count and width * element.count == len(values):
            table = values.reshape(element.count, width)
            uniform = _ascii_uniform(element, table)
            if uniform is not None:
                out[element.name] = uniform
                continue
        out[element.name] = _ascii_records(path, element, block)
    missing = wanted - set(out)
    if missing:
        raise _Unreadable(f"no {' or '.join(sorted(missing))} data in the file")
    return out


def _ascii_uniform(element: _Element, table: np.ndarray) -> dict | None:
    """Columns of an ASCII element whose records all have the same size, or
    None when the lists' sizes differ from record to record."""
    out, column = {}, 0
    for p in element.properties:
        if p.count_dtype is None:
            if column >= table.shape[1]:
                return None
            out[p.name] = table[:, column].astype(p.dtype)
            column += 1
            continue
        if column >= table.shape[1]:
            return None
        counts = table[:, column]
        n = int(counts[0]) if len(counts) else 0
        if not (counts == n).all() or column + 1 + n > table.shape[1]:
            return None
        out[p.name] = table[:, column + 1 : column + 1 + n].astype(p.dtype)
        column += 1 + n
    if column != table.shape[1]:
        return None
    if any(p.count_dtype is not None for p in element.properties):
        out["__lists__"] = out[_face_list(element)]
    return out


def _ascii_records(path: Path, element: _Element, block: list[bytes]) -> dict:
    """Columns of an ASCII element, record by record."""
    out: dict = {p.name: [] for p in element.properties}
    for number, line in enumerate(block):
        try:
            values = [float(word) for word in line.split()]
        except ValueError:
            words = one_line(line.decode("ascii", "replace"))
            raise _Unreadable(f"{element.name} {number} is not numbers: {words}") from None
        column = 0
        for p in element.properties:
            if p.count_dtype is None:
                if column >= len(values):
                    raise _Unreadable(f"{element.name} {number} has too few values")
                out[p.name].append(values[column])
                column += 1
            else:
                n = int(values[column]) if column < len(values) else -1
                if n < 0 or column + 1 + n > len(values):
                    raise _Unreadable(f"{element.name} {number} has too few values")
                out[p.name].append(np.asarray(values[column + 1 : column + 1 + n]))
                column += 1 + n
    result: dict = {}
    for p in element.properties:
        result[p.name] = (
            np.asarray(out[p.name], dtype=p.dtype) if p.count_dtype is None else out[p.name]
        )
    if any(p.count_dtype is not None for p in element.properties):
        result["__lists__"] = result[_face_list(element)]
    return result
