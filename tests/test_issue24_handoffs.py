"""Issue 24, part 3: hand-offs to trimesh, pyvista and meshio (and back) keep
vertices, orientation, normals, values and labels; check_mesh takes the other
libraries' meshes; isoconvert.marching_cubes takes a (z, y, x) array as
scikit-image does and gives scikit-image's surface in (x, y, z) columns.

pyvista is not installed here: its tests are skipped (importorskip) unless it is.
"""

from __future__ import annotations

import sys

import meshio
import numpy as np
import pytest
import trimesh
from conftest import SAMPLES
from scipy.spatial import cKDTree

import isoconvert
from isoconvert import Mesh, as_mesh, check_mesh, extract, marching_cubes, read_volume
from isoconvert.errors import IsoconvertError, VolumeError


@pytest.fixture(scope="module")
def sphere() -> Mesh:
    """A closed extraction (the sphere lies inside the grid)."""
    return extract(read_volume(SAMPLES / "sphere.nrrd"), 100.5)


@pytest.fixture(scope="module")
def decorated(sphere) -> Mesh:
    rng = np.random.default_rng(3)
    return Mesh(
        sphere.vertices,
        sphere.cells,
        normals=sphere.vertex_normals().astype(np.float32),
        values=rng.random(sphere.n_vertices).astype(np.float32),
        cell_labels=rng.integers(0, 5, size=(sphere.n_cells, 2)),
    )


def same_mesh(a: Mesh, b: Mesh, attributes: bool = True) -> None:
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.cells, b.cells)
    if attributes:
        for name in ("normals", "values", "cell_labels"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_to_trimesh_of_a_closed_extraction_is_watertight_with_the_same_volume(sphere):
    tm = sphere.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume > 0  # outward, as extraction orients a bright object
    assert tm.volume == pytest.approx(sphere.signed_volume(), rel=1e-12)
    np.testing.assert_array_equal(tm.vertices, sphere.vertices)  # nothing merged
    np.testing.assert_array_equal(tm.faces, sphere.cells)


def test_trimesh_round_trip_keeps_normals_values_and_labels(decorated):
    tm = decorated.to_trimesh()
    np.testing.assert_array_equal(tm.vertex_normals, decorated.normals)
    same_mesh(Mesh.from_trimesh(tm), decorated)


def test_from_trimesh_computes_no_normals(sphere):
    tm = trimesh.Trimesh(sphere.vertices, sphere.cells, process=False)
    back = Mesh.from_trimesh(tm)
    assert back.normals is None and back.values is None and back.cell_labels is None
    same_mesh(back, Mesh(sphere.vertices, sphere.cells))


@pytest.mark.parametrize("file_format", ["vtu", "gmsh", "ply"])
def test_meshio_round_trip_and_meshio_files_of_it(decorated, tmp_path, file_format):
    converted = decorated.to_meshio()
    assert converted.cells[0].type == "triangle"
    same_mesh(Mesh.from_meshio(converted), decorated)
    # what a user does next: meshio writes it, meshio reads it back
    path = tmp_path / f"m.{ {'gmsh': 'msh'}.get(file_format, file_format) }"
    plain = Mesh(decorated.vertices, decorated.cells).to_meshio()
    meshio.write(path, plain, file_format=file_format)
    read = meshio.read(path, file_format=file_format)
    np.testing.assert_allclose(read.points, decorated.vertices, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(read.cells_dict["triangle"], decorated.cells)


def test_segments_go_to_meshio_lines_and_not_to_trimesh():
    contours = extract(read_volume(SAMPLES / "figure_2_4.nrrd"), 4.5)
    converted = contours.to_meshio()
    assert converted.cells[0].type == "line"
    same_mesh(Mesh.from_meshio(converted), contours, attributes=False)
    with pytest.raises(IsoconvertError, match="contour segments.*to_meshio"):
        contours.to_trimesh()


@pytest.mark.parametrize("kind", ["trimesh", "meshio", "mesh"])
def test_check_mesh_takes_each_library_s_mesh(sphere, kind):
    plain = Mesh(sphere.vertices, sphere.cells)
    given = {"trimesh": plain.to_trimesh, "meshio": plain.to_meshio, "mesh": lambda: plain}[kind]()
    assert check_mesh(given).to_dict() == check_mesh(plain).to_dict()
    assert as_mesh(given).n_cells == sphere.n_cells


def test_anything_else_is_refused_in_one_line():
    with pytest.raises(IsoconvertError, match="got dict"):
        check_mesh({"vertices": [], "faces": []})


def test_a_missing_library_is_the_install_hint(sphere, monkeypatch):
    monkeypatch.setitem(sys.modules, "trimesh", None)
    with pytest.raises(IsoconvertError, match="trimesh is not installed.*; pip install trimesh"):
        sphere.to_trimesh()
    monkeypatch.setitem(sys.modules, "pyvista", None)
    with pytest.raises(IsoconvertError, match="pip install pyvista"):
        sphere.to_pyvista()


def test_pyvista_round_trip(decorated, sphere):
    pytest.importorskip("pyvista")
    poly = decorated.to_pyvista()
    assert poly.volume == pytest.approx(sphere.signed_volume(), rel=1e-9)
    same_mesh(Mesh.from_pyvista(poly), decorated)
    # the labels come along, so the report is the label mesh's, judged label by label
    assert check_mesh(poly).to_dict() == check_mesh(decorated).to_dict()
    plain = Mesh(sphere.vertices, sphere.cells)
    assert check_mesh(plain.to_pyvista()).to_dict() == check_mesh(plain).to_dict()


def test_vtk_flat_polygons_become_fans_keeping_orientation():
    from isoconvert.mesh import _fans

    cells, source = _fans(np.array([3, 0, 1, 2, 4, 3, 4, 5, 6]), 3)
    np.testing.assert_array_equal(cells, [[0, 1, 2], [3, 4, 5], [3, 5, 6]])
    np.testing.assert_array_equal(source, [0, 1, 1])
    lines, source = _fans(np.array([3, 0, 1, 2, 2, 7, 8]), 2)
    np.testing.assert_array_equal(lines, [[0, 1], [1, 2], [7, 8]])
    np.testing.assert_array_equal(source, [0, 0, 1])


# --- the scikit-image call ---------------------------------------------------------------


@pytest.fixture(scope="module")
def blob_zyx() -> np.ndarray:
    """A C-ordered (z, y, x) array with a different length on each axis."""
    z, y, x = np.mgrid[:30, :40, :50].astype(np.float64)
    return np.exp(-(((x - 24.3) / 14) ** 2 + ((y - 19.1) / 11) ** 2 + ((z - 15.2) / 9) ** 2))


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.5, 1.25, 2.0)])
def test_marching_cubes_gives_scikit_image_s_surface_in_xyz_columns(blob_zyx, spacing):
    skimage_measure = pytest.importorskip("skimage.measure")
    verts, faces, _, _ = skimage_measure.marching_cubes(blob_zyx, 0.4, spacing=spacing)
    mesh = marching_cubes(blob_zyx, 0.4, spacing=spacing)
    assert mesh.n_vertices == len(verts) and mesh.n_cells == len(faces)
    area = skimage_measure.mesh_surface_area(verts, faces)
    assert mesh.area() == pytest.approx(area, rel=1e-5)
    theirs = trimesh.Trimesh(verts[:, ::-1], faces, process=False)  # to (x, y, z)
    assert mesh.signed_volume() > 0 and theirs.volume > 0
    assert mesh.signed_volume() == pytest.approx(theirs.volume, rel=1e-4)
    # the same points, up to the column order (scikit-image computes in float32)
    distance, index = cKDTree(verts[:, ::-1]).query(mesh.vertices)
    assert distance.max() < 1e-4 * max(spacing)
    assert len(np.unique(index)) == len(verts)


