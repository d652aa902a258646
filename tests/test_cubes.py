"""Marching Cubes on analytic surfaces and real scans, against VTK and scikit-image."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import (
    ball,
    dataset,
    directed_edges_consistent,
    edge_key,
    edge_use,
    euler_characteristic,
    load_samples_module,
    vtk_flying_edges,
)

import isoconvert
from isoconvert import Volume, extract


def check_closed_oriented(mesh, expected_euler):
    _, uses = edge_use(mesh.cells)
    assert (uses == 2).all(), "every edge in exactly two triangles"
    assert directed_edges_consistent(mesh.cells)
    used = len(np.unique(mesh.cells))
    assert used == mesh.n_vertices, "no unreferenced vertices"
    assert euler_characteristic(used, mesh.cells) == expected_euler
    tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.euler_number == expected_euler


@pytest.mark.parametrize("radius", [20.0, 23.3])
def test_sphere_is_closed_outward_and_has_the_right_area(radius):
    n = int(2 * radius + 6)
    mesh = extract(Volume(ball(n, radius, center=(n / 2 - 0.3, n / 2 + 0.1, n / 2 - 0.2))), 0.0)
    check_closed_oriented(mesh, 2)
    assert mesh.signed_volume() > 0, "normals point out of the bright ball"
    assert abs(mesh.area() / (4 * np.pi * radius**2) - 1) < 0.01
    assert abs(mesh.signed_volume() / (4 / 3 * np.pi * radius**3) - 1) < 0.01


def test_flip_reverses_orientation():
    vol = Volume(ball(30, 10.0))
    assert extract(vol, 0.0, flip=True).signed_volume() < 0


def test_torus_of_figure_1_1_has_genus_one():
    field = load_samples_module().torus()  # distance field: the torus is negative
    mesh = extract(Volume(field), 3.0, flip=True)
    check_closed_oriented(mesh, 0)
    assert mesh.signed_volume() > 0
    # tube radius 3 around a circle of radius 6: volume 2 pi^2 R r^2 (coarse grid)
    assert abs(mesh.signed_volume() / (2 * np.pi**2 * 6 * 9) - 1) < 0.05


def test_vertices_interpolate_on_bipolar_edges():
    rng = np.random.default_rng(1)
    data = rng.random((9, 8, 7))
    level = 0.4
    mesh = extract(Volume(data), level)
    ids = mesh.edge_ids
    axis = ids % 3
    lin = ids // 3
    i, j, k = lin % 9, (lin // 9) % 8, lin // 72
    start = np.column_stack([i, j, k])
    end = start + np.eye(3, dtype=int)[axis]
    s0 = data[tuple(start.T)]
    s1 = data[tuple(end.T)]
    assert ((s0 >= level) != (s1 >= level)).all()
    t = (level - s0) / (s1 - s0)
    assert np.allclose(mesh.vertices, start + t[:, None] * (end - start), atol=1e-12)
    # every bipolar grid edge carries exactly one vertex
    n_bipolar = sum(
        int(
            (
                (np.take(data, range(d - 1), a) >= level)
                != (np.take(data, range(1, d), a) >= level)
            ).sum()
        )
        for a, d in enumerate(data.shape)
    )
    assert len(np.unique(ids)) == len(ids) == n_bipolar


def test_blocks_stitch_exactly_by_edge_id():
    """Two halves of a volume (sharing one layer) give the whole mesh's vertices by id."""
    data = ball(24, 9.0)
    whole = extract(Volume(data), 0.0)
    lower = extract(Volume(data[:, :, :13]), 0.0)
    upper = extract(Volume(data[:, :, 12:], origin=(0, 0, 12)), 0.0)
    shift = 3 * 24 * 24 * 12
    ids = np.union1d(lower.edge_ids, upper.edge_ids + shift)
    assert np.array_equal(ids, np.sort(whole.edge_ids))
    assert lower.n_cells + upper.n_cells == whole.n_cells


def test_mirrored_direction_keeps_normals_outward():
    vol = Volume(ball(26, 9.0), direction=np.diag([-1.0, 1.0, 1.0]), spacing=(1, 2, 0.5))
    mesh = extract(vol, 0.0)
    assert mesh.signed_volume() > 0


