"""Marching Cubes kernels over a C-ordered (Z, Y, X) array.

Two passes: :func:`count_cubes` sizes the output, :func:`fill_cubes` writes it.
The fill pass walks the volume one slab (two neighbouring z-layers) at a time and
keeps, per layer, a map from each bipolar grid edge to its vertex number; cubes
read their vertex numbers from those maps, so neighbouring cubes share vertices
by construction and memory beyond the output is a few (Y, X) int64 layers.

Vertices are numbered in the order layer 0 x-edges, layer 0 y-edges, slab 0
z-edges, layer 1 x-edges, ... (row-major within each group); triangles slab by
slab, row-major within a slab. Both orders are deterministic.
"""

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def count_cubes(f, level, n_triangles):
    """Count isosurface vertices and triangles.

    Parameters
    ----------
    f : (Z, Y, X) array
        Samples; a grid vertex is positive when its value is >= ``level``.
    level : float
        The isovalue.
    n_triangles : (256,) int64
        Triangles per cube configuration.

    Returns
    -------
    (int, int)
        Number of bipolar grid edges (= vertices) and of triangles.
    """
    nz, ny, nx = f.shape
    n_vert = 0
    n_tri = 0
    lo = np.empty((ny, nx), dtype=np.uint8)
    hi = np.empty((ny, nx), dtype=np.uint8)
    for j in range(ny):
        for i in range(nx):
            lo[j, i] = f[0, j, i] >= level
    for k in range(nz):
        # x- and y-edges of layer k
        for j in range(ny):
            for i in range(nx):
                s = lo[j, i]
                if i + 1 < nx and s != lo[j, i + 1]:
                    n_vert += 1
                if j + 1 < ny and s != lo[j + 1, i]:
                    n_vert += 1
        if k + 1 == nz:
            break
        for j in range(ny):
            for i in range(nx):
                hi[j, i] = f[k + 1, j, i] >= level
                if hi[j, i] != lo[j, i]:
                    n_vert += 1
        for j in range(ny - 1):
            for i in range(nx - 1):
                case = (
                    lo[j, i]
                    | (lo[j, i + 1] << 1)
                    | (lo[j + 1, i] << 2)
                    | (lo[j + 1, i + 1] << 3)
                    | (hi[j, i] << 4)
                    | (hi[j, i + 1] << 5)
                    | (hi[j + 1, i] << 6)
                    | (hi[j + 1, i + 1] << 7)
                )
                n_tri += n_triangles[case]
        lo, hi = hi, lo
    return n_vert, n_tri


@njit(cache=True, nogil=True)
def _layer_xy(f, level, offset, k, xmap, ymap, verts, edge_ids, n):
    """Number the bipolar x- and y-edges of layer k from n on; return the next number."""
    nz, ny, nx = f.shape
    for j in range(ny):
        for i in range(nx):
            s0 = np.float64(f[k, j, i])
            p0 = s0 >= level
            if i + 1 < nx:
                s1 = np.float64(f[k, j, i + 1])
                if p0 != (s1 >= level):
                    t = min(max((level - s0) / (s1 - s0), offset), 1.0 - offset)
                    verts[n, 0] = i + t
                    verts[n, 1] = j
                    verts[n, 2] = k
                    edge_ids[n] = 3 * (i + nx * (j + ny * k))
                    xmap[j, i] = n
                    n += 1
            if j + 1 < ny:
                s1 = np.float64(f[k, j + 1, i])
                if p0 != (s1 >= level):
                    t = min(max((level - s0) / (s1 - s0), offset), 1.0 - offset)
                    verts[n, 0] = i
                    verts[n, 1] = j + t
                    verts[n, 2] = k
                    edge_ids[n] = 3 * (i + nx * (j + ny * k)) + 1
                    ymap[j, i] = n
                    n += 1
    return n


@njit(cache=True, nogil=True)
def fill_cubes(
    f, level, offset, n_triangles, triangles, edge_base, edge_axis, verts, edge_ids, tris
):
    """Write vertices (index coordinates), their grid-edge ids and triangles.

    Parameters
    ----------
    f : (Z, Y, X) array
        Samples, as for :func:`count_cubes`.
    level : float
        The isovalue.
    offset : float
        Vertices keep at least this fraction of their edge's length from its
        ends (0: plain linear interpolation).
    n_triangles : (256,) int64
        Triangles per configuration.
    triangles : (256, T, 3) int64
        Cube-edge indices of each configuration's triangles.
    edge_base : (12, 3) int64
        (dx, dy, dz) offset of each cube edge's lower vertex.
    edge_axis : (12,) int64
        Axis of each cube edge.
    verts : (V, 3) float64
        Out: vertex positions (x, y, z) in index units.
    edge_ids : (V,) int64
        Out: global id ``3 * (i + X * (j + Y * k)) + axis`` of each vertex's edge.
    tris : (C, 3) int64
        Out: triangles as vertex indices.
    """
    nz, ny, nx = f.shape
    xmap_lo = np.empty((ny, nx), dtype=np.int64)
    ymap_lo = np.empty((ny, nx), dtype=np.int64)
    xmap_hi = np.empty((ny, nx), dtype=np.int64)
    ymap_hi = np.empty((ny, nx), dtype=np.int64)
    zmap = np.empty((ny, nx), dtype=np.int64)
    n = _layer_xy(f, level, offset, 0, xmap_lo, ymap_lo, verts, edge_ids, 0)
    m = 0
    for k in range(nz - 1):
        for j in range(ny):
            for i in range(nx):
                s0 = np.float64(f[k, j, i])
                s1 = np.float64(f[k + 1, j, i])
                if (s0 >= level) != (s1 >= level):
                    t = min(max((level - s0) / (s1 - s0), offset), 1.0 - offset)
                    verts[n, 0] = i
                    verts[n, 1] = j
                    verts[n, 2] = k + t
                    edge_ids[n] = 3 * (i + nx * (j + ny * k)) + 2
                    zmap[j, i] = n
                    n += 1
        n = _layer_xy(f, level, offset, k + 1, xmap_hi, ymap_hi, verts, edge_ids, n)
        for j in range(ny - 1):
            for i in range(nx - 1):
                case = 0
                for c in range(8):
                    dx = c & 1
                    dy = (c >> 1) & 1
                    dz = (c >> 2) & 1
                    if f[k + dz, j + dy, i + dx] >= level:
                        case |= 1 << c
                for t in range(n_triangles[case]):
                    for c in range(3):
                        e = triangles[case, t, c]
                        ii = i + edge_base[e, 0]
                        jj = j + edge_base[e, 1]
                        upper = edge_base[e, 2] == 1
                        a = edge_axis[e]
                        if a == 0:
                            v = xmap_hi[jj, ii] if upper else xmap_lo[jj, ii]
                        elif a == 1:
                            v = ymap_hi[jj, ii] if upper else ymap_lo[jj, ii]
                        else:
                            v = zmap[jj, ii]
                        tris[m, c] = v
                    m += 1
        xmap_lo, xmap_hi = xmap_hi, xmap_lo
        ymap_lo, ymap_hi = ymap_hi, ymap_lo
    return n, m
