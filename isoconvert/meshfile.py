"""Reading mesh files (PLY, OBJ, OFF, STL) for ``isoconvert check``.

PLY, OBJ and OFF are read here, so that vertices and cells come back exactly as the
file holds them (the file's vertex indices, nothing merged, reordered or
dropped) and so that a header's grid record and a bad vertex index can be
told; STL, which has no indices, is read by trimesh.
"""

from __future__ import annotations

import mmap
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import FormatError, InputNotFoundError, one_line
from .mesh import Mesh
from .writers.header import parse_grid_comment

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl")

#: A PLY header longer than this is not one (a binary file without end_header).
_MAX_HEADER_BYTES = 1 << 24
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


def read_mesh(path: str | Path) -> Mesh:
    """Read triangles, or contour segments, from a PLY, OBJ or STL file.

    Vertices and cells come back as the file holds them: PLY and OBJ with the
    file's vertex order and indices (polygons split into fans of triangles),
    STL with three vertices per triangle (trimesh, ``process=False``); the
    report merges equal positions itself and says how many it merged.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` (values of the stored precision) and
        ``cells (C, 3)`` or ``(C, 2)`` int64 with indices in ``0..V-1``.
        ``info`` has ``source`` (the path), ``stored_precision`` ("float32"
        for PLY ``float`` coordinates and STL, "float64" for PLY ``double`` or
        integer coordinates and for OBJ) and, when a PLY or OBJ header records
        a well-formed grid (``isoconvert grid {...}``), ``grid``.

    Raises
    ------
    InputNotFoundError
        No such file.
    FormatError
        Unknown suffix, unreadable file, no triangles or segments, or a cell
        that refers to a vertex that does not exist (the message names the
        cell and the index).
    """
    path = Path(path)
    if not path.is_file():
        raise InputNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise FormatError(
            f"{path}: unknown mesh extension {suffix or '(none)'!r}; "
            f"check reads {', '.join(MESH_SUFFIXES)}"
        )
    if suffix == ".stl":
        return _read_stl(path)
    reader = {".ply": _read_ply, ".obj": _read_obj, ".off": _read_off}[suffix]
    try:
        return reader(path)
    except (_Unreadable, ValueError, TypeError, KeyError, IndexError, OverflowError) as exc:
        # a file broken in a way the reader does not name
        raise FormatError(
            f"{path}: not a readable {suffix[1:].upper()} mesh ({one_line(exc)})"
        ) from None


def _why(index: int, n_vertices: int, what: str = "vertex indices start at 0") -> str:
    if index < 0:
        return f"but {what}"
    if n_vertices == 0:
        return "but there are no vertices"
    if n_vertices == 1:
        return "but there is only 1 vertex"
    return f"but there are only {n_vertices} vertices"


def _as_stored(vertices: np.ndarray, precision: str) -> np.ndarray:
    """(V, 3) float64 holding values of ``precision``."""
    vertices = np.asarray(vertices, dtype=np.float64)
    if precision == "float32":
        with np.errstate(over="ignore", invalid="ignore"):
            vertices = vertices.astype(np.float32).astype(np.float64)
    return vertices


