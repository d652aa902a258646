"""Marching Squares: a hand-worked grid, the properties of book section 2.2.3 as
hypothesis tests, the degenerate cases of Figures 2.5-2.7, and scikit-image."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import dataset, edge_key
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from isoconvert import Volume, extract, read_volume
from isoconvert.mesh import polylines


def contour(grid_yx, level, **kw):
    """Contour a (rows, cols) array; return vertices (V, 2) in (x, y), segments, edge ids.

    Vertices are placed exactly (``vertex_offset=0``), as the book places them,
    unless a test asks otherwise: these tests are about the book's cases.
    """
    kw.setdefault("vertex_offset", 0.0)
    mesh = extract(Volume.from_zyx(np.asarray(grid_yx)), level, method="squares", **kw)
    return mesh.vertices[:, :2], mesh.cells, mesh.edge_ids


def test_hand_worked_diamond_around_one_positive_vertex():
    # Only the centre (value 8) is >= 5. Its four edges are bipolar:
    #   x-edge (0,1)-(1,1): 2 -> 8, t = (5-2)/(8-2) = 0.5   -> (0.5, 1)
    #   x-edge (1,1)-(2,1): 8 -> 4, t = (5-8)/(4-8) = 0.75  -> (1.75, 1)
    #   y-edge (1,0)-(1,1): 2 -> 8, t = 0.5                 -> (1, 0.5)
    #   y-edge (1,1)-(1,2): 8 -> 4, t = 0.75                -> (1, 1.75)
    # The diamond runs counter-clockwise around the positive centre.
    grid = [[1, 2, 1], [2, 8, 4], [1, 4, 1]]  # rows are y, columns x
    verts, segs, _ = contour(grid, 5)
    expected = [(1, 0.5), (1.75, 1), (1, 1.75), (0.5, 1)]
    got = {tuple(np.round(verts[a], 12)): tuple(np.round(verts[b], 12)) for a, b in segs}
    assert got == {expected[n]: expected[(n + 1) % 4] for n in range(4)}
    ((line, closed),) = polylines(segs)
    assert closed and len(line) == 4


def test_ambiguity_rules_on_a_saddle():
    # Diagonal corners 6 and 7 positive, 0 and 1 negative: an ambiguous square
    # whose bilinear saddle is (6*7 - 0*1) / (6 + 7 - 0 - 1) = 3.5.
    grid = [[6, 0], [1, 7]]

    def joined(level, rule):
        verts, segs, _ = contour(grid, level, ambiguity=rule)
        # each segment cuts off one corner: which corner is nearer its midpoint?
        mids = verts[segs].mean(axis=1)
        near = {tuple(np.rint(m).astype(int)) for m in mids}
        return {(0, 0), (1, 1)} == near  # positive corners (x, y) = (0, 0), (1, 1)

    assert joined(4, "separate-positive")
    assert not joined(4, "separate-negative")
    assert not joined(3, "asymptotic")  # saddle 3.5 >= 3: positives joined
    assert joined(4, "asymptotic")  # saddle 3.5 < 4: positives separated


# --- properties (book section 2.2.3) ---------------------------------------------

grids = arrays(
    np.int16, st.tuples(st.integers(2, 7), st.integers(2, 7)), elements=st.integers(0, 9)
)


def bipolar_ids(g, level):
    """2D edge ids 2 * (i + X * j) + axis of the bipolar edges of (rows, cols) grid g."""
    ids = set()
    ny, nx = g.shape
    pos = g >= level
    for j in range(ny):
        for i in range(nx):
            if i + 1 < nx and pos[j, i] != pos[j, i + 1]:
                ids.add(2 * (i + nx * j))
            if j + 1 < ny and pos[j, i] != pos[j + 1, i]:
                ids.add(2 * (i + nx * j) + 1)
    return ids


def edge_cells(edge_id, nx, ny):
    """The (i, j) squares that have this grid edge on their boundary."""
    axis, lin = edge_id % 2, edge_id // 2
    i, j = lin % nx, lin // nx
    if axis == 0:
        cand = [(i, j - 1), (i, j)]
    else:
        cand = [(i - 1, j), (i, j)]
    return {(a, b) for a, b in cand if 0 <= a < nx - 1 and 0 <= b < ny - 1}


def _root(parent, x):
    """Union-find root."""
    while parent[x] != x:
        x = parent[x]
    return x


def check_properties_1_to_5(g, level, rule):
    verts, segs, ids = contour(g, level, ambiguity=rule)
    ny, nx = g.shape
    # 1-2: every vertex lies on its grid edge, where the linear interpolant equals the level
    axis, lin = ids % 2, ids // 2
    i, j = lin % nx, lin // nx
    di, dj = 1 - axis, axis
    s0, s1 = g[j, i].astype(float), g[j + dj, i + di].astype(float)
    t = np.where(axis == 0, verts[:, 0] - i, verts[:, 1] - j)
    other = np.where(axis == 0, verts[:, 1] - j, verts[:, 0] - i)
    assert np.all((t >= 0) & (t <= 1)) and np.allclose(other, 0)
    assert np.allclose(s0 + t * (s1 - s0), level)
    # 3-4: exactly the bipolar edges carry a vertex, one each (none on negative or
    # strictly positive edges)
    assert len(set(ids.tolist())) == len(ids)
    assert set(ids.tolist()) == bipolar_ids(g, level)
    # 5: in every square the segments separate its positive from its negative corners
    pos = g >= level
    by_cell: dict = {}
    for a, b in segs:
        (cell,) = edge_cells(ids[a], nx, ny) & edge_cells(ids[b], nx, ny)
        by_cell.setdefault(cell, []).append((ids[a], ids[b]))
    for ci in range(nx - 1):
        for cj in range(ny - 1):
            corners = [(ci, cj), (ci + 1, cj), (ci + 1, cj + 1), (ci, cj + 1)]  # ccw
            sides = [
                2 * (ci + nx * cj),
                2 * (ci + 1 + nx * cj) + 1,
                2 * (ci + nx * (cj + 1)),
                2 * (ci + nx * cj) + 1,
            ]
            crossing = [e for e in sides if e in set(ids.tolist())]
            chords = by_cell.get((ci, cj), [])
            assert sorted(e for c in chords for e in c) == sorted(crossing)
            if not crossing:
                assert len({pos[y, x] for x, y in corners}) == 1
                continue
            # arcs of the square's boundary between consecutive crossings; the
            # region beyond a chord continues on the arc after its other end
            order = [sides.index(e) for e in crossing]
            m = len(order)
            arc_corners = [
                [(order[k] + 1 + n) % 4 for n in range((order[(k + 1) % m] - order[k]) % 4 or 4)]
                for k in range(m)
            ]
            partner = {}
            for a, b in chords:
                partner[crossing.index(a)] = crossing.index(b)
                partner[crossing.index(b)] = crossing.index(a)
            parent = list(range(m))
            for k in range(m):
                parent[_root(parent, k)] = _root(parent, partner[(k + 1) % m])
            regions: dict = {}
            for k in range(m):
                for c in arc_corners[k]:
                    x, y = corners[c]
                    regions.setdefault(_root(parent, k), set()).add(bool(pos[y, x]))
            assert all(len(signs) == 1 for signs in regions.values()), (ci, cj)
    return verts, segs, ids


rules = st.sampled_from(["separate-positive", "separate-negative", "asymptotic"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(g=grids, level=st.integers(1, 9), rule=rules)
def test_properties_1_to_5_hold_even_when_values_equal_the_level(g, level, rule):
    assume(g.min() < level <= g.max())
    check_properties_1_to_5(g, level, rule)


@settings(max_examples=150, deadline=None)
@given(g=grids, level=st.integers(1, 9), rule=rules)
def test_properties_6_to_8_when_no_value_equals_the_level(g, level, rule):
    level = level - 0.5
    assume(g.min() < level <= g.max())
    verts, segs, ids = check_properties_1_to_5(g, level, rule)
    ny, nx = g.shape
    # 6: a 1-manifold: every vertex ends one segment and/or starts one
    starts = np.bincount(segs[:, 0], minlength=len(verts))
    ends = np.bincount(segs[:, 1], minlength=len(verts))
    assert starts.max() <= 1 and ends.max() <= 1
    # 7: its boundary (vertices used once) lies on the grid boundary
    once = (starts + ends) == 1
    x, y = verts[once].T
    assert np.all((x == 0) | (x == nx - 1) | (y == 0) | (y == ny - 1))
    assert np.all(starts + ends >= 1)
    # 8: no zero-length and no duplicate segments
    assert np.all(np.linalg.norm(verts[segs[:, 0]] - verts[segs[:, 1]], axis=1) > 0)
    assert len(np.unique(np.sort(segs, axis=1), axis=0)) == len(segs)


# --- the degenerate cases (book Figures 2.5-2.7) ------------------------------------


def test_isolated_vertex_at_the_level_gives_zero_length_segments():
    # The centre equals the level, all else below: it is positive and its four
    # edges are bipolar with the vertex at the centre itself (t = 0 or 1).
    verts, segs, _ = contour([[0, 0, 0], [0, 5, 0], [0, 0, 0]], 5)
    assert len(verts) == 4 and np.allclose(verts, [1, 1])
    lengths = np.linalg.norm(verts[segs[:, 0]] - verts[segs[:, 1]], axis=1)
    assert len(segs) == 4 and np.all(lengths == 0)


def test_edge_at_the_level_gives_duplicate_segments():
    # Two neighbours equal the level, all else below: both squares beside their
    # edge put a segment along it, so the same segment appears twice (reversed).
    verts, segs, _ = contour([[0, 0, 0], [0, 5, 5], [0, 0, 0]], 5)
    ends = [frozenset(map(tuple, np.round(verts[s], 12))) for s in segs]
    along = [e for e in ends if e == frozenset({(1.0, 1.0), (2.0, 1.0)})]
    assert len(along) == 2


def test_vertex_at_the_level_between_positive_diagonals():
    # Centre at the level (so positive), diagonal neighbours above, edge
    # neighbours below: all four squares are ambiguous.
    grid = [[9, 0, 9], [0, 5, 0], [9, 0, 9]]
    # Joining the positives, four curves pass through the centre: eight segments
    # of non-zero length end there (a non-manifold point of the contour).
    verts, segs, _ = contour(grid, 5, ambiguity="separate-negative")
    lengths = np.linalg.norm(verts[segs[:, 0]] - verts[segs[:, 1]], axis=1)
    ends_at_centre = np.all(np.isclose(verts[segs], [1, 1]), axis=2).sum(axis=1)
    assert np.all(lengths > 0) and ends_at_centre.sum() == 8
    # Separating them, the centre becomes a loop of four zero-length segments.
    verts, segs, _ = contour(grid, 5, ambiguity="separate-positive")
    lengths = np.linalg.norm(verts[segs[:, 0]] - verts[segs[:, 1]], axis=1)
    assert np.sum(lengths == 0) == 4
    assert np.allclose(verts[segs[lengths == 0]], [1, 1])


# --- against scikit-image's find_contours -------------------------------------------


def skimage_segments(image, level, fully_connected):
    measure = pytest.importorskip("skimage.measure")
    segs = []
    for c in measure.find_contours(image, level, fully_connected=fully_connected):
        xy = c[:, ::-1]  # (row, col) -> (x, y)
        segs.extend(zip(xy[:-1], xy[1:], strict=True))
    return segs


@pytest.mark.parametrize(
    ("name", "level"),
    [("camera", 100.5), ("coins", 120.5), ("horse", 0.5), ("mri", 60.5), ("flair", 100.5)],
)
@pytest.mark.parametrize(
    ("rule", "fully_connected"), [("separate-positive", "low"), ("separate-negative", "high")]
)
def test_agrees_with_find_contours(name, level, rule, fully_connected):
    data = pytest.importorskip("skimage.data")
    if name == "mri":
        image = np.asarray(read_volume(dataset("mri-stack.tif")).data[:, :, 13].T, float)
    elif name == "flair":
        image = np.asarray(read_volume(dataset("FLAIR.nrrd")).data[:, :, 70].T, float)
    else:
        image = np.asarray(getattr(data, name)(), float)
    assert not (image == level).any()
    verts, segs, _ = contour(image, level, ambiguity=rule)
    theirs = skimage_segments(image, level, fully_connected)
    ours_keys, ours_t = edge_key(verts)
    sk_pts = np.unique(np.round(np.array([p for s in theirs for p in s]), 9), axis=0)
    sk_keys, sk_t = edge_key(sk_pts)
    assert np.array_equal(ours_keys, sk_keys)
    assert np.abs(ours_t - sk_t).max() < 1e-9
    ours = {
        frozenset((tuple(np.round(verts[a], 7)), tuple(np.round(verts[b], 7)))) for a, b in segs
    }
    theirs = {frozenset((tuple(np.round(a, 7)), tuple(np.round(b, 7)))) for a, b in theirs}
    assert ours == theirs