def test_raw_nrrd_and_tiff_samples_give_identical_meshes():
    samples = load_samples_module()
    root = samples.HERE
    for name, level in (("torus", 3.0), ("sphere", 127.5), ("two_spheres", 0.25)):
        meshes = []
        for path in [*root.glob(f"{name}_*.raw"), root / f"{name}.nrrd", root / f"{name}.tif"]:
            meshes.append(extract(isoconvert.read_volume(path), level))
        assert len(meshes) == 3
        for other in meshes[1:]:
            assert np.array_equal(meshes[0].vertices, other.vertices)
            assert np.array_equal(meshes[0].cells, other.cells)


def test_committed_samples_match_their_script(tmp_path):
    samples = load_samples_module()
    for name, make in samples.SAMPLES.items():
        data = make()
        vol = isoconvert.read_volume(next(samples.HERE.glob(f"{name}_*.raw")))
        assert np.array_equal(vol.data, data), name


# --- real scans against the peers --------------------------------------------

SCANS = [
    ("engine_256x256x128_uint8.raw", "uint8", 80.5),
    ("tooth_103x94x161_uint8.raw", "uint8", 100.5),
    ("hydrogen_atom_128x128x128_uint8.raw", "uint8", 20.5),
    ("marschner_lobb_41x41x41_uint8.raw", "uint8", 100.5),
    ("hydrogen_vtk_64x64x64_float32.raw", "float32", 0.1001),
]


@pytest.mark.parametrize(("name", "dtype", "level"), SCANS)
def test_real_scan_matches_vtk_flying_edges(name, dtype, level):
    path = dataset(name)
    vol = isoconvert.read_volume(path)
    zyx = vol.data.T
    assert not (zyx == level).any(), "the level must equal no sample"
    mesh = extract(vol, level)
    points, cells = vtk_flying_edges(np.ascontiguousarray(zyx), level)
    assert mesh.n_vertices == len(points)
    assert mesh.n_cells == len(cells)
    ours_k, ours_t = edge_key(mesh.vertices)
    vtk_k, vtk_t = edge_key(points)
    assert np.array_equal(ours_k, vtk_k)
    assert np.abs(ours_t - vtk_t).max() < 1e-5
    # same orientation: VTK's normals also point to lower values
    tm_ours = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    tm_vtk = trimesh.Trimesh(points, cells, process=False)
    assert np.sign(tm_ours.volume) == np.sign(tm_vtk.volume)


@pytest.mark.parametrize(("name", "dtype", "level"), SCANS)
def test_real_scan_matches_scikit_image(name, dtype, level):
    measure = pytest.importorskip("skimage.measure")
    vol = isoconvert.read_volume(dataset(name))
    mesh = extract(vol, level)
    # scikit-image indexes the array it is given: pass (x, y, z) so no axis mapping is needed
    verts, faces, _, _ = measure.marching_cubes(vol.data, level, method="lorensen")
    assert (mesh.n_vertices, mesh.n_cells) == (len(verts), len(faces))
    ours_k, ours_t = edge_key(mesh.vertices)
    sk_k, sk_t = edge_key(verts.astype(np.float64))
    assert np.array_equal(ours_k, sk_k)
    assert np.abs(ours_t - sk_t).max() < 1e-5
    # Lewiner (the default method) adds a vertex inside the cube for some ambiguous
    # cases (MC33); its vertices on grid edges are still exactly ours.
    lv, _, _, _ = measure.marching_cubes(vol.data, level, method="lewiner")
    idx = lv.astype(np.float64)
    on_edge = (np.abs(idx - np.rint(idx)) < 1e-6).sum(axis=1) >= 2
    lew_k, lew_t = edge_key(idx[on_edge])
    assert np.array_equal(ours_k, lew_k)
    assert np.abs(ours_t - lew_t).max() < 1e-5


def test_anisotropic_spacing_and_lps_directions_avf():
    import nrrd

    path = dataset("avf_float_32.nrrd")
    header = nrrd.read_header(str(path))
    vol = isoconvert.read_volume(path)
    assert np.allclose(vol.spacing, [0.72265601, 0.72265601, 1.0])
    mesh = extract(vol, 500.0)
    index_mesh = extract(Volume(vol.data), 500.0)
    # world = origin + index @ space_directions (rows are the axis vectors)
    expected = header["space origin"] + index_mesh.vertices @ header["space directions"]
    assert np.allclose(mesh.vertices, expected, atol=1e-9)
    # diag(-s, -s, 1) has a positive determinant: triangles keep their order
    assert np.array_equal(mesh.cells, index_mesh.cells)
    assert mesh.signed_volume() > 0