def _numbers(blob: bytes, dtype=np.float64) -> np.ndarray | None:
    """Whitespace-separated numbers of ``blob`` (1D), or None when it holds other text."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        try:
            return np.fromstring(blob, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None


class _Unreadable(Exception):
    """The file is broken; the message says how (read_mesh adds the file and format)."""


# --- STL -----------------------------------------------------------------------------------


def _read_stl(path: Path) -> Mesh:
    import trimesh

    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many kinds for a broken file
        raise FormatError(f"{path}: not a readable STL mesh ({one_line(exc)})") from None
    if isinstance(loaded, trimesh.Scene):  # several solids in one ASCII file
        meshes = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(meshes) if len(meshes) > 1 else (meshes or [None])[0]
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FormatError(f"{path}: holds no triangles or segments")
    info = {"source": str(path), "stored_precision": "float32"}
    return Mesh(
        _as_stored(loaded.vertices, "float32"), np.asarray(loaded.faces, np.int64), info=info
    )


# --- PLY -----------------------------------------------------------------------------------


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


def _ply_header(path: Path, fh) -> _PlyHeader:
    first = fh.readline(64)
    if first.strip() != b"ply":
        raise _Unreadable("not a PLY file (its first line is not 'ply')")
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
    grid = _first_grid(header.comments)
    if grid is not None:
        info["grid"] = grid
    return Mesh(vertices, cells, info=info)


def _first_grid(comments: list[str]) -> dict | None:
    for text in comments:
        grid = parse_grid_comment(text)
        if grid is not None:
            return grid
    return None


def _face_list(element: _Element) -> str:
    """Name of the vertex index list of a face element."""
    lists = [p.name for p in element.properties if p.count_dtype is not None]
    for name in ("vertex_indices", "vertex_index"):
        if name in lists:
            return name
    if lists:
        return lists[0]
    raise _Unreadable(f"the PLY face element has no list of vertex indices ({element.name})")


def _mapped(fh, start: int):
    """The bytes of an open file from ``start`` on, memory-mapped (no copy of a
    file of millions of triangles; the page cache serves it), or read when the
    file cannot be mapped."""
    try:
        whole = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):  # an empty file, or one mmap does not serve
        fh.seek(start)
        return fh.read()
    return memoryview(whole)[start:]


def _fans(path: Path, faces: dict, kind: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Triangles (T, 3) int64 of polygons, and the polygon each comes from (T,),
    None when that is the triangle itself (all polygons are triangles)."""
    lists = faces["__lists__"]
    if isinstance(lists, np.ndarray):  # every polygon has the same size
        polygons = lists.astype(np.int64)
        size = polygons.shape[1]
        if size < 3:
            raise _Unreadable(f"{kind} 0 has {size} vertices; a face needs 3 or more")
        if size == 3:
            return polygons, None
        fan = np.arange(1, size - 1)
        cells = np.stack(
            [np.repeat(polygons[:, :1], size - 2, axis=1), polygons[:, fan], polygons[:, fan + 1]],
            axis=2,
        ).reshape(-1, 3)
        owner = np.repeat(np.arange(len(polygons)), size - 2)
        return cells, owner
    rows, owners = [], []
    for number, polygon in enumerate(lists):
        if len(polygon) < 3:
            raise _Unreadable(
                f"{kind} {number} has {len(polygon)} vertices; a face needs 3 or more"
            )
        for i in range(1, len(polygon) - 1):
            rows.append((int(polygon[0]), int(polygon[i]), int(polygon[i + 1])))
            owners.append(number)
    return np.array(rows, dtype=np.int64).reshape(-1, 3), np.array(owners, dtype=np.int64)


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
            out[element.name] = {"__lists__": records[_face_list(element)]}
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


# --- OBJ -----------------------------------------------------------------------------------

_OBJ_LINES = {
    kind: re.compile(rb"^[ \t]*" + kind + rb"[ \t]+([^\r\n]*)", re.MULTILINE)
    for kind in (b"v", b"f", b"l")
}
_OBJ_SLASH = re.compile(rb"/[^ \t\r\n]*")


def _read_obj(path: Path) -> Mesh:
    text = path.read_bytes()
    vertices = _obj_vertices(path, text)
    n = len(vertices)
    faces = _OBJ_LINES[b"f"].findall(text)
    if faces:
        polygons, sizes = _obj_indices(path, text, faces, b"f", n)
        cells, owner = _obj_fan(path, polygons, sizes, 3)
    else:
        lines = _OBJ_LINES[b"l"].findall(text)
        if not lines:
            raise FormatError(f"{path}: holds no triangles or segments")
        polygons, sizes = _obj_indices(path, text, lines, b"l", n)
        cells, owner = _obj_fan(path, polygons, sizes, 2)
    info: dict = {"source": str(path), "stored_precision": "float64"}
    grid = _first_grid(_obj_comments(text))
    if grid is not None:
        info["grid"] = grid
    return Mesh(vertices, cells, info=info)


