"""Issue 24, part 1: ``convert -o NAME.vtu|.vtk|.msh|.xdmf|.inp|.mesh|.med`` writes
through meshio; meshio (the other library) reads the file back with the same
vertices (to float64 precision), the same triangles in the same orientation,
and the normals, values and labels the format keeps."""

from __future__ import annotations

import io
import os
import re
from contextlib import redirect_stdout

import meshio
import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import Blocks, Mesh, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError, extra_hint
from isoconvert.writers import WRITERS

#: writer name -> (suffix, attributes it keeps, has a text form, segments too)
MESHIO_WRITERS = {
    "vtu": (".vtu", {"normals", "values", "labels"}, False, True),
    "vtk": (".vtk", {"normals", "values", "labels"}, True, True),
    "msh": (".msh", {"normals", "values", "labels"}, False, True),
    "xdmf": (".xdmf", {"normals", "values", "labels"}, False, True),
    "inp": (".inp", set(), False, False),
    "medit": (".mesh", set(), False, False),
    "med": (".med", set(), False, False),
}


def needs(name: str) -> None:
    if name in ("xdmf", "med"):
        pytest.importorskip("h5py", reason="meshio writes XDMF and MED with h5py")


@pytest.fixture(scope="module")
def torus() -> Mesh:
    """A closed extraction with normals, values and (made-up) labels per triangle."""
    mesh = extract(read_volume(SAMPLES / "torus.nrrd"), 5.0)
    rng = np.random.default_rng(24)
    mesh.normals = mesh.vertex_normals().astype(np.float32)
    mesh.values = rng.random(mesh.n_vertices).astype(np.float32)
    mesh.cell_labels = rng.integers(0, 7, size=(mesh.n_cells, 2))
    return mesh


def plain(mesh: Mesh) -> Mesh:
    return Mesh(mesh.vertices, mesh.cells, info=dict(mesh.info))


def triangles_of(read: meshio.Mesh, kind: str = "triangle") -> np.ndarray:
    blocks = [c.data for c in read.cells if c.type == kind]
    assert len(blocks) == 1, [c.type for c in read.cells]
    return blocks[0]


@pytest.mark.parametrize("name", list(MESHIO_WRITERS))
@pytest.mark.parametrize("ascii", [False, True], ids=["binary", "ascii"])
def test_meshio_reads_back_what_was_written(torus, tmp_path, name, ascii):
    suffix, keeps, has_text, _ = MESHIO_WRITERS[name]
    if ascii and not has_text:
        pytest.skip(f"{name} has one form")
    needs(name)
    mesh = torus if keeps else plain(torus)
    path = write_mesh(mesh, tmp_path / f"torus{suffix}", ascii=ascii)
    assert sorted(os.listdir(tmp_path)) == [f"torus{suffix}"]  # nothing beside it
    read = meshio.read(path)
    np.testing.assert_array_equal(read.points, torus.vertices)  # float64, exactly
    cells = triangles_of(read)
    # the same triangles in the same order and orientation (no rotation of the corners)
    np.testing.assert_array_equal(cells, torus.cells)
    if "normals" in keeps:
        np.testing.assert_array_equal(read.point_data["Normals"], torus.normals)
    if "values" in keeps:
        np.testing.assert_array_equal(read.point_data["value"], torus.values)
    if "labels" in keeps:
        inside = np.concatenate(read.cell_data["inside_label"])
        outside = np.concatenate(read.cell_data["outside_label"])
        np.testing.assert_array_equal(np.stack([inside, outside], axis=1), torus.cell_labels)


@pytest.mark.parametrize("name", [n for n, spec in MESHIO_WRITERS.items() if spec[3]])
def test_contour_segments_are_lines(tmp_path, name):
    needs(name)
    contours = extract(read_volume(SAMPLES / "figure_2_4.nrrd"), 4.5)
    path = write_mesh(contours, tmp_path / f"c{MESHIO_WRITERS[name][0]}")
    read = meshio.read(path)
    np.testing.assert_array_equal(read.points, contours.vertices)
    np.testing.assert_array_equal(triangles_of(read, "line"), contours.cells)


@pytest.mark.parametrize("name", [n for n, spec in MESHIO_WRITERS.items() if not spec[3]])
def test_formats_without_segments_or_attributes_refuse_them(torus, tmp_path, name):
    contours = extract(read_volume(SAMPLES / "figure_2_4.nrrd"), 4.5)
    suffix = MESHIO_WRITERS[name][0]
    with pytest.raises(FormatError, match="cannot hold contour segments"):
        write_mesh(contours, tmp_path / f"c{suffix}")
    with pytest.raises(FormatError, match="cannot store per-vertex normals; write ply"):
        write_mesh(torus, tmp_path / f"t{suffix}")
    assert os.listdir(tmp_path) == []


