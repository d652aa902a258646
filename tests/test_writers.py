"""Writers, read back by independent libraries (trimesh, meshio)."""

from __future__ import annotations

import dataclasses

import meshio
import numpy as np
import pytest
import trimesh
from conftest import ball

from isoconvert import Mesh, Volume, extract, write_mesh
from isoconvert.errors import FormatError, OutputError
from isoconvert.writers import WRITERS


@pytest.fixture(scope="module")
def mesh():
    return extract(Volume(ball(16, 5.3), origin=(100.0, -20.0, 3.0)), 0.0)


CASES = [("ply", False), ("ply", True), ("obj", True), ("stl", False), ("stl", True)]


def corners(vertices, cells):
    """Triangles as sorted rows of their 9 corner coordinates (order-free comparison)."""
    c = np.asarray(vertices, np.float64)[np.asarray(cells)].reshape(len(cells), 9)
    return c[np.lexsort(c.T[::-1])]


@pytest.mark.parametrize(("fmt", "ascii"), CASES)
def test_read_back_with_trimesh(tmp_path, mesh, fmt, ascii):
    path = write_mesh(mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    back = trimesh.load(path, process=False, force="mesh")
    tol = 1e-4  # float32 in PLY and STL, relative to coordinates ~100
    if fmt == "stl":
        # STL has no shared vertices: compare triangle by triangle
        assert np.allclose(
            corners(back.vertices, back.faces), corners(mesh.vertices, mesh.cells), atol=tol
        )
        return
    assert len(back.vertices) == mesh.n_vertices
    assert np.allclose(back.vertices, mesh.vertices, atol=tol)
    assert np.array_equal(back.faces, mesh.cells)


@pytest.mark.parametrize(("fmt", "ascii"), CASES)
def test_read_back_with_meshio(tmp_path, mesh, fmt, ascii):
    path = write_mesh(mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    back = meshio.read(path)
    tri = back.cells_dict["triangle"]
    if fmt == "stl":
        assert np.allclose(corners(back.points, tri), corners(mesh.vertices, mesh.cells), atol=1e-4)
        return
    assert np.allclose(back.points, mesh.vertices, atol=1e-4)
    assert np.array_equal(tri, mesh.cells)


def test_obj_keeps_full_precision(tmp_path, mesh):
    back = meshio.read(write_mesh(mesh, tmp_path / "m.obj"))
    assert np.array_equal(back.points, mesh.vertices)


def test_binary_stl_normals_are_unit_or_zero_never_nan(tmp_path):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    cells = np.array([[0, 1, 2], [0, 1, 3]])  # the second has zero area
    path = write_mesh(Mesh(verts, cells), tmp_path / "d.stl")
    records = np.frombuffer(
        path.read_bytes()[84:], dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]
    )
    assert np.allclose(records["n"], [[0, 0, 1], [0, 0, 0]])


def test_existing_output_needs_force(tmp_path, mesh):
    path = tmp_path / "m.ply"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="already exists; pass --force"):
        write_mesh(mesh, path)
    assert path.read_bytes() == b"keep me"
    write_mesh(mesh, path, force=True)
    assert path.read_bytes().startswith(b"ply\n")


def test_failure_while_writing_leaves_nothing(tmp_path, mesh, monkeypatch):
    def broken(mesh, fh, ascii):
        fh.write(b"half a file")
        raise KeyboardInterrupt

    monkeypatch.setitem(
        WRITERS._entries, "ply", dataclasses.replace(WRITERS.get("ply"), write=broken)
    )
    with pytest.raises(KeyboardInterrupt):
        write_mesh(mesh, tmp_path / "m.ply")
    assert list(tmp_path.iterdir()) == []


def test_unknown_extension_lists_formats(tmp_path, mesh):
    with pytest.raises(FormatError, match=r"known output formats: ply .*obj .*stl"):
        write_mesh(mesh, tmp_path / "m.xyz")  # .vtk is written via meshio (issue 24)


def test_missing_folder(tmp_path, mesh):
    with pytest.raises(OutputError, match="does not exist"):
        write_mesh(mesh, tmp_path / "no" / "m.ply")
