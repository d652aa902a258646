"""What storing vertex coordinates as float32 would lose.

PLY and STL have stored float32 coordinates. Far from the origin (scanner or
geographic coordinates) or where vertices lie very close together, rounding
to float32 merges distinct vertices and makes triangles degenerate that were
not. :func:`float32_loss` counts both, with the project's one definition of a
degenerate triangle (:mod:`isoconvert.geometry`: a repeated position, or flat).

Speed: the shared predicate gathers every triangle's corners twice over and
would cost seconds on millions of triangles. It is evaluated only on the few
triangles whose verdict float32 rounding could change; a cheaper bound, applied
block by block, proves the others safe (see :func:`_candidates`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import flat_triangles, triangle_cross
from ..graph import mix64, row_groups

#: Unit roundoff of float32: rounding moves a normal value by at most this, relatively.
_U32 = 2.0**-24
#: Absolute rounding error bound below float32's normal range (half the smallest subnormal is
#: 2**-150; twice that for margin).
_TINY32 = 2.0**-149
_EPS64 = float(np.finfo(np.float64).eps)
#: Triangles per block of the bound: small enough that the temporaries stay in cache.
_BLOCK = 1 << 16


@dataclass(frozen=True)
class Float32Loss:
    """What float32 vertex coordinates would lose against float64.

    Attributes
    ----------
    merged_vertices : int
        Distinct float64 positions minus distinct float32 positions: how many
        vertices would coincide with another one.
    degenerate_cells : int or None
        Triangles (or segments) not degenerate in float64 that would be in
        float32; None when not counted (see ``count_degenerate``).
    overflow_vertices : int
        Finite vertices with a coordinate beyond float32's range (it would
        become infinite).
    """

    merged_vertices: int = 0
    degenerate_cells: int | None = 0
    overflow_vertices: int = 0

    @property
    def any(self) -> bool:
        """Whether float32 loses anything at all."""
        return bool(self.merged_vertices or self.degenerate_cells or self.overflow_vertices)

    def describe(self, kind: str = "triangles") -> str:
        """The loss as words, e.g. ``"152 vertices merge and 80 triangles become degenerate"``."""
        parts = []
        if self.overflow_vertices:
            parts.append(f"{self.overflow_vertices:,} vertices exceed its range")
        if self.merged_vertices:
            parts.append(f"{self.merged_vertices:,} vertices merge")
        if self.degenerate_cells:
            parts.append(f"{self.degenerate_cells:,} {kind} become degenerate")
        return " and ".join(parts) or "nothing is lost"


def float32_loss(
    vertices: np.ndarray, cells: np.ndarray, *, count_degenerate: bool = True
) -> Float32Loss:
    """Count what rounding ``vertices`` to float32 would merge or make degenerate.

    Parameters
    ----------
    vertices : (V, 3) float
        Positions as they are (float64).
    cells : (C, 3) or (C, 2) int
        Triangles or segments; indices must be valid.
    count_degenerate : bool
        When False and vertices already merge (or overflow), the degenerate
        cells are not counted (``degenerate_cells`` is None): the answer to
        "does float32 lose anything?" is known, and counting is the costly part.

    Returns
    -------
    Float32Loss
        A triangle counts as made degenerate when it is not degenerate with the
        float64 positions and is with the float32 ones (a repeated position or
        flat, :func:`isoconvert.geometry.flat_triangles`); a segment when its
        two ends are distinct in float64 and equal in float32.
    """
    v64 = np.asarray(vertices, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64)
    with np.errstate(over="ignore", invalid="ignore"):
        v32 = v64.astype(np.float32)
    if not (v32 != v64).any():  # already float32 values (or NaN, which rounding keeps)
        return Float32Loss()
    overflow = int((np.isfinite(v64).all(axis=1) & ~np.isfinite(v32).all(axis=1)).sum())
    merged, group = _merges(v64, v32)
    if not count_degenerate and (merged or overflow):
        return Float32Loss(merged, None, overflow)
    if cells.shape[1] == 2:
        degenerate = 0
        if group is not None:
            a, b = cells[:, 0], cells[:, 1]
            degenerate = int(((group[a] == group[b]) & (v64[a] != v64[b]).any(axis=1)).sum())
        return Float32Loss(merged, degenerate, overflow)
    r32 = v32.astype(np.float64)
    candidates = _candidates(v64, cells, group)
    degenerate = 0
    for start in range(0, len(candidates), _BLOCK):
        sub = cells[candidates[start : start + _BLOCK]]
        degenerate += int((_degenerate(r32, sub) & ~_degenerate(v64, sub)).sum())
    return Float32Loss(merged, degenerate, overflow)


def _merges(v64: np.ndarray, v32: np.ndarray) -> tuple[int, np.ndarray | None]:
    """How many distinct float64 positions float32 merges, and (when it merges
    any) the float32 position group of each vertex, (V,) int64."""
    n = len(v64)
    if n < 2:
        return 0, None
    bits = (v32 + np.float32(0.0)).view(np.uint32).astype(np.uint64)  # -0.0 -> 0.0
    packed = np.column_stack([(bits[:, 0] << np.uint64(32)) | bits[:, 1], bits[:, 2]])
    # fast answer for the usual case: no two float32 positions share even a hash
    hashes = np.sort(mix64(packed[:, 0] ^ mix64(packed[:, 1])))
    if not (hashes[1:] == hashes[:-1]).any():
        return 0, None
    order, new = row_groups(packed)
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, n))
    if not (sizes > 1).any():
        return 0, None
    # only vertices sharing a float32 position can be distinct float64 positions that merge
    members = order[np.repeat(sizes > 1, sizes)]
    _, distinct = row_groups(v64[members] + 0.0)
    merged = int(distinct.sum()) - int((sizes > 1).sum())
    if merged == 0:
        return 0, None
    group = np.empty(n, dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return merged, group


def _degenerate(vertices: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(C,) bool: the shared definition, a repeated position or flat."""
    p = vertices[cells]  # (C, 3, 3)
    repeated = (
        (p[:, 0] == p[:, 1]).all(axis=1)
        | (p[:, 1] == p[:, 2]).all(axis=1)
        | (p[:, 0] == p[:, 2]).all(axis=1)
    )
    return repeated | flat_triangles(vertices, cells, triangle_cross(vertices, cells))


