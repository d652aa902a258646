"""STL, read by trimesh: STL has no vertex indices to keep."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, one_line
from ..mesh import Mesh
from .common import _as_stored


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
