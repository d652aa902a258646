"""An object's level of detail as a layer stores it, read back from its files:
what ``convert --report`` checks and the "wrote" line counts for a layer, since
a cut level can hold fewer triangles than the mesh it was made from (corners
quantized to one position within a fragment merge, :func:`.octree.cut_level`).

Fragments meet only by position: their vertices are joined where their
quantized positions, in the level's whole grid of steps, are equal (exact
integers, as the writer snaps both sides of a seam to the same steps).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .shards import manifest_range


def stored_level(
    folder: str | Path, segment: int, lod: int = 0
) -> tuple[np.ndarray, np.ndarray] | None:
    """Level ``lod`` of ``segment`` in the multi-resolution layer ``folder``
    (sharded or not), or None for a legacy layer (whose fragments hold every
    triangle of the mesh, unquantized).

    Returns
    -------
    vertices : (V, 3) float64
        Index coordinates (the volume's sample (i, j, k) at (i, j, k)).
    cells : (C, 3) int64
    """
    level = _fragments(folder, segment, lod)
    if level is None:
        return None
    grid_origin, step, pieces = level
    steps, cells, base = [], [], 0
    for q, faces in pieces:
        steps.append(q)
        cells.append(faces + base)
        base += len(q)
    if not steps:
        return np.empty((0, 3)), np.empty((0, 3), np.int64)
    joined, where = _joined(np.concatenate(steps))
    return grid_origin + joined * step, where[np.concatenate(cells)]


def stored_counts(folder: str | Path, segment: int, lod: int = 0) -> tuple[int, int] | None:
    """How many vertices and triangles :func:`stored_level` gives, a fragment
    decoded at a time (the level itself is not built); None for a legacy layer."""
    level = _fragments(folder, segment, lod)
    if level is None:
        return None
    keys, triangles = [], 0
    for q, faces in level[2]:
        keys.append(q)
        triangles += len(faces)
    if not keys:
        return 0, 0
    return len(_joined(np.concatenate(keys))[0]), triangles


def _joined(steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``steps`` ((N, 3) int64, >= 0) and each row's index
    among them: by one int64 key a row where the grid of steps allows (always
    but for objects of some 2^21 steps a side), else row by row."""
    if not len(steps):
        return steps, np.empty(0, np.int64)
    span = steps.max(axis=0) + 1
    if float(np.prod(span.astype(np.float64))) >= 2.0**62:
        joined, where = np.unique(steps, axis=0, return_inverse=True)
        return joined, where.reshape(-1)  # (N, 1) in some numpy versions
    keys = (steps[:, 0] * span[1] + steps[:, 1]) * span[2] + steps[:, 2]
    distinct, where = np.unique(keys, return_inverse=True)
    x, rest = np.divmod(distinct, span[1] * span[2])
    y, z = np.divmod(rest, span[2])
    return np.stack([x, y, z], axis=1), where.reshape(-1)


def _fragments(folder: str | Path, segment: int, lod: int):
    """Level ``lod``'s grid origin and step (index units per quantization step),
    and its fragments decoded one at a time, each as its vertices' positions in
    the level's whole grid of steps ((n, 3) int64) and its triangles ((m, 3)
    int64); None for a legacy layer."""
    from .fragments import dracopy

    mesh_folder = Path(folder) / "mesh"
    info = json.loads((mesh_folder / "info").read_text(encoding="utf-8"))
    if info.get("@type") != "neuroglancer_multilod_draco":
        return None
    manifest, data = _object_bytes(mesh_folder, segment, info.get("sharding"))
    top = 2 ** int(info["vertex_quantization_bits"]) - 1
    shape, grid_origin, positions, sizes = _parse_manifest(manifest)
    start = int(sum(int(s.sum()) for s in sizes[:lod]))
    draco = dracopy()

    def pieces():
        at = start
        for position, size in zip(positions[lod], sizes[lod], strict=True):
            if size:
                piece = draco.decode(data[at : at + int(size)])
                q = np.rint(np.asarray(piece.points, dtype=np.float64)).astype(np.int64)
                faces = np.asarray(piece.faces, dtype=np.int64).reshape(-1, 3)
                yield q.reshape(-1, 3) + position.astype(np.int64) * top, faces
            at += int(size)

    return grid_origin, shape * 2.0**lod / top, pieces()


def _parse_manifest(manifest: bytes):
    """The manifest's finest node shape and grid origin (float64), and each
    level's fragment positions ((F, 3) uint32) and sizes ((F,) uint32)."""
    shape = np.frombuffer(manifest, "<f4", 3, 0).astype(np.float64)
    grid_origin = np.frombuffer(manifest, "<f4", 3, 12).astype(np.float64)
    (n,) = np.frombuffer(manifest, "<u4", 1, 24)
    at = 28 + 4 * n + 12 * n  # past the scales and the vertex offsets
    counts = np.frombuffer(manifest, "<u4", n, at)
    at += 4 * n
    positions, sizes = [], []
    for k in range(n):
        f = int(counts[k])
        positions.append(np.frombuffer(manifest, "<u4", 3 * f, at).reshape(3, f).T)
        at += 12 * f
        sizes.append(np.frombuffer(manifest, "<u4", f, at))
        at += 4 * f
    return shape, grid_origin, positions, sizes


def _object_bytes(mesh_folder: Path, segment: int, spec: dict | None) -> tuple[bytes, bytes]:
    """An object's manifest and fragment data: its two files, or the ranges of its
    shard that hold them (its fragment data just before its manifest,
    :func:`.shards.manifest_range`), not the whole shard."""
    if spec is None:
        manifest = (mesh_folder / f"{segment}.index").read_bytes()
        return manifest, (mesh_folder / str(segment)).read_bytes()
    path, start, size = manifest_range(mesh_folder, segment, spec)
    with open(path, "rb") as shard:
        shard.seek(start)
        manifest = shard.read(size)
        data_size = int(sum(int(s.sum()) for s in _parse_manifest(manifest)[3]))
        shard.seek(start - data_size)
        return manifest, shard.read(data_size)