def _obj_comments(text: bytes) -> list[str]:
    """Texts of the leading ``#`` lines (before the first other non-blank line)."""
    comments = []
    for raw in text[: 1 << 20].split(b"\n"):
        line = raw.strip()
        if not line:
            continue
        if not line.startswith(b"#"):
            break
        comments.append(line[1:].lstrip().decode("utf-8", errors="replace"))
    return comments


def _obj_vertices(path: Path, text: bytes) -> np.ndarray:
    """(V, 3) float64 positions of the ``v`` lines (their first three numbers)."""
    tails = _OBJ_LINES[b"v"].findall(text)
    values = _numbers(b" ".join(tails)) if tails else np.zeros(0)
    if values is not None and len(values) == 3 * len(tails):
        return values.reshape(-1, 3)
    rows = []
    for number, tail in enumerate(tails):
        words = tail.split(b"#", 1)[0].split()[:3]
        try:
            if len(words) < 3:
                raise ValueError
            rows.append([float(w) for w in words])
        except ValueError:
            raise _Unreadable(
                f"vertex {number + 1} is not three numbers: "
                f"v {one_line(tail.decode('utf-8', 'replace'))}"
            ) from None
    return np.asarray(rows, dtype=np.float64).reshape(-1, 3)


def _obj_indices(
    path: Path, text: bytes, tails: list[bytes], kind: bytes, n_vertices: int
) -> tuple[np.ndarray, np.ndarray]:
    """0-based vertex indices of every ``f`` (or ``l``) element, flat (K,), and
    the number of indices of each element (E,)."""
    name = "face" if kind == b"f" else "line"
    joined = b" 0 ".join(tails) + b" 0"  # 0 is no OBJ index: it marks where an element ends
    if b"/" in joined:
        joined = _OBJ_SLASH.sub(b"", joined)
    if b"#" not in joined:
        values = _numbers(joined, np.int64)
    else:
        values = None
    if values is not None:
        ends = np.flatnonzero(values == 0)
        if len(ends) == len(tails):
            sizes = np.diff(np.concatenate([[-1], ends])) - 1
            indices = np.delete(values, ends)
            if (indices > 0).all() and (len(indices) == 0 or indices.max() <= n_vertices):
                return indices - 1, sizes
    # something to look at closely: zero, relative (negative) or too large indices,
    # comments or other text: element by element, as the file says it
    starts = [m.start() for m in _OBJ_LINES[b"v"].finditer(text)]
    owners = [m.start() for m in _OBJ_LINES[kind].finditer(text)]
    before = np.searchsorted(np.asarray(starts, dtype=np.int64), np.asarray(owners, np.int64))

    def where(number: int) -> str:
        line = text.count(b"\n", 0, owners[number]) + 1
        return f"{name} {number + 1} (line {line})"

    flat: list[int] = []
    sizes_list: list[int] = []
    for number, tail in enumerate(tails):
        words = tail.split(b"#", 1)[0].split()
        row = []
        for word in words:
            try:
                written = int(word.split(b"/", 1)[0])
            except ValueError:
                raise _Unreadable(
                    f"{where(number)} has {one_line(word.decode('utf-8', 'replace'))!r} "
                    "where a vertex index belongs"
                ) from None
            if written > 0:
                index = written - 1
                if index >= n_vertices:
                    raise FormatError(
                        f"{path}: {where(number)} refers to vertex {written}, "
                        + _why(written, n_vertices)
                    )
            elif written < 0:
                index = int(before[number]) + written
                if index < 0:
                    raise FormatError(
                        f"{path}: {where(number)} refers to vertex {written}, "
                        f"but only {int(before[number])} vertices precede it"
                    )
            else:
                raise FormatError(
                    f"{path}: {where(number)} refers to vertex 0, but OBJ vertex indices start at 1"
                )
            row.append(index)
        flat.extend(row)
        sizes_list.append(len(row))
    return np.asarray(flat, dtype=np.int64), np.asarray(sizes_list, dtype=np.int64)


