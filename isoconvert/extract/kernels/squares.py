"""Marching Squares kernels over one C-ordered (rows, cols) = (v, u) image.

:func:`count_squares` sizes the output, :func:`fill_squares` writes it. Vertex
numbers come from per-image maps from bipolar grid edges to vertex indices, so
neighbouring squares share vertices by construction.

Ambiguity codes: 0 separate positive corners, 1 separate negative corners,
2 asymptotic decider (the bilinear interpolant's saddle value decides, per
square; book section 2.2.5).
"""

import numpy as np
from numba import njit

from .interpolate import edge_fraction


@njit(cache=True, nogil=True)
def count_squares(f, level, n_segments):
    """Number of bipolar grid edges (vertices) and segments of image ``f``."""
    ny, nx = f.shape
    n_vert = 0
    n_seg = 0
    for j in range(ny):
        for i in range(nx):
            p = f[j, i] >= level
            if i + 1 < nx and p != (f[j, i + 1] >= level):
                n_vert += 1
            if j + 1 < ny and p != (f[j + 1, i] >= level):
                n_vert += 1
            if i + 1 < nx and j + 1 < ny:
                case = (
                    p
                    | ((f[j, i + 1] >= level) << 1)
                    | ((f[j + 1, i] >= level) << 2)
                    | ((f[j + 1, i + 1] >= level) << 3)
                )
                n_seg += n_segments[case]
    return n_vert, n_seg


@njit(cache=True, nogil=True)
def fill_squares(
    f, level, offset, ambiguity, n_segments, segments, verts, edge_ids, segs, xmap, ymap
):
    """Write vertices (u, v index coordinates), their edge ids and segments.

    Parameters
    ----------
    f : (V, U) array
        The image; a grid vertex is positive when its value is >= ``level``.
    level : float
    offset : float
        Minimum distance of vertices from edge ends, as a fraction of the edge.
    ambiguity : int
        0, 1 or 2, see the module docstring.
    n_segments : (16,) int64
        Segments per configuration (the same for both rules).
    segments : (2, 16, 2, 2) int64
        Square-edge indices of segments, for rule 0 and rule 1.
    verts : (V, 2) float64
        Out: (u, v) positions.
    edge_ids : (V,) int64
        Out: ``2 * (u + U * v) + axis`` of each vertex's grid edge.
    segs : (C, 2) int64
        Out: segments as vertex indices, positive side on the left.
    xmap, ymap : (V, U) int64
        Scratch: vertex index of the x- and y-edge starting at each grid vertex.
    """
    ny, nx = f.shape
    n = 0
    for j in range(ny):
        for i in range(nx):
            s0 = np.float64(f[j, i])
            p0 = s0 >= level
            if i + 1 < nx:
                s1 = np.float64(f[j, i + 1])
                if p0 != (s1 >= level):
                    verts[n, 0] = i + edge_fraction(s0, s1, level, offset)
                    verts[n, 1] = j
                    edge_ids[n] = 2 * (i + nx * j)
                    xmap[j, i] = n
                    n += 1
            if j + 1 < ny:
                s1 = np.float64(f[j + 1, i])
                if p0 != (s1 >= level):
                    verts[n, 0] = i
                    verts[n, 1] = j + edge_fraction(s0, s1, level, offset)
                    edge_ids[n] = 2 * (i + nx * j) + 1
                    ymap[j, i] = n
                    n += 1
    m = 0
    for j in range(ny - 1):
        for i in range(nx - 1):
            f0 = np.float64(f[j, i])
            f1 = np.float64(f[j, i + 1])
            f2 = np.float64(f[j + 1, i])
            f3 = np.float64(f[j + 1, i + 1])
            case = (
                (f0 >= level) | ((f1 >= level) << 1) | ((f2 >= level) << 2) | ((f3 >= level) << 3)
            )
            count = n_segments[case]
            if count == 0:
                continue
            rule = ambiguity
            if rule == 2:
                rule = 0
                if case == 6 or case == 9:
                    # saddle of the bilinear interpolant; at or above the level the
                    # positive corners are joined through the centre
                    saddle = (f0 * f3 - f1 * f2) / (f0 + f3 - f1 - f2)
                    if saddle >= level:
                        rule = 1
            for s in range(count):
                for c in range(2):
                    e = segments[rule, case, s, c]
                    if e == 0:
                        v = xmap[j, i]
                    elif e == 1:
                        v = xmap[j + 1, i]
                    elif e == 2:
                        v = ymap[j, i]
                    else:
                        v = ymap[j, i + 1]
                    segs[m, c] = v
                m += 1
    return n, m
