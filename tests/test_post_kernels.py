"""The compiled kernels of post-processing: point-to-mesh distances against
trimesh, the distance certificate against surfaces whose distance is known in
closed form, and connected components against scipy."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from isoconvert.post.decimate import TriangleGrid, within_bound

pytest.importorskip("rtree", reason="trimesh.proximity needs rtree")


def test_a_triangle_nearer_by_less_than_float32_rounding_is_still_found():
    """The grid keeps triangle boxes in float32, rounded outwards so that they
    only prune less. Two walls facing the point at x = 0.1 and 0.1 + 1e-10: the
    farther one, listed first, is the best so far when the nearer one's box is
    tested, and 0.1 rounded to the nearest float32 (0.10000000149) would put
    that box beyond it."""
    near = 0.1
    walls = []
    for x in (near + 1e-10, near):  # the farther wall first
        walls += [[x, -1.0, -1.0], [x, 2.0, -1.0], [x, -1.0, 2.0]]
    cells = np.array([[0, 1, 2], [3, 4, 5]])
    grid = TriangleGrid(np.array(walls), cells, 1.0)
    distance, nearest = grid.distances(np.zeros((1, 3)))
    assert nearest[0] == 1 and distance[0] == near


def test_distances_equal_trimesh_within_the_radius_and_exceed_it_beyond():
    sphere = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(0)
    points = rng.normal(size=(20_000, 3)) * 0.7
    _, expected, _ = trimesh.proximity.closest_point(sphere, points)
    grid = TriangleGrid(sphere.vertices, sphere.faces, 5.0)
    distance, nearest = grid.distances(points)
    assert np.abs(distance - expected).max() < 1e-12
    # the nearest triangle is at that distance (trimesh may name another of equals)
    assert (nearest >= 0).all()
    foot = trimesh.triangles.closest_point(sphere.triangles[nearest], points)
    assert np.abs(np.linalg.norm(foot - points, axis=1) - distance).max() < 1e-12
    small = TriangleGrid(sphere.vertices, sphere.faces, 0.05)
    distance, nearest = small.distances(points)
    inside = expected <= 0.05
    assert np.abs(distance[inside] - expected[inside]).max() < 1e-12
    assert (distance[~inside] > 0.05).all()
    assert (nearest[np.isinf(distance)] == -1).all()


def _valley(slope: float, n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A V-shaped valley z = slope * |x| over [-1, 1]^2, its ridge at x = 0 an
    edge row of the mesh: (vertices (V, 3), triangles (T, 3))."""
    t = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), slope * np.abs(x.ravel())])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    triangles = np.concatenate([np.column_stack([a.ravel(), b.ravel(), d.ravel()])])
    triangles = np.concatenate([triangles, np.column_stack([a.ravel(), d.ravel(), c.ravel()])])
    return vertices, triangles


@pytest.mark.parametrize("slope", [0.5, 1.0, 2.0])
def test_a_lid_over_a_valley_is_certified_exactly_at_its_distance(slope):
    """A flat lid resting on the valley's two rims: its farthest point, above
    the ridge, is slope / sqrt(1 + slope^2) from the valley (the distance from
    (0, y, slope) to the plane z = slope x). Certified within a bound 25 %
    above that, the certificate between the two; refused for one 1 % below."""
    vertices, triangles = _valley(slope)
    n = 41  # vertices per row; the corners (+-1, +-1) are the rims' ends, at height slope
    lid = np.array([[0, n * (n - 1), n - 1], [n * (n - 1), n * n - 1, n - 1]])
    exact = slope / np.sqrt(1.0 + slope**2)
    grid = TriangleGrid(vertices, triangles, 2 * exact)
    reach, failed = within_bound(vertices, lid, grid, triangles, 1.25 * exact)
    assert not failed.any() and exact <= reach <= 1.25 * exact
    _, failed = within_bound(vertices, lid, grid, triangles, 0.99 * exact)
    assert failed.all()


def test_corner_distances_count_and_shared_triangles_are_at_distance_zero():
    """The input side: corners off the surface add their distance (a plane
    lifted by h is h away); a triangle the other surface also has is 0."""
    vertices, triangles = _valley(0.0, n=4)  # the plane z = 0
    lifted = vertices + [0.0, 0.0, 0.3]
    both = np.concatenate([vertices, lifted])
    grid = TriangleGrid(both, triangles, 1.0)
    corner = np.concatenate([np.zeros(len(vertices)), np.full(len(vertices), 0.3)])
    reach, failed = within_bound(both, triangles + len(vertices), grid, triangles, 0.33, corner)
    assert not failed.any() and 0.3 <= reach <= 0.33
    _, failed = within_bound(both, triangles + len(vertices), grid, triangles, 0.29, corner)
    assert failed.all()
    reach, failed = within_bound(both, triangles, grid, triangles, 1e-9)
    assert reach == 0.0 and not failed.any()


@pytest.mark.parametrize("n, m", [(1, 0), (12, 7), (50_000, 40_000), (50_000, 150_000)])
def test_components_are_scipys_labelled_by_their_smallest_node(n, m):
    """The compiled union-find behind every component count (largest, smoothing's
    small-component hold, decimation's guard, the report) against scipy's."""
    import scipy.sparse
    import scipy.sparse.csgraph

    from isoconvert.graph import connected_components

    rng = np.random.default_rng(n + m)
    u, v = rng.integers(0, n, m), rng.integers(0, n, m)
    labels = connected_components(n, u, v)
    graph = scipy.sparse.coo_matrix((np.ones(m), (u, v)), shape=(n, n))
    count, theirs = scipy.sparse.csgraph.connected_components(graph, directed=False)
    smallest = np.full(count, n)
    np.minimum.at(smallest, theirs, np.arange(n))
    assert (labels == smallest[theirs]).all()


def test_a_parallel_lid_is_certified_at_its_height_by_convexity():
    """A triangle 0.01 above a coplanar copy of itself: its distance to that one
    triangle is convex, so its corners' (0.01) bound it everywhere. The Lipschitz
    bound alone (0.01 plus a cover radius) would need pieces a hundredth of that
    size: far past the six halvings the certificate allows."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0.01], [1, 0, 0.01], [0, 1, 0.01]])
    below, lid = np.array([[0, 1, 2]]), np.array([[3, 4, 5]])
    grid = TriangleGrid(vertices.astype(float), below, 1.0)
    corner = np.array([0.0, 0.0, 0.0, 0.01, 0.01, 0.01])
    reach, failed = within_bound(vertices.astype(float), lid, grid, below, 0.0101, corner)
    assert not failed.any() and abs(reach - 0.01) < 1e-12
    _, failed = within_bound(vertices.astype(float), lid, grid, below, 0.0099, corner)
    assert failed.all()
