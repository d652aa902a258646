"""STL, binary or ASCII: three vertices of their own per triangle (STL has no indices).

Read here with numpy rather than through trimesh, so that a broken file is
named for what is wrong with it (trimesh's fallbacks named a missing optional
module of theirs instead), and so that the size a binary header declares is
checked against the file before anything is allocated.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from .common import _as_stored, _mapped, _numbers

#: A binary STL: an 80-byte header, a uint32 triangle count, 50 bytes per triangle.
_HEADER, _RECORD = 84, 50
_BINARY = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
#: What isoconvert's STL writer puts in the header or on the ``solid`` line.
_OURS = (b"binary STL written by isoconvert", b"solid isoconvert")
_VERTEX = re.compile(rb"^[ \t]*vertex[ \t]+([^\r\n]*)", re.MULTILINE | re.IGNORECASE)
_FACET = re.compile(rb"^[ \t]*facet\b", re.MULTILINE | re.IGNORECASE)
_SOLID = re.compile(rb"\A\s*solid\b", re.IGNORECASE)
_ENDSOLID = re.compile(rb"^[ \t]*endsolid\b", re.MULTILINE | re.IGNORECASE)


def _read_stl(path: Path) -> Mesh:
    """Binary STL (when the file's size is what its triangle count needs) or ASCII.

    Returns
    -------
    Mesh
        ``vertices (3T, 3)`` float64 holding float32 values (triangle t's corners
        are vertices 3t, 3t + 1, 3t + 2), ``cells (T, 3)``.

    Raises
    ------
    FormatError
        Neither a binary nor an ASCII STL (the message says what each would
        need), or no triangles.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEADER)
        count = int(np.frombuffer(head, "<u4", 1, 80)[0]) if len(head) == _HEADER else None
        needed = None if count is None else _HEADER + _RECORD * count
        binary = (
            f"not a binary STL ({size} bytes: shorter than its 84-byte header and count)"
            if needed is None
            else f"not a binary STL (80-byte header + count {count:,} needs {needed:,} "
            f"bytes, the file has {size:,})"
        )
        vertices = None
        if _SOLID.match(head) and size != needed:  # a binary header may start "solid" too
            fh.seek(0)
            binary_fits = needed is not None and size > needed
            vertices = _ascii_corners(path, fh.read(), None if binary_fits else binary)
        if vertices is None:
            if needed is None or size < needed:
                raise FormatError(f"{path}: {binary} nor an ASCII STL (no 'solid' line)")
            # binary; bytes after the records (some writers pad) are ignored
            records = np.frombuffer(_mapped(fh, _HEADER), _BINARY, count)
            vertices = records["corners"].astype(np.float64).reshape(-1, 3)
    if not len(vertices):
        raise FormatError(f"{path}: holds no triangles or segments")
    info: dict = {"source": str(path), "stored_precision": "float32"}
    if head.startswith(_OURS):
        info["cut_by_grid"] = True  # isoconvert's file: extracted from a volume
    cells = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
    return Mesh(_as_stored(vertices, "float32"), cells, info=info)


def _ascii_corners(path: Path, text: bytes, binary: str | None) -> np.ndarray | None:
    """(3T, 3) float64 corners of the ``vertex x y z`` lines of an ASCII STL.

    ``binary`` says why the file is no binary STL; None when it may be one (its
    size holds its count's records): then a file without ``facet`` and
    ``vertex`` lines gives None, to be read as binary."""
    tails = _VERTEX.findall(text)
    facets = len(_FACET.findall(text))
    if not tails:
        if binary is None and not facets:
            return None
        if facets:
            raise FormatError(f"{path}: an ASCII STL whose facets have no 'vertex' lines")
        if _ENDSOLID.search(text):  # solid ... endsolid, and nothing between
            raise FormatError(f"{path}: holds no triangles or segments")
        raise FormatError(
            f"{path}: not an ASCII STL (a 'solid' line, but no 'facet' or 'vertex' lines) "
            f"nor a binary STL ({binary.removeprefix('not a binary STL (')}"
        )
    values = _numbers(b" ".join(tails))
    if values is None or len(values) != 3 * len(tails):
        number = next(i for i, t in enumerate(tails) if (v := _numbers(t)) is None or len(v) != 3)
        line = text.count(b"\n", 0, text.find(tails[number])) + 1
        raise FormatError(f"{path}: ASCII STL line {line} is not 'vertex x y z' (three numbers)")
    if len(tails) != 3 * facets:
        raise FormatError(
            f"{path}: an ASCII STL with {facets} facets but {len(tails)} vertices; "
            "each facet needs 3"
        )
    return values.reshape(-1, 3)
