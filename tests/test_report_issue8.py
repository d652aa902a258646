"""Issue #8: degenerate triangles in the analysis, cell indices, the frame of boundaries."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from conftest import ball, dataset, edge_use
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from isoconvert import Mesh, Volume, extract, read_volume
from isoconvert.errors import FormatError, IsoconvertError
from isoconvert.report import (
    SCHEMA_PATH,
    check_mesh,
    format_report,
    grid_from_volume,
)

SCHEMA = json.loads(SCHEMA_PATH.read_text())
FALLBACK = "boundaries judged against the bounding box:"


def validated(report):
    jsonschema.validate(json.loads(json.dumps(report.to_dict())), SCHEMA)
    return report


def sphere() -> Mesh:
    return extract(Volume(ball(16, 5.0)), 0.0)


# --- 1. degenerate triangles take part in the analysis --------------------------------


def test_isolated_flat_triangle_counts_its_edges_and_vertices():
    """The issue's case: a closed sphere plus one zero-area triangle of three new vertices."""
    s = sphere()
    n = s.n_vertices
    centre = s.vertices.mean(axis=0)
    line = centre + np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]])  # three collinear points
    mesh = Mesh(np.vstack([s.vertices, line]), np.vstack([s.cells, [[n, n + 1, n + 2]]]))
    r = validated(check_mesh(mesh))
    assert r.counts["unreferenced_vertices"] == 0
    deg = r.problems["degenerate_triangles"]
    assert deg["count"] == 1 and deg["examples"][0] == {
        "triangle": s.n_cells,
        "reason": "zero area",
        "position": line[0].tolist(),
    }
    plain = check_mesh(s)
    assert r.counts["edges"] == plain.counts["edges"] + 3
    # its three edges are each in one triangle, inside the sphere's bounding box
    assert r.problems["boundary_edges_inside"]["count"] == 3
    assert not r.checks["watertight"] and not r.checks["no-holes"]
    assert r.checks["manifold"] and r.checks["oriented"]
    assert r.topology["components"] == 2
    assert r.topology["euler_characteristic"] == 2 + (3 - 3 + 1)
    flat = [c for c in r.topology["per_component"] if c["triangles"] == 1]
    assert flat == [{"triangles": 1, "vertices": 3, "euler": 1, "closed": False}]
    assert "volume" not in r.measures


def test_triangle_with_a_repeated_position_is_no_cell_but_its_vertices_are_used():
    s = sphere()
    n, v = s.n_vertices, s.vertices
    extra = np.array([[100.0, 0, 0], [101.0, 0, 0], v[s.cells[0, 0]]])
    cells = np.vstack(
        [
            s.cells,
            [[n, n, n + 1]],  # a repeated index: a segment, not a 2-cell
            [[n + 2, s.cells[0, 0], s.cells[0, 1]]],  # n + 2 sits where cells[0, 0] does
        ]
    )
    r = validated(check_mesh(Mesh(np.vstack([v, extra]), cells)))
    assert r.counts["unreferenced_vertices"] == 0
    assert r.counts["merged_vertices"] == 1
    deg = r.problems["degenerate_triangles"]
    assert deg["count"] == 2
    assert [e["reason"] for e in deg["examples"]] == ["repeated vertex"] * 2
    # no edge of theirs is counted: the sphere stays closed, one component, Euler 2
    plain = check_mesh(s)
    assert r.counts["edges"] == plain.counts["edges"]
    assert r.checks["watertight"] and r.checks["manifold"] and r.checks["no-holes"]
    assert r.topology["components"] == 1 and r.topology["euler_characteristic"] == 2
    assert r.measures["volume"] == pytest.approx(plain.measures["volume"])


