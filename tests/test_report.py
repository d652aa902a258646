"""The mesh report against hand-made meshes, independent counts and trimesh."""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
import trimesh
from conftest import SAMPLES, ball, edge_use, load_samples_module
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from isoconvert import Mesh, Volume, extract, read_volume, write_mesh
from isoconvert.cli import EXIT_CHECK_FAILED, main
from isoconvert.meshfile import read_mesh
from isoconvert.report import SCHEMA_PATH, check_mesh

SCHEMA = json.loads(SCHEMA_PATH.read_text())


def validated(report):
    jsonschema.validate(json.loads(json.dumps(report.to_dict())), SCHEMA)
    return report


def test_schema_is_a_valid_json_schema():
    jsonschema.Draft202012Validator.check_schema(SCHEMA)


def test_sphere_watertight_genus_zero_with_its_volume():
    mesh = extract(Volume(ball(30, 11.0)), 0.0)
    r = validated(check_mesh(mesh))
    assert all(r.checks.values())
    assert r.topology["components"] == 1
    assert r.topology["per_component"][0]["genus"] == 0
    assert r.measures["volume"] == pytest.approx(4 / 3 * np.pi * 11**3, rel=0.01)
    assert r.measures["area"] == pytest.approx(mesh.area())


def test_torus_genus_one():
    mesh = extract(Volume(load_samples_module().torus()), 3.0, flip=True)
    r = check_mesh(mesh)
    assert r.checks["watertight"] and r.checks["manifold"]
    assert r.topology["euler_characteristic"] == 0
    assert r.topology["per_component"][0]["genus"] == 1


def test_two_spheres_touching_point_is_the_one_non_manifold_vertex():
    # exact placement: the level equals samples there, which is the point of the test
    mesh = extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.0, vertex_offset=0)
    r = validated(check_mesh(mesh))
    bad = r.problems["non_manifold_vertices"]
    assert bad["count"] == 1
    assert bad["examples"][0]["position"] == [14.0, 10.0, 10.0]
    assert bad["examples"][0]["fans"] == 2
    assert not r.checks["manifold"]
    # two spheres sharing one point: chi = 2 + 2 - 1
    assert r.topology["euler_characteristic"] == 3
    # the degenerate-free option separates them by a thin neck instead
    clean = check_mesh(extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.0, vertex_offset=1e-3))
    assert all(clean.checks.values())


def test_sphere_with_a_hole():
    mesh = extract(Volume(ball(30, 11.0)), 0.0)
    centroid_z = mesh.vertices[mesh.cells].mean(axis=1)[:, 2]
    keep = centroid_z < 14.5 + 9.0  # remove a cap near the top
    holed = Mesh(mesh.vertices, mesh.cells[keep], info=mesh.info)
    r = check_mesh(holed)
    edges, uses = edge_use(holed.cells)
    assert r.problems["boundary_edges_inside"]["count"] == int((uses == 1).sum()) > 0
    assert r.problems["boundary_edges_on_domain_boundary"]["count"] == 0
    assert not r.checks["no-holes"] and not r.checks["watertight"] and r.checks["manifold"]
    # without the grid, the bounding box's top is cut by the hole's rim: still "inside"
    bare = check_mesh(Mesh(holed.vertices, holed.cells, info={"cut_by_grid": True}))
    assert bare.boundary_frame == "bounding box"
    assert bare.problems["boundary_edges_inside"]["count"] > 0
    # and with no record that a grid cut it, every boundary edge is a hole
    foreign = check_mesh(Mesh(holed.vertices, holed.cells))
    assert foreign.boundary_frame == "none"
    assert foreign.problems["boundary_edges_inside"]["count"] == int((uses == 1).sum())


def test_surface_cut_by_the_grid_has_boundary_only_on_the_grid():
    mesh = extract(Volume(ball(20, 12.0, center=(2.0, 3.0, 1.0))), 0.0)
    r = validated(check_mesh(mesh))
    assert r.problems["boundary_edges_on_domain_boundary"]["count"] > 0
    assert r.problems["boundary_edges_inside"]["count"] == 0
    assert r.checks["no-holes"] and not r.checks["watertight"]
    assert "volume" not in r.measures


