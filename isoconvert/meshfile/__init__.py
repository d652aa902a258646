"""Reading mesh files (PLY, OBJ, OFF, STL, VTP, GLB, 3MF; VTU, VTK, MSH, ... through meshio).

Every format is read here, with the standard library and numpy only (VTK and
trimesh are test extras, never needed at run time), so that vertices and cells
come back exactly as the file holds them (the file's vertex indices, nothing
merged, reordered or dropped), so that a header's grid record and a bad vertex
index can be told, and so that a broken file is named for what is wrong with it.

Nothing is allocated or inflated past what the file can back: compressed VTP
blocks no further than their header declares, 3MF parts no further than their
ZIP entry declares and never more than 100 times their compressed size (above
16 MiB), counts in PLY, OFF, STL and GLB headers checked against the file's
size first. A decompression bomb is a one-line FormatError.

Every other surface format meshio reads (VTU, legacy VTK, Gmsh, XDMF, Abaqus,
Medit, MED, ...: :data:`MESHIO_SUFFIXES`) is read through meshio
(:mod:`.meshio`, imported only for those files).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import FormatError, InputNotFoundError, one_line
from ..mesh import Mesh
from .common import _Unreadable
from .glb import _read_glb
from .meshio import MESHIO_SUFFIXES, _read_meshio
from .obj import _read_obj
from .off import _read_off
from .ply import _read_ply
from .stl import _read_stl
from .threemf import _read_3mf
from .vtp import _read_vtp

__all__ = ["MESHIO_SUFFIXES", "MESH_SUFFIXES", "READ_SUFFIXES", "read_mesh"]

#: What isoconvert's own readers read.
MESH_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".vtp", ".glb", ".3mf")
#: Everything read_mesh reads: its own formats, then meshio's others.
READ_SUFFIXES = MESH_SUFFIXES + tuple(s for s in MESHIO_SUFFIXES if s not in MESH_SUFFIXES)

#: The reader of each suffix.
_READERS = {
    ".stl": _read_stl,
    ".ply": _read_ply,
    ".obj": _read_obj,
    ".off": _read_off,
    ".vtp": _read_vtp,
    ".glb": _read_glb,
    ".3mf": _read_3mf,
}


def read_mesh(path: str | Path, format: str | None = None) -> Mesh:
    """Read triangles, or contour segments, from a PLY, OBJ, OFF, STL, VTP, GLB or 3MF
    file, or any surface file meshio reads (:data:`MESHIO_SUFFIXES`).

    Vertices and cells come back as the file holds them: PLY, OBJ, OFF, VTP,
    GLB and 3MF with the file's vertex order and indices (polygons split into
    fans of triangles; several VTP pieces, glTF primitives or 3MF objects one
    after the other, placed by their node or build transforms), STL (binary,
    or ASCII) with three vertices per triangle; the report merges equal
    positions itself and says how many it merged.

    Parameters
    ----------
    path : str or Path
        A mesh file, or ``-``: standard input (``format`` then required).
    format : str or None
        The format by its usual extension (``ply``, ``stl``, ``vtu``, ...),
        instead of the file's suffix.

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
        ``grid``; ``cut_by_grid`` True when isoconvert wrote the file (its
        header, comments, extras, metadata or STL header say so), so that
        without a grid record the report may judge boundaries against the
        bounding box (:func:`isoconvert.check_mesh`).

    A meshio format's triangles (quads split in two), or its lines when it
    has no faces, come back in the file's order (:meth:`Mesh.from_meshio`),
    with ``stored_precision`` from its points' type.

    Raises
    ------
    InputNotFoundError
        No such file.
    FormatError
        Unknown suffix, unreadable file, no triangles or segments, or a cell
        that refers to a vertex that does not exist (the message names the
        cell and the index).
    """
    if str(path) == "-":
        return _read_stdin(format)
    path = Path(path)
    if path.is_dir():
        raise FormatError(
            f"{path} is a folder, not a mesh file; give a mesh file ({', '.join(READ_SUFFIXES)})"
        )
    if not path.is_file():
        raise InputNotFoundError(f"{path}: no such file")
    suffix = _format_suffix(path, format)
    if suffix not in READ_SUFFIXES:
        raise FormatError(
            f"{path}: unknown mesh extension {suffix or '(none)'!r}; "
            f"check reads {', '.join(READ_SUFFIXES)}"
        )
    if path.stat().st_size == 0:
        raise FormatError(f"{path}: the file is empty (0 bytes); nothing to check")
    reader = _READERS.get(suffix)
    try:
        return reader(path) if reader is not None else _read_meshio(path, suffix)
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


def _format_suffix(path: str | Path, format: str | None) -> str:
    """The suffix that picks the reader: ``format`` (``ply`` or ``.ply``), else the file's."""
    if format is None:
        return Path(path).suffix.lower()
    suffix = "." + format.lower().lstrip(".")
    if suffix not in READ_SUFFIXES:
        raise FormatError(
            f"{path}: unknown mesh format {format!r}; check reads "
            f"{', '.join(s[1:] for s in READ_SUFFIXES)}"
        )
    return suffix


def _read_stdin(format: str | None) -> Mesh:
    """A mesh piped to standard input: copied to a temporary file (the readers
    map and seek their files), read as ``format``, the file removed."""
    import os
    import shutil
    import sys
    import tempfile

    if not format:
        raise FormatError("-: standard input has no extension to tell the format; give --format")
    suffix = _format_suffix("-", format)
    with tempfile.TemporaryDirectory(prefix="isoconvert-stdin-") as folder:
        copy = Path(folder) / f"stdin{suffix}"
        with open(copy, "wb") as out:
            shutil.copyfileobj(sys.stdin.buffer, out, 1 << 20)
        if os.path.getsize(copy) == 0:
            raise FormatError("-: standard input is empty; nothing to check")
        mesh = read_mesh(copy)
    mesh.info["source"] = "-"
    return mesh