def test_slivers_are_degenerate_and_the_rule_is_scale_free():
    tetra = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    sliver = np.array([[2.0, 0, 0], [3, 0, 0], [2.5, 1e-18, 0]])  # twice its area: 1e-18
    small_far = 1e6 + np.array([[0.0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0]])  # tiny, well formed
    vertices = np.vstack([tetra, sliver, small_far])
    cells = np.vstack([faces, [[4, 5, 6]], [[7, 8, 9]]])
    for scale in (1.0, 1e-12, 1e9):
        r = validated(check_mesh(Mesh(vertices * scale, cells)))
        deg = r.problems["degenerate_triangles"]
        assert deg["count"] == 1, scale
        assert deg["examples"][0]["triangle"] == 4 and deg["examples"][0]["reason"] == "zero area"
        assert not r.checks["no-degenerate"]
        # the sliver is a 2-cell all the same: three vertices, three edges, one triangle
        assert r.topology["components"] == 3
        assert r.topology["euler_characteristic"] == 2 + 1 + 1


def single_collapsed_point() -> Mesh:
    """One sample equal to the level among lower ones: every triangle collapses to it."""
    data = np.zeros((5, 5, 5), np.int16)
    data[2, 2, 2] = 1
    return extract(Volume(data), 1, vertex_offset=0)


def test_a_surface_collapsed_to_a_point_references_its_vertices():
    mesh = single_collapsed_point()
    assert mesh.n_cells > 0 and len(np.unique(mesh.vertices, axis=0)) == 1
    r = validated(check_mesh(mesh))
    assert r.counts["unreferenced_vertices"] == 0
    assert r.counts["merged_vertices"] == mesh.n_vertices - 1
    assert r.problems["degenerate_triangles"]["count"] == mesh.n_cells
    assert r.counts["edges"] == 0 and r.topology["components"] == 0
    assert r.topology["euler_characteristic"] == 0
    assert r.measures["area"] == 0.0
    assert "0 component(s)" in format_report(r)


def surface_cells(mesh: Mesh) -> tuple[np.ndarray, int]:
    """Independently: triangles with three distinct positions, and their vertex count."""
    _, inverse = np.unique(mesh.vertices, axis=0, return_inverse=True)
    tris = inverse.reshape(-1)[mesh.cells]
    ok = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return tris[ok], len(np.unique(tris[ok]))


@settings(max_examples=60, deadline=None)
@given(
    data=arrays(np.int16, st.tuples(*[st.integers(2, 6)] * 3), elements=st.integers(0, 4)),
    level=st.integers(1, 4),
    method=st.sampled_from(["cubes", "tetra"]),
)
def test_levels_equal_to_sample_values_give_sensible_reports(data, level, method):
    assume(data.min() < level <= data.max())
    mesh = extract(Volume(data), level, method=method, vertex_offset=0)
    r = validated(check_mesh(mesh))
    # every vertex of an extracted mesh is used by a triangle, collapsed or not
    assert r.counts["unreferenced_vertices"] == 0
    tris, n_used = surface_cells(mesh)
    edges, uses = edge_use(tris)
    assert r.counts["edges"] == len(edges)
    assert r.topology["euler_characteristic"] == n_used - len(edges) + len(tris)
    assert sum(c["triangles"] for c in r.topology["per_component"]) == len(tris)
    assert r.checks["watertight"] == (len(tris) > 0 and bool((uses == 2).all()))
    # three distinct points on the edges of one cube (or tetrahedron) are never collinear,
    # so only the triangles with a repeated position are degenerate
    assert r.problems["degenerate_triangles"]["count"] == mesh.n_cells - len(tris)


# --- 2. cell indices ---------------------------------------------------------------------


def test_a_vertex_index_past_the_end_is_a_format_error():
    vertices = np.zeros((40, 3))
    cells = np.zeros((20, 3), np.int64)
    cells[12, 1] = 99
    cells[15, 2] = 120
    with pytest.raises(FormatError) as err:
        check_mesh(Mesh(vertices, cells), source="part.obj")
    expected = "part.obj: triangle 12 refers to vertex 99, but there are only 40 vertices"
    assert str(err.value) == expected


