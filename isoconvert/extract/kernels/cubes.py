"""Marching Cubes kernels over a C-ordered (Z, Y, X) array.

Two passes, both parallel over z-slabs: :func:`count_cubes` counts, per slab,
the vertices and triangles it will make; prefix sums of those counts give each
slab its own place in the output, and :func:`fill_cubes` writes it. A slab keeps
maps from the bipolar edges of its two layers to their vertex numbers, so
neighbouring cubes share vertices by construction; memory beyond the output is
a few (Y, X) int64 layers per thread.

Vertices are numbered in the order layer 0 x-edges, layer 0 y-edges, slab 0
z-edges, layer 1 x-edges, ... (row-major within each group); triangles slab by
slab, row-major within a slab. Both orders are deterministic and independent
of the number of threads.
"""

import numpy as np
from numba import njit, prange

from .interpolate import edge_fraction


@njit(cache=True, nogil=True)
def _signs(f, level, k, out):
    ny, nx = out.shape
    for j in range(ny):
        for i in range(nx):
            out[j, i] = f[k, j, i] >= level


@njit(cache=True, nogil=True, inline="always")
def _case(lo, hi, j, i):
    """Configuration of cube (i, j) between sign layers lo and hi (bit v: vertex v)."""
    return (
        lo[j, i]
        | (lo[j, i + 1] << 1)
        | (lo[j + 1, i] << 2)
        | (lo[j + 1, i + 1] << 3)
        | (hi[j, i] << 4)
        | (hi[j, i + 1] << 5)
        | (hi[j + 1, i] << 6)
        | (hi[j + 1, i + 1] << 7)
    )


@njit(cache=True, nogil=True, parallel=True)
def count_cubes(f, level, n_triangles):
    """Count, per z-slab, the vertices and triangles of the isosurface.

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
    vertices : (Z,) int64
        Bipolar x- and y-edges of layer k plus bipolar z-edges from layer k to k + 1.
    triangles : (Z,) int64
        Triangles of the cubes between layers k and k + 1 (0 for the last layer).
    """
    nz, ny, nx = f.shape
    n_vert = np.zeros(nz, dtype=np.int64)
    n_tri = np.zeros(nz, dtype=np.int64)
    for k in prange(nz):
        lo = np.empty((ny, nx), dtype=np.uint8)
        _signs(f, level, k, lo)
        count = 0
        for j in range(ny):
            for i in range(nx):
                s = lo[j, i]
                if i + 1 < nx and s != lo[j, i + 1]:
                    count += 1
                if j + 1 < ny and s != lo[j + 1, i]:
                    count += 1
        tris = 0
        if k + 1 < nz:
            hi = np.empty((ny, nx), dtype=np.uint8)
            _signs(f, level, k + 1, hi)
            for j in range(ny):
                for i in range(nx):
                    if hi[j, i] != lo[j, i]:
                        count += 1
            for j in range(ny - 1):
                for i in range(nx - 1):
                    case = _case(lo, hi, j, i)
                    tris += n_triangles[case]
        n_vert[k] = count
        n_tri[k] = tris
    return n_vert, n_tri


@njit(cache=True, nogil=True)
def _layer_xy(f, level, offset, k, sign, xmap, ymap, verts, edge_ids, n, write):
    """Number the bipolar x- and y-edges of layer k from n on (writing their
    vertices when ``write``); ``sign`` is the layer's signs. Return the next number."""
    nz, ny, nx = f.shape
    for j in range(ny):
        for i in range(nx):
            p0 = sign[j, i]
            if i + 1 < nx and p0 != sign[j, i + 1]:
                if write:
                    s0 = np.float64(f[k, j, i])
                    s1 = np.float64(f[k, j, i + 1])
                    t = edge_fraction(s0, s1, level, offset)
                    verts[n, 0] = i + t
                    verts[n, 1] = j
                    verts[n, 2] = k
                    edge_ids[n] = 3 * (i + nx * (j + ny * k))
                xmap[j, i] = n
                n += 1
            if j + 1 < ny and p0 != sign[j + 1, i]:
                if write:
                    s0 = np.float64(f[k, j, i])
                    s1 = np.float64(f[k, j + 1, i])
                    t = edge_fraction(s0, s1, level, offset)
                    verts[n, 0] = i
                    verts[n, 1] = j + t
                    verts[n, 2] = k
                    edge_ids[n] = 3 * (i + nx * (j + ny * k)) + 1
                ymap[j, i] = n
                n += 1
    return n


@njit(cache=True, nogil=True, parallel=True)
def fill_cubes(
    f,
    level,
    offset,
    n_triangles,
    triangles,
    edge_base,
    edge_axis,
    vert_start,
    tri_start,
    verts,
    edge_ids,
    tris,
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
    vert_start, tri_start : (Z + 1,) int64
        Prefix sums of :func:`count_cubes`' counts: where slab k's vertices
        and triangles begin.
    verts : (V, 3) float64
        Out: vertex positions (x, y, z) in index units.
    edge_ids : (V,) int64
        Out: global id ``3 * (i + X * (j + Y * k)) + axis`` of each vertex's edge.
    tris : (C, 3) int64
        Out: triangles as vertex indices.
    """
    nz, ny, nx = f.shape
    for k in prange(nz):
        lo = np.empty((ny, nx), dtype=np.uint8)
        _signs(f, level, k, lo)
        xmap_lo = np.empty((ny, nx), dtype=np.int64)
        ymap_lo = np.empty((ny, nx), dtype=np.int64)
        n = _layer_xy(
            f, level, offset, k, lo, xmap_lo, ymap_lo, verts, edge_ids, vert_start[k], True
        )
        if k + 1 < nz:
            hi = np.empty((ny, nx), dtype=np.uint8)
            _signs(f, level, k + 1, hi)
            zmap = np.empty((ny, nx), dtype=np.int64)
            for j in range(ny):
                for i in range(nx):
                    if lo[j, i] != hi[j, i]:
                        s0 = np.float64(f[k, j, i])
                        s1 = np.float64(f[k + 1, j, i])
                        t = edge_fraction(s0, s1, level, offset)
                        verts[n, 0] = i
                        verts[n, 1] = j
                        verts[n, 2] = k + t
                        edge_ids[n] = 3 * (i + nx * (j + ny * k)) + 2
                        zmap[j, i] = n
                        n += 1
            # the upper layer's numbers, without writing: slab k + 1 writes them
            xmap_hi = np.empty((ny, nx), dtype=np.int64)
            ymap_hi = np.empty((ny, nx), dtype=np.int64)
            _layer_xy(
                f,
                level,
                offset,
                k + 1,
                hi,
                xmap_hi,
                ymap_hi,
                verts,
                edge_ids,
                vert_start[k + 1],
                False,
            )
            m = tri_start[k]
            for j in range(ny - 1):
                for i in range(nx - 1):
                    case = _case(lo, hi, j, i)
                    for t in range(n_triangles[case]):
                        for c in range(3):
                            e = triangles[case, t, c]
                            ii = i + edge_base[e, 0]
                            jj = j + edge_base[e, 1]
                            a = edge_axis[e]
                            if a == 2:
                                v = zmap[jj, ii]
                            elif edge_base[e, 2] == 1:
                                v = xmap_hi[jj, ii] if a == 0 else ymap_hi[jj, ii]
                            else:
                                v = xmap_lo[jj, ii] if a == 0 else ymap_lo[jj, ii]
                            tris[m, c] = v
                        m += 1
