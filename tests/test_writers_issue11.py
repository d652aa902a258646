"""OFF and VTP writers (issue 11), read back by independent libraries: VTK's
own XML PolyData reader, meshio and trimesh."""

from __future__ import annotations

import json
import re

import meshio
import numpy as np
import pytest
import trimesh
from conftest import SAMPLES, ball

from isoconvert import Mesh, Volume, extract, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.extract.blocks import Blocks
from isoconvert.writers import WRITERS, stored_mesh
from isoconvert.writers.header import GRID_PREFIX, unescape_comment

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

NASTY = "données/Müller\nscan--x\r\t\\v\x00 \u2028日本.nrrd-"


@pytest.fixture(scope="module")
def sphere() -> Mesh:
    volume = Volume(ball(14, 4.7), spacing=(0.3, 0.7, 1.1), origin=(100.1, -20.3, 3.7))
    return extract(volume, 0.0)


@pytest.fixture(scope="module")
def contours() -> Mesh:
    image = np.zeros((7, 9))
    image[2:5, 3:7] = 1.0
    image[3, 4] = 0.2
    return extract(Volume(image, spacing=(0.25, 0.5), origin=(1.5, -2.0)), 0.5)


@pytest.fixture(scope="module")
def far_sphere() -> Mesh:
    """A grid step (1e-3) far below float32's rounding 5e6 units from the origin."""
    volume = Volume(ball(14, 4.7), spacing=(1e-3,) * 3, origin=(5e6, 0.0, 0.0))
    return extract(volume, 0.0)


def with_source(mesh: Mesh, source: str) -> Mesh:
    return Mesh(mesh.vertices, mesh.cells, mesh.edge_ids, {**mesh.info, "source": source})


def read_vtp(path):
    """VTK's reader; fails the test on any VTK error or warning."""
    messages = []
    reader = vtk.vtkXMLPolyDataReader()
    for event in ("ErrorEvent", "WarningEvent"):
        reader.AddObserver(event, lambda obj, ev: messages.append(ev))
    reader.SetFileName(str(path))
    reader.Update()
    assert not messages and reader.GetErrorCode() == 0
    return reader.GetOutput()


def vtp_points(data) -> np.ndarray:
    return vtk_to_numpy(data.GetPoints().GetData())


def vtp_field(data) -> list[str]:
    array = data.GetFieldData().GetAbstractArray("isoconvert")
    return [array.GetValue(i) for i in range(array.GetNumberOfValues())]


def vtp_grid(lines: list[str]) -> dict:
    [grid] = [line for line in lines if line.startswith(GRID_PREFIX)]
    return json.loads(grid[len(GRID_PREFIX) :])


# --- registration -----------------------------------------------------------------------------


def test_the_writers_are_registered_between_stl_and_svg():
    names = list(WRITERS.names())
    assert names.index("stl") < names.index("off") < names.index("vtp") < names.index("svg")
    off, vtp = WRITERS.get("off"), WRITERS.get("vtp")
    assert off.suffixes == (".off",) and vtp.suffixes == (".vtp",)
    assert off.cell_sizes == {3} and vtp.cell_sizes == {2, 3}
    assert (off.precision, vtp.precision) == ("float64", "adaptive")
    assert off.streams and vtp.streams and off.records_grid and vtp.records_grid
    assert not off.has_binary and vtp.has_binary


# --- VTP --------------------------------------------------------------------------------------


@pytest.mark.parametrize("ascii", [False, True])
def test_vtp_triangles_read_back_with_vtk(tmp_path, sphere, ascii):
    path = write_mesh(sphere, tmp_path / "m.vtp", ascii=ascii)
    data = read_vtp(path)
    points = vtp_points(data)
    assert points.dtype == np.float32  # nothing lost in float32 here
    stored = stored_mesh(sphere, "vtp")
    assert stored.info["stored_precision"] == "float32"
    assert points.tobytes() == stored.vertices.astype(np.float32).tobytes()
    assert data.GetNumberOfPolys() == sphere.n_cells and data.GetNumberOfLines() == 0
    polys = data.GetPolys()
    assert np.array_equal(vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3), sphere.cells)
    offsets = vtk_to_numpy(polys.GetOffsetsArray())
    assert np.array_equal(offsets, 3 * np.arange(sphere.n_cells + 1))
    lines = vtp_field(data)
    assert lines[0].startswith("made by isoconvert") and "method cubes level 0" in lines
    assert vtp_grid(lines) == stored.info["grid"]


@pytest.mark.parametrize("ascii", [False, True])
def test_vtp_contour_segments_are_lines(tmp_path, contours, ascii):
    path = write_mesh(contours, tmp_path / "c.vtp", ascii=ascii)
    data = read_vtp(path)
    assert data.GetNumberOfLines() == contours.n_cells and data.GetNumberOfPolys() == 0
    lines = data.GetLines()
    connectivity = vtk_to_numpy(lines.GetConnectivityArray()).reshape(-1, 2)
    assert np.array_equal(connectivity, contours.cells)
    assert np.array_equal(
        vtk_to_numpy(lines.GetOffsetsArray()), 2 * np.arange(contours.n_cells + 1)
    )
    assert vtp_points(data).tobytes() == contours.vertices.astype(np.float32).tobytes()
    grid = vtp_grid(vtp_field(data))
    assert grid["shape"] == [7, 9] and grid["origin"] == [1.5, -2.0]


