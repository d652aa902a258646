"""What several of the mesh file readers use: the error a broken file raises,
numbers from text, the stored precision, a header's grid record, polygons as
fans of triangles and the check of vertex indices."""

from __future__ import annotations

import mmap
import warnings
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..writers.header import GRID_PREFIX, parse_grid_comment, unescape_comment

#: A PLY header longer than this is not one (a binary file without end_header).
_MAX_HEADER_BYTES = 1 << 24


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


def _first_grid(comments: list[str]) -> dict | None:
    for text in comments:
        grid = parse_grid_comment(text)
        if grid is not None:
            return grid
    return None


#: Comment texts by which isoconvert's writers sign a file (every mesh isoconvert
#: writes was extracted from a volume, so its open boundaries are where a grid cut it).
_OUR_COMMENTS = ("made by isoconvert", GRID_PREFIX.strip())


def _extraction(lines: list[str]) -> dict:
    """``method`` and ``ambiguity`` from isoconvert's provenance lines (``method M
    level L``, ``ambiguity R``; escaped as the writers escape them), where present."""
    out: dict = {}
    for text in lines:
        words = text.split() if isinstance(text, str) else []
        if len(words) == 4 and words[0] == "method" and words[2] == "level":
            out.setdefault("method", unescape_comment(words[1]))
        elif len(words) == 2 and words[0] == "ambiguity":
            out.setdefault("ambiguity", unescape_comment(words[1]))
    return out


def _recorded(comments: list[str]) -> dict:
    """What isoconvert's header comments record for the report: ``grid`` (the grid
    record), ``unit`` (the volume's length unit, from a ``unit U`` line),
    ``cut_by_grid`` (True when isoconvert wrote the file, see
    :func:`isoconvert.check_mesh`), and from such a file ``method`` and
    ``ambiguity`` (the extraction rule, from ``method M level L`` and
    ``ambiguity R`` lines)."""
    out: dict = {}
    if any(t.startswith(_OUR_COMMENTS) for t in comments):
        out["cut_by_grid"] = True
        out.update(_extraction(comments))
    grid = _first_grid(comments)
    if grid is not None:
        out["grid"] = grid
    unit = next((t[5:].strip() for t in comments if t.startswith("unit ") and t[5:].strip()), None)
    if unit is not None:
        out["unit"] = unescape_comment(unit)  # PLY headers are ASCII: "\\xb5m" for µm
    return out


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


def _check_indices(path: Path, cells: np.ndarray, n: int, kind: str) -> None:
    """A FormatError naming the first cell that refers to a vertex that does not exist."""
    if cells.size and (cells.min() < 0 or cells.max() >= n):
        bad = (cells < 0) | (cells >= n)
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(cells[row][bad[row]][0])
        raise FormatError(f"{path}: {kind} {row} refers to vertex {index}, {_why(index, n)}")


def _tag(element) -> str:
    """An XML element's name without its namespace."""
    return element.tag.rsplit("}", 1)[-1]
