"""Marching Tetrahedra kernels over a C-ordered (Z, Y, X) array.

Each cube is split into six tetrahedra around its diagonal from (0, 0, 0) to
(1, 1, 1). Their edges run from a grid vertex along one of seven directions
(``dirs``: x, y, z, xy, xz, yz, xyz), so a vertex's global id is
``7 * (i + X * (j + Y * k)) + direction``. As for cubes, the fill pass walks one
slab at a time with per-layer maps from bipolar edges to vertex numbers:
``maps_lo[d]`` holds the edges starting in the slab's lower layer (all seven
directions), ``maps_hi[d]`` the in-layer ones (x, y, xy) of its upper layer.
"""

import numpy as np
from numba import njit

from .interpolate import edge_fraction


@njit(cache=True, nogil=True)
def _bipolar(f, level, k, j, i, d, dirs):
    nz, ny, nx = f.shape
    dx, dy, dz = dirs[d, 0], dirs[d, 1], dirs[d, 2]
    if i + dx >= nx or j + dy >= ny or k + dz >= nz:
        return False
    return (f[k, j, i] >= level) != (f[k + dz, j + dy, i + dx] >= level)


@njit(cache=True, nogil=True)
def count_tetra(f, level, dirs, tets, n_triangles):
    """Number of bipolar edges (vertices) and triangles."""
    nz, ny, nx = f.shape
    n_vert = 0
    n_tri = 0
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                for d in range(7):
                    if _bipolar(f, level, k, j, i, d, dirs):
                        n_vert += 1
                if i + 1 < nx and j + 1 < ny and k + 1 < nz:
                    signs = 0
                    for c in range(8):
                        if f[k + (c >> 2), j + ((c >> 1) & 1), i + (c & 1)] >= level:
                            signs |= 1 << c
                    for t in range(6):
                        config = 0
                        for n in range(4):
                            config |= ((signs >> tets[t, n]) & 1) << n
                        n_tri += n_triangles[16 * t + config]
    return n_vert, n_tri


@njit(cache=True, nogil=True)
def _number(f, level, offset, k, d, dirs, maps, verts, edge_ids, n):
    """Number the bipolar edges of direction d starting in layer k, from n on."""
    nz, ny, nx = f.shape
    dx, dy, dz = dirs[d, 0], dirs[d, 1], dirs[d, 2]
    for j in range(ny):
        for i in range(nx):
            if not _bipolar(f, level, k, j, i, d, dirs):
                continue
            s0 = np.float64(f[k, j, i])
            s1 = np.float64(f[k + dz, j + dy, i + dx])
            t = edge_fraction(s0, s1, level, offset)
            verts[n, 0] = i + t * dx
            verts[n, 1] = j + t * dy
            verts[n, 2] = k + t * dz
            edge_ids[n] = 7 * (i + nx * (j + ny * k)) + d
            maps[d, j, i] = n
            n += 1
    return n


@njit(cache=True, nogil=True)
def fill_tetra(
    f,
    level,
    offset,
    dirs,
    in_layer,
    crossing,
    tets,
    n_triangles,
    triangles,
    edge_base,
    edge_dir,
    verts,
    edge_ids,
    tris,
):
    """Write vertices (index coordinates), their edge ids and triangles.

    Parameters
    ----------
    f : (Z, Y, X) array
    level : float
    offset : float
        Minimum distance of vertices from edge ends, as a fraction of the edge.
    dirs : (7, 3) int64
        Edge directions.
    in_layer, crossing : int64 arrays
        Directions with dz = 0 and dz = 1.
    tets : (6, 4) int64
        Cube vertices of each tetrahedron.
    n_triangles : (96,) int64
        Triangles of tetrahedron t in configuration c at ``16 * t + c``.
    triangles : (96, 2, 3) int64
        Indices into the cube's 19 tetrahedron edges.
    edge_base : (19, 3) int64
        Offset of each edge's lower vertex.
    edge_dir : (19,) int64
        Direction of each edge.
    verts, edge_ids, tris : outputs, sized by :func:`count_tetra`.
    """
    nz, ny, nx = f.shape
    maps_lo = np.empty((7, ny, nx), dtype=np.int64)
    maps_hi = np.empty((7, ny, nx), dtype=np.int64)
    n = 0
    for d in in_layer:
        n = _number(f, level, offset, 0, d, dirs, maps_lo, verts, edge_ids, n)
    m = 0
    for k in range(nz - 1):
        for d in crossing:
            n = _number(f, level, offset, k, d, dirs, maps_lo, verts, edge_ids, n)
        for d in in_layer:
            n = _number(f, level, offset, k + 1, d, dirs, maps_hi, verts, edge_ids, n)
        for j in range(ny - 1):
            for i in range(nx - 1):
                signs = 0
                for c in range(8):
                    if f[k + (c >> 2), j + ((c >> 1) & 1), i + (c & 1)] >= level:
                        signs |= 1 << c
                if signs == 0 or signs == 255:
                    continue
                for t in range(6):
                    config = 0
                    for q in range(4):
                        config |= ((signs >> tets[t, q]) & 1) << q
                    entry = 16 * t + config
                    for s in range(n_triangles[entry]):
                        for c in range(3):
                            e = triangles[entry, s, c]
                            jj = j + edge_base[e, 1]
                            ii = i + edge_base[e, 0]
                            if edge_base[e, 2] == 1:
                                tris[m, c] = maps_hi[edge_dir[e], jj, ii]
                            else:
                                tris[m, c] = maps_lo[edge_dir[e], jj, ii]
                        m += 1
        maps_lo, maps_hi = maps_hi, maps_lo
    return n, m
