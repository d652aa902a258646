"""Issue 24, part 2: ``check`` and ``preview`` read the surface formats meshio
reads; files written by meshio (the other library) come back exactly and
give the same report as the PLY of the same mesh; broken files and missing
optional packages are one line."""

from __future__ import annotations

import io
import sys
import warnings
from contextlib import redirect_stderr, redirect_stdout

import meshio
import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import Mesh, check_mesh, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError, extra_hint
from isoconvert.meshfile import MESH_SUFFIXES, READ_SUFFIXES, read_mesh

#: the issue's formats and a few more, as meshio writes them
FORMATS = [".vtu", ".vtk", ".msh", ".xdmf", ".inp", ".mesh", ".med", ".avs", ".mdpa"]

HINT = f"needs the h5py package; {extra_hint('hdf5')}"


def needs(suffix: str) -> None:
    if suffix in (".xdmf", ".med"):
        pytest.importorskip("h5py", reason="meshio writes XDMF and MED with h5py")


def meshio_write(path, mesh: Mesh, file_format=None, **data) -> None:
    with warnings.catch_warnings(), redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        # int32 cells: meshio's Gmsh 4.1 writer makes files it cannot read of int64 ones
        cells = mesh.cells.astype(np.int32)
        m = meshio.Mesh(mesh.vertices, [("triangle", cells)], **data)
        meshio.write(path, m, file_format=file_format)


@pytest.fixture(scope="module")
def torus() -> Mesh:
    return extract(read_volume(SAMPLES / "torus.nrrd"), 5.0)


@pytest.fixture(scope="module")
def cut_sphere() -> Mesh:
    """An open surface: the sphere cut by the grid (boundary edges, holes)."""
    volume = read_volume(SAMPLES / "sphere.nrrd")
    return extract(volume, 60.5)


def report(mesh: Mesh) -> dict:
    out = check_mesh(mesh, source="mesh").to_dict()
    out.pop("source", None)
    return out


@pytest.mark.parametrize("suffix", FORMATS)
@pytest.mark.parametrize("which", ["torus", "cut_sphere"])
def test_files_meshio_wrote_come_back_exactly_with_the_report_of_the_ply(
    request, tmp_path, suffix, which
):
    needs(suffix)
    mesh = request.getfixturevalue(which)
    # meshio writes ANSYS for .msh by default; Gmsh (4.1) is what users mean by it
    meshio_write(tmp_path / f"m{suffix}", mesh, "gmsh" if suffix == ".msh" else None)
    meshio_write(tmp_path / "m.ply", mesh)  # read by isoconvert's own PLY reader
    read = read_mesh(tmp_path / f"m{suffix}")
    np.testing.assert_array_equal(read.vertices, mesh.vertices)
    np.testing.assert_array_equal(read.cells, mesh.cells)  # same corners, same orientation
    ply = read_mesh(tmp_path / "m.ply")
    assert report(read) == report(ply)


def test_an_ansys_msh_is_read_too(torus, tmp_path):
    meshio_write(tmp_path / "m.msh", torus, "ansys")
    read = read_mesh(tmp_path / "m.msh")
    np.testing.assert_array_equal(read.vertices, torus.vertices)
    np.testing.assert_array_equal(read.cells, torus.cells)


def test_isoconvert_vtu_gives_back_normals_values_and_labels(torus, tmp_path):
    rng = np.random.default_rng(7)
    mesh = Mesh(
        torus.vertices,
        torus.cells,
        normals=torus.vertex_normals().astype(np.float32),
        values=rng.random(torus.n_vertices).astype(np.float32),
        cell_labels=rng.integers(0, 9, size=(torus.n_cells, 2)),
    )
    for suffix in (".vtu", ".vtk", ".msh"):
        read = read_mesh(write_mesh(mesh, tmp_path / f"t{suffix}"))
        np.testing.assert_array_equal(read.normals, mesh.normals)
        np.testing.assert_array_equal(read.values, mesh.values)
        np.testing.assert_array_equal(read.cell_labels, mesh.cell_labels)
        assert read.info["stored_precision"] == "float64"