def test_negative_indices_and_segments_are_format_errors_too():
    vertices = np.zeros((3, 3))
    with pytest.raises(FormatError, match=r"^rings.obj: segment 1 refers to vertex -1\b"):
        check_mesh(Mesh(vertices, np.array([[0, 1], [2, -1]]), info={"source": "rings.obj"}))
    with pytest.raises(
        FormatError, match=r"^mesh: segment 0 refers to vertex 3, but there are only"
    ):
        check_mesh(Mesh(vertices, np.array([[0, 3], [1, 2]])))
    with pytest.raises(FormatError, match="but there are no vertices"):
        check_mesh(Mesh(np.zeros((0, 3)), np.array([[0, 1, 2]])))
    assert "\n" not in str(
        pytest.raises(FormatError, check_mesh, Mesh(vertices, np.array([[0, 1, 7]]))).value
    )


# --- 3. the frame of boundaries -----------------------------------------------------------


def as_float32_file(mesh: Mesh, **info) -> Mesh:
    """The mesh as a float32 file holds it: rounded positions, no grid unless given."""
    return Mesh(
        mesh.vertices.astype(np.float32).astype(np.float64),
        mesh.cells,
        info={"source": "stored.ply", "stored_precision": "float32", **info},
    )


@pytest.fixture(scope="module")
def flair_cut():
    """FLAIR.nrrd (oblique space directions) from z index 60 on, and its surface at 60.5.

    The scan's outer samples are all 0, so its surfaces are closed; cut at k = 60,
    the brain's surface ends on the grid's k = 0 face, which is oblique in world space.
    """
    vol = read_volume(dataset("FLAIR.nrrd"))
    assert not np.allclose(vol.direction, np.diag(np.diag(vol.direction)))
    k0 = 60
    cut = Volume(
        np.asarray(vol.data)[:, :, k0:],
        spacing=vol.spacing,
        origin=vol.index_to_world(np.array([[0.0, 0.0, k0]]))[0],
        direction=vol.direction,
        source="FLAIR.nrrd[:, :, 60:]",
    )
    return cut, extract(cut, 60.5)


def test_flair_boundary_is_judged_against_the_grid_given_by_the_volume(flair_cut):
    volume, mesh = flair_cut
    memory = validated(check_mesh(mesh))
    assert memory.boundary_frame == "grid"
    on_grid = memory.problems["boundary_edges_on_domain_boundary"]["count"]
    assert on_grid > 100 and memory.problems["boundary_edges_inside"]["count"] == 0
    assert memory.checks["no-holes"] and not memory.checks["watertight"]
    assert not any(FALLBACK in note for note in memory.notes)

    stored = as_float32_file(mesh, cut_by_grid=True)  # as isoconvert's STL records
    bare = validated(check_mesh(stored))
    assert bare.boundary_frame == "bounding box"
    assert not bare.checks["no-holes"]  # the oblique cut is no face of the bounding box
    note = [n for n in bare.notes if n.startswith(FALLBACK)]
    assert len(note) == 1 and "--grid VOLUME" in note[0]
    assert note[0] in format_report(bare)

    judged = validated(check_mesh(stored, grid=grid_from_volume(volume)))
    assert judged.boundary_frame == "grid"
    assert judged.checks["no-holes"]
    assert judged.problems["boundary_edges_on_domain_boundary"]["count"] == on_grid
    assert not any(FALLBACK in note for note in judged.notes)
    assert FALLBACK not in format_report(judged)


def test_float32_positions_without_a_stated_precision_are_taken_as_float32(flair_cut):
    volume, mesh = flair_cut
    stored = as_float32_file(mesh)
    del stored.info["stored_precision"]  # an older file, or STL (always float32)
    assert check_mesh(stored, grid=grid_from_volume(volume)).checks["no-holes"]
    stored.info["stored_precision"] = "float64"  # stated, it is believed
    assert not check_mesh(stored, grid=grid_from_volume(volume)).checks["no-holes"]


def test_grid_from_volume_is_the_grid_extracted_meshes_record(flair_cut):
    volume, mesh = flair_cut
    assert grid_from_volume(volume) == mesh.info["grid"]
    json.dumps(grid_from_volume(volume))  # plain lists, ready for a file header


