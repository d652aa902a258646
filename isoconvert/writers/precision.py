"""What storing vertex coordinates as float32 would lose.

PLY and STL have stored float32 coordinates. Far from the origin (scanner or
geographic coordinates) or where vertices lie very close together, rounding
to float32 merges distinct vertices and makes triangles degenerate that were
not. :func:`float32_loss` counts both, with the project's one definition of a
degenerate triangle (:mod:`isoconvert.geometry`: a repeated position, or flat).

Speed: the shared predicate gathers every triangle's corners twice over and
would cost seconds on millions of triangles. A compiled pass first finds the
vertices rounding moves at all (on a label mesh, the few split vertices); only
they, the vertices where they land and the triangles they touch are tested. Of
those triangles, the predicate sees only the few whose verdict rounding could
change; a cheaper bound proves the others safe (see :func:`_candidates`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import flat_triangles, triangle_cross
from ..graph import merge_positions
from ..threads import kernel_threads

#: Candidate triangles per block of the exact test: small enough that the temporaries stay in cache.
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
    from .. import _native

    v64 = np.ascontiguousarray(vertices, dtype=np.float64)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    # Rounding changes only the "moved" vertices: only they can merge, overflow or
    # turn a cell degenerate, so the exact tests below see them, the vertices that
    # stay where one of them lands, and the cells with a moved corner. On a label
    # mesh that is the few split vertices of thousands.
    some, touched = _native.moved_by_float32(v64, cells)
    if len(some) == 0:  # already float32 values
        return Float32Loss()
    sub64 = v64[some]
    with np.errstate(over="ignore", invalid="ignore"):
        sub32 = sub64.astype(np.float32).astype(np.float64)
    overflow = int((np.isfinite(sub64).all(axis=1) & ~np.isfinite(sub32).all(axis=1)).sum())
    merged, group = _merges(sub64, sub32, some, len(v64))
    if not count_degenerate and (merged or overflow):
        return Float32Loss(merged, None, overflow)
    cells = cells[touched]  # every other cell keeps its corners, so its verdict
    if cells.shape[1] == 2:
        degenerate = 0
        if group is not None:
            a, b = cells[:, 0], cells[:, 1]
            degenerate = int(((group[a] == group[b]) & (v64[a] != v64[b]).any(axis=1)).sum())
        return Float32Loss(merged, degenerate, overflow)
    candidates = cells[_candidates(v64, cells, group)]
    if not len(candidates):
        return Float32Loss(merged, 0, overflow)
    with np.errstate(over="ignore", invalid="ignore"):
        r32 = v64.astype(np.float32).astype(np.float64)
    degenerate = 0
    for start in range(0, len(candidates), _BLOCK):
        sub = candidates[start : start + _BLOCK]
        degenerate += int((_degenerate(r32, sub) & ~_degenerate(v64, sub)).sum())
    return Float32Loss(merged, degenerate, overflow)


def _merges(
    sub64: np.ndarray, sub32: np.ndarray, some: np.ndarray, n_vertices: int
) -> tuple[int, np.ndarray | None]:
    """How many distinct float64 positions float32 merges, and (when it merges
    any) the float32 position group of each vertex, (V,) int64: the distinct
    positions counted by the report's compiled hash kernel
    (:func:`isoconvert.graph.merge_positions`), -0.0 and 0.0 as one.

    Only the vertices ``some`` need counting: every float32 position that holds
    two float64 ones holds a moved vertex, and ``some`` has all the vertices at
    such a position (a vertex elsewhere stays its own group, alone or with
    vertices at the same float64 position).

    Parameters
    ----------
    sub64 : (K, 3) float64
        The positions of the vertices ``some``.
    sub32 : (K, 3) float64
        ``sub64`` rounded to float32.
    some : (K,) int64
        Their indices among the mesh's ``n_vertices``, ascending.
    """
    if len(sub64) < 2:
        return 0, None
    rounded = merge_positions(sub32, dtype=np.int64)
    if rounded.unique == len(sub64):  # the usual case: every float32 position distinct
        return 0, None
    merged = merge_positions(sub64, dtype=np.int64).unique - rounded.unique
    if not merged:
        return 0, None
    group = np.arange(n_vertices, dtype=np.int64)
    group[some] = some[rounded.rep]
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
    position group (``group``). Evaluated per triangle by the compiled
    ``float32_candidates`` (src/precision.cpp), in this arithmetic and order.
    """
    from .. import _native

    none = np.zeros(0, dtype=np.int64)
    return _native.float32_candidates(
        np.ascontiguousarray(v64),
        np.ascontiguousarray(cells, dtype=np.int64),
        none if group is None else np.ascontiguousarray(group, dtype=np.int64),
        kernel_threads(),
    )
