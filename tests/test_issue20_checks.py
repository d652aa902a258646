"""Issue 20: checks and pictures that must not call a broken mesh fine.

- A mesh with no recorded grid, and no record that a grid cut it, is not
  excused by its own bounding box: an open box written by trimesh has holes.
- A preview says what ``check`` says: NaN/Inf vertices, and failed checks it
  cannot draw, are in its footer; the surface is still drawn.
- A zero-length edge is one whose ends are at one position, by two indices or
  by one index twice; counted the same way in triangles and in segments.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import ball

from isoconvert import Volume, extract
from isoconvert.checks import CHECK_NAMES
from isoconvert.cli import main
from isoconvert.mesh import Mesh
from isoconvert.meshfile import read_mesh
from isoconvert.report import NO_FACE_NOTE, NO_FRAME_NOTE, check_mesh, format_report
from isoconvert.writers import write_mesh


def run(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# --- an open box is open --------------------------------------------------------------------


def open_box() -> trimesh.Trimesh:
    """A 2 x 2 x 2 cube without the triangles of its -x and +x faces.

    By hand: each missing square face leaves its 4 sides as edges of one triangle
    (the face's diagonal went with it), so 8 boundary edges, none shared.
    """
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    keep = np.abs(box.face_normals[:, 0]) < 0.5
    assert keep.sum() == 8  # 12 triangles, 2 per face
    return trimesh.Trimesh(box.vertices, box.faces[keep], process=False)


@pytest.mark.parametrize("suffix", ["ply", "stl"])
def test_an_open_box_written_by_trimesh_has_holes(tmp_path, suffix):
    path = tmp_path / f"box.{suffix}"
    open_box().export(path)
    report = check_mesh(read_mesh(path))
    assert report.boundary_frame == "none"
    assert report.problems["boundary_edges_inside"]["count"] == 8
    assert report.problems["boundary_edges_on_domain_boundary"]["count"] == 0
    assert not report.checks["no-holes"] and not report.checks["watertight"]
    assert report.notes == [NO_FRAME_NOTE]
    assert NO_FRAME_NOTE in format_report(report)


@pytest.mark.parametrize("suffix", ["ply", "stl"])
def test_check_require_no_holes_fails_on_an_open_box(tmp_path, capsys, suffix):
    path = tmp_path / f"box.{suffix}"
    open_box().export(path)
    code, out, _ = run(capsys, "check", path, "--require", "no-holes")
    assert code == 4
    assert "FAIL  no-holes" in out


def test_the_bounding_box_stands_in_only_for_a_mesh_a_grid_cut():
    """The same open box, recorded as cut by a grid (as isoconvert's files are):
    its rims lie on the box's x faces, which then stand for the grid's."""
    box = open_box()
    cut = check_mesh(Mesh(box.vertices, box.faces, info={"cut_by_grid": True}))
    assert cut.boundary_frame == "bounding box"
    assert cut.problems["boundary_edges_on_domain_boundary"]["count"] == 8
    assert cut.checks["no-holes"]


def test_isoconvert_stl_of_a_cut_ball_passes_and_trimesh_copy_fails(tmp_path):
    """A ball cut by the grid's top face, extracted and written as STL (no grid in
    STL): check judges its rim against the bounding box, as isoconvert's header
    says a grid cut it; the same triangles written by trimesh are an open surface."""
    mesh = extract(Volume(ball(24, 9.0, center=(12.0, 12.0, 20.0))), 0.0)
    ours = write_mesh(mesh, tmp_path / "ours.stl")
    mine = check_mesh(read_mesh(ours))
    assert mine.boundary_frame == "bounding box" and mine.checks["no-holes"]
    rim = mine.problems["boundary_edges_on_domain_boundary"]["count"]
    assert rim > 0
    theirs = tmp_path / "theirs.stl"
    trimesh.Trimesh(mesh.vertices, mesh.cells, process=False).export(theirs)
    other = check_mesh(read_mesh(theirs))
    assert other.boundary_frame == "none" and not other.checks["no-holes"]
    assert other.problems["boundary_edges_inside"]["count"] == rim


# --- previews say what check says ------------------------------------------------------------

vtk = pytest.importorskip("vtkmodules", reason="previews need isoconvert[render] (VTK)")

from isoconvert.preview import (  # noqa: E402
    PROBLEMS,
    RenderError,
    preview_file,
    render_preview,
    require_renderer,
)
from isoconvert.preview.annotate import ALL_PASS  # noqa: E402

HOLE = PROBLEMS["boundary_edges_inside"][1]


@pytest.fixture(autouse=True)
def _headless(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


@pytest.fixture
def renderer():
    try:
        require_renderer()
    except RenderError as why:
        pytest.skip(str(why))


def sphere() -> Mesh:
    s = trimesh.creation.icosphere(2)
    return Mesh(np.array(s.vertices), np.array(s.faces, np.int64))


def surface_pixels(preview) -> int:
    """Pixels of the shaded surface (grey, not white, not a mark colour) in the panels."""
    image = preview.image.astype(int)
    grey = (np.ptp(image, axis=2) < 8) & (image.sum(axis=2) < 3 * 245) & (image.sum(axis=2) > 90)
    top = min(view.box[1] for view in preview.views)
    bottom = max(view.box[3] for view in preview.views)
    return int(grey[top:bottom].sum())


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_preview_of_non_finite_vertices_says_what_check_says(renderer, bad):
    mesh = sphere()
    mesh.vertices[5, 1] = bad
    report = check_mesh(mesh)
    failed = report.failures(list(CHECK_NAMES))
    assert failed == list(CHECK_NAMES)  # check fails every test on it
    preview = render_preview(mesh, size=(400, 300))
    summary = preview.summary()
    assert summary["failed_checks"] == failed
    assert summary["non_finite_vertices"] == 1
    assert "1 vertex is NaN/Inf: not drawn" in summary["footer"]
    assert ALL_PASS not in summary["footer"]
    # the rest of the surface is drawn (it was a blank picture): nearly all the
    # sphere's pixels, less the few triangles around the vertex
    whole = surface_pixels(render_preview(sphere(), size=(400, 300)))
    assert 0.9 * whole < surface_pixels(preview) <= whole


def test_a_preview_names_failed_checks_it_cannot_draw(renderer):
    """A closed sphere with one triangle turned over: no hole, non-manifold or
    zero-length edge to draw, but check fails 'oriented'; the footer says so."""
    mesh = sphere()
    mesh.cells[0] = mesh.cells[0, ::-1]
    failed = check_mesh(mesh).failures(list(CHECK_NAMES))
    assert failed == ["oriented"]
    footer = render_preview(mesh, size=(400, 300)).summary()["footer"]
    assert footer == ["check fails oriented"]


def test_a_sound_preview_says_all_pass(renderer):
    mesh = sphere()
    assert check_mesh(mesh).failures(list(CHECK_NAMES)) == []
    assert render_preview(mesh, size=(400, 300)).summary()["footer"] == [ALL_PASS]


@pytest.mark.parametrize("suffix", ["ply", "stl"])
def test_the_preview_of_an_open_box_marks_its_holes(renderer, tmp_path, suffix):
    path = tmp_path / f"box.{suffix}"
    open_box().export(path)
    preview = preview_file(path, tmp_path / "box.png", size=(400, 300))
    assert preview.marks.counts["boundary_edges_inside"] == 8
    footer = preview.summary()["footer"]
    assert footer[0] == "holes (boundary edges inside) 8"
    assert footer[1] == "check fails watertight, no-holes"
    red = (preview.image == HOLE).all(axis=2)
    for view in preview.views:  # drawn in every panel
        x0, y0, x1, y1 = view.box
        assert red[y0:y1, x0:x1].any(), view.name


# --- zero-length edges -----------------------------------------------------------------------

#: Vertex 3 is at vertex 0's position.
POINTS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]], float)


@pytest.mark.parametrize(
    ("triangles", "expected"),
    [
        # (i, j, k), k at i's position: edges 01, 13, 30; 30 has zero length
        ([[0, 1, 3]], [[0, 3]]),
        # (i, j, i): edges 01, 10, 00; 00 has zero length
        ([[0, 1, 0]], [[0, 0]]),
        # (i, i, i): the edge 00, three times: one edge
        ([[0, 0, 0]], [[0, 0]]),
        # (i, k, k), k at i's position: edges 03, 33, 30: two distinct edges
        ([[0, 3, 3]], [[0, 3], [3, 3]]),
        # all together: the edges 00 and 03 (twice)
        ([[0, 1, 3], [0, 1, 0], [0, 0, 0], [0, 3, 3]], [[0, 0], [0, 3], [3, 3]]),
    ],
)
def test_zero_length_edges_by_index_and_by_position(triangles, expected):
    report = check_mesh(Mesh(POINTS, np.array(triangles)))
    zero = report.problems["zero_length_edges"]
    assert zero["count"] == len(expected)
    assert sorted(e["vertices"] for e in zero["examples"]) == expected
    assert not report.checks["no-zero-length"]
    # every one of these triangles repeats a position: degenerate, no 2-cell
    assert report.problems["degenerate_triangles"]["count"] == len(triangles)
    assert report.counts["edges"] == 0


@pytest.mark.parametrize("segment", [[0, 3], [0, 0]])
def test_zero_length_segments_by_index_and_by_position(segment):
    report = check_mesh(Mesh(POINTS, np.array([segment, [1, 2]])))
    assert report.problems["zero_length_segments"]["count"] == 1
    assert report.problems["degenerate_segments"]["count"] == 1
    assert not report.checks["no-zero-length"] and not report.checks["no-degenerate"]


# --- other ways to call a broken mesh fine ------------------------------------------------------


def test_an_unused_non_finite_vertex_still_fails_every_check():
    mesh = sphere()
    vertices = np.vstack([mesh.vertices, [[np.inf, 0.0, 0.0]]])
    report = check_mesh(Mesh(vertices, mesh.cells))
    assert report.problems["non_finite_vertices"]["count"] == 1
    assert not any(report.checks.values())


@pytest.mark.parametrize(
    "cells",
    [
        np.zeros((0, 3), np.int64),  # no triangle at all
        np.array([[0, 0, 0], [1, 1, 2], [0, 1, 3]]),  # every one repeats a position
        np.array([[0, 3], [1, 1]]),  # segments, every one of zero length
    ],
)
def test_a_mesh_with_no_face_passes_no_check(cells):
    """'manifold' or 'no-holes' would hold only vacuously: --require must not pass it."""
    report = check_mesh(Mesh(POINTS, cells))
    assert report.topology["components"] == 0
    assert report.failures(list(CHECK_NAMES)) == list(CHECK_NAMES)
    assert NO_FACE_NOTE in report.notes


def test_an_open_polyline_without_a_grid_has_holes():
    """Segments: the ends of an open polyline are holes unless a grid cut it."""
    line = Mesh(POINTS[:3], np.array([[0, 1], [1, 2]]))
    report = check_mesh(line)
    assert report.boundary_frame == "none"
    assert report.problems["open_ends_inside"]["count"] == 2
    assert not report.checks["no-holes"]
    cut = check_mesh(Mesh(line.vertices, line.cells, info={"cut_by_grid": True}))
    assert cut.boundary_frame == "bounding box" and cut.checks["no-holes"]


def test_the_preview_command_says_what_the_footer_says(renderer, tmp_path, capsys):
    """`isoconvert preview` of an OBJ with a NaN vertex said "no problems marked"."""
    mesh = sphere()
    mesh.vertices[5] = np.nan
    path = tmp_path / "nan.obj"
    lines = [f"v {x} {y} {z}" for x, y, z in mesh.vertices]
    lines += [f"f {a} {b} {c}" for a, b, c in mesh.cells + 1]
    path.write_text("\n".join(lines) + "\n")
    code, out, err = run(capsys, "preview", path, "-o", tmp_path / "nan.png", "--size", "320x240")
    assert code == 0, err
    assert "1 vertex is NaN/Inf: not drawn; check fails every test" in out
    assert "no problems" not in out


def test_contact_sheet_card_says_what_check_says_of_a_nan_mesh(tmp_path):
    """A thumbnail with nothing to mark (the NaN vertex is not drawn) still
    records the failed checks: the batch sheet's card must show them, in red."""
    pytest.importorskip("vtk")
    import html as html_module
    import re

    from isoconvert.mesh import Mesh
    from isoconvert.preview import SheetEntry, contact_sheet, render_preview, write_preview
    from isoconvert.preview.sheet import thumbnail_name
    from isoconvert.report import check_mesh

    sphere = trimesh.creation.icosphere(2)
    vertices = sphere.vertices.copy()
    vertices[5] = np.nan
    mesh = Mesh(vertices, sphere.faces.astype(np.int64))
    checks = check_mesh(mesh).checks
    assert not any(checks.values())  # what check says: every test fails
    out = tmp_path / "nan.ply"
    out.write_bytes(b"")  # the card links the mesh file
    picture = render_preview(mesh, size=(200, 150))
    assert not any(picture.marks.counts.values())  # nothing drawn to mark
    write_preview(picture, thumbnail_name(out))
    page = contact_sheet([SheetEntry(str(tmp_path / "nan.nrrd"), str(out), "ok")], tmp_path)
    (card,) = re.findall(r'<figure class="([a-z]+)"', page)
    text = html_module.unescape(page)
    assert "no problems found" not in text
    assert "NaN" in text and "check fails" in text
    assert card == "bad", page
