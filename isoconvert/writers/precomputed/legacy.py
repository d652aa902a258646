"""The legacy single-resolution mesh format (``neuroglancer_legacy_mesh``), for
tools that read no other: per object a JSON manifest ``<id>:0`` naming one
fragment ``<id>:0:0`` (the vertex count, float32 nanometres, uint32 triangles)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ...errors import IsoconvertError
from ...memory import row_chunks
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
    triangles, all little-endian), written a block of rows at a time: with a whole
    copy of the mesh in each of those forms, the 1.5 M-triangle ball's layer within
    ``--max-memory 256M`` peaked at 295 MB, written so at 202 MB."""
    fragment = f"{segment}:0:0"
    manifest = json.dumps({"fragments": [fragment]}, indent=1) + "\n"
    (folder / f"{segment}:0").write_text(manifest, encoding="utf-8")
    # index = inverse @ (world - origin), then the layer's affine, each point by the
    # same operations whatever the block (no matrix product's kernel)
    to_nm = transform[:, :3] @ inverse
    shift = transform[:, 3]
    with open(folder / fragment, "wb") as out:
        out.write(np.uint32(len(mesh.vertices)).astype("<u4").tobytes())
        for block in row_chunks(np.asarray(mesh.vertices)):
            d = np.asarray(block, dtype=np.float64) - origin
            nm = d[:, 0:1] * to_nm[:, 0] + d[:, 1:2] * to_nm[:, 1] + d[:, 2:3] * to_nm[:, 2]
            out.write((nm + shift).astype("<f4").tobytes())
        for block in row_chunks(np.asarray(mesh.cells)):
            out.write(block.astype("<u4").tobytes())