def _obj_fan(
    path: Path, indices: np.ndarray, sizes: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (fans of the polygons) or segments (of the polylines), and the
    element each comes from."""
    small = np.flatnonzero(sizes < size)
    if len(small):
        name = "face" if size == 3 else "line"
        raise _Unreadable(
            f"{name} {int(small[0]) + 1} has {int(sizes[small[0]])} vertices; "
            f"a {name} needs {size} or more"
        )
    if len(sizes) and (sizes == size).all():
        cells = indices.reshape(-1, size)
        return cells, np.arange(len(cells))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    pieces = sizes - (size - 1)  # triangles per polygon, segments per polyline
    owner = np.repeat(np.arange(len(sizes)), pieces)
    step = np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    base = starts[owner]
    if size == 3:
        cells = np.column_stack([indices[base], indices[base + step + 1], indices[base + step + 2]])
    else:
        cells = np.column_stack([indices[base + step], indices[base + step + 1]])
    return cells.astype(np.int64), owner


def _read_off(path: Path) -> Mesh:
    """OFF: an optional ``[ST][C][N]OFF`` keyword, counts ``V F E``, vertices
    (their first three numbers), faces ``n i1 .. in [colour]``; ``#`` starts a
    comment anywhere. Polygons become fans of triangles, as in PLY."""
    comments: list[str] = []
    lines: list[bytes] = []
    for raw in path.read_bytes().split(b"\n"):
        line, hash_, comment = raw.partition(b"#")
        if hash_ and len(lines) < 2:  # comments of the header
            comments.append(comment.strip().decode("utf-8", errors="replace"))
        if line.strip():
            lines.append(line)
    if not lines:
        raise _Unreadable("an empty file")
    counts = 0  # the line with the counts
    words = lines[0].split()
    if words[0].upper().endswith(b"OFF"):
        if words[0].upper() not in (b"OFF", b"COFF", b"NOFF", b"CNOFF", b"STOFF", b"STCOFF"):
            raise _Unreadable(f"unsupported OFF variant {words[0].decode('ascii', 'replace')!r}")
        words = words[1:]  # the counts may follow the keyword on its line
        if not words and len(lines) > 1:
            counts = 1
            words = lines[1].split()
    if len(words) < 2:
        raise _Unreadable("no vertex and face counts")
    n_vertices, n_faces = int(words[0]), int(words[1])
    rows = lines[counts + 1 : counts + 1 + n_vertices + n_faces]
    if len(rows) < n_vertices + n_faces:
        raise _Unreadable(f"the file ends before its {n_vertices} vertices and {n_faces} faces")
    if n_faces == 0:
        raise FormatError(f"{path}: holds no triangles or segments")
    values = _numbers(b" ".join(rows[:n_vertices])) if n_vertices else np.zeros(0)
    if values is not None and len(values) == 3 * n_vertices:
        vertices = values.reshape(-1, 3)
    else:  # colours or normals after the positions
        vertices = np.array([[float(w) for w in r.split()[:3]] for r in rows[:n_vertices]])
        vertices = vertices.reshape(-1, 3)
    faces = rows[n_vertices:]
    table = _numbers(b" ".join(faces), np.int64)
    if table is not None and len(table) == 4 * n_faces and (table[::4] == 3).all():
        lists: object = table.reshape(-1, 4)[:, 1:]
    else:  # other polygons, or colours after the indices
        lists = []
        for number, face in enumerate(faces):
            items = [int(w) for w in face.split()]
            if not items or items[0] < 3 or len(items) < items[0] + 1:
                raise _Unreadable(f"face {number} is not 3 or more vertex indices")
            lists.append(np.asarray(items[1 : items[0] + 1], np.int64))
    cells, owner = _fans(path, {"__lists__": lists}, "face")
    n = len(vertices)
    if cells.min() < 0 or cells.max() >= n:
        bad = (cells < 0) | (cells >= n)
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(cells[row][bad[row]][0])
        cell = row if owner is None else int(owner[row])
        raise FormatError(f"{path}: face {cell} refers to vertex {index}, {_why(index, n)}")
    info: dict = {"source": str(path), "stored_precision": "float64"}
    grid = _first_grid(comments)
    if grid is not None:
        info["grid"] = grid
    return Mesh(vertices, cells, info=info)