def cut_ball_far_away(spacing: float) -> tuple[Volume, Mesh]:
    """A ball cut by the grid's low x and high y faces; the grid starts at (5e6, 5e6, 0)."""
    volume = Volume(
        ball(20, 9.0, center=(2.0, 16.0, 9.5)), spacing=(spacing,) * 3, origin=(5e6, 5e6, 0.0)
    )
    return volume, extract(volume, 0.0)


# float32 holds 5e6 + 19 * spacing only to within 0.25 (its ulp there is 0.5)
@pytest.mark.parametrize("spacing", [0.7, 1.3, 3.1])
def test_float32_rounding_far_from_the_origin_makes_no_holes(spacing):
    volume, mesh = cut_ball_far_away(spacing)
    assert check_mesh(mesh).checks["no-holes"]
    stored = as_float32_file(mesh, grid=grid_from_volume(volume))
    assert np.abs(stored.vertices - mesh.vertices).max() > 1e-6 * spacing  # rounding is real
    r = validated(check_mesh(stored))
    assert r.boundary_frame == "grid"
    assert r.problems["boundary_edges_on_domain_boundary"]["count"] > 0
    assert r.problems["boundary_edges_inside"]["count"] == 0 and r.checks["no-holes"]


def test_the_wider_float32_tolerance_still_finds_a_hole():
    volume, mesh = cut_ball_far_away(3.0)
    centroids = mesh.vertices[mesh.cells].mean(axis=1)
    top = centroids[:, 2] > volume.origin[2] + 3.0 * 15.5  # a cap well inside the grid
    assert top.any()
    holed = Mesh(mesh.vertices, mesh.cells[~top], info=mesh.info)
    r = check_mesh(as_float32_file(holed), grid=grid_from_volume(volume))
    assert r.problems["boundary_edges_inside"]["count"] > 0 and not r.checks["no-holes"]


def test_the_grid_keyword_overrides_the_recorded_grid():
    volume, mesh = cut_ball_far_away(1.0)
    wrong = dict(grid_from_volume(volume), origin=[5e6 - 4.0, 5e6, 0.0])
    misplaced = Mesh(mesh.vertices, mesh.cells, info={"grid": wrong})
    assert not check_mesh(misplaced).checks["no-holes"]
    assert check_mesh(misplaced, grid=grid_from_volume(volume)).checks["no-holes"]


def test_contours_take_a_grid_too():
    y, x = np.mgrid[:40, :50]
    turn = np.radians(30.0)
    rotation = [[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]]
    img = 200 - 8 * np.hypot(x - 24.3, y - 45.0)  # a blob cut by the grid's border
    volume = Volume.from_zyx(img, direction=rotation, origin=(-7.25, 3.5))
    mesh = extract(volume, 100.5)
    stored = as_float32_file(mesh, cut_by_grid=True)
    bare = check_mesh(stored)
    assert any(n.startswith(FALLBACK) for n in bare.notes)
    r = validated(check_mesh(stored, grid=grid_from_volume(volume)))
    assert r.boundary_frame == "grid" and r.checks["no-holes"]
    assert r.problems["open_ends_on_domain_boundary"]["count"] == 2
    # with no boundary to judge, the bounding box needs no note
    closed = as_float32_file(
        extract(Volume.from_zyx(200 - 8 * np.hypot(x - 24.3, y - 19.6)), 100.5)
    )
    r = check_mesh(closed)
    assert r.boundary_frame == "none" and r.checks["no-holes"] and r.checks["watertight"]
    assert not any(FALLBACK in note for note in r.notes) and FALLBACK not in format_report(r)


def test_a_malformed_grid_is_a_clear_error():
    mesh = sphere()
    bad = {"shape": [16, 16], "origin": [0, 0, 0], "affine": np.eye(3).tolist()}
    with pytest.raises(IsoconvertError, match="grid"):
        check_mesh(mesh, grid=bad)
    singular = {"shape": [16, 16, 16], "origin": [0, 0, 0], "affine": np.zeros((3, 3)).tolist()}
    with pytest.raises(IsoconvertError, match="grid"):
        check_mesh(mesh, grid=singular)