def test_marching_cubes_origin_is_z_y_x_and_level_defaults_to_mid_range(blob_zyx):
    at_zero = marching_cubes(blob_zyx)
    mid = 0.5 * (blob_zyx.min() + blob_zyx.max())
    same_mesh(at_zero, extract_xyz(blob_zyx, mid), attributes=False)
    moved = marching_cubes(blob_zyx, origin=(100.0, 20.0, 3.0))
    shift = np.broadcast_to([3.0, 20.0, 100.0], moved.vertices.shape)  # (x, y, z) now
    np.testing.assert_allclose(moved.vertices - at_zero.vertices, shift, rtol=0, atol=1e-12)


def extract_xyz(zyx: np.ndarray, level: float) -> Mesh:
    return extract(isoconvert.Volume(zyx.T), level)


def test_marching_cubes_normals_point_outward(blob_zyx):
    mesh = marching_cubes(blob_zyx, 0.4, normals=True)
    assert mesh.normals.shape == (mesh.n_vertices, 3)
    centre = mesh.vertices.mean(axis=0)
    assert (np.einsum("ij,ij->i", mesh.normals, mesh.vertices - centre) > 0).all()


def test_marching_cubes_refuses_what_is_not_a_3d_array():
    with pytest.raises(VolumeError, match=r"3D \(z, y, x\) array"):
        marching_cubes(np.zeros((4, 4)), 0.5)
    with pytest.raises(VolumeError, match="spacing needs 3 numbers"):
        marching_cubes(np.zeros((4, 4, 4)), 0.5, spacing=(1.0, 2.0))
