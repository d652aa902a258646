"""``isoconvert check`` reads VTP, GLB and 3MF: isoconvert's own writers in
every mode, and files written by VTK and trimesh, come back exactly; the
report equals that of the same mesh as PLY; broken files give one line."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES

from isoconvert import Mesh, check_mesh, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.meshfile import read_mesh
from isoconvert.writers import stored_mesh

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import (  # noqa: E402
    numpy_to_vtk,
    numpy_to_vtkIdTypeArray,
    vtk_to_numpy,
)


@pytest.fixture(scope="module")
def torus() -> Mesh:
    return extract(read_volume(SAMPLES / "torus.nrrd"), 5.0)


@pytest.fixture(scope="module")
def sphere() -> Mesh:
    return extract(read_volume(SAMPLES / "sphere.nrrd"), 100.5)


@pytest.fixture(scope="module")
def contours() -> Mesh:
    return extract(read_volume(SAMPLES / "figure_2_4.nrrd"), 4.5)


@pytest.fixture(scope="module")
def far_sphere() -> Mesh:
    """A sphere far from the origin: float32 would merge vertices, so VTP stores doubles."""
    volume = read_volume(SAMPLES / "sphere.nrrd", origin=(1e6, -2e6, 3.25e5), spacing=(1e-3,) * 3)
    return extract(volume, 100.5)


MODES = [("vtp", False), ("vtp", True), ("glb", False), ("3mf", False)]


def report_counts(mesh: Mesh) -> dict:
    """The report as a dict, without what names the file."""
    report = check_mesh(mesh, source="mesh").to_dict()
    report.pop("source", None)
    return report


# --- our own writers ---------------------------------------------------------------------


@pytest.mark.parametrize(("fmt", "ascii"), MODES)
@pytest.mark.parametrize("name", ["torus", "sphere"])
def test_own_files_read_back_exactly(tmp_path, request, name, fmt, ascii):
    mesh = request.getfixturevalue(name)
    path = write_mesh(mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    got = read_mesh(path)
    stored = stored_mesh(mesh, fmt, ascii)
    np.testing.assert_array_equal(got.vertices, stored.vertices)
    np.testing.assert_array_equal(got.cells, stored.cells)
    assert got.vertices.dtype == np.float64 and got.cells.dtype == np.int64
    assert got.info["stored_precision"] == stored.info["stored_precision"] == "float32"
    assert got.info["grid"] == stored.info["grid"]


@pytest.mark.parametrize("ascii", [False, True])
def test_vtp_doubles_and_segments(tmp_path, far_sphere, contours, ascii):
    path = write_mesh(far_sphere, tmp_path / "far.vtp", ascii=ascii)
    got, stored = read_mesh(path), stored_mesh(far_sphere, "vtp", ascii)
    assert got.info["stored_precision"] == stored.info["stored_precision"] == "float64"
    np.testing.assert_array_equal(got.vertices, stored.vertices)
    np.testing.assert_array_equal(got.cells, stored.cells)
    path = write_mesh(contours, tmp_path / "c.vtp", ascii=ascii)
    got, stored = read_mesh(path), stored_mesh(contours, "vtp", ascii)
    assert got.cells.shape[1] == 2
    np.testing.assert_array_equal(got.vertices, stored.vertices)
    np.testing.assert_array_equal(got.cells, stored.cells)


@pytest.mark.parametrize(("fmt", "ascii"), MODES)
def test_check_report_equals_the_ply_report(tmp_path, torus, fmt, ascii):
    ply = write_mesh(torus, tmp_path / "m.ply")
    other = write_mesh(torus, tmp_path / f"m.{fmt}", ascii=ascii)
    expected = report_counts(read_mesh(ply))
    assert report_counts(read_mesh(other)) == expected
    # and through the command line, as JSON
    for path in (ply, other):
        out = tmp_path / f"{path.suffix[1:]}.json"
        assert main(["check", str(path), "--report", str(out), "--quiet"]) == 0
    first = json.loads((tmp_path / "ply.json").read_text())
    second = json.loads((tmp_path / f"{fmt}.json").read_text())
    first.pop("source", None), second.pop("source", None)
    assert first == second
    # the grid the file records judges the boundary: the torus cut by the box has no holes
    assert first["boundary_frame"] == expected["boundary_frame"] == "grid"
    assert first["problems"]["boundary_edges_on_domain_boundary"]["count"] > 0
    assert first["checks"]["no-holes"] and first["topology"]["components"] == 1


# --- files VTK and trimesh write ---------------------------------------------------------


def vtk_polydata(mesh: Mesh, dtype) -> vtk.vtkPolyData:
    data = vtk.vtkPolyData()
    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(mesh.vertices, dtype=dtype), deep=True))
    data.SetPoints(points)
    size = mesh.cells.shape[1]
    cells = vtk.vtkCellArray()
    offsets = np.arange(0, size * len(mesh.cells) + 1, size, dtype=np.int64)
    cells.SetData(
        numpy_to_vtkIdTypeArray(offsets, deep=True),
        numpy_to_vtkIdTypeArray(mesh.cells.astype(np.int64).ravel(), deep=True),
    )
    if size == 3:
        data.SetPolys(cells)
    else:
        data.SetLines(cells)
    return data


def vtk_read(path) -> tuple[np.ndarray, np.ndarray]:
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    data = reader.GetOutput()
    points = vtk_to_numpy(data.GetPoints().GetData()).astype(np.float64)
    cells = data.GetPolys() if data.GetNumberOfPolys() else data.GetLines()
    size = 3 if data.GetNumberOfPolys() else 2
    return points, vtk_to_numpy(cells.GetConnectivityArray()).reshape(-1, size)


@pytest.mark.parametrize("compressor", ["none", "zlib", "lzma"])
@pytest.mark.parametrize("header", ["UInt32", "UInt64"])
@pytest.mark.parametrize("mode", ["appended", "appended-base64", "binary", "ascii"])
def test_vtk_written_vtp(tmp_path, torus, compressor, header, mode):
    writer = vtk.vtkXMLPolyDataWriter()
    writer.SetInputData(vtk_polydata(torus, np.float32))
    writer.SetFileName(str(tmp_path / "v.vtp"))
    writer.SetDataMode({"appended": 2, "appended-base64": 2, "binary": 1, "ascii": 0}[mode])
    writer.SetEncodeAppendedData(mode == "appended-base64")
    writer.SetHeaderType(writer.UInt32 if header == "UInt32" else writer.UInt64)
    {"none": writer.SetCompressorTypeToNone, "zlib": writer.SetCompressorTypeToZLib}.get(
        compressor, writer.SetCompressorTypeToLZMA
    )()
    writer.SetBlockSize(4096)  # several compressed blocks, the last one partial
    assert writer.Write() == 1
    got = read_mesh(tmp_path / "v.vtp")
    np.testing.assert_array_equal(got.vertices, torus.vertices.astype(np.float32))
    np.testing.assert_array_equal(got.cells, torus.cells)
    assert got.info["stored_precision"] == "float32"
    points, cells = vtk_read(tmp_path / "v.vtp")
    np.testing.assert_array_equal(got.vertices, points)
    np.testing.assert_array_equal(got.cells, cells)


def test_vtk_defaults_doubles_and_lines(tmp_path, torus, contours):
    for mesh, name in ((torus, "t.vtp"), (contours, "c.vtp")):
        writer = vtk.vtkXMLPolyDataWriter()  # defaults: appended raw, zlib, UInt64 headers
        writer.SetInputData(vtk_polydata(mesh, np.float64))
        writer.SetFileName(str(tmp_path / name))
        assert writer.Write() == 1
        got = read_mesh(tmp_path / name)
        assert got.info["stored_precision"] == "float64"
        np.testing.assert_array_equal(got.vertices, mesh.vertices)
        np.testing.assert_array_equal(got.cells, mesh.cells)


def test_vtk_rewrite_keeps_our_grid(tmp_path, torus):
    """VTK drops our XML comments but keeps the ``isoconvert`` field array."""
    ours = write_mesh(torus, tmp_path / "ours.vtp")
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(ours))
    reader.Update()
    writer = vtk.vtkXMLPolyDataWriter()
    writer.SetInputData(reader.GetOutput())
    writer.SetFileName(str(tmp_path / "again.vtp"))
    assert writer.Write() == 1
    assert read_mesh(tmp_path / "again.vtp").info["grid"] == stored_mesh(torus, "vtp").info["grid"]


@pytest.mark.parametrize("fmt", ["glb", "3mf"])
def test_trimesh_written(tmp_path, sphere, fmt):
    mesh = trimesh.Trimesh(sphere.vertices, sphere.cells, process=False)
    path = tmp_path / f"t.{fmt}"
    mesh.export(path)
    got = read_mesh(path)
    expected = sphere.vertices.astype(np.float32) if fmt == "glb" else sphere.vertices
    np.testing.assert_array_equal(got.vertices, expected)
    np.testing.assert_array_equal(got.cells, sphere.cells)
    assert got.info["stored_precision"] == ("float32" if fmt == "glb" else "float64")
    # trimesh's own reading (it may merge vertices: compare the triangles' corners)
    back = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(
        got.vertices[got.cells], np.asarray(back.vertices)[back.faces], rtol=0, atol=1e-6
    )
    # the same report as the same mesh in a file of the same precision
    same = stored_mesh(Mesh(expected, sphere.cells), "ply" if fmt == "glb" else "obj")
    del same.info["cut_by_grid"]  # isoconvert's file says a grid cut the mesh; trimesh's not
    counts = report_counts(got)
    # a 3MF always has a unit (millimeter unless it says otherwise): the report gives it
    assert counts["measures"].pop("unit", None) == ("mm" if fmt == "3mf" else None)
    assert counts == report_counts(same)


def test_trimesh_reads_ours_the_same(tmp_path, sphere):
    for fmt in ("glb", "3mf"):
        path = write_mesh(sphere, tmp_path / f"o.{fmt}")
        got = read_mesh(path)
        back = trimesh.load(path, force="mesh", process=False)
        np.testing.assert_allclose(
            got.vertices[got.cells], np.asarray(back.vertices)[back.faces], rtol=0, atol=1e-6
        )


def test_glb_and_3mf_transforms(tmp_path, torus):
    """Node and build-item transforms place the vertices."""
    scene = trimesh.Scene()
    matrix = trimesh.transformations.rotation_matrix(0.5, [0, 0, 1])
    matrix[:3, 3] = [10.0, -3.0, 2.5]
    scene.add_geometry(
        trimesh.Trimesh(torus.vertices, torus.cells, process=False), transform=matrix
    )
    expected = torus.vertices.astype(np.float32).astype(np.float64) @ matrix[:3, :3].T
    expected += matrix[:3, 3]
    for fmt in ("glb", "3mf"):
        path = tmp_path / f"moved.{fmt}"
        scene.export(path)
        got = read_mesh(path)
        assert got.info["stored_precision"] == "float64"
        np.testing.assert_allclose(got.vertices, expected, rtol=0, atol=1e-5)
        np.testing.assert_array_equal(got.cells, torus.cells)


# --- broken files ------------------------------------------------------------------------


def corruptions(path):
    """(name, bytes) of broken versions of a good file."""
    data = path.read_bytes()
    yield "empty", b""
    yield "half", data[: len(data) // 2]
    yield "tail cut", data[:-20]
    yield "garbage", b"\x00\xffnot a mesh" * 50
    middle = bytearray(data)
    middle[len(data) // 3 : len(data) // 3 + 64] = b"\x07" * 64
    yield "overwritten", bytes(middle)


@pytest.mark.parametrize(("fmt", "ascii"), MODES)
def test_broken_files_give_one_line(tmp_path, torus, fmt, ascii, capsys):
    good = write_mesh(torus, tmp_path / f"good.{fmt}", ascii=ascii)
    for name, data in corruptions(good):
        bad = tmp_path / f"bad.{fmt}"
        bad.write_bytes(data)
        try:
            got = read_mesh(bad)
        except FormatError as exc:
            message = str(exc)
            assert "\n" not in message and str(bad) in message, (name, message)
        else:
            # a corruption the format cannot notice (text numbers changed): still a mesh
            assert name == "overwritten" and got.cells.shape[1] == 3
            continue
        capsys.readouterr()
        code = main(["check", str(bad)])
        err = capsys.readouterr().err
        assert code != 0, name
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, (name, err)


def test_broken_structure_names_the_problem(tmp_path, torus):
    glb = write_mesh(torus, tmp_path / "m.glb").read_bytes()
    (tmp_path / "v2.glb").write_bytes(glb[:4] + b"\x01\x00\x00\x00" + glb[8:])
    with pytest.raises(FormatError, match="glTF version 1"):
        read_mesh(tmp_path / "v2.glb")
    with zipfile.ZipFile(tmp_path / "empty.3mf", "w") as package:
        package.writestr("readme.txt", "no model")
    with pytest.raises(FormatError, match="no 3D model part"):
        read_mesh(tmp_path / "empty.3mf")
    text = write_mesh(torus, tmp_path / "a.vtp", ascii=True).read_text()
    start = text.index('Name="connectivity" format="ascii">') + len(
        'Name="connectivity" format="ascii">'
    )
    (tmp_path / "index.vtp").write_text(text[:start] + "\n99999 " + text[start:])
    with pytest.raises(FormatError, match="refers to vertex"):
        read_mesh(tmp_path / "index.vtp")


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".off", ".vtp", ".glb", ".3mf"])
def test_an_empty_file_says_so(tmp_path, suffix):
    (tmp_path / f"e{suffix}").write_bytes(b"")
    with pytest.raises(FormatError, match=r"the file is empty \(0 bytes\)"):
        read_mesh(tmp_path / f"e{suffix}")


def test_a_misspelt_ply_header_line_is_named(tmp_path, torus):
    """An unknown header keyword is an error, not an element silently lost."""
    good = write_mesh(torus, tmp_path / "t.ply", ascii=True).read_bytes()
    bad = tmp_path / "bad.ply"
    bad.write_bytes(good.replace(b"\nelement face", b"\nelemnt face", 1))
    with pytest.raises(FormatError, match="unknown PLY header line 'elemnt face"):
        read_mesh(bad)
    # obj_info lines (some exporters write them) are still read past
    (tmp_path / "info.ply").write_bytes(good.replace(b"\nelement", b"\nobj_info made\nelement", 1))
    assert read_mesh(tmp_path / "info.ply").n_cells == torus.n_cells