def test_oblique_space_directions_flair():
    import nrrd

    path = dataset("FLAIR.nrrd")
    header = nrrd.read_header(str(path))
    vol = isoconvert.read_volume(path)
    mesh = extract(vol, 100.5)
    index_mesh = extract(Volume(vol.data), 100.5)
    expected = header["space origin"] + index_mesh.vertices @ header["space directions"]
    assert np.allclose(mesh.vertices, expected, atol=1e-9)
    mirrored = np.linalg.det(header["space directions"]) < 0
    assert np.array_equal(mesh.cells, index_mesh.cells[:, ::-1] if mirrored else index_mesh.cells)
    # orientation survives the map: the bright brain's surface points outward
    assert np.sign(mesh.signed_volume()) == np.sign(index_mesh.signed_volume())


@pytest.mark.parametrize(
    ("name", "level"), [("engine_256x256x128_uint8.raw", 80), ("tooth_103x94x161_uint8.raw", 100)]
)
def test_integer_level_on_integer_data_keeps_vtk_counts_without_degenerate_elements(name, level):
    """At a level equal to sample values, VTK (and exact placement) put vertices
    on those samples: zero-length edges and collapsed triangles. The default
    placement keeps them 0.001 of an edge away: the same vertex and triangle
    counts as VTK, no vertex moved by more than 0.001 of an edge, and no
    degenerate element."""
    from isoconvert.report import check_mesh

    vol = isoconvert.read_volume(dataset(name))
    zyx = np.ascontiguousarray(vol.data.T)
    assert (zyx == level).any(), "the level must equal some samples"
    notices = []
    mesh = extract(vol, level, on_status=notices.append)
    exact = extract(vol, level, vertex_offset=0.0)
    points, cells = vtk_flying_edges(zyx, level)
    assert mesh.n_vertices == exact.n_vertices == len(points)
    assert mesh.n_cells == exact.n_cells == len(cells)
    assert np.array_equal(mesh.cells, exact.cells)
    shift = np.abs(mesh.vertices - exact.vertices).max(axis=1)
    assert shift.max() <= 1e-3 + 1e-12 and (shift > 0).any()
    assert any(f"equals {np.count_nonzero(zyx == level):,} samples" in n for n in notices)
    ours = check_mesh(mesh)
    theirs = check_mesh(as_mesh(points, cells))
    assert theirs.problems["zero_length_edges"]["count"] > 0
    assert ours.problems["zero_length_edges"]["count"] == 0
    assert ours.problems["degenerate_triangles"]["count"] == 0
    assert ours.checks["manifold"] and ours.checks["oriented"]


def as_mesh(points, cells):
    return isoconvert.Mesh(np.asarray(points, np.float64), np.asarray(cells, np.int64))


@pytest.mark.parametrize("method", ["cubes", "tetra", "squares"])
def test_samples_near_the_largest_doubles_interpolate_as_scaled_down_ones(method):
    """s1 - s0 overflows to infinity for samples of opposite sign near 1.7e308;
    the vertex must still be the linear interpolation. Scaling all samples by a
    power of two scales no interpolation fraction, so the mesh must equal that
    of the scaled-down volume exactly."""
    field = ball(12, 4.3)  # about -13 .. 4.3
    # samples of both signs near the largest doubles: inside, +1.7e308 ...;
    # outside, -1.7e308 ... (every bipolar edge overflows s1 - s0)
    huge = np.where(field >= 0, 1.7e308 - field * 1e300, -1.7e308 + field * 1e300)
    small = huge / 2.0**1000
    kw = {"axis": "z"} if method == "squares" else {}
    big = extract(Volume(huge), 0.0, method=method, **kw)
    ref = extract(Volume(small), 0.0, method=method, **kw)
    assert np.isfinite(big.vertices).all()
    with np.errstate(over="ignore"):
        assert np.isinf(np.diff(huge, axis=0)).any()
    # no vertex on a grid point: each lies strictly inside its edge
    assert (np.abs(big.vertices - np.rint(big.vertices)).max(axis=1) > 0.1).all()
    np.testing.assert_array_equal(big.vertices, ref.vertices)
    np.testing.assert_array_equal(big.cells, ref.cells)
