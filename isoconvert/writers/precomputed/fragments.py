"""Draco fragments and the manifests that list them.

An object's levels, each a dict of octree node position to the node's quantized
vertices and triangles, become Draco fragments (:func:`encoded`), and those one
object's fragment data and its manifest (:func:`assemble`), as the multi-resolution
format of Neuroglancer's meshes.md lays them out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...errors import IsoconvertError, extra_hint
from ...mesh import Mesh
from .octree import cut_rows, level_frame, object_frame, one_node


def dracopy():
    """The DracoPy module; missing, the one line that says how to install it."""
    try:
        import DracoPy
    except ImportError:
        raise IsoconvertError(
            f"the precomputed format needs DracoPy: {extra_hint('precomputed')}"
        ) from None
    return DracoPy


def encode_levels(
    levels: list[Mesh], bits: int, draco, chunk: float | None = None, phase: float = 0.0
) -> tuple[bytes, bytes]:
    """One object's manifest and fragment data.

    The octree's finest nodes are ``chunk`` index units wide (cubes), their planes
    at ``phase`` of the voxel grid (:func:`.octree.object_frame`), or, when
    ``chunk`` is None or the object fits in one, the object's bounding box: then
    every level is a single fragment. Otherwise each level's mesh is cut at the
    planes of its nodes' 2x2x2 partition and its triangles go to the node holding
    their centroid, one row of nodes (along x) at a time (:func:`encoded_level`). The
    levels end at one with no fewer triangles, cut, than the one before.
    """
    lo = np.min([m.vertices.min(axis=0) for m in levels], axis=0)
    hi = np.max([m.vertices.max(axis=0) for m in levels], axis=0)
    grid_origin, shape, cut = object_frame(lo, hi, chunk, phase)
    octree = (grid_origin, shape, float(2**bits - 1), lo, hi, cut)
    nodes: list[dict[tuple[int, int, int], bytes]] = []
    previous = None
    for k, mesh in enumerate(levels):
        vertices, cells = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.cells, np.int64)
        level, triangles = encoded_level(vertices, cells, k, octree, bits, draco)
        if not levels_go_on(triangles, previous):
            break
        nodes.append(level)
        previous = triangles
    return assemble(nodes, shape, grid_origin)


def encoded_level(
    vertices: np.ndarray, cells: np.ndarray, k: int, octree: tuple, bits: int, draco
) -> tuple[dict[tuple[int, int, int], bytes], int]:
    """Level ``k`` of an object (index coordinates) as Draco fragments, and how many
    triangles they hold. ``octree`` is its grid origin, finest nodes' shape, ``top``,
    box and whether it is cut: cut, the level is cut a row of nodes at a time and
    each row encoded as it comes (:func:`.octree.cut_rows`: one row's pieces held,
    not the level's); else it lies in the first node (its box is the object's),
    one fragment, corners merged from level 1 on (:func:`.octree.one_node`)."""
    grid_origin, shape, top, lo, hi, cut = octree
    if cut:
        rows = cut_rows(vertices, cells, level_frame(grid_origin, shape, k, top, lo, hi))
    else:
        rows = [one_node(vertices, cells, grid_origin, shape * 2.0**k, top, merge=k > 0)]
    level: dict[tuple[int, int, int], bytes] = {}
    triangles = 0
    for row in rows:
        triangles += level_triangles(row)
        level.update(encoded(row, bits, draco))
    return level, triangles


def levels_go_on(triangles: int, previous: int | None) -> bool:
    """Whether a level of ``triangles``, as cut, is kept after one of ``previous``
    (None: it is level 0): one with no fewer triangles than the level before (a
    collapse that went no further within its bound) ends the levels, as does one
    whose corners all merged away (no fragment to draw)."""
    return previous is None or 0 < triangles < previous


def level_triangles(level: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]]) -> int:
    """How many triangles a level's fragments hold (:func:`.octree.cut_level`'s)."""
    return sum(len(cells) for _, cells in level.values())


def assemble(
    levels: list[dict[tuple[int, int, int], bytes]], shape: np.ndarray, grid_origin: np.ndarray
) -> tuple[bytes, bytes]:
    """The manifest and the fragment data of an object's levels, each a dict of
    node position to its Draco fragment (:func:`encoded`)."""
    # every node's parent is listed too (empty when the coarser level has no
    # triangles there), as the viewer walks the octree down from the top
    for k in range(len(levels) - 1):
        for x, y, z in list(levels[k]):
            levels[k + 1].setdefault((x // 2, y // 2, z // 2), b"")
    table, data = [], []
    for level in levels:
        positions = sorted(level, key=_morton)
        table.append((positions, [len(level[p]) for p in positions]))
        data.extend(level[p] for p in positions)
    return _manifest(shape, grid_origin, table), b"".join(data)


def encoded(level: dict, bits: int, draco) -> dict[tuple[int, int, int], bytes]:
    """A level's (or a row's) nodes' Draco fragments. A node whose triangles all
    merged away (a coarse level's speck, quantized to one position) has none,
    which Draco cannot encode: it is left out, and :func:`assemble` lists it empty
    where a finer node needs it as a parent."""
    top = float(2**bits - 1)
    return {
        position: _encode(draco, q, cells, bits, top)
        for position, (q, cells) in level.items()
        if len(cells)
    }


def _manifest(
    shape: np.ndarray, grid_origin: np.ndarray, levels: Sequence[tuple[Sequence, Sequence[int]]]
) -> bytes:
    """An object's manifest: its octree's finest nodes' ``shape`` and grid origin,
    and for each level its nodes' positions, in Z-curve order, with the sizes of
    their fragments."""
    parts = [
        shape.astype("<f4").tobytes(),
        grid_origin.astype("<f4").tobytes(),
        np.uint32(len(levels)).astype("<u4").tobytes(),
        np.array([2.0**k for k in range(len(levels))], "<f4").tobytes(),  # lod_scales
        np.zeros((len(levels), 3), "<f4").tobytes(),  # vertex_offsets
        np.array([len(positions) for positions, _ in levels], "<u4").tobytes(),
    ]
    for positions, sizes in levels:
        parts.append(np.array(positions, "<u4").reshape(-1, 3).T.copy().tobytes())
        parts.append(np.array(sizes, "<u4").tobytes())
    return b"".join(parts)


def _encode(draco, q: np.ndarray, cells: np.ndarray, bits: int, top: float) -> bytes:
    """One Draco fragment, by Draco's edgebreaker (about 5x smaller than its
    sequential encoding on the atlas's labels) when every vertex has a position of
    its own. The edgebreaker merges vertices quantized to one position and drops the
    triangles that become degenerate (a few on half of the atlas's labels, where
    smoothing brings vertices within a step): a fragment with such vertices is
    encoded in its own order instead, every triangle kept (cut fragments merged
    them already, see :func:`.octree.cut_level`)."""
    q = np.asarray(q)
    keys = (q[:, 0].astype(np.int64) << 32) | (q[:, 1].astype(np.int64) << 16) | q[:, 2]
    keys.sort()
    own_positions = not len(keys) or bool((keys[1:] != keys[:-1]).all())
    return draco.encode(
        q,
        cells,
        quantization_bits=bits,
        quantization_range=top,
        quantization_origin=[0.0, 0.0, 0.0],
        compression_level=7,
        preserve_order=not own_positions,
    )


def _morton(position: tuple[int, int, int]) -> int:
    """The Z-curve key of an octree node, x in the lowest bit (meshes.md)."""
    key = 0
    for bit in range(21):
        for axis in range(3):
            key |= ((position[axis] >> bit) & 1) << (3 * bit + axis)
    return key
