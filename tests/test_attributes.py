"""Per-vertex normals (--normals) and values of a second volume (--values), issue 11."""

from __future__ import annotations

import nrrd
import numpy as np
import pytest
from conftest import SAMPLES, ball, dataset

from isoconvert import extract, read_volume, vertex_normals, vertex_values
from isoconvert.attributes import SLAB_LAYERS
from isoconvert.cli import main
from isoconvert.convert import convert
from isoconvert.errors import FormatError, VolumeError
from isoconvert.extract.blocks import Blocks
from isoconvert.mesh import Mesh
from isoconvert.volume import Volume

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy  # noqa: E402


def vtk_normals(zyx: np.ndarray, level: float, spacing, origin=(0.0, 0.0, 0.0)):
    """Points and normals of VTK's vtkFlyingEdges3D with ComputeNormalsOn: central
    differences at the samples, interpolated along the edge, as isoconvert does."""
    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.SetSpacing(*spacing)
    image.SetOrigin(*origin)
    image.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(zyx).ravel(), deep=True))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, level)
    fe.ComputeNormalsOn()
    fe.Update()
    out = fe.GetOutput()
    points = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    return points, vtk_to_numpy(out.GetPointData().GetNormals()).astype(np.float64)


def matched(ours: np.ndarray, theirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orders that pair the two vertex sets (equal up to VTK's float32 points)."""
    from scipy.spatial import cKDTree

    distance, nearest = cKDTree(theirs).query(ours)
    assert distance.max() < 1e-4
    assert len(np.unique(nearest)) == len(theirs) == len(ours)
    return np.arange(len(ours)), nearest


def area_weighted_normals(mesh) -> np.ndarray:
    v, t = mesh.vertices, mesh.cells
    cross = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    total = np.zeros_like(v)
    for corner in range(3):
        np.add.at(total, t[:, corner], cross)
    return total


def test_normals_equal_vtk_flying_edges_on_an_anisotropic_sphere():
    spacing = np.array([1.0, 1.5, 0.7])
    z, y, x = np.mgrid[0:36, 0:30, 0:40].astype(np.float64)
    centre = np.array([19.3, 14.1, 17.7])
    f = np.sqrt(
        ((x - centre[0]) * spacing[0]) ** 2
        + ((y - centre[1]) * spacing[1]) ** 2
        + ((z - centre[2]) * spacing[2]) ** 2
    ).astype(np.float32)
    volume = Volume.from_zyx(f, spacing=spacing, origin=(3.0, -2.0, 5.5))
    mesh = extract(volume, 9.0)
    normals = vertex_normals(mesh, volume)
    points, expected = vtk_normals(f, 9.0, spacing, origin=(3.0, -2.0, 5.5))
    a, b = matched(mesh.vertices, points)
    assert normals.dtype == np.float32 and normals.shape == mesh.vertices.shape
    assert np.abs(normals[a] - expected[b]).max() < 1e-5
    # the analytic answer: values grow outward, so the positive side is outside
    # and normals point inward, toward the centre
    radial = mesh.vertices - (np.array([3.0, -2.0, 5.5]) + centre * spacing)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", normals, radial).max() < -0.999


def test_normals_equal_vtk_on_a_real_scan():
    volume = read_volume(dataset("engine_256x256x128_uint8.raw"))
    mesh = extract(volume, 80.5)
    normals = vertex_normals(mesh, volume)
    points, expected = vtk_normals(volume.data.T, 80.5, volume.spacing)
    a, b = matched(mesh.vertices, points)
    close = np.abs(normals[a] - expected[b]).max(axis=1)
    # VTK normalizes in float32; where the gradient is tiny both are ill-defined
    assert np.mean(close < 1e-4) > 0.9999
    assert len(normals) == len(points) > 100_000


@pytest.mark.parametrize("method", ["cubes", "tetra"])
@pytest.mark.parametrize("flip", [False, True])
def test_normals_point_like_the_triangles(method, flip):
    torus = read_volume(SAMPLES / "torus.nrrd")
    mesh = extract(torus, 3.0, method=method, flip=flip)
    normals = vertex_normals(mesh, torus, flip=flip)
    agree = np.einsum("ij,ij->i", normals, area_weighted_normals(mesh))
    assert (agree > 0).all()
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)


def test_normals_follow_the_direction_matrix_and_the_frame():
    xyz = ball(14, 4.6, center=(6.2, 6.9, 5.4))
    plain = Volume(xyz)
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = Volume(xyz, direction=rotation, spacing=(1.0, 2.0, 0.5), frame="LPS")
    n_plain = vertex_normals(extract(plain, 0.0), plain)
    mesh = extract(turned, 0.0)
    n_turned = vertex_normals(mesh, turned)
    # index-space gradients map to world space through the inverse transpose
    grad = -n_plain.astype(np.float64) @ np.linalg.inv(turned.affine)
    grad /= np.linalg.norm(grad, axis=1, keepdims=True)
    assert np.abs(-grad - n_turned).max() < 1e-6
    ras = turned.in_frame("RAS")
    n_ras = vertex_normals(extract(ras, 0.0), ras)
    assert np.abs(n_ras - n_turned * np.array([-1, -1, 1])).max() < 1e-6


def test_block_wise_and_slab_by_slab_normals_equal_in_memory(tmp_path, monkeypatch):
    xyz = ball(30, 9.3, center=(14.2, 15.1, 13.6)).astype(np.float32)
    path = tmp_path / "b.nrrd"
    nrrd.write(str(path), xyz, {"spacing": [0.5, 0.5, 1.5]}, index_order="F")
    lazy = read_volume(path)
    assert lazy.grid is not None
    in_memory = Volume(xyz, spacing=lazy.spacing)
    expected = vertex_normals(extract(in_memory, 0.0), in_memory)
    monkeypatch.setattr("isoconvert.attributes.SLAB_LAYERS", 3)
    mesh = extract(lazy, 0.0, blocks=Blocks(size=4))
    assert np.array_equal(vertex_normals(mesh, lazy), expected)
    assert SLAB_LAYERS > 3
    # vertices in any order (a mesh from elsewhere) are sampled alike
    shuffle = np.random.default_rng(5).permutation(mesh.n_vertices)
    mixed = Mesh(mesh.vertices[shuffle], np.argsort(shuffle)[mesh.cells])
    assert np.array_equal(vertex_normals(mixed, lazy), expected[shuffle])
    assert np.array_equal(vertex_values(mixed, lazy), vertex_values(mesh, in_memory)[shuffle])


def test_nan_samples_take_their_stand_in_value():
    xyz = ball(16, 5.0)
    xyz[0, 0, 0] = np.nan
    volume = Volume(xyz)
    filled = Volume(np.nan_to_num(xyz, nan=-100.0))
    mesh = extract(volume, 0.0, nan_as=-100.0)
    assert np.array_equal(vertex_normals(mesh, volume, nan_as=-100.0), vertex_normals(mesh, filled))


def test_values_of_the_volume_itself_are_the_level():
    sphere = read_volume(SAMPLES / "sphere.nrrd")
    mesh = extract(sphere, 127.5, vertex_offset=0.0)
    values = vertex_values(mesh, sphere)
    assert values.dtype == np.float32
    assert np.abs(values - 127.5).max() < 1e-4


def test_values_of_another_grid_are_sampled_in_world_coordinates():
    """A field linear in world position is reproduced exactly by trilinear
    interpolation, whatever the second grid's spacing, origin and extent."""
    torus = read_volume(SAMPLES / "torus.nrrd")
    mesh = extract(torus, 3.0)
    lo = mesh.vertices.min(axis=0)
    spacing = np.array([0.37, 0.5, 0.23])
    origin = lo - 1.0
    shape = (60, 50, 100)
    i, j, k = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    x, y, z = (origin[a] + spacing[a] * idx for a, idx in enumerate((i, j, k)))
    other = Volume(2.0 * x - 3.0 * y + 0.5 * z + 7.0, spacing=spacing, origin=origin)
    values = vertex_values(mesh, other).astype(np.float64)
    v = mesh.vertices
    expected = 2.0 * v[:, 0] - 3.0 * v[:, 1] + 0.5 * v[:, 2] + 7.0
    assert np.abs(values - expected).max() < 1e-4
    # shifted half outside: those vertices get NaN, the others their value
    shifted = Volume(other.data, spacing=spacing, origin=origin + (np.ptp(v[:, 0]) / 2, 0, 0))
    outside = np.isnan(vertex_values(mesh, shifted))
    limit = shifted.origin[0]
    assert outside.any() and not outside.all()
    assert np.array_equal(outside, v[:, 0] < limit - 1e-9)


def read_vtp(path):
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    data = reader.GetOutput()
    points = vtk_to_numpy(data.GetPoints().GetData())
    normals = vtk_to_numpy(data.GetPointData().GetNormals())
    values = vtk_to_numpy(data.GetPointData().GetScalars())
    return points, normals, values


@pytest.mark.parametrize("suffix", [".ply", ".vtp", ".glb", ".obj"])
@pytest.mark.parametrize("ascii", [False, True])
def test_files_hold_the_normals_and_values(tmp_path, suffix, ascii):
    import meshio
    import trimesh

    source = SAMPLES / "torus.nrrd"
    out = tmp_path / f"t{suffix}"
    values = None if suffix == ".obj" else source
    result = convert(source, out, 3.0, normals=True, values=values, ascii=ascii)
    mesh = result.mesh
    normals = mesh.normals
    if suffix == ".ply":
        read = meshio.read(out)
        got_normals = np.column_stack([read.point_data[k] for k in ("nx", "ny", "nz")])
        got_values = read.point_data["value"]
        got_points = read.points
    elif suffix == ".vtp":
        got_points, got_normals, got_values = read_vtp(out)
    elif suffix == ".glb":
        scene = trimesh.load(out, process=False)
        (geometry,) = scene.geometry.values()
        got_points = geometry.vertices
        got_normals = geometry.vertex_normals
        got_values = geometry.vertex_attributes["_VALUE"]
    else:
        loaded = trimesh.load(out, process=False)
        got_points, got_normals, got_values = loaded.vertices, loaded.vertex_normals, None
    assert np.allclose(got_points, mesh.vertices, atol=1e-5)
    assert np.array_equal(np.asarray(got_normals, dtype=np.float32), normals)
    if got_values is not None:
        assert np.array_equal(np.asarray(got_values, dtype=np.float32).ravel(), mesh.values)
        assert np.abs(mesh.values - 3.0).max() < 1e-4
    header = out.read_bytes()[:4000]
    assert b"normals volume gradient" in header or suffix == ".glb"


@pytest.mark.parametrize("suffix", [".stl", ".off", ".3mf"])
def test_formats_without_vertex_attributes_refuse_them_before_the_work(tmp_path, suffix, capsys):
    out = tmp_path / f"t{suffix}"
    with pytest.raises(FormatError, match="cannot store per-vertex normals; write ply"):
        convert(SAMPLES / "torus.nrrd", out, 3.0, normals=True)
    code = main(["convert", str(SAMPLES / "torus.nrrd"), "-o", str(out), "-l", "3", "--normals"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "leave out --normals" in err[0]
    assert not out.exists()
    assert not list(tmp_path.iterdir())


def test_obj_refuses_values(tmp_path):
    with pytest.raises(FormatError, match="obj cannot store per-vertex values; write ply, vtp"):
        convert(SAMPLES / "torus.nrrd", tmp_path / "t.obj", 3.0, values=SAMPLES / "torus.nrrd")


def test_cli_values_from_a_missing_file_and_normals_of_contours(tmp_path, capsys):
    out = tmp_path / "t.ply"
    args = ["convert", str(SAMPLES / "torus.nrrd"), "-o", str(out), "-l", "3"]
    code = main([*args, "--values", str(tmp_path / "nope.nrrd")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "nope.nrrd" in err[0]
    assert not out.exists()
    image = SAMPLES / "figure_2_4.nrrd"
    code = main(["convert", str(image), "-o", str(out), "-l", "5.5", "--normals"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "normals need a 3D volume" in err[0]
    assert not out.exists()


def test_cli_notes_vertices_outside_the_values_volume(tmp_path, capsys):
    torus = read_volume(SAMPLES / "torus.nrrd")
    half = tmp_path / "half.nrrd"
    nrrd.write(str(half), np.ascontiguousarray(torus.data[:10]), index_order="F")
    out = tmp_path / "t.ply"
    code = main(
        ["convert", str(SAMPLES / "torus.nrrd"), "-o", str(out), "-l", "3", "--values", str(half)]
    )
    assert code == 0
    err = capsys.readouterr().err
    assert "lie outside" in err and "their value is NaN" in err
    import meshio

    values = meshio.read(out).point_data["value"]
    points = meshio.read(out).points
    assert np.array_equal(np.isnan(values), points[:, 0] > 9 + 1e-6)


def test_batch_writes_normals_like_convert(tmp_path):
    import meshio

    out = tmp_path / "out"
    code = main(
        ["batch", str(SAMPLES / "torus.nrrd"), "-o", str(out), "-l", "3", "--normals", "-q"]
    )
    assert code == 0
    (written,) = out.glob("*.ply")
    single = convert(SAMPLES / "torus.nrrd", tmp_path / "one.ply", 3.0, normals=True)
    read = meshio.read(written)
    got = np.column_stack([read.point_data[k] for k in ("nx", "ny", "nz")])
    assert np.array_equal(got, single.mesh.normals)
    stl = ["batch", str(SAMPLES / "torus.nrrd"), "-o", str(tmp_path / "o2"), "-l", "3"]
    assert main([*stl, "--normals", "--format", "stl"]) == 1
    assert not (tmp_path / "o2").exists()


def test_two_dimensional_volumes_have_no_normals():
    image = read_volume(SAMPLES / "figure_2_4.nrrd")
    mesh = extract(image, 5.0)
    with pytest.raises(VolumeError, match="3D volume"):
        vertex_normals(mesh, image)


def test_a_vanishing_gradient_falls_back_to_the_triangles():
    """Samples 0, 1, 0, 1, ... along x: central differences are 0 at every inner
    sample, so the surface's own (area-weighted) normals stand in there."""
    xyz = np.zeros((6, 4, 4))
    xyz[1::2] = 1.0
    volume = Volume(xyz)
    mesh = extract(volume, 0.5)
    normals = vertex_normals(mesh, volume).astype(np.float64)
    inner = (mesh.vertices[:, 0] > 1) & (mesh.vertices[:, 0] < 4)
    assert inner.any()
    faces = area_weighted_normals(mesh)
    faces /= np.linalg.norm(faces, axis=1, keepdims=True)
    assert np.abs(normals[inner] - faces[inner]).max() < 1e-6
    assert np.allclose(np.abs(normals[:, 0]), 1.0)
