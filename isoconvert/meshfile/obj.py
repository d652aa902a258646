"""OBJ: ``v`` lines, and ``f`` lines (polygons) or ``l`` lines (polylines)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import FormatError, one_line
from ..mesh import Mesh
from .common import _numbers, _obj_fan, _recorded, _Unreadable, _why

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
    info.update(_recorded(_obj_comments(text)))
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