@pytest.mark.parametrize("ascii", [False, True])
def test_far_from_the_origin_vtp_stores_float64_like_ply(tmp_path, far_sphere, ascii):
    notes: list[str] = []
    path = write_mesh(far_sphere, tmp_path / "f.vtp", ascii=ascii, on_status=notes.append)
    assert len(notes) == 1 and notes[0].startswith("note: vertex coordinates written as double")
    assert b'type="Float64" Name="Points"' in path.read_bytes()
    points = vtp_points(read_vtp(path))
    assert points.dtype == np.float64
    assert points.tobytes() == np.asarray(far_sphere.vertices, np.float64).tobytes()
    assert len(np.unique(points, axis=0)) == far_sphere.n_vertices
    ply = write_mesh(far_sphere, tmp_path / "f.ply")
    assert b"property double x" in ply.read_bytes()


@pytest.mark.parametrize("ascii", [False, True])
def test_vtp_provenance_survives_any_source_name(tmp_path, sphere, ascii):
    path = write_mesh(with_source(sphere, NASTY), tmp_path / "n.vtp", ascii=ascii)
    data = path.read_bytes()
    head = data.split(b"<AppendedData")[0]
    head.decode("ascii")  # the XML part is ASCII whatever the path holds
    comments = re.findall(rb"<!--(.*?)-->", head, re.S)
    assert comments and all(b"--" not in c and b"\n" not in c for c in comments)
    sources = [c.decode().strip() for c in comments if c.strip().startswith(b"source ")]
    assert [unescape_comment(s[len("source ") :]) for s in sources] == [NASTY]
    [field] = [line for line in vtp_field(read_vtp(path)) if line.startswith("source ")]
    assert unescape_comment(field[len("source ") :]) == NASTY


@pytest.mark.parametrize("cell_size", [2, 3])
@pytest.mark.parametrize("ascii", [False, True])
def test_an_empty_mesh_is_a_valid_vtp(tmp_path, cell_size, ascii):
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, cell_size), np.int64))
    data = read_vtp(write_mesh(empty, tmp_path / "e.vtp", ascii=ascii))
    assert data.GetNumberOfPoints() == 0 and data.GetNumberOfCells() == 0


def test_binary_vtp_layout(tmp_path, sphere):
    """Raw appended arrays, each after its UInt64 byte count, at the offsets
    the header states (checked by hand, without VTK)."""
    data = write_mesh(sphere, tmp_path / "m.vtp").read_bytes()
    start = data.index(b'<AppendedData encoding="raw">')
    body = data[data.index(b"_", start) + 1 :]
    head = data[:start].decode("ascii")
    assert 'header_type="UInt64"' in head and 'byte_order="LittleEndian"' in head
    offsets = [int(x) for x in re.findall(r'offset="(\d+)"', head)]
    sizes = [int(np.frombuffer(body, "<u8", 1, o)[0]) for o in offsets]
    v, c = sphere.n_vertices, sphere.n_cells
    assert sizes[1:] == [12 * v, 24 * c, 8 * c]
    assert offsets == [0] + list(np.cumsum(np.add(sizes, 8))[:-1])
    cells = np.frombuffer(body, "<i8", 3 * c, offsets[2] + 8).reshape(-1, 3)
    assert np.array_equal(cells, sphere.cells)
    end = offsets[3] + 8 + sizes[3]
    assert body[end:] == b"\n  </AppendedData>\n</VTKFile>\n"


# --- OFF --------------------------------------------------------------------------------------


def test_off_reads_back_exactly_with_trimesh_and_meshio(tmp_path, sphere):
    path = write_mesh(sphere, tmp_path / "m.off")
    text = path.read_text("ascii")
    lines = text.splitlines()
    assert lines[0] == "OFF" and lines[1].startswith("# made by isoconvert")
    assert f"{sphere.n_vertices} {sphere.n_cells} 0" in lines
    grid = [line for line in lines if line.startswith("# " + GRID_PREFIX)]
    assert json.loads(grid[0][2 + len(GRID_PREFIX) :]) == stored_mesh(sphere, "off").info["grid"]
    back = trimesh.load(path, process=False)
    assert back.vertices.tobytes() == np.asarray(sphere.vertices, np.float64).tobytes()
    assert np.array_equal(back.faces, sphere.cells)
    other = meshio.read(path)
    assert other.points.tobytes() == np.asarray(sphere.vertices, np.float64).tobytes()
    assert np.array_equal(other.cells_dict["triangle"], sphere.cells)


def test_off_far_from_the_origin_keeps_every_vertex(tmp_path, far_sphere):
    notes: list[str] = []
    path = write_mesh(far_sphere, tmp_path / "f.off", on_status=notes.append)
    assert notes == []  # float64: nothing to say
    back = trimesh.load(path, process=False)
    assert np.array_equal(back.vertices, far_sphere.vertices)


