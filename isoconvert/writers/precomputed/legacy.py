"""The legacy single-resolution mesh format (``neuroglancer_legacy_mesh``), for
tools that read no other: per object a JSON manifest ``<id>:0`` naming one
fragment ``<id>:0:0`` (the vertex count, float32 nanometres, uint32 triangles)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...errors import IsoconvertError
from ...mesh import Mesh


def check_legacy(legacy: bool, lods: int, chunk: float | str | None, sharded: bool) -> None:
    """Refuse what the legacy format cannot hold (``chunk`` None or "auto": not given)."""
    if legacy and (lods > 1 or chunk not in (None, "auto") or sharded):
        raise IsoconvertError(
            "precomputed: the legacy mesh format has one level of detail, one fragment per "
            "object and no shards: leave out --lods, --fragment-size and --sharded with it"
        )


def write_legacy(
    folder: Path,
    segment: int,
    mesh: Mesh,
    origin: np.ndarray,
    inverse: np.ndarray,
    transform: np.ndarray,
) -> None:
    """One object in the legacy format: its manifest ``<id>:0`` and its one fragment
    ``<id>:0:0`` (vertex count, float32 nanometres in the layer's frame, uint32
    triangles, all little-endian)."""
    index = (np.asarray(mesh.vertices, dtype=np.float64) - origin) @ inverse.T
    nm = index @ transform[:, :3].T + transform[:, 3]
    fragment = f"{segment}:0:0"
    manifest = json.dumps({"fragments": [fragment]}, indent=1) + "\n"
    (folder / f"{segment}:0").write_text(manifest, encoding="utf-8")
    (folder / fragment).write_bytes(
        b"".join(
            [
                np.uint32(len(nm)).astype("<u4").tobytes(),
                nm.astype("<f4").tobytes(),
                np.asarray(mesh.cells).astype("<u4").tobytes(),
            ]
        )
    )
