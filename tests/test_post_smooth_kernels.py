"""The compiled smoothing stencil and filters (src/smooth.cpp) against a plain
numpy/scipy construction of the same rules: edges and their triangle counts
from numpy's unique rows, fans and components from scipy's connected
components, the umbrella operator as a sparse matrix and the filters' recurrences
written out step by step."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from isoconvert import extract
from isoconvert.post import smooth as smoothing
from isoconvert.volume import Volume

FIXED, CURVE, SMALL = 16, 32, 64


def _gyroid(n: int) -> np.ndarray:
    t = np.linspace(0.0, 4.0 * np.pi, n)
    z, y, x = np.meshgrid(t, t, t, indexing="ij")
    return (np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)).astype(
        np.float32
    )


def _awkward_mesh() -> tuple[np.ndarray, np.ndarray, dict]:
    """A gyroid piece that meets every grid face, with holes cut in it, a fin on
    one of its edges (an edge in three triangles), two tetrahedra sharing a
    vertex (a vertex on two fans), a triangle repeating a vertex, an unused
    vertex and a lone triangle: (vertices (V, 3), triangles (T, 3), grid)."""
    mesh = extract(Volume.from_zyx(_gyroid(24)), 0.1)
    vertices = np.asarray(mesh.vertices, np.float64)
    cells = np.asarray(mesh.cells, np.int64)
    rng = np.random.default_rng(3)
    cells = cells[rng.random(len(cells)) > 0.02]  # holes: open boundaries
    n = len(vertices)
    fin_apex = vertices[cells[0]].mean(axis=0) + 0.3
    tetra = np.array([[30.0, 30, 30], [31, 30, 30], [30, 31, 30], [30, 30, 31]])
    other = np.array([[29.0, 29, 29], [29, 30, 29], [30, 29, 29]])  # shares tetra[0]
    lone = np.array([[40.0, 40, 40], [41, 40, 40], [40, 41, 40]])
    unused = np.array([[50.0, 50, 50]])
    vertices = np.vstack([vertices, fin_apex, tetra, other, lone, unused])
    t0 = n + 1
    extra = [
        [cells[0, 0], cells[0, 1], n],  # the fin
        [t0, t0 + 1, t0 + 2],
        [t0, t0 + 3, t0 + 1],
        [t0, t0 + 2, t0 + 3],
        [t0 + 1, t0 + 3, t0 + 2],
        [t0, t0 + 4, t0 + 5],
        [t0, t0 + 5, t0 + 6],
        [t0, t0 + 6, t0 + 4],
        [t0 + 4, t0 + 6, t0 + 5],
        [t0 + 7, t0 + 8, t0 + 9],
        [cells[5, 0], cells[5, 0], cells[5, 1]],  # repeats a vertex: no 2-cell
    ]
    cells = np.vstack([cells, np.array(extra, np.int64)])
    return vertices, cells, dict(mesh.info["grid"])


def _reference(vertices, cells, grid, hold_below):
    """The stencil by the rules of isoconvert.post.smooth, in numpy and scipy:
    (rows: list of sets, fixed, curve, small: (V,) bool, small components)."""
    n = len(vertices)
    c = cells[
        (cells[:, 0] != cells[:, 1]) & (cells[:, 1] != cells[:, 2]) & (cells[:, 0] != cells[:, 2])
    ]
    t = len(c)
    ends = np.concatenate([c[:, [0, 1]], c[:, [1, 2]], c[:, [2, 0]]])  # edge j of triangle
    tri = np.tile(np.arange(t), 3)
    key = np.sort(ends, axis=1)
    edges, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    degree = np.bincount(edges.ravel(), minlength=n)
    boundary = edges[counts == 1]
    n_boundary = np.bincount(boundary.ravel(), minlength=n)
    on_many = np.bincount(edges[counts > 2].ravel(), minlength=n) > 0
    # fans: corners (3 t + j, at vertex c.ravel()[3 t + j]) joined across each
    # edge used exactly twice, at both of its ends
    order = np.argsort(inverse, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    twice = np.flatnonzero(counts == 2)
    t1, t2 = tri[order[starts[twice]]], tri[order[starts[twice] + 1]]
    pairs = []
    for end in (0, 1):
        v = edges[twice, end]
        j1 = np.argmax(c[t1] == v[:, None], axis=1)
        j2 = np.argmax(c[t2] == v[:, None], axis=1)
        pairs.append(np.stack([3 * t1 + j1, 3 * t2 + j2], axis=1))
    pairs = np.concatenate(pairs)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(3 * t, 3 * t))
    _, corner_fan = connected_components(graph, directed=False)
    fan_pairs = np.unique(np.stack([c.ravel(), corner_fan], axis=1), axis=0)
    fans = np.bincount(fan_pairs[:, 0], minlength=n)
    shape = np.asarray(grid["shape"], np.float64)
    index = vertices - np.asarray(grid["origin"])  # an identity affine
    planes = (np.abs(index) < 1e-9) | (np.abs(index - (shape - 1)) < 1e-9)
    adjacency = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, component = connected_components(adjacency, directed=False)
    size = np.bincount(component, weights=degree > 0)
    small = (size[component] < hold_below) & (degree > 0)
    n_small = int(np.count_nonzero((size > 0) & (size < hold_below)))
    fixed = (degree == 0) | on_many | ((n_boundary != 0) & (n_boundary != 2)) | (fans > 1)
    fixed |= planes.all(axis=1) | small
    curve = (n_boundary == 2) & ~fixed
    rows = [set() for _ in range(n)]
    for (a, b), m in zip(edges, counts, strict=True):
        for v, w in ((a, b), (b, a)):
            if not fixed[v] and (not curve[v] or m == 1):
                rows[v].add(int(w))
    return rows, fixed, curve, small, n_small, planes


@pytest.mark.parametrize("hold_below", [0, 64])
def test_stencil_follows_the_rules_written_out_in_numpy(hold_below):
    vertices, cells, grid = _awkward_mesh()
    rows, fixed, curve, small, n_small, planes = _reference(vertices, cells, grid, hold_below)
    stencil = smoothing._Stencil(vertices, cells, grid, "test", hold_below)
    offsets, neighbours = stencil.rows()
    got = [set(neighbours[a:b].tolist()) for a, b in zip(offsets[:-1], offsets[1:], strict=True)]
    assert got == rows
    assert np.array_equal(stencil.fixed, fixed)
    assert np.array_equal((stencil.code & CURVE) != 0, curve)
    assert np.array_equal((stencil.code & SMALL) != 0, small)
    assert stencil.n_small == n_small
    assert np.array_equal((stencil.code[:, None] >> np.arange(3)) & 1 == 1, planes)
    # the cases the mesh was built to have are there
    assert curve.any() and (fixed & ~small).any() and planes.any(axis=1).any()
    used = np.zeros(len(vertices), bool)
    used[cells.ravel()] = True
    assert np.allclose(stencil.lo, vertices[used].min(axis=0))
    assert np.allclose(stencil.hi, vertices[used].max(axis=0))


def _operator(rows, planes, fixed):
    """The umbrella operator as a function of (V, 3) positions, from reference rows."""
    n = len(rows)
    r = [v for v in range(n) for _ in rows[v]]
    cols = [w for v in range(n) for w in sorted(rows[v])]
    count = np.array([len(s) for s in rows], np.float64)
    weights = np.array([1.0 / count[v] for v in r])
    mean = sp.csr_matrix((weights, (r, cols)), shape=(n, n))
    held = planes & ~fixed[:, None]
    still = count == 0

    def laplacian(x):
        out = x - mean @ x
        out[still] = 0.0
        out[held] = 0.0
        return out

    return laplacian


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("iterations", [1, 2, 7, 20])
@pytest.mark.parametrize("shuffled", [False, True])
def test_filters_are_the_recurrences_written_out(threads, iterations, shuffled):
    """Natural order lets the sinc filter run two steps per sweep (neighbours lie
    within a few slabs' vertices); shuffled vertices make it run one."""
    mesh = extract(Volume.from_zyx(_gyroid(64)), 0.1)
    vertices = np.asarray(mesh.vertices, np.float64)
    cells = np.asarray(mesh.cells, np.int64)
    if shuffled:
        order = np.random.default_rng(1).permutation(len(vertices))
        vertices = vertices[order]
        cells = np.argsort(order)[cells]
    grid = dict(mesh.info["grid"])
    rows, fixed, _, _, _, planes = _reference(vertices, cells, grid, 64)
    laplacian = _operator(rows, planes, fixed)
    stencil = smoothing._Stencil(vertices, cells, grid, "test", 64)
    stencil.threads = threads
    x = (vertices - vertices.mean(axis=0)) / 100.0

    c, _ = smoothing.sinc_coefficients(iterations, 0.1)
    x0, x1 = x, x - 0.5 * laplacian(x)
    expected = c[0] * x0 + (c[1] * x1 if len(c) > 1 else 0.0)
    for ci in c[2:]:
        x0, x1 = x1, 2.0 * x1 - laplacian(x1) - x0
        expected = expected + ci * x1
    got = stencil.sinc(x, c, np.zeros(3), 1.0)
    assert np.abs(got - expected).max() < 1e-13

    steps = [0.5, -0.53] * iterations
    expected = x.copy()
    for f in steps:
        expected = expected - f * laplacian(expected)
    got = x.copy()
    stencil.steps(got, steps, np.zeros(3), 1.0)
    assert np.abs(got - expected).max() < 1e-13
