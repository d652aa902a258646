"""Marching Tetrahedra, and the book's properties for cubes and tetra on random grids."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import ball, dataset, directed_edges_consistent, edge_use, load_samples_module
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import isoconvert
from isoconvert import Volume, extract
from isoconvert.extract.tables import TETRA_DIRECTIONS

CUBE_DIRS = np.eye(3, dtype=np.int64)


def bipolar_edge_ids(data, level, dirs):
    """Global ids n_dirs * lin + d of the bipolar edges along ``dirs`` of (X, Y, Z) data."""
    nx, ny, nz = data.shape
    pos = data >= level
    ids = []
    for d, (dx, dy, dz) in enumerate(dirs):
        a = pos[: nx - dx, : ny - dy, : nz - dz]
        b = pos[dx:, dy:, dz:]
        i, j, k = np.nonzero(a != b)
        ids.append(len(dirs) * (i + nx * (j + ny * k)) + d)
    return np.sort(np.concatenate(ids))


def check_grid_bounded_manifold(mesh, shape):
    """Every edge in two triangles, or in one when it lies on the grid boundary."""
    edges, uses = edge_use(mesh.cells)
    assert uses.max() <= 2
    single = edges[uses == 1]
    if len(single):
        a, b = mesh.vertices[single[:, 0]], mesh.vertices[single[:, 1]]
        on_face = np.zeros(len(single), bool)
        for axis, n in enumerate(shape):
            for side in (0, n - 1):
                on_face |= (a[:, axis] == side) & (b[:, axis] == side)
        assert on_face.all(), "a boundary edge inside the grid (a hole)"
    assert directed_edges_consistent(mesh.cells)


grids3 = arrays(
    np.int16,
    st.tuples(st.integers(2, 6), st.integers(2, 6), st.integers(2, 6)),
    elements=st.integers(0, 9),
)
# Two values only: ambiguous faces and cubes are frequent
binary3 = arrays(
    np.int16,
    st.tuples(st.integers(2, 6), st.integers(2, 6), st.integers(2, 6)),
    elements=st.integers(0, 1),
)


@pytest.mark.parametrize("rule", ["separate-positive", "separate-negative"])
def test_diagonal_negatives_across_a_face_regression(rule):
    """Found by hypothesis: two negative vertices diagonal on a face shared by two
    cubes. Fan triangulation put the same chord in both cubes (four triangles)."""
    data = np.ones((3, 3, 6))
    data[1, 1, 1] = data[1, 2, 0] = 0
    mesh = extract(Volume(data), 0.5, ambiguity=rule)
    check_grid_bounded_manifold(mesh, data.shape)


@settings(max_examples=150, deadline=None)
@given(
    data=st.one_of(grids3, binary3),
    level=st.integers(1, 9),
    method=st.sampled_from(["cubes:separate-positive", "cubes:separate-negative", "tetra"]),
)
def test_random_grids_give_grid_bounded_oriented_manifolds(data, level, method):
    level = 0.5 if data.max() <= 1 else level - 0.5  # no grid value equals the level
    assume(data.min() < level <= data.max())
    name, _, rule = method.partition(":")
    mesh = extract(Volume(data), level, method=name, ambiguity=rule or None)
    check_grid_bounded_manifold(mesh, data.shape)
    dirs = CUBE_DIRS if name == "cubes" else TETRA_DIRECTIONS
    # every bipolar edge carries exactly one vertex; no other edge carries one
    assert np.array_equal(np.sort(mesh.edge_ids), bipolar_edge_ids(data, level, dirs))
    # and each vertex sits where the linear interpolant equals the level
    lin, d = mesh.edge_ids // len(dirs), mesh.edge_ids % len(dirs)
    nx, ny, _ = data.shape
    start = np.column_stack([lin % nx, (lin // nx) % ny, lin // (nx * ny)])
    end = start + dirs[d]
    s0, s1 = data[tuple(start.T)].astype(float), data[tuple(end.T)].astype(float)
    t = (level - s0) / (s1 - s0)
    assert np.allclose(mesh.vertices, start + t[:, None] * dirs[d], atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(data=grids3, level=st.integers(1, 9))
def test_random_grids_with_values_at_the_level_still_give_valid_meshes(data, level):
    """Levels equal to grid values (book 2.3.4): vertices still on bipolar edges, one each,
    and patches still oriented consistently."""
    assume(data.min() < level <= data.max())
    for method in ("cubes", "tetra"):
        mesh = extract(Volume(data), level, method=method)
        dirs = CUBE_DIRS if method == "cubes" else TETRA_DIRECTIONS
        assert np.array_equal(np.sort(mesh.edge_ids), bipolar_edge_ids(data, level, dirs))
        assert directed_edges_consistent(mesh.cells)


def closed_summary(mesh):
    edges, uses = edge_use(mesh.cells)
    assert (uses == 2).all() and directed_edges_consistent(mesh.cells)
    return mesh.n_vertices - len(edges) + mesh.n_cells


def test_tetra_sphere_is_closed_and_has_the_area_of_cubes():
    vol = Volume(ball(48, 20.0, center=(23.7, 23.9, 24.1)))
    tetra, cubes = extract(vol, 0.0, method="tetra"), extract(vol, 0.0, method="cubes")
    assert closed_summary(tetra) == closed_summary(cubes) == 2
    assert tetra.signed_volume() > 0
    assert abs(tetra.area() / cubes.area() - 1) < 0.01
    assert abs(tetra.area() / (4 * np.pi * 20.0**2) - 1) < 0.01
    tm = trimesh.Trimesh(tetra.vertices, tetra.cells, process=False)
    assert tm.is_watertight and tm.is_winding_consistent and tm.euler_number == 2


def test_tetra_torus_has_genus_one():
    field = load_samples_module().torus()
    mesh = extract(Volume(field), 3.0, method="tetra", flip=True)
    assert closed_summary(mesh) == 0 and mesh.signed_volume() > 0


@pytest.mark.parametrize(
    ("name", "level"),
    [
        ("hydrogen_atom_128x128x128_uint8.raw", 20.5),
        ("fuel_64x64x64_uint8.raw", 30.5),
        ("engine_256x256x128_uint8.raw", 80.5),
    ],
)
def test_tetra_on_real_scans(name, level):
    vol = isoconvert.read_volume(dataset(name))
    tetra = extract(vol, level, method="tetra")
    cubes = extract(vol, level, method="cubes")
    check_grid_bounded_manifold(tetra, vol.shape)
    check_grid_bounded_manifold(cubes, vol.shape)
    t_edges, _ = edge_use(tetra.cells)
    c_edges, _ = edge_use(cubes.cells)
    euler_t = tetra.n_vertices - len(t_edges) + tetra.n_cells
    euler_c = cubes.n_vertices - len(c_edges) + cubes.n_cells
    assert euler_t == euler_c
    assert abs(tetra.area() / cubes.area() - 1) < 0.02


def test_slices_stack_matches_2d_contours_of_each_slice():
    vol = isoconvert.read_volume(load_samples_module().HERE / "sphere.nrrd")
    stack = extract(vol, 127.5, method="squares", axis="y")
    assert stack.cells.shape[1] == 2
    total = 0
    for j in range(vol.shape[1]):
        plane = vol.data[:, j, :]  # (x, z)
        if plane.min() < 127.5 <= plane.max():
            total += extract(Volume(plane), 127.5, method="squares").n_cells
    assert stack.n_cells == total
    # every stack vertex lies in its slice plane y = j and on a grid edge there
    assert np.allclose(stack.vertices[:, 1], np.rint(stack.vertices[:, 1]))
    # contours of a bright ball run counter-clockwise seen from +y, i.e. in the
    # right-handed (z, x) plane: signed area in (z, x) is positive per closed loop
    from isoconvert.mesh import polylines

    for line, closed in polylines(stack.cells):
        assert closed
        z, x = stack.vertices[line, 2], stack.vertices[line, 0]
        assert 0.5 * np.sum(z * np.roll(x, -1) - np.roll(z, -1) * x) > 0