def test_off_comments_stay_comments_whatever_the_source(tmp_path, sphere):
    path = write_mesh(with_source(sphere, NASTY), tmp_path / "n.off")
    text = path.read_bytes().decode("ascii")
    head = text.split(f"\n{sphere.n_vertices} {sphere.n_cells} 0\n")[0].splitlines()
    assert head[0] == "OFF" and all(line.startswith("# ") for line in head[1:])
    [source] = [line[len("# source ") :] for line in head if line.startswith("# source ")]
    assert unescape_comment(source) == NASTY
    assert len(meshio.read(path).points) == sphere.n_vertices


def test_an_empty_mesh_is_a_valid_off(tmp_path):
    path = write_mesh(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)), tmp_path / "e.off")
    assert path.read_text().splitlines()[-1] == "0 0 0"
    assert len(meshio.read(path).points) == 0


def test_off_cannot_hold_contours(tmp_path, contours):
    with pytest.raises(FormatError, match="off cannot hold contour segments; write .*vtp"):
        write_mesh(contours, tmp_path / "c.off")
    assert not (tmp_path / "c.off").exists()


# --- streaming, CLI ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def raw_volume(tmp_path_factory):
    """A 2 MiB float32 raw file with a bumpy surface."""
    folder = tmp_path_factory.mktemp("raw")
    n = 96
    r = np.arange(n, dtype=np.float32) - (n - 1) / 2
    z, y, x = np.meshgrid(r[:56], r, r, indexing="ij")
    zyx = 40 - np.sqrt(x**2 + y**2 + (z + 20) ** 2) + 3 * np.sin(x / 3) * np.cos(y / 4)
    path = folder / f"bumps_{n}x{n}x56_float32.raw"
    zyx.astype(np.float32).tofile(path)
    return path


@pytest.mark.parametrize("fmt, ascii", [("off", False), ("vtp", False), ("vtp", True)])
def test_a_mesh_larger_than_the_budget_streams_to_the_same_file(raw_volume, tmp_path, fmt, ascii):
    from isoconvert.convert import convert
    from isoconvert.extract.blocks import BlockMesh

    convert(raw_volume, tmp_path / f"a.{fmt}", 0.5, ascii=ascii)
    streamed = convert(
        raw_volume, tmp_path / f"b.{fmt}", 0.5, ascii=ascii, blocks=Blocks(max_memory=1 << 18)
    )
    assert isinstance(streamed.mesh, BlockMesh) and streamed.mesh.info["blocks"] > 10
    assert (tmp_path / f"a.{fmt}").read_bytes() == (tmp_path / f"b.{fmt}").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"a.{fmt}", f"b.{fmt}"]


@pytest.mark.parametrize("name", ["s.off", "s.vtp"])
def test_cli_converts_to_off_and_vtp(tmp_path, capsys, name):
    out = tmp_path / name
    assert main(["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(out)]) == 0
    expected = trimesh.load(write_mesh(extract_sample(), tmp_path / "ref.ply"), process=False)
    if name.endswith(".off"):
        back = trimesh.load(out, process=False)
        assert np.array_equal(back.faces, expected.faces)
        assert np.allclose(back.vertices, expected.vertices, atol=1e-3)
    else:
        data = read_vtp(out)
        assert data.GetNumberOfPolys() == len(expected.faces)
        assert vtp_points(data).tobytes() == np.asarray(expected.vertices, np.float32).tobytes()


def extract_sample() -> Mesh:
    from isoconvert import read_volume

    return extract(read_volume(SAMPLES / "sphere.nrrd"), 127.5)


def test_cli_formats_lists_off_and_vtp(capsys):
    assert main(["formats"]) == 0
    out = capsys.readouterr().out
    assert ".off" in out and ".vtp" in out and "PolyData" in out


def test_check_reads_an_off_file_back_as_it_was_stored(tmp_path):
    """`isoconvert check x.off` sees the mesh the file holds: the stored mesh
    (vertices to the bit, the cells, the grid record), and the report equals
    the one of the same mesh written as PLY."""
    from isoconvert.convert import convert
    from isoconvert.meshfile import read_mesh
    from isoconvert.report import check_mesh
    from isoconvert.writers import stored_mesh

    sphere = SAMPLES / "sphere.nrrd"
    result = convert(sphere, tmp_path / "s.off", 127.5)
    back = read_mesh(tmp_path / "s.off")
    stored = stored_mesh(result.mesh, "off")
    assert back.vertices.tobytes() == stored.vertices.tobytes()
    assert np.array_equal(back.cells, stored.cells)
    assert back.info["grid"] == stored.info["grid"]
    convert(sphere, tmp_path / "s.ply", 127.5)
    as_off = check_mesh(back).to_dict()
    as_ply = check_mesh(read_mesh(tmp_path / "s.ply")).to_dict()
    for report in (as_off, as_ply):
        report.pop("source")
    assert as_off["checks"] == as_ply["checks"] and as_off["topology"] == as_ply["topology"]