def test_quads_are_split_in_two_keeping_orientation_and_lines_are_segments(tmp_path):
    # a unit cube of six outward quads
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    quads = np.array(
        [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]]
    )
    meshio.write(tmp_path / "cube.vtu", meshio.Mesh(v, [("quad", quads)]))
    cube = read_mesh(tmp_path / "cube.vtu")
    assert cube.n_cells == 12
    assert cube.signed_volume() == pytest.approx(1.0)  # outward, as the quads
    checked = check_mesh(cube)
    assert checked.to_dict()["kind"] == "triangles"
    lines = np.array([[0, 1], [1, 3], [3, 2], [2, 0]])
    meshio.write(tmp_path / "square.vtk", meshio.Mesh(v, [("line", lines)]))
    square = read_mesh(tmp_path / "square.vtk")
    np.testing.assert_array_equal(square.cells, lines)


def run(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(list(args))
    return code, out.getvalue(), err.getvalue()


def one_line_error(code: int, out: str, err: str, *parts: str) -> None:
    assert code == 1, err
    assert err.count("\n") == 1 and err.startswith("isoconvert: error: "), err
    assert "Traceback" not in err
    for part in parts:
        assert part in err, (part, err)


def test_a_volume_mesh_without_a_surface_is_one_line(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    meshio.write(tmp_path / "tet.vtu", meshio.Mesh(v, [("tetra", np.array([[0, 1, 2, 3]]))]))
    one_line_error(*run("check", str(tmp_path / "tet.vtu")), "tetra", "no triangles")


@pytest.mark.parametrize("suffix", [".vtu", ".vtk", ".msh", ".inp", ".xdmf", ".mesh"])
@pytest.mark.parametrize("content", [b"not a mesh at all\n", b"\x00\xff" * 200])
def test_unreadable_files_are_one_line(tmp_path, suffix, content):
    path = tmp_path / f"broken{suffix}"
    path.write_bytes(content)
    code, _, err = run("check", str(path))
    assert code == 1 and "Traceback" not in err and err.count("\n") == 1, err
    assert str(path) in err


def test_a_truncated_vtu_is_one_line(torus, tmp_path):
    path = write_mesh(torus, tmp_path / "t.vtu")
    path.write_bytes(path.read_bytes()[:2000])
    one_line_error(*run("check", str(path)), "not a readable VTU mesh")


def test_a_missing_h5py_is_the_install_hint_not_a_traceback(tmp_path, monkeypatch):
    path = tmp_path / "m.med"
    path.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    monkeypatch.setitem(sys.modules, "h5py", None)
    one_line_error(*run("check", str(path)), HINT)


def test_check_and_preview_read_a_vtu_from_the_command_line(torus, tmp_path):
    path = write_mesh(torus, tmp_path / "t.vtu")
    code, out, err = run("check", str(path))
    assert code == 0, err
    assert "triangles" in out and "7,388" not in out
    assert f"{torus.n_cells:,} triangles" in out
    code, _, err = run("preview", str(path), "-o", str(tmp_path / "t.png"), "--size", "160x120")
    assert code == 0, err
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_native_readers_keep_their_formats():
    from isoconvert.meshfile import _READERS
    from isoconvert.meshfile.meshio import FORMATS as MESHIO

    assert set(MESH_SUFFIXES) == set(_READERS)
    assert not set(MESHIO) & set(MESH_SUFFIXES)
    assert set(READ_SUFFIXES) == set(MESH_SUFFIXES) | set(MESHIO)


def test_an_unknown_suffix_names_every_format_read(tmp_path):
    path = tmp_path / "m.xyz"
    path.write_text("x")
    with pytest.raises(FormatError, match=r"check reads .*\.ply.*\.vtu.*\.msh"):
        read_mesh(path)


def test_an_xdmf_with_hdf5_data_without_h5py_is_the_install_hint(torus, tmp_path, monkeypatch):
    pytest.importorskip("h5py")
    path = tmp_path / "m.xdmf"
    meshio.write(path, meshio.Mesh(torus.vertices, [("triangle", torus.cells)]))  # HDF5 data
    assert read_mesh(path).n_cells == torus.n_cells
    monkeypatch.setitem(sys.modules, "h5py", None)
    one_line_error(*run("check", str(path)), HINT)