def test_the_registry_and_formats_say_via_meshio_and_what_each_keeps():
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["formats"]) == 0
    listing = out.getvalue()
    for name, (suffix, keeps, _, segments) in MESHIO_WRITERS.items():
        writer = WRITERS.get(name)
        assert suffix in writer.suffixes and "via meshio" in writer.summary
        assert set(writer.attributes) == keeps
        assert (2 in writer.cell_sizes) == segments
        assert not writer.streams  # meshio needs the whole mesh
        line = next(row for row in listing.splitlines() if row.split()[:1] == [name])
        assert suffix in line and "via meshio" in line


def test_convert_writes_vtu_from_the_command_line(tmp_path):
    out = tmp_path / "sphere.vtu"
    with redirect_stdout(io.StringIO()):
        code = main(["convert", str(SAMPLES / "sphere.nrrd"), "-l", "100.5", "-o", str(out)])
    assert code == 0
    expected = extract(read_volume(SAMPLES / "sphere.nrrd"), 100.5)
    read = meshio.read(out)
    np.testing.assert_array_equal(read.points, expected.vertices)
    np.testing.assert_array_equal(triangles_of(read), expected.cells)


def test_a_block_wise_run_keeps_the_mesh_in_memory_for_meshio(tmp_path):
    """The engine spills a block-wise mesh to disk only for writers that stream:
    with a budget far below the mesh, a VTU is still written, the same as
    from an in-memory run."""
    from isoconvert.convert import convert
    from isoconvert.extract.blocks import BlockMesh

    source = SAMPLES / "sphere.nrrd"
    convert(source, tmp_path / "a.vtu", 100.5)
    small = convert(source, tmp_path / "b.vtu", 100.5, blocks=Blocks(max_memory=1 << 16))
    assert small.mesh.info["blocks"] > 1 and not isinstance(small.mesh, BlockMesh)
    a, b = meshio.read(tmp_path / "a.vtu"), meshio.read(tmp_path / "b.vtu")
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(triangles_of(a), triangles_of(b))


def test_a_mesh_spilled_to_disk_is_refused_in_one_line(tmp_path):
    from isoconvert.extract.blocks import BlockMesh

    volume = read_volume(SAMPLES / "sphere.nrrd")
    spilled = extract(volume, 100.5, blocks=Blocks(max_memory=1 << 16, spill_dir=tmp_path))
    assert isinstance(spilled, BlockMesh)
    with pytest.raises(FormatError) as caught:
        write_mesh(spilled, tmp_path / "big.vtu")
    message = str(caught.value)
    assert "\n" not in message and "written whole" in message and "ply" in message
    assert not (tmp_path / "big.vtu").exists()
    write_mesh(spilled, tmp_path / "big.ply")  # a streaming writer takes it


def test_a_meshio_failure_is_one_line_and_leaves_no_file(torus, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise ValueError("something inside meshio\nwith a second line")

    monkeypatch.setattr(meshio, "write", broken)
    with pytest.raises(FormatError) as caught:
        write_mesh(plain(torus), tmp_path / "t.vtu")
    assert "\n" not in str(caught.value) and "meshio could not write" in str(caught.value)
    assert os.listdir(tmp_path) == []


def test_a_missing_h5py_is_the_install_hint(torus, tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "h5py", None)  # import h5py now raises ImportError
    with pytest.raises(
        FormatError, match=re.escape(f"needs the h5py package; {extra_hint('hdf5')}")
    ):
        write_mesh(plain(torus), tmp_path / "t.xdmf")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    "suffix, why", [(".vtu", "12 significant digits"), (".msh", "cannot read back")]
)
def test_a_text_form_meshio_does_not_give_back_is_refused(torus, tmp_path, suffix, why):
    with pytest.raises(FormatError, match=f"{why}.*; leave out --ascii"):
        write_mesh(torus, tmp_path / f"t{suffix}", ascii=True)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("name", ["vtu", "vtk", "msh", "inp"])
def test_the_report_on_what_is_written_is_the_report_on_the_file(tmp_path, name):
    """convert --report judges stored_mesh(mesh, format): for an open mesh (a sphere
    cut by the grid) it must say what check of the file says, and meshio's files
    cannot record that a grid cut the mesh (isoconvert's own headers do)."""
    from isoconvert import check_mesh
    from isoconvert.meshfile import read_mesh
    from isoconvert.writers import stored_mesh

    mesh = extract(read_volume(SAMPLES / "sphere.nrrd"), 60.5)
    path = write_mesh(mesh, tmp_path / f"cut{MESHIO_WRITERS[name][0]}")
    on_file = check_mesh(read_mesh(path), source="m").to_dict()
    on_stored = check_mesh(stored_mesh(mesh, name), source="m").to_dict()
    assert on_stored == on_file
    assert on_file["checks"]["no-holes"] is False  # no record: every open edge is a hole
