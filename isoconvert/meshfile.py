"""Reading mesh files (OBJ, PLY, STL) for ``isoconvert check``, via trimesh."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import FormatError, InputNotFoundError, one_line
from .mesh import Mesh

MESH_SUFFIXES = (".obj", ".ply", ".stl")


def read_mesh(path: str | Path) -> Mesh:
    """Read triangles, or contour segments, from an OBJ, PLY or STL file.

    Vertices and cells come back as the file holds them (trimesh with
    ``process=False``): nothing is merged, reordered or dropped, so indices in a
    report are the file's. STL stores three vertices per triangle; the report
    merges equal positions itself and says how many it merged. OBJ line
    elements (``l``), which trimesh and meshio skip, are read here. PLY edges
    come through trimesh, which joins them into polylines, so their order may
    differ from the file's (vertex indices do not).

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` and ``cells (C, 3)`` or ``(C, 2)`` int64.
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
    import trimesh

    try:
        kwargs = {"maintain_order": True} if suffix == ".obj" else {}
        loaded = trimesh.load(str(path), process=False, **kwargs)
    except Exception as exc:  # trimesh raises many kinds for a broken file
        raise FormatError(
            f"{path}: not a readable {suffix[1:].upper()} mesh ({one_line(exc)})"
        ) from None
    if isinstance(loaded, trimesh.Scene):
        geometry = list(loaded.geometry.values())
        meshes = [g for g in geometry if isinstance(g, trimesh.Trimesh)]
        if meshes:
            loaded = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        elif geometry:
            loaded = geometry[0]
    info = {"source": str(path)}
    if isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        return Mesh(
            np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces, np.int64), info=info
        )
    if isinstance(loaded, (trimesh.path.Path2D, trimesh.path.Path3D)):
        vertices = np.asarray(loaded.vertices, np.float64)
        if vertices.shape[1] == 2:
            vertices = np.column_stack([vertices, np.zeros(len(vertices))])
        segs = [np.column_stack([e.points[:-1], e.points[1:]]) for e in loaded.entities]
        cells = np.concatenate(segs) if segs else np.zeros((0, 2), np.int64)
        return Mesh(vertices, cells.astype(np.int64), info=info)
    if suffix == ".obj":
        return _obj_lines(path, info)
    raise FormatError(f"{path}: holds no triangles or segments")


def _obj_lines(path: Path, info: dict) -> Mesh:
    """Vertices and ``l`` polylines of an OBJ file, as segments."""
    vertices, segments = [], []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v" and len(parts) >= 4:
                vertices.append([float(x) for x in parts[1:4]])
            elif parts[0] == "l" and len(parts) >= 3:
                # indices are 1-based, negative ones count back from the last vertex
                ids = [int(p.split("/")[0]) for p in parts[1:]]
                ids = [i - 1 if i > 0 else len(vertices) + i for i in ids]
                segments.extend(zip(ids[:-1], ids[1:], strict=True))
    if not segments:
        raise FormatError(f"{path}: holds no triangles or segments")
    cells = np.asarray(segments, dtype=np.int64)
    if cells.min() < 0 or cells.max() >= len(vertices):
        raise FormatError(f"{path}: a line refers to a vertex that does not exist")
    return Mesh(np.asarray(vertices, np.float64).reshape(-1, 3), cells, info=info)