def _candidates(v64: np.ndarray, cells: np.ndarray, group: np.ndarray | None) -> np.ndarray:
    """Indices (K,) of the triangles whose degeneracy float32 rounding could change.

    Every other triangle is provably as (non-)degenerate in float32 as in
    float64. Rounding moves each coordinate by at most ``s = u m + tiny`` (``u``
    = 2**-24, ``m`` the triangle's largest absolute coordinate), each corner by
    ``d <= sqrt(3) s < 2 s``, each edge vector by ``2 d``. So the cross product
    of two edge vectors (norm twice the area) moves by at most ``4 d l + 4 d**2``
    (``l`` the longest edge, at most twice the longer of the two edges from
    corner 0), and the computed ones by a few float64 rounding units of
    ``m l`` more. A triangle flat in float32 has ``|cross32| <= 8 eps m32 l32``
    (:func:`~isoconvert.geometry.flat_triangles`), hence ``|cross64| <= 40 eps
    (m + s)(l + 4 s) + 8 l s + 16 s**2``; twice that, with 64 for 40, is the
    bound used. A repeated float32 position needs two corners in one float32
    position group (``group``).
    """
    vx, vy, vz = (np.ascontiguousarray(v64[:, k]) for k in range(3))
    vmax = np.abs(v64).max(axis=1)
    keep = [np.zeros(0, dtype=np.int64)]
    for start in range(0, len(cells), _BLOCK):
        c = cells[start : start + _BLOCK]
        i0, i1, i2 = c[:, 0], c[:, 1], c[:, 2]
        x0, y0, z0 = vx[i0], vy[i0], vz[i0]
        ax, ay, az = vx[i1] - x0, vy[i1] - y0, vz[i1] - z0
        bx, by, bz = vx[i2] - x0, vy[i2] - y0, vz[i2] - z0
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        cross2 = cx * cx + cy * cy + cz * cz
        longer = np.maximum(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz)
        longest = 2.0 * np.sqrt(longer)
        m = np.maximum(np.maximum(vmax[i0], vmax[i1]), vmax[i2])
        s = _U32 * m + _TINY32
        rounding = 64.0 * _EPS64 * (m + s) * (longest + 4.0 * s)
        bound = 2.0 * (rounding + 8.0 * longest * s + 16.0 * s * s)
        near = cross2 <= bound * bound
        if group is not None:
            g0, g1, g2 = group[i0], group[i1], group[i2]
            near |= (g0 == g1) | (g1 == g2) | (g0 == g2)
        keep.append(np.flatnonzero(near) + start)
    return np.concatenate(keep)
