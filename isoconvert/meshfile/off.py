"""OFF (Object File Format)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .common import _fans, _numbers, _recorded, _Unreadable, _why


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
    if n_vertices < 0 or n_faces < 0:
        raise _Unreadable(f"negative vertex or face count ({n_vertices} {n_faces})")
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
    info.update(_recorded(comments))
    return Mesh(vertices, cells, info=info)
