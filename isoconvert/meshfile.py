"""Reading mesh files (PLY, OBJ, OFF, STL, VTP, GLB, 3MF) for ``isoconvert check``.

PLY, OBJ, OFF, VTP, GLB and 3MF are read here, with the standard library and
numpy only (VTK and trimesh are test extras, never needed at run time), so
that vertices and cells come back exactly as the file holds them (the file's
vertex indices, nothing merged, reordered or dropped) and so that a header's
grid record and a bad vertex index can be told; STL, which has no indices, is
read by trimesh.
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

MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".vtp", ".glb", ".3mf")

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
    """Read triangles, or contour segments, from a PLY, OBJ, OFF, STL, VTP, GLB or 3MF file.

    Vertices and cells come back as the file holds them: PLY, OBJ, OFF, VTP,
    GLB and 3MF with the file's vertex order and indices (polygons split into
    fans of triangles; several VTP pieces, glTF primitives or 3MF objects one
    after the other, placed by their node or build transforms), STL with three
    vertices per triangle (trimesh, ``process=False``); the report merges
    equal positions itself and says how many it merged.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` (values of the stored precision) and
        ``cells (C, 3)`` or ``(C, 2)`` int64 with indices in ``0..V-1``.
        ``info`` has ``source`` (the path), ``stored_precision`` ("float32"
        for PLY ``float`` coordinates, VTP ``Float32`` points, GLB and STL;
        "float64" for PLY ``double`` or integer coordinates, OBJ, OFF and VTP
        ``Float64``; for 3MF's text, float32 when every coordinate is a float32
        value) and, when the file records a well-formed grid as isoconvert's
        writers do (PLY/OBJ/OFF header comment, VTP comment or ``isoconvert``
        field array, GLB ``asset.extras``, 3MF ``isoconvert:grid`` metadata),
        ``grid``.

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
    reader = {
        ".ply": _read_ply,
        ".obj": _read_obj,
        ".off": _read_off,
        ".vtp": _read_vtp,
        ".glb": _read_glb,
        ".3mf": _read_3mf,
    }[suffix]
    try:
        return reader(path)
    except (
        _Unreadable,
        ValueError,
        TypeError,
        KeyError,
        IndexError,
        OverflowError,
        AttributeError,
        RecursionError,
    ) as exc:
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


# --- VTP (VTK XML PolyData) ------------------------------------------------------------------

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


@dataclass
class _VtkData:
    """How a VTK XML file encodes its binary arrays, and its appended data."""

    order: str  # "<" or ">"
    header: str  # numpy code of the block headers: "u4" or "u8"
    compressor: str | None  # "zlib", "lzma" or None
    appended: bytes | memoryview  # bytes after the "_" of <AppendedData>, or b""
    appended_base64: bool


def _tag(element) -> str:
    """An XML element's name without its namespace."""
    return element.tag.rsplit("}", 1)[-1]


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
    vtk = _VtkData(order, header, known[compressor], appended, base64_data)
    polydata = next((e for e in root if _tag(e) == "PolyData"), None)
    if polydata is None:
        raise _Unreadable("no PolyData element")
    comments = [m.group(1).strip().decode("utf-8", "replace") for m in _XML_COMMENT.finditer(xml)]
    comments += _vtp_field_strings(polydata, vtk)
    points_list, cells_list, kinds = [], [], set()
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
            cells, _ = _obj_fan(path, indices, sizes, size)
            cells_list.append(cells + n)
            kinds.add(size)
        n += count
    if not cells_list:
        raise FormatError(f"{path}: holds no triangles or segments")
    if len(kinds) > 1:
        raise _Unreadable("it holds both polygons and lines; check reads one kind")
    vertices = np.concatenate(points_list) if points_list else np.zeros((0, 3))
    cells = np.concatenate(cells_list)
    _check_indices(path, cells, len(vertices), "polygon" if 3 in kinds else "line")
    info: dict = {"source": str(path), "stored_precision": precision}
    grid = _first_grid(comments)
    if grid is not None:
        info["grid"] = grid
    return Mesh(vertices, cells, info=info)


def _check_indices(path: Path, cells: np.ndarray, n: int, kind: str) -> None:
    """A FormatError naming the first cell that refers to a vertex that does not exist."""
    if cells.size and (cells.min() < 0 or cells.max() >= n):
        bad = (cells < 0) | (cells >= n)
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(cells[row][bad[row]][0])
        raise FormatError(f"{path}: {kind} {row} refers to vertex {index}, {_why(index, n)}")


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
    compressed size of each block."""
    import lzma
    import zlib

    blocks, block_size, last = int(sizes[0]), int(sizes[1]), int(sizes[2])
    decompress = zlib.decompress if vtk.compressor == "zlib" else lzma.decompress
    parts = []
    for number, size in enumerate(sizes[3:].tolist()):
        try:
            part = decompress(bytes(source[start : start + size]))
        except (zlib.error, lzma.LZMAError) as exc:
            raise _Unreadable(f"its {name} array does not decompress ({exc})") from None
        expected = last if number == blocks - 1 and last else block_size
        if len(part) != expected:
            raise _Unreadable(f"a block of its {name} array has the wrong size")
        parts.append(part)
        start += size
    raw = b"".join(parts)
    return np.frombuffer(raw, dtype, len(raw) // dtype.itemsize)


# --- GLB (binary glTF 2.0) -------------------------------------------------------------------

_GLTF_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_GLTF_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_GLTF_TRIANGLES, _GLTF_LINES = 4, 1


def _read_glb(path: Path) -> Mesh:
    """GLB: the triangle (mode 4) or line (mode 1) primitives of the meshes the
    default scene's nodes place, with the nodes' transforms; indexed or not."""
    import json
    import struct

    data = path.read_bytes()
    if len(data) < 20:
        raise _Unreadable("shorter than a GLB header")
    magic, version, total = struct.unpack_from("<III", data)
    if magic != 0x46546C67:
        raise _Unreadable("not a GLB file (it does not start with 'glTF')")
    if version != 2:
        raise _Unreadable(f"glTF version {version}; check reads glTF 2.0")
    if total > len(data):
        raise _Unreadable(f"its header says {total} bytes, but the file has {len(data)}")
    chunks: list[tuple[int, bytes]] = []
    offset = 12
    while offset + 8 <= total:
        length, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + length > total:
            raise _Unreadable("the file ends inside a chunk")
        chunks.append((kind, data[offset + 8 : offset + 8 + length]))
        offset += 8 + length
    if not chunks or chunks[0][0] != 0x4E4F534A:
        raise _Unreadable("its first chunk is not JSON")
    try:
        gltf = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _Unreadable(f"its JSON chunk is not JSON ({exc})") from None
    if not isinstance(gltf, dict):
        raise _Unreadable("its JSON chunk is not a glTF object")
    binary = next((chunk for kind, chunk in chunks[1:] if kind == 0x004E4942), None)
    buffers = [_gltf_buffer(b, binary) for b in gltf.get("buffers", [])]
    vertices_list, cells_list, kinds = [], [], set()
    n = 0
    transformed = False
    for mesh_index, matrix in _gltf_instances(gltf):
        mesh = gltf["meshes"][mesh_index]
        for primitive in mesh.get("primitives", []):
            mode = primitive.get("mode", _GLTF_TRIANGLES)
            if mode not in (_GLTF_TRIANGLES, _GLTF_LINES):
                raise _Unreadable(
                    f"a primitive has mode {mode}; check reads triangles (4) and lines (1)"
                )
            if "POSITION" not in primitive.get("attributes", {}):
                raise _Unreadable("a primitive has no POSITION attribute")
            positions = _gltf_accessor(gltf, buffers, primitive["attributes"]["POSITION"])
            if positions.ndim != 2 or positions.shape[1] != 3:
                raise _Unreadable("its POSITION accessor is not VEC3")
            with np.errstate(invalid="ignore", over="ignore"):  # the report names non-finite ones
                positions = positions.astype(np.float64)
            if not np.array_equal(matrix, np.eye(4)):
                positions = positions @ matrix[:3, :3].T + matrix[:3, 3]
                transformed = True
            size = 3 if mode == _GLTF_TRIANGLES else 2
            if "indices" in primitive:
                indices = _gltf_accessor(gltf, buffers, primitive["indices"]).astype(np.int64)
            else:
                indices = np.arange(len(positions), dtype=np.int64)
            if indices.size % size:
                raise _Unreadable(f"a primitive's {indices.size} indices are no whole cells")
            cells = indices.reshape(-1, size)
            _check_indices(path, cells, len(positions), "triangle" if size == 3 else "segment")
            vertices_list.append(positions)
            cells_list.append(cells + n)
            kinds.add(size)
            n += len(positions)
    if not cells_list or not sum(len(c) for c in cells_list):
        raise FormatError(f"{path}: holds no triangles or segments")
    if len(kinds) > 1:
        raise _Unreadable("it holds both triangles and lines; check reads one kind")
    info: dict = {
        "source": str(path),
        # float32 positions placed by a transform are float64 values
        "stored_precision": "float64" if transformed else "float32",
    }
    extras = gltf.get("asset", {}).get("extras", {})
    ours = extras.get("isoconvert") if isinstance(extras, dict) else None
    if isinstance(ours, dict):
        from .geometry import normalized_grid

        grid = normalized_grid(ours.get("grid"))
        if grid is not None:
            info["grid"] = grid
    return Mesh(np.concatenate(vertices_list), np.concatenate(cells_list), info=info)


def _gltf_buffer(buffer: dict, binary: bytes | None) -> bytes:
    """A buffer's bytes: the BIN chunk, or a base64 ``data:`` URI."""
    import base64
    import binascii

    uri = buffer.get("uri")
    if uri is None:
        if binary is None:
            raise _Unreadable("it has a buffer but no BIN chunk")
        data = binary
    elif uri.startswith("data:") and ";base64," in uri:
        try:
            data = base64.b64decode(uri.split(";base64,", 1)[1])
        except binascii.Error as exc:
            raise _Unreadable(f"a buffer's data URI is not base64 ({exc})") from None
    else:
        raise _Unreadable(f"a buffer refers to another file ({one_line(uri, 80)}), not read")
    if len(data) < int(buffer.get("byteLength", 0)):
        raise _Unreadable("a buffer is shorter than its byteLength (a truncated file?)")
    return data


def _gltf_accessor(gltf: dict, buffers: list[bytes], index: int) -> np.ndarray:
    """The values of accessor ``index``: (count,) for SCALAR, (count, k) for VECk."""
    accessor = gltf["accessors"][index]
    if "sparse" in accessor:
        raise _Unreadable("a sparse accessor, which check does not read")
    code = _GLTF_COMPONENTS.get(accessor.get("componentType"))
    width = _GLTF_WIDTH.get(accessor.get("type"))
    if code is None or width is None:
        raise _Unreadable(f"accessor {index} has an unsupported component type or type")
    count = int(accessor["count"])
    dtype = np.dtype("<" + code)
    if "bufferView" not in accessor:  # glTF: all zeros
        values = np.zeros((count, width), dtype)
        return values[:, 0] if width == 1 else values
    view = gltf["bufferViews"][accessor["bufferView"]]
    data = buffers[view["buffer"]]
    start = int(view.get("byteOffset", 0)) + int(accessor.get("byteOffset", 0))
    stride = int(view.get("byteStride", 0)) or width * dtype.itemsize
    end = start + (count - 1) * stride + width * dtype.itemsize if count else start
    view_end = int(view.get("byteOffset", 0)) + int(view["byteLength"])
    if start < 0 or end > min(len(data), view_end):
        raise _Unreadable(f"accessor {index} reaches past the end of its buffer view")
    if count == 0:
        values = np.zeros((0, width), dtype)
    else:
        values = np.ndarray((count, width), dtype, data, start, (stride, dtype.itemsize))
    return values[:, 0] if width == 1 else values


def _gltf_instances(gltf: dict) -> list[tuple[int, np.ndarray]]:
    """(mesh index, 4x4 world matrix) of every node with a mesh in the default
    scene; every mesh, untransformed, when the file has no scene."""
    meshes = gltf.get("meshes", [])
    nodes = gltf.get("nodes", [])
    scenes = gltf.get("scenes", [])
    if not scenes:
        return [(i, np.eye(4)) for i in range(len(meshes))]
    scene = scenes[gltf.get("scene", 0)]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(i, np.eye(4), 0) for i in scene.get("nodes", [])]
    while stack:
        index, parent, depth = stack.pop()
        if depth > len(nodes):  # a cycle: glTF nodes form trees
            raise _Unreadable("its nodes form a cycle")
        node = nodes[index]
        matrix = parent @ _gltf_local(node)
        if "mesh" in node:
            out.append((int(node["mesh"]), matrix))
        stack.extend((child, matrix, depth + 1) for child in node.get("children", []))
    return out


def _gltf_local(node: dict) -> np.ndarray:
    """A node's local transform: its ``matrix`` (column-major) or T * R * S."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    local = np.eye(4)
    local[:3, :3] = rotation * np.asarray(node.get("scale", [1.0, 1.0, 1.0]), dtype=np.float64)
    local[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return local


# --- 3MF -------------------------------------------------------------------------------------

_3MF_MODEL = "3D/3dmodel.model"


def _read_3mf(path: Path) -> Mesh:
    """3MF: the triangles of every build item (objects and their components,
    with their transforms), from the package's start part."""
    import zipfile
    import zlib
    from xml.etree import ElementTree

    try:
        with zipfile.ZipFile(path) as package:
            names = set(package.namelist())
            part = _3mf_start_part(package, names)
            xml = package.read(part)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError) as exc:
        raise _Unreadable(f"not a readable ZIP package ({exc})") from None
    except zlib.error as exc:
        raise _Unreadable(f"a part does not decompress ({exc})") from None
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError as exc:
        raise _Unreadable(f"its model part is not well-formed XML ({exc})") from None
    if _tag(root) != "model":
        raise _Unreadable("its model part has no <model> element")
    objects: dict[str, object] = {}
    for resources in (e for e in root if _tag(e) == "resources"):
        for obj in (e for e in resources if _tag(e) == "object"):
            objects[obj.get("id")] = obj
    build = next((e for e in root if _tag(e) == "build"), None)
    items = (
        [(e.get("objectid"), _3mf_transform(e)) for e in build if _tag(e) == "item"]
        if build is not None
        else [(key, np.eye(4)) for key in objects]
    )
    vertices_list, cells_list = [], []
    n = 0
    transformed = False
    stack = [(key, matrix, 0) for key, matrix in reversed(items)]
    while stack:
        key, matrix, depth = stack.pop()
        if key not in objects:
            raise _Unreadable(f"a build item or component refers to object {key}, not defined")
        if depth > len(objects):
            raise _Unreadable("its components refer to each other in a cycle")
        obj = objects[key]
        mesh = next((e for e in obj if _tag(e) == "mesh"), None)
        if mesh is not None:
            vertices, cells = _3mf_mesh(path, mesh)
            if not np.array_equal(matrix, np.eye(4)):
                vertices = vertices @ matrix[:3, :3].T + matrix[:3, 3]
                transformed = True
            vertices_list.append(vertices)
            cells_list.append(cells + n)
            n += len(vertices)
        components = next((e for e in obj if _tag(e) == "components"), None)
        if components is not None:
            children = [e for e in components if _tag(e) == "component"]
            stack.extend(
                (c.get("objectid"), matrix @ _3mf_transform(c), depth + 1)
                for c in reversed(children)
            )
    if not cells_list or not sum(len(c) for c in cells_list):
        raise FormatError(f"{path}: holds no triangles or segments")
    vertices = np.concatenate(vertices_list)
    info: dict = {"source": str(path)}
    if not transformed and _float32_text(vertices):
        info["stored_precision"] = "float32"
        vertices = _as_stored(vertices, "float32")
    else:
        info["stored_precision"] = "float64"
    for meta in (e for e in root if _tag(e) == "metadata"):
        grid = parse_grid_comment((meta.text or "").strip())
        if meta.get("name", "").endswith("grid") and grid is not None:
            info["grid"] = grid
            break
    return Mesh(vertices, np.concatenate(cells_list), info=info)


def _float32_text(values: np.ndarray) -> bool:
    """Whether decimal coordinates are float32 values: each one either is a
    float32 value or is the 9-significant-digit text of one (as isoconvert's
    3MF writer prints them: the nearest float32 gives the value back exactly,
    the nearest double does not)."""
    flat = values.reshape(-1)
    # a few thousand coordinates settle most float64 meshes without a pass over all
    for part in (flat[:4096], flat):
        with np.errstate(over="ignore", invalid="ignore"):
            as32 = part.astype(np.float32).astype(np.float64)
        differ = as32 != part
        if differ.any():
            printed = np.char.mod("%.9g", as32[differ]).astype(np.float64)
            if not (printed == part[differ]).all():
                return False
    return True


def _3mf_start_part(package, names: set[str]) -> str:
    """The model part the package's relationships name (else ``3D/3dmodel.model``)."""
    from xml.etree import ElementTree

    if "_rels/.rels" in names:
        try:
            rels = ElementTree.fromstring(package.read("_rels/.rels"))
        except ElementTree.ParseError:
            rels = None
        for rel in rels if rels is not None else []:
            if rel.get("Type", "").endswith("/3dmodel"):
                target = rel.get("Target", "").lstrip("/")
                if target in names:
                    return target
    if _3MF_MODEL in names:
        return _3MF_MODEL
    raise _Unreadable("the package has no 3D model part (3D/3dmodel.model)")


def _3mf_transform(element) -> np.ndarray:
    """A ``transform="m00 m01 m02 m10 ... m32"`` attribute as a 4x4 matrix acting
    on column vectors (3MF multiplies row vectors on the left)."""
    text = element.get("transform")
    matrix = np.eye(4)
    if text:
        values = np.array(text.split(), dtype=np.float64)
        if values.size != 12:
            raise _Unreadable(f"a transform has {values.size} numbers, not 12")
        matrix[:3, :] = values.reshape(4, 3).T
    return matrix


def _3mf_mesh(path: Path, mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (T, 3) int64 triangles of one ``<mesh>``."""
    vertices_element = next((e for e in mesh if _tag(e) == "vertices"), None)
    triangles_element = next((e for e in mesh if _tag(e) == "triangles"), None)
    rows = [] if vertices_element is None else list(vertices_element)
    try:
        vertices = np.array(
            [(v.get("x"), v.get("y"), v.get("z")) for v in rows], dtype=np.float64
        ).reshape(-1, 3)
    except (TypeError, ValueError):
        raise _Unreadable("a vertex lacks x, y or z, or they are not numbers") from None
    rows = [] if triangles_element is None else list(triangles_element)
    try:
        cells = np.array(
            [(t.get("v1"), t.get("v2"), t.get("v3")) for t in rows], dtype=np.int64
        ).reshape(-1, 3)
    except (TypeError, ValueError):
        raise _Unreadable("a triangle lacks v1, v2 or v3, or they are not integers") from None
    _check_indices(path, cells, len(vertices), "triangle")
    return vertices, cells