def collapsed_grid_vertex(data, level, edge_ids):
    """Independent of positions: the grid vertex a vertex sits on, or -1.

    A vertex lies on a grid vertex exactly when its edge's positive end has the
    level as its value (t = 0 or 1); other vertices lie strictly inside edges.
    """
    nx, ny, _ = data.shape
    axis, lin = edge_ids % 3, edge_ids // 3
    start = np.column_stack([lin % nx, (lin // nx) % ny, lin // (nx * ny)])
    end = start + np.eye(3, dtype=np.int64)[axis]
    s0, s1 = data[tuple(start.T)], data[tuple(end.T)]
    lin_start = start[:, 0] + nx * (start[:, 1] + ny * start[:, 2])
    lin_end = end[:, 0] + nx * (end[:, 1] + ny * end[:, 2])
    return np.where(s0 == level, lin_start, np.where(s1 == level, lin_end, -1))


@settings(max_examples=40, deadline=None)
@given(
    data=arrays(np.int16, st.tuples(*[st.integers(2, 6)] * 3), elements=st.integers(0, 6)),
    level=st.integers(1, 6),
)
def test_zero_length_edges_match_an_independent_count(data, level):
    assume(data.min() < level <= data.max())
    mesh = extract(Volume(data), level, vertex_offset=0)
    at = collapsed_grid_vertex(data, level, mesh.edge_ids)
    edges, _ = edge_use(mesh.cells)
    expected = int(((at[edges[:, 0]] >= 0) & (at[edges[:, 0]] == at[edges[:, 1]])).sum())
    r = check_mesh(mesh)
    assert r.problems["zero_length_edges"]["count"] == expected
    assert r.checks["no-zero-length"] == (expected == 0)


@settings(max_examples=40, deadline=None)
@given(
    data=arrays(np.int16, st.tuples(*[st.integers(2, 6)] * 3), elements=st.integers(0, 6)),
    level=st.integers(1, 6),
    method=st.sampled_from(["cubes", "tetra"]),
)
def test_degenerate_free_option_keeps_surfaces_closed(data, level, method):
    data = np.pad(data, 1)  # zero border: every surface is closed
    assume(level <= data.max())
    mesh = extract(Volume(data), level, method=method, vertex_offset=1e-3)
    r = check_mesh(mesh)
    assert r.problems["zero_length_edges"]["count"] == 0
    assert r.checks["watertight"] and r.checks["oriented"] and r.checks["no-holes"]
    # the offset moves no vertex by more than a thousandth of an edge
    plain = extract(Volume(data), level, method=method, vertex_offset=0)
    assert np.abs(plain.vertices - mesh.vertices).max() <= 1e-3 * np.sqrt(3) + 1e-12
    assert np.array_equal(plain.cells, mesh.cells)


def analysis_arrays(mesh):
    """Independently: merge equal positions, drop collapsed triangles and unused vertices."""
    unique, inverse = np.unique(mesh.vertices, axis=0, return_inverse=True)
    tris = inverse.reshape(-1)[mesh.cells]
    ok = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    tris = tris[ok]
    used, tris = np.unique(tris, return_inverse=True)
    return unique[used], tris.reshape(-1, 3)


@pytest.mark.parametrize(
    "make",
    [
        lambda: extract(Volume(ball(24, 8.0)), 0.0),
        lambda: extract(Volume(load_samples_module().torus()), 3.0),
        lambda: extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.0, vertex_offset=0),
        lambda: extract(Volume(ball(20, 12.0, center=(2.0, 3.0, 1.0))), 0.0),
        lambda: extract(
            Volume(np.random.default_rng(5).integers(0, 5, (9, 8, 7))), 2, vertex_offset=0
        ),
        lambda: extract(
            Volume(np.random.default_rng(6).integers(0, 5, (9, 8, 7))), 2.5, method="tetra"
        ),
    ],
)
def test_agrees_with_trimesh(make):
    mesh = make()
    r = check_mesh(mesh)
    v, f = analysis_arrays(mesh)
    tm = trimesh.Trimesh(v, f, process=False)
    assert r.checks["watertight"] == tm.is_watertight
    assert r.topology["euler_characteristic"] == tm.euler_number
    if tm.is_watertight:
        assert r.checks["oriented"] == tm.is_winding_consistent
    assert r.measures["area"] == pytest.approx(tm.area)
    if "volume" in r.measures:
        assert r.measures["volume"] == pytest.approx(tm.volume)


def test_inconsistent_orientation_duplicates_and_degenerate_triangles():
    mesh = extract(Volume(ball(16, 5.0)), 0.0)
    cells = mesh.cells.copy()
    cells[0] = cells[0, ::-1]  # one triangle flipped
    r = check_mesh(Mesh(mesh.vertices, cells))
    assert not r.checks["oriented"] and r.problems["inconsistently_oriented_edges"]["count"] == 3
    doubled = np.concatenate([mesh.cells, mesh.cells[:2]])
    r = check_mesh(Mesh(mesh.vertices, doubled))
    assert r.problems["duplicate_triangles"]["count"] == 2
    assert not r.checks["no-duplicates"] and not r.checks["manifold"]
    assert r.problems["non_manifold_edges"]["count"] == 6
    verts = np.vstack([mesh.vertices, [[0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    n = len(mesh.vertices)
    bad = np.concatenate([mesh.cells, [[n, n + 1, n + 2], [0, 0, 1]]])
    r = check_mesh(Mesh(verts, bad))
    reasons = sorted(e["reason"] for e in r.problems["degenerate_triangles"]["examples"])
    assert reasons == ["repeated vertex", "zero area"]


def test_contour_report():
    y, x = np.mgrid[:40, :50]
    img = 200 - 8 * np.hypot(x - 24.3, y - 45.0)  # a blob cut by the bottom border
    mesh = extract(Volume.from_zyx(img), 100.5)
    r = validated(check_mesh(mesh))
    assert r.kind == "segments"
    assert r.topology["open_polylines"] == 1 and r.topology["closed_polylines"] == 0
    assert r.problems["open_ends_on_domain_boundary"]["count"] == 2
    assert r.checks["no-holes"] and not r.checks["watertight"] and r.checks["manifold"]
    lengths = np.linalg.norm(np.diff(mesh.vertices[mesh.cells], axis=1)[:, 0], axis=1)
    assert r.measures["length"] == pytest.approx(lengths.sum())
    closed = check_mesh(extract(Volume.from_zyx(200 - 8 * np.hypot(x - 24.3, y - 19.6)), 100.5))
    assert all(closed.checks.values()) and closed.topology["closed_polylines"] == 1


def test_stl_is_merged_and_says_how_many(tmp_path):
    mesh = extract(Volume(ball(20, 6.0)), 0.0)
    path = write_mesh(mesh, tmp_path / "b.stl")
    r = check_mesh(read_mesh(path))
    assert r.counts["vertices"] == 3 * mesh.n_cells
    assert r.counts["merged_vertices"] == 3 * mesh.n_cells - mesh.n_vertices
    assert all(r.checks.values())


@pytest.fixture
def failing_meshes(tmp_path):
    """One OBJ file failing each check (and one passing all)."""
    good = extract(Volume(ball(16, 5.0)), 0.0)
    v, c = good.vertices, good.cells
    n = len(v)
    files = {}

    def save(name, verts, cells):
        files[name] = write_mesh(Mesh(verts, cells), tmp_path / f"{name}.obj")

    save("good", v, c)
    save("watertight", v, c[1:])  # one triangle missing
    flipped = c.copy()
    flipped[0] = flipped[0, ::-1]
    save("oriented", v, flipped)
    save("no-duplicates", v, np.concatenate([c, c[:1]]))
    save(
        "no-degenerate",
        np.vstack([v, [[0, 0, 0], [1, 0, 0], [2, 0, 0]]]),
        np.concatenate([c, [[n, n + 1, n + 2]]]),
    )
    # a new vertex at the position of vertex c[0, 0], joined to it by an edge
    save("no-zero-length", np.vstack([v, v[c[0, 0]]]), np.concatenate([c, [[c[0, 0], n, c[0, 1]]]]))
    # two balls touching at one vertex: the second is the first moved so that its
    # lowest vertex lands on the first's highest
    top, bottom = np.argmax(v[:, 0]), np.argmin(v[:, 0])
    save("manifold", np.vstack([v, v + (v[top] - v[bottom])]), np.concatenate([c, c + n]))
    return files


@pytest.mark.parametrize(
    "name",
    ["watertight", "oriented", "no-duplicates", "no-degenerate", "no-zero-length", "manifold"],
)
def test_require_exit_codes_for_each_check(failing_meshes, capsys, name):
    assert (
        main(
            [
                "check",
                str(failing_meshes["good"]),
                "--require",
                ",".join(
                    [
                        "watertight",
                        "manifold",
                        "oriented",
                        "no-zero-length",
                        "no-degenerate",
                        "no-duplicates",
                        "no-holes",
                    ]
                ),
            ]
        )
        == 0
    )
    code = main(["check", str(failing_meshes[name]), "--require", name, "-q"])
    err = capsys.readouterr().err
    assert code == EXIT_CHECK_FAILED
    assert f"required check failed: {name}" in err


def test_require_manifold_and_no_holes_on_extracted_meshes(tmp_path, capsys):
    out = tmp_path / "two.ply"
    code = main(
        [
            "convert",
            str(SAMPLES / "two_spheres.nrrd"),
            "-l",
            "0",
            "-o",
            str(out),
            "--require",
            "manifold",
            "--exact-placement",
            "-q",
        ]
    )
    assert code == EXIT_CHECK_FAILED and "manifold" in capsys.readouterr().err
    assert out.exists()  # the mesh is still written; the check is about it
    code = main(
        [
            "convert",
            str(SAMPLES / "two_spheres.nrrd"),
            "-l",
            "0",
            "-o",
            str(out),
            "--require",
            "manifold,no-zero-length",
            "--no-degenerate",
            "--force",
            "-q",
        ]
    )
    assert code == 0
    holed = tmp_path / "holed.obj"
    mesh = extract(Volume(ball(30, 11.0)), 0.0)
    keep = mesh.vertices[mesh.cells].mean(axis=1)[:, 2] < 23.5
    write_mesh(Mesh(mesh.vertices, mesh.cells[keep]), holed)
    assert main(["check", str(holed), "--require", "no-holes", "-q"]) == EXIT_CHECK_FAILED


def test_report_json_file_and_schema(tmp_path, capsys):
    out, rep = tmp_path / "t.ply", tmp_path / "t.json"
    code = main(
        [
            "convert",
            str(SAMPLES / "torus.nrrd"),
            "-l",
            "3",
            "--flip",
            "-o",
            str(out),
            "--report",
            str(rep),
            "-q",
        ]
    )
    assert code == 0
    data = json.loads(rep.read_text())
    jsonschema.validate(data, SCHEMA)
    assert data["topology"]["per_component"][0]["genus"] == 1
    # an existing report is not replaced without --force
    code = main(
        [
            "convert",
            str(SAMPLES / "torus.nrrd"),
            "-l",
            "3",
            "-o",
            str(tmp_path / "u.ply"),
            "--report",
            str(rep),
        ]
    )
    assert code == 1 and "already exists" in capsys.readouterr().err
    code = main(["check", str(out), "--json"])
    jsonschema.validate(json.loads(capsys.readouterr().out), SCHEMA)
    assert code == 0


def table_of_check(path, capsys) -> str:
    capsys.readouterr()
    assert main(["check", str(path)]) == 0
    return capsys.readouterr().out


def test_report_to_a_text_file_is_the_printed_table(tmp_path, capsys):
    """``--report r.txt`` (no ``=``) writes the table that a bare ``--report`` prints;
    ``check --report`` likewise, and .json names still get JSON."""
    torus = str(SAMPLES / "torus.nrrd")
    out, txt, js = tmp_path / "t.ply", tmp_path / "r.txt", tmp_path / "r.json"
    assert main(["convert", torus, "-l", "3", "-o", str(out), "--report", str(txt), "-q"]) == 0
    capsys.readouterr()
    assert main(["convert", torus, "-l", "3", "-o", str(out), "--force", "--report"]) == 0
    printed = capsys.readouterr().out
    table = txt.read_text(encoding="utf-8")
    assert table.strip() and table.strip() in printed
    assert "genus" in table.lower() or "euler" in table.lower()
    with pytest.raises(json.JSONDecodeError):
        json.loads(table)

    assert main(["check", str(out), "--report", str(tmp_path / "c.txt"), "-q"]) == 0
    assert main(["check", str(out)]) == 0
    assert (tmp_path / "c.txt").read_text(encoding="utf-8") == capsys.readouterr().out
    # check's --report always takes the next word, whatever its suffix
    assert main(["check", str(out), "--report", str(tmp_path / "c.md"), "-q"]) == 0
    assert (tmp_path / "c.md").read_text(encoding="utf-8") == table_of_check(out, capsys)
    # a folder given as the report: one line suggesting a report's name, not a mesh's
    assert main(["check", str(out), "--report", str(tmp_path), "-q"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"such as {tmp_path / 'report.txt'}" in err
    assert main(["check", str(out), "--report", str(js), "-q"]) == 0
    assert json.loads(js.read_text())["topology"]["per_component"][0]["genus"] == 1


def test_check_prints_a_table_and_rejects_unknown_names(tmp_path, capsys):
    out = tmp_path / "s.ply"
    write_mesh(extract(Volume(ball(16, 5.0)), 0.0), out)
    assert main(["check", str(out)]) == 0
    table = capsys.readouterr().out
    assert "PASS  watertight" in table and "genus 0" in table
    assert main(["check", str(out), "--require", "shiny"]) == 1
    assert "unknown check 'shiny'" in capsys.readouterr().err
    assert main(["check", str(tmp_path / "nope.ply")]) == 1
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat nonsense\n")
    assert main(["check", str(tmp_path / "bad.ply")]) == 1
    assert "not a readable PLY" in capsys.readouterr().err


def test_a_report_name_convert_does_not_take_is_said_in_the_error(tmp_path, capsys):
    """convert's --report takes a file named *.json or *.txt (bare, it prints): a
    name of another kind, wherever it stands, is one usage line (exit 2) that says
    so and names it, not only "an argument too many", and nothing is written."""
    sphere = str(SAMPLES / "sphere.nrrd")
    out = tmp_path / "s.ply"
    for argv in (
        ["convert", sphere, "-l", "127.5", "-o", str(out), "--report", "r.md"],
        ["convert", "--report", "r.xyz", sphere, "-l", "127.5", "-o", str(out)],
    ):
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        named = argv[argv.index("--report") + 1]
        assert len(err.splitlines()) == 1 and "*.json or *.txt" in err and named in err, err
        assert not out.exists()
    # an argument too many for another reason gets no word about reports
    assert main(["convert", sphere, "extra", "-l", "127.5", "-o", str(out)]) == 2
    assert "--report" not in capsys.readouterr().err


@pytest.mark.parametrize(("name", "level", "unit"), [
    ("ct_chest_LIDC-IDRI-0314_dicom", "1300.5", "mm"),
    ("XYZ_organ-of-corti_confocal.tif", "2500.5", "µm"),
])  # fmt: skip
def test_reports_give_the_unit_the_file_records(tmp_path, capsys, name, level, unit):
    """Every format that records the volume's unit gives it back to the report (PLY's
    ASCII header escapes µm); STL records none. Areas agree across formats."""
    from conftest import dataset

    first = tmp_path / "m.ply"
    assert main(["convert", str(dataset(name)), "-l", level, "-o", str(first), "-q"]) == 0
    mesh = read_mesh(first)
    mesh.info.update(unit=unit, source="")  # as convert gives it to the writers
    areas = {}
    for fmt in ("ply", "obj", "off", "vtp", "glb", "3mf", "stl"):
        out = first if fmt == "ply" else write_mesh(mesh, tmp_path / f"m.{fmt}")
        report = check_mesh(read_mesh(out))
        areas[fmt] = report.measures["area"]
        assert report.measures.get("unit") == (None if fmt == "stl" else unit)
        capsys.readouterr()
        assert main(["check", str(out)]) == 0
        assert (f" {unit}²" in capsys.readouterr().out) == (fmt != "stl")
    assert max(areas.values()) == pytest.approx(min(areas.values()), rel=1e-6)
