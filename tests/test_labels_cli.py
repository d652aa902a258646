"""Label volumes from the command line and the API: --labels, --label, --single-file (issue 12)."""

from __future__ import annotations

import nrrd
import numpy as np
import pytest
from conftest import dataset

from isoconvert import check_mesh
from isoconvert.cli import main
from isoconvert.extract.labels import label_surfaces
from isoconvert.label_convert import convert_labels
from isoconvert.meshfile import read_mesh
from isoconvert.volume import Volume

vtk = pytest.importorskip("vtk")
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

SPACING = (0.5, 0.5, 1.0)


@pytest.fixture
def atlas(tmp_path):
    """Two boxes (3, 7) touching each other and the grid's z = 0 face, and a ball (9)."""
    x, y, z = np.meshgrid(*(np.arange(30),) * 3, indexing="ij")
    labels = np.zeros((30, 30, 30), np.uint8)
    labels[2:15, 2:20, 0:12] = 3
    labels[15:28, 2:20, 0:12] = 7
    labels[((x - 15) ** 2 + (y - 20) ** 2 + (z - 20) ** 2) < 64] = 9
    path = tmp_path / "atlas.nrrd"
    nrrd.write(str(path), labels, {"spacings": list(SPACING)}, index_order="F")
    return path, labels


def test_one_closed_file_per_label(atlas, tmp_path):
    path, labels = atlas
    out = tmp_path / "out" / "atlas.ply"
    out.parent.mkdir()
    assert main(["convert", str(path), "--labels", "-o", str(out), "--smooth", "0", "-q"]) == 0
    names = sorted(p.name for p in out.parent.iterdir())
    assert names == ["atlas_label3.ply", "atlas_label7.ply", "atlas_label9.ply"]
    for value in (3, 7, 9):
        mesh = read_mesh(out.parent / f"atlas_label{value}.ply")
        report = check_mesh(mesh).to_dict()
        assert report["checks"]["watertight"] and report["checks"]["oriented"]
        # the blocky surface encloses exactly the label's voxels
        voxels = np.count_nonzero(labels == value) * np.prod(SPACING)
        assert np.isclose(mesh.signed_volume(), voxels)


def test_files_equal_the_api_and_share_boundaries(atlas, tmp_path):
    path, labels = atlas
    results = convert_labels(path, tmp_path / "a.ply", (3, 7))
    assert [r.output.name for r in results] == ["a_label3.ply", "a_label7.ply"]
    surfaces = label_surfaces(Volume(labels, spacing=SPACING), (3, 7))
    for result, value in zip(results, (3, 7), strict=True):
        read = read_mesh(result.output)
        assert np.array_equal(read.cells, surfaces[value].cells)
        assert np.allclose(read.vertices, surfaces[value].vertices, atol=1e-5)
    # the faces between 3 and 7 are the same triangles, opposite ways round
    three, seven = (r.mesh for r in results)
    shared3 = {tuple(t) for t in np.round(three.vertices[three.cells], 6).reshape(-1, 9)}
    shared7 = {tuple(t) for t in np.round(seven.vertices[seven.cells[:, ::-1]], 6).reshape(-1, 9)}
    # every face between the two boxes (18 x 12 sample faces, two triangles each)
    assert len(shared3 & shared7) == 2 * 18 * 12


@pytest.mark.parametrize("format", ["ply", "precomputed"])
def test_results_do_not_hold_every_label_mesh(atlas, tmp_path, format):
    # a run over many labels keeps counts, not meshes: each mesh is built again,
    # the same as the one written, when a result is asked for it
    import gc
    import weakref

    path, labels = atlas
    out = tmp_path / ("a.ply" if format == "ply" else "layer")
    results = convert_labels(path, out, format=format)
    surfaces = label_surfaces(Volume(labels, spacing=SPACING))
    assert len(results) == 3
    for result, value in zip(results, (3, 7, 9), strict=True):
        mesh = result.mesh
        held = weakref.ref(mesh)
        assert result.summary.n_cells == len(surfaces[value].cells) == mesh.n_cells
        assert result.summary.n_vertices == mesh.n_vertices and mesh.info["label"] == value
        assert np.array_equal(mesh.cells, surfaces[value].cells)
        assert np.array_equal(mesh.vertices, surfaces[value].vertices)
        if format == "ply":
            assert np.array_equal(read_mesh(result.output).cells, mesh.cells)
        del mesh
        gc.collect()
        assert held() is None  # nothing but the caller held it


def test_single_file_holds_both_labels_of_each_triangle(atlas, tmp_path):
    path, labels = atlas
    out = tmp_path / "a.vtp"
    assert main(["convert", str(path), "--labels", "--single-file", "-o", str(out), "-q"]) == 0
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(out))
    reader.Update()
    data = reader.GetOutput()
    pairs = vtk_to_numpy(data.GetCellData().GetArray("labels"))
    surfaces = label_surfaces(Volume(labels, spacing=SPACING))
    assert np.array_equal(pairs, surfaces.boundary_labels)
    assert {tuple(p) for p in pairs.tolist()} == {(3, 0), (7, 0), (9, 0), (3, 7)}
    ply = tmp_path / "a.ply"
    args = ["convert", str(path), "--labels", "--single-file", "-o", str(ply), "-q", "--ascii"]
    assert main(args) == 0
    lines = ply.read_text().splitlines()
    assert "property int inside_label" in lines and "property int outside_label" in lines
    faces = [line.split() for line in lines if line.startswith("3 ")]
    got = np.array([[int(f[4]), int(f[5])] for f in faces])
    assert np.array_equal(got, surfaces.boundary_labels)


