"""Geometric predicates shared by the report and the writers.

One definition of "degenerate" for everything that judges a mesh: the report,
and the writers deciding whether a lower precision would make new degenerate
triangles.
"""

from __future__ import annotations

import numpy as np

#: A triangle is flat when twice its area is at most this many float64 rounding
#: units of the cross product computed from its coordinates (see :func:`flat_triangles`).
FLAT_ROUNDING_UNITS = 8.0


def triangle_cross(vertices: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Cross products ``(p1 - p0) x (p2 - p0)`` of each triangle.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int

    Returns
    -------
    (C, 3) float64
        Their norms are twice the triangles' areas; their directions the
        right-hand normals.
    """
    v = np.asarray(vertices, dtype=np.float64)
    out = np.empty((len(cells), 3))
    # a block of triangles at a time: the corners and edges of all of them at
    # once were five times the result (a large mesh's decimation peaked there)
    for start in range(0, len(cells), _CROSS_BLOCK):
        block = cells[start : start + _CROSS_BLOCK]
        p0 = v[block[:, 0]]
        out[start : start + len(block)] = np.cross(v[block[:, 1]] - p0, v[block[:, 2]] - p0)
    return out


#: Triangles whose cross products :func:`triangle_cross` computes at once.
_CROSS_BLOCK = 1 << 16


def flat_triangles(vertices: np.ndarray, cells: np.ndarray, cross: np.ndarray) -> np.ndarray:
    """Triangles whose area is zero within the rounding error of their coordinates.

    The cross product of two edge vectors is computed from coordinates of
    magnitude up to ``m`` (the triangle's largest absolute coordinate), so its
    rounding error is about ``eps * m * l`` (``l`` its longest edge, ``eps`` the
    float64 machine epsilon). A triangle is flat when ``|cross| <= k * eps * m * l``
    with ``k`` = :data:`FLAT_ROUNDING_UNITS`: an exactly collinear triangle, or a
    sliver of area 1e-18 on a unit-size mesh, is flat; a small but well-formed
    triangle far from the origin is not. The test is scale-free: scaling a mesh
    does not change which triangles are flat.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int
    cross : (C, 3) float64
        From :func:`triangle_cross`.

    Returns
    -------
    (C,) bool
    """
    norm = np.linalg.norm(cross, axis=1)
    # Triangles above the coarse bound are not flat; the exact bound is
    # computed only for the rest (usually almost none).
    candidates = np.flatnonzero(~(norm > flat_bound(vertices)))
    flat = np.zeros(len(cells), dtype=bool)
    if len(candidates):
        flat[candidates] = flat_among(vertices, np.asarray(cells)[candidates], norm[candidates])
    return flat


def flat_bound(vertices: np.ndarray, magnitude: float | None = None) -> float:
    """A ``|cross|`` above which no triangle of ``vertices`` is flat.

    The bound of :func:`flat_triangles` is at most ``k * eps * M * 2 sqrt(3) M``
    for ``M`` the largest finite absolute coordinate (``m <= M``, and no edge is
    longer than the diagonal of ``[-M, M]^3``); this is that, with a margin.

    Parameters
    ----------
    vertices : (V, 3) float64
    magnitude : float, optional
        ``M`` when the caller knows it (:func:`isoconvert.graph.merge_positions`
        finds it); else it is computed from ``vertices``.
    """
    if magnitude is not None:
        big = float(magnitude)
    else:
        v = np.asarray(vertices, dtype=np.float64)
        if v.size == 0:
            big = 0.0
        elif np.isfinite(v).all():  # the usual case, without a masked copy
            big = float(max(v.max(), -v.min()))
        else:
            finite = np.isfinite(v)
            big = float(np.abs(v[finite]).max()) if finite.any() else 0.0
    coarse = FLAT_ROUNDING_UNITS * np.finfo(np.float64).eps * big * (2.0 * np.sqrt(3.0) * big)
    return coarse * (1.0 + 1e-9)


def flat_among(vertices: np.ndarray, cells: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """The exact test of :func:`flat_triangles`, for a few triangles.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (K, 3) int
    norm : (K,) float64
        ``|cross|`` of each triangle (:func:`triangle_cross`).

    Returns
    -------
    (K,) bool
    """
    corners = np.asarray(vertices, dtype=np.float64)[cells]  # (K, 3, 3)
    magnitude = np.abs(corners).max(axis=(1, 2))
    edges = corners - np.roll(corners, -1, axis=1)
    longest = np.sqrt((edges**2).sum(axis=2).max(axis=1))
    bound = FLAT_ROUNDING_UNITS * np.finfo(np.float64).eps * magnitude * longest
    return norm <= bound


def normalized_grid(grid: object) -> dict | None:
    """A volume's grid as meshes record it (``info["grid"]``, a file header), or
    None when ``grid`` is not a usable one.

    Parameters
    ----------
    grid : object
        ``{"shape": (nd,) int, "origin": (nd,) float, "affine": (nd, nd) float}``
        with nd 2 or 3, whole sizes >= 1, finite numbers and an invertible affine.

    Returns
    -------
    dict or None
        Plain lists of Python ints and floats (``shape``, ``origin``,
        ``affine``), so that JSON gives it back exactly.
    """
    if not isinstance(grid, dict):
        return None
    try:
        sizes = np.asarray(grid["shape"], dtype=np.float64)
        origin = np.asarray(grid["origin"], dtype=np.float64)
        affine = np.asarray(grid["affine"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return None
    nd = sizes.size
    if (
        sizes.shape != (nd,)
        or nd not in (2, 3)
        or any(isinstance(n, bool) for n in grid["shape"])
        or not (np.isfinite(sizes).all() and (sizes >= 1).all() and (sizes % 1 == 0).all())
        or origin.shape != (nd,)
        or affine.shape != (nd, nd)
        or not (np.isfinite(origin).all() and np.isfinite(affine).all())
    ):
        return None
    if abs(np.linalg.det(affine)) <= 1e-12 * max(float(np.abs(affine).max()), 1e-300) ** nd:
        return None
    return {"shape": [int(n) for n in sizes], "origin": origin.tolist(), "affine": affine.tolist()}