def test_real_binary_scan(tmp_path):
    src = dataset("bat-cochlea-volume.tif")
    out = tmp_path / "cochlea.ply"
    assert main(["convert", str(src), "--labels", "-o", str(out), "-q"]) == 0
    (written,) = tmp_path.glob("cochlea_label*.ply")
    report = check_mesh(read_mesh(written)).to_dict()
    assert all(report["checks"][name] for name in ("watertight", "manifold", "oriented"))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--labels", "-l", "3"], "leave out --level"),
        (["--label", "3,5"], "label 5 not in the volume; labels present: 3, 7, 9"),
        (["--label", "3,x"], "--label takes whole numbers"),
        (["--labels", "--single-file", "--format", "stl"], "cannot store per-triangle labels"),
        (["--single-file"], "--single-file writes the surfaces of --labels"),
        (["--labels", "--normals"], "leave them out with --labels"),
        (["--labels", "--single-file", "--largest"], "would break the shared boundaries"),
        ([], "convert needs --level"),
    ],
)
def test_label_mistakes_are_one_line(atlas, tmp_path, capsys, extra, message):
    path, _ = atlas
    out = tmp_path / "x.ply"
    code = main(["convert", str(path), "-o", str(out), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and message in err[0]
    assert not list(tmp_path.glob("x*"))


def test_an_intensity_scan_is_not_taken_for_labels(tmp_path, capsys):
    """Every value of a CT scan would be a label: 255 files, minutes of work."""
    src = dataset("engine_256x256x128_uint8.raw")
    code = main(["convert", str(src), "--labels", "-o", str(tmp_path / "e.ply")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "looks like an intensity image" in err[0]
    assert not list(tmp_path.iterdir())
    # naming the labels says the user means it
    assert main(["convert", str(src), "--label", "200", "-o", str(tmp_path / "e.ply"), "-q"]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["e_label200.ply"]


def test_batch_extracts_the_labels_of_every_file(atlas, tmp_path, capsys):
    path, labels = atlas
    folder = tmp_path / "in"
    folder.mkdir()
    path.rename(folder / "a.nrrd")
    nrrd.write(str(folder / "b.nrrd"), (labels == 9).astype(np.uint8), index_order="F")
    out = tmp_path / "out"
    args = ["batch", str(folder), "-o", str(out), "--labels", "--smooth", "0", "-q"]
    assert main([*args, "--require", "watertight", "--summary", str(tmp_path / "s.json")]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["a_label3.ply", "a_label7.ply", "a_label9.ply", "b_label1.ply"]
    ball = read_mesh(out / "b_label1.ply")
    assert np.isclose(ball.signed_volume(), np.count_nonzero(labels == 9))
    import json

    rows = json.loads((tmp_path / "s.json").read_text())["files"]
    assert [r["status"] for r in rows] == ["ok", "ok"]
    # the label files count as the file's output
    assert main([*args, "--summary", str(tmp_path / "s2.json")]) == 1
    rows = json.loads((tmp_path / "s2.json").read_text())["files"]
    assert "a_label*.ply: already exists" in rows[0]["message"]


def test_a_single_file_is_judged_label_by_label(atlas, tmp_path, capsys):
    """Where three labels meet, edges have four triangles: the single-file mesh is
    judged on each label's surface, which is closed, and encloses that label's voxels
    (the background's encloses the others, inside out). A missing face is named."""
    path, labels = atlas
    out = tmp_path / "s.ply"
    args = ["convert", str(path), "--labels", "--single-file", "--smooth", "0", "-o", str(out)]
    assert main([*args, "-q", "--require", "watertight,manifold,oriented,no-holes"]) == 0
    mesh = read_mesh(out)
    report = check_mesh(mesh)
    assert report.problems["non_manifold_edges"]["count"] > 0  # the triple junctions
    assert all(report.checks[c] for c in ("watertight", "manifold", "oriented", "no-holes"))
    voxel = np.prod(SPACING)
    volumes = {s["label"]: s["volume"] for s in report.topology["per_label"]}
    for value in (3, 7, 9):
        assert np.isclose(volumes[value], np.count_nonzero(labels == value) * voxel)
    assert np.isclose(volumes[0], -np.count_nonzero(labels) * voxel)
    # the VTP file carries the labels too (its 2-component cell array)
    vtp = tmp_path / "s.vtp"
    assert main([*args[:-1], str(vtp), "-q"]) == 0
    assert check_mesh(read_mesh(vtp)).topology["per_label"] == report.topology["per_label"]
    # one face between 3 and 7 taken out: those two labels are open, and say so
    shared = np.flatnonzero((mesh.cell_labels == (3, 7)).all(axis=1))[0]
    keep = np.arange(mesh.n_cells) != shared
    broken = type(mesh)(mesh.vertices, mesh.cells[keep], cell_labels=mesh.cell_labels[keep])
    report = check_mesh(broken)
    assert not report.checks["watertight"]
    open_labels = {s["label"] for s in report.topology["per_label"] if not s["watertight"]}
    assert open_labels == {3, 7}
    from isoconvert.report import format_report

    text = format_report(report)
    assert "label 3: " in text and "not watertight" in text and "label 9: " in text
