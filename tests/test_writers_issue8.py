"""Issue #8 for writers: any path in a header, the grid and the precision in the
file, the mesh as written for the report, bad vertex indices in mesh files."""

from __future__ import annotations

import re
import struct
import unicodedata
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
import trimesh
from conftest import SAMPLES, ball, dataset
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert import Mesh, Volume, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.meshfile import read_mesh
from isoconvert.report import check_mesh

#: A path with everything that has broken headers: non-ASCII, a newline, a
#: carriage return, a tab, a backslash, a NUL, "--" and a trailing "-".
NASTY = "données/Müller\nscan--x\r\t\\v\x00 \u2028日本.nrrd-"

CASES = [("ply", False), ("ply", True), ("obj", True), ("stl", False), ("stl", True)]


@pytest.fixture(scope="module")
def ball_mesh() -> Mesh:
    volume = Volume(ball(12, 4.3), spacing=(0.3, 0.7, 1.1), origin=(100.1, -20.3, 3.7))
    return extract(volume, 0.0)


@pytest.fixture(scope="module")
def hydrogen() -> Mesh:
    volume = read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw"))
    return extract(volume, 0.001)


@pytest.fixture(scope="module")
def far_sphere() -> Mesh:
    """The sample sphere placed at scanner-like coordinates."""
    volume = read_volume(SAMPLES / "sphere.nrrd").with_placement(origin=(5e6, 5e6, 0.0))
    return extract(volume, 127.5)


def with_source(mesh: Mesh, source: str) -> Mesh:
    return Mesh(mesh.vertices, mesh.cells, mesh.edge_ids, {**mesh.info, "source": source})


def header_lines(path, fmt: str) -> list[str]:
    """Header comment texts of a PLY (``comment``) or OBJ (leading ``#``) file."""
    data = path.read_bytes()
    if fmt == "ply":
        head = data[: data.index(b"end_header\n")]
        head.decode("ascii")  # a PLY header is ASCII
        lines = head.split(b"\n")
        return [line[len(b"comment ") :].decode() for line in lines if line.startswith(b"comment")]
    lines = data.decode("utf-8").split("\n")
    return [line[2:] for line in lines if line.startswith("# ")]


def corners(vertices, cells) -> np.ndarray:
    """Triangles as sorted rows of their 9 corner coordinates (order-free comparison)."""
    c = np.asarray(vertices, np.float64)[np.asarray(cells)].reshape(len(cells), 9)
    return c[np.lexsort(c.T[::-1])]


def report_dict(mesh: Mesh) -> dict:
    found = check_mesh(mesh).to_dict()
    del found["source"]
    return found


# --- 1. any path in a header -----------------------------------------------------------


@pytest.mark.parametrize(("fmt", "ascii"), CASES)
def test_any_source_path_keeps_the_file_readable(tmp_path, ball_mesh, fmt, ascii):
    mesh = with_source(ball_mesh, NASTY)
    path = write_mesh(mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    tol = 1e-4 * np.abs(mesh.vertices).max()  # float32 in STL
    back = trimesh.load(path, process=False, force="mesh")
    other = meshio.read(path)
    if fmt == "stl":
        expected = corners(mesh.vertices, mesh.cells)
        assert np.allclose(corners(back.vertices, back.faces), expected, atol=tol)
        assert np.allclose(corners(other.points, other.cells_dict["triangle"]), expected, atol=tol)
        return
    assert np.allclose(back.vertices, mesh.vertices, atol=tol)
    assert np.array_equal(back.faces, mesh.cells)
    assert np.allclose(other.points, mesh.vertices, atol=tol)
    assert np.array_equal(other.cells_dict["triangle"], mesh.cells)
    from isoconvert.writers.header import unescape_comment

    sources = [line for line in header_lines(path, fmt) if line.startswith("source ")]
    assert len(sources) == 1
    assert unescape_comment(sources[0][len("source ") :]) == NASTY
    if fmt == "obj":  # OBJ comments are UTF-8: names stay legible
        assert "données/Müller" in sources[0]


@pytest.mark.parametrize("ascii", [False, True])
def test_vtk_reads_a_ply_whose_source_is_any_path(tmp_path, ball_mesh, ascii):
    vtk = pytest.importorskip("vtk")
    path = write_mesh(with_source(ball_mesh, NASTY), tmp_path / "m.ply", ascii=ascii)
    reader = vtk.vtkPLYReader()
    reader.SetFileName(str(path))
    reader.Update()
    poly = reader.GetOutput()
    assert poly.GetNumberOfPoints() == ball_mesh.n_vertices
    assert poly.GetNumberOfCells() == ball_mesh.n_cells
    from vtk.util.numpy_support import vtk_to_numpy

    points = vtk_to_numpy(poly.GetPoints().GetData())
    assert np.allclose(points, ball_mesh.vertices, atol=1e-4)
    polys = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    assert np.array_equal(polys, ball_mesh.cells)


def test_svg_comment_stays_valid_xml_for_any_path(tmp_path):
    image = np.zeros((9, 9))
    image[3:6, 3:6] = 1.0
    contours = extract(Volume(image), 0.5)
    path = write_mesh(with_source(contours, NASTY), tmp_path / "c.svg")
    data = path.read_bytes()
    data.decode("utf-8")
    root = ET.fromstring(data)  # expat rejects "--" in a comment and control characters
    assert root.tag.endswith("svg")
    comment = re.search(rb"<!--(.*?)-->", data, re.S).group(1).decode()
    assert "--" not in comment and "\n" not in comment
    from isoconvert.writers.header import unescape_comment

    assert unescape_comment(comment.strip()).endswith(f"source {NASTY}")


@settings(max_examples=300, deadline=None)
@given(st.text(), st.booleans(), st.booleans())
def test_escaped_comments_are_one_safe_line_and_decode_back(text, ascii, xml):
    from isoconvert.writers.header import escape_comment, unescape_comment

    escaped = escape_comment(text, ascii=ascii, xml=xml)
    assert unescape_comment(escaped) == text
    assert len(escaped.splitlines()) <= 1  # no character any reader takes for a line break
    # no control characters, no surrogates (not UTF-8), no unassigned code points
    assert not {unicodedata.category(c) for c in escaped} & {"Cc", "Cs", "Cn", "Zl", "Zp"}
    escaped.encode("ascii" if ascii else "utf-8")
    if xml:
        assert "--" not in escaped and not escaped.endswith("-")


# --- 2. the grid and the stored precision in the file ------------------------------------


@pytest.mark.parametrize(("fmt", "ascii"), [("ply", False), ("ply", True), ("obj", True)])
def test_grid_round_trips_exactly(tmp_path, ball_mesh, fmt, ascii):
    path = write_mesh(ball_mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    back = read_mesh(path)
    grid = ball_mesh.info["grid"]
    assert back.info["grid"] == {
        "shape": [int(n) for n in grid["shape"]],
        "origin": [float(x) for x in grid["origin"]],
        "affine": [[float(x) for x in row] for row in grid["affine"]],
    }
    assert report_dict(back)["boundary_frame"] == "grid"


def test_grid_of_2d_contours_round_trips(tmp_path):
    image = np.zeros((7, 9))
    image[2:5, 2:8] = 1.0
    contours = extract(Volume(image, spacing=(0.25, 0.5), origin=(1.5, -2.0)), 0.5)
    for name in ("c.obj", "c.ply"):
        back = read_mesh(write_mesh(contours, tmp_path / name))
        assert back.info["grid"]["shape"] == [7, 9]
        assert back.info["grid"]["origin"] == [1.5, -2.0]
        assert back.info["grid"]["affine"] == [[0.25, 0.0], [0.0, 0.5]]
        assert back.cells.shape[1] == 2


@pytest.mark.parametrize(
    ("fmt", "ascii", "precision"),
    [("ply", False, "float32"), ("ply", True, "float32"), ("obj", True, "float64")]
    + [("stl", False, "float32"), ("stl", True, "float32")],
)
def test_stored_precision_is_read_back(tmp_path, ball_mesh, fmt, ascii, precision):
    back = read_mesh(write_mesh(ball_mesh, tmp_path / f"m.{fmt}", ascii=ascii))
    assert back.info["stored_precision"] == precision
    if precision == "float32":
        assert np.array_equal(back.vertices, back.vertices.astype(np.float32))


PLY_HEAD = "ply\nformat ascii 1.0\n{comments}element vertex 3\n{props}element face 1\n"
PLY_TAIL = "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"


@pytest.mark.parametrize(
    "comment",
    [
        "isoconvert grid {not json",
        'isoconvert grid {"shape":[4,4,4],"origin":[0,0],"affine":[[1,0,0],[0,1,0],[0,0,1]]}',
        'isoconvert grid {"shape":[4,4,4],"origin":[0,0,0],"affine":[[1,0,0],[0,1,0],[0,0,0]]}',
        'isoconvert grid {"shape":[4,4,4],"origin":[0,0,NaN],"affine":[[1,0,0],[0,1,0],[0,0,1]]}',
        'isoconvert grid {"shape":[4.5,4,4],"origin":[0,0,0],"affine":[[1,0,0],[0,1,0],[0,0,1]]}',
        "isoconvert grid [1, 2, 3]",
        "made by another tool",
    ],
)
def test_a_malformed_or_foreign_grid_comment_is_ignored(tmp_path, comment):
    props = "".join(f"property double {a}\n" for a in "xyz")
    path = tmp_path / "other.ply"
    path.write_text(PLY_HEAD.format(comments=f"comment {comment}\n", props=props) + PLY_TAIL)
    back = read_mesh(path)
    assert "grid" not in back.info
    assert back.info["stored_precision"] == "float64"
    # an isoconvert grid record, even a broken one, says that a grid cut the mesh
    ours = comment.startswith("isoconvert grid")
    assert report_dict(back)["boundary_frame"] == ("bounding box" if ours else "none")
    obj = tmp_path / "other.obj"
    obj.write_text(f"# {comment}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    back = read_mesh(obj)
    assert "grid" not in back.info and back.info["stored_precision"] == "float64"


def test_files_of_other_tools_read_as_before(tmp_path, ball_mesh):
    tm = trimesh.Trimesh(ball_mesh.vertices, ball_mesh.cells, process=False)
    for name in ("t.ply", "t.obj", "t.stl"):
        tm.export(tmp_path / name)
        back = read_mesh(tmp_path / name)
        assert "grid" not in back.info
        assert back.info["stored_precision"] in ("float32", "float64")
        assert back.n_cells == ball_mesh.n_cells
    meshio.write_points_cells(
        tmp_path / "m.ply", ball_mesh.vertices, [("triangle", ball_mesh.cells)], binary=False
    )
    back = read_mesh(tmp_path / "m.ply")
    assert back.info["stored_precision"] == "float64"  # meshio writes double
    assert np.array_equal(back.vertices, ball_mesh.vertices)
    assert np.array_equal(back.cells, ball_mesh.cells)


# --- 3. precision ---------------------------------------------------------------------------


def ply_coordinate_type(path) -> str:
    head = path.read_bytes().split(b"end_header")[0].decode("ascii")
    return re.search(r"property (\w+) x", head).group(1)


@pytest.mark.parametrize("ascii", [False, True])
def test_hydrogen_ply_keeps_every_vertex_distinct(tmp_path, hydrogen, ascii):
    # in memory: distinct vertices, no zero-length edge, no degenerate triangle
    assert len(np.unique(hydrogen.vertices, axis=0)) == hydrogen.n_vertices
    notes: list[str] = []
    path = write_mesh(hydrogen, tmp_path / "h.ply", ascii=ascii, on_status=notes.append)
    assert ply_coordinate_type(path) == "double"
    assert notes == ["note: vertex coordinates written as double: in float32, 56 vertices merge"]
    back = read_mesh(path)
    assert back.info["stored_precision"] == "float64"
    problems = check_mesh(back).to_dict()["problems"]
    assert problems["zero_length_edges"]["count"] == 0
    assert problems["degenerate_triangles"]["count"] == 0
    # independently of isoconvert's reader and report
    other = trimesh.load(path, process=False)
    assert len(np.unique(np.asarray(other.vertices), axis=0)) == hydrogen.n_vertices
    assert np.array_equal(other.vertices, hydrogen.vertices)


def test_far_from_the_origin_ply_stores_doubles_and_stl_says_what_it_loses(tmp_path, far_sphere):
    notes: list[str] = []
    path = write_mesh(far_sphere, tmp_path / "s.ply", on_status=notes.append)
    assert ply_coordinate_type(path) == "double"
    assert len(notes) == 1 and notes[0].startswith("note: vertex coordinates written as double")
    back = read_mesh(path)
    assert np.array_equal(back.vertices, far_sphere.vertices)
    notes.clear()
    stl = write_mesh(far_sphere, tmp_path / "s.stl", on_status=notes.append)
    assert len(notes) == 1
    found = re.fullmatch(
        r"note: STL stores float32: ([\d,]+) vertices merge and ([\d,]+) triangles become "
        r"degenerate at that precision; write PLY \(which then stores doubles\) or OBJ, or move "
        r"the origin nearer the mesh",
        notes[0],
    )
    assert found, notes[0]
    merged, degenerate = (int(g.replace(",", "")) for g in found.groups())
    # the counts are what the file shows
    rounded = far_sphere.vertices.astype(np.float32)
    assert merged == len(np.unique(far_sphere.vertices, axis=0)) - len(np.unique(rounded, axis=0))
    assert check_mesh(read_mesh(stl)).problems["degenerate_triangles"]["count"] == degenerate


def test_ply_stays_float_when_float_loses_nothing(tmp_path, ball_mesh):
    notes: list[str] = []
    path = write_mesh(ball_mesh, tmp_path / "b.ply", on_status=notes.append)
    assert ply_coordinate_type(path) == "float"  # half the size, when that loses nothing
    assert notes == []
    assert read_mesh(path).info["stored_precision"] == "float32"
    path = write_mesh(ball_mesh, tmp_path / "b.stl", on_status=notes.append)
    assert notes == []


def test_a_triangle_float32_would_flatten_makes_a_double_ply(tmp_path):
    # no two vertices merge in float32, but y = 1e4 + 1e-4 rounds to 1e4: collinear
    vertices = np.array([[0.0, 1e4, 0.0], [1.0, 1e4, 0.0], [0.5, 1e4 + 1e-4, 0.0]])
    mesh = Mesh(vertices, np.array([[0, 1, 2]]))
    notes: list[str] = []
    path = write_mesh(mesh, tmp_path / "t.ply", on_status=notes.append)
    assert ply_coordinate_type(path) == "double"
    assert notes == [
        "note: vertex coordinates written as double: in float32, 1 triangles become degenerate"
    ]
    assert check_mesh(read_mesh(path)).problems["degenerate_triangles"]["count"] == 0
    write_mesh(mesh, tmp_path / "t.stl", on_status=notes.append)
    assert notes[-1].startswith("note: STL stores float32: 1 triangles become degenerate")


def test_segments_float32_would_collapse_make_a_double_ply(tmp_path):
    vertices = np.array([[5e6, 0.0, 0.0], [5e6 + 0.01, 0.0, 0.0], [5e6 + 1.0, 0.0, 0.0]])
    mesh = Mesh(vertices, np.array([[0, 1], [1, 2]]))
    notes: list[str] = []
    path = write_mesh(mesh, tmp_path / "s.ply", on_status=notes.append)
    assert ply_coordinate_type(path) == "double"
    assert notes == ["note: vertex coordinates written as double: in float32, 1 vertices merge"]
    assert np.array_equal(read_mesh(path).vertices, vertices)


def brute_force_loss(vertices, cells):
    """The shared definition applied to every cell, without shortcuts."""
    from isoconvert.geometry import flat_triangles, triangle_cross

    def degenerate(v):
        p = v[cells]
        same = [(p[:, i] == p[:, j]).all(axis=1) for i, j in ((0, 1), (1, 2), (0, 2))]
        return same[0] | same[1] | same[2] | flat_triangles(v, cells, triangle_cross(v, cells))

    rounded = vertices.astype(np.float32).astype(np.float64)
    merged = len(np.unique(vertices, axis=0)) - len(np.unique(rounded, axis=0))
    return merged, int((degenerate(rounded) & ~degenerate(vertices)).sum())


@settings(max_examples=150, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 1.0, 1e3, 1e5, 5e6, -3e7]),
    st.sampled_from([1e-9, 1e-6, 1e-3, 1.0, 100.0]),
)
def test_float32_loss_agrees_with_the_shared_definition(seed, offset, scale):
    from isoconvert.writers.precision import float32_loss

    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 40))
    vertices = offset + scale * rng.random((n, 3))
    # some exact duplicates, some collinear triples, some near-collinear slivers
    vertices[rng.integers(0, n, 3)] = vertices[rng.integers(0, n, 3)]
    a, b = vertices[0], vertices[1]
    vertices[2] = a + 0.5 * (b - a)
    vertices[3] = a + 0.25 * (b - a) + scale * 1e-9
    cells = rng.integers(0, n, (60, 3))
    cells[:4] = [[0, 1, 2], [0, 1, 3], [1, 2, 3], [0, 2, 3]]
    loss = float32_loss(vertices, cells)
    assert (loss.merged_vertices, loss.degenerate_cells) == brute_force_loss(vertices, cells)


@settings(max_examples=150, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from([0.0, 1e3, 5e6, -3e7]),
    st.sampled_from([2, 3]),
)
def test_float32_loss_with_few_moved_vertices_agrees_with_the_shared_definition(
    seed, offset, corners
):
    """Most vertices already float32 values (a label mesh's voxel corners), a few
    moved off them by less than half a float32 step: they land on a vertex that
    stays, on each other, or alone, so only they and where they land are tested."""
    from isoconvert.writers.precision import float32_loss

    rng = np.random.default_rng(seed)
    n = int(rng.integers(12, 60))
    vertices = np.float32(offset) + rng.integers(0, 8, (n, 3)).astype(np.float32) * np.float32(0.5)
    vertices = vertices.astype(np.float64)
    step = np.spacing(np.abs(vertices).astype(np.float32)).astype(np.float64)
    few = rng.choice(n, int(rng.integers(1, n // 3)), replace=False)
    vertices[few] += step[few] * rng.uniform(-0.45, 0.45, (len(few), 3))
    # one moved vertex lands on another (stay or moved) vertex's float32 position
    vertices[few[0]] = vertices[rng.integers(0, n)].astype(np.float32) + step[few[0]] * 0.3
    cells = rng.integers(0, n, (80, corners))
    loss = float32_loss(vertices, cells)
    merged, degenerate = brute_force_loss(vertices, cells) if corners == 3 else (None, None)
    if corners == 2:
        rounded = vertices.astype(np.float32).astype(np.float64)
        merged = len(np.unique(vertices, axis=0)) - len(np.unique(rounded, axis=0))
        a, b = cells[:, 0], cells[:, 1]
        same = (rounded[a] == rounded[b]).all(axis=1)
        degenerate = int((same & (vertices[a] != vertices[b]).any(axis=1)).sum())
    assert (loss.merged_vertices, loss.degenerate_cells) == (merged, degenerate)


# --- 4. what was written, for the report ----------------------------------------------------


@pytest.mark.parametrize(("fmt", "ascii"), CASES)
@pytest.mark.parametrize("which", ["hydrogen", "far_sphere"])
def test_report_on_stored_mesh_equals_report_on_the_file(tmp_path, request, which, fmt, ascii):
    from isoconvert.writers import stored_mesh

    mesh = request.getfixturevalue(which)
    path = write_mesh(mesh, tmp_path / f"m.{fmt}", ascii=ascii)
    stored = stored_mesh(mesh, fmt, ascii)
    back = read_mesh(path)
    assert report_dict(stored) == report_dict(back)
    assert np.array_equal(stored.vertices, back.vertices)
    assert np.array_equal(stored.cells, back.cells)
    assert stored.info["stored_precision"] == back.info["stored_precision"]
    assert stored.info.get("grid") == back.info.get("grid")


@pytest.mark.parametrize(("fmt", "ascii"), CASES)
def test_writing_the_stored_mesh_writes_the_same_file(tmp_path, far_sphere, fmt, ascii):
    from isoconvert.writers import stored_mesh

    notes: list[str] = []
    stored = stored_mesh(far_sphere, fmt, ascii, on_status=notes.append)
    first = write_mesh(far_sphere, tmp_path / f"a.{fmt}", ascii=ascii)
    again = write_mesh(stored, tmp_path / f"b.{fmt}", ascii=ascii, on_status=notes.append)
    assert first.read_bytes() == again.read_bytes()
    assert stored.info["stored_precision"] == read_mesh(first).info["stored_precision"]
    if fmt == "obj":
        assert notes == []
    elif fmt == "stl":  # the stored STL mesh is float32 already: nothing more to say
        assert len(notes) == 1
    else:  # the stored PLY mesh holds the same doubles, for the same reason
        assert len(notes) == 2 and notes[0] == notes[1]


# --- 5. vertex indices that do not exist ----------------------------------------------------


def ply_with_bad_face(path, ascii: bool, bad: int) -> None:
    """40 vertices, 20 triangles; face 12 refers to vertex ``bad``, face 15 to 120."""
    vertices = np.random.default_rng(1).random((40, 3))
    faces = np.arange(60).reshape(20, 3) % 40
    faces[12, 1] = bad
    faces[15, 2] = 120
    head = (
        f"ply\nformat {'ascii' if ascii else 'binary_little_endian'} 1.0\n"
        "element vertex 40\nproperty float x\nproperty float y\nproperty float z\n"
        "element face 20\nproperty list uchar int vertex_indices\nend_header\n"
    )
    if ascii:
        body = "".join(f"{x} {y} {z}\n" for x, y, z in vertices)
        body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
        path.write_text(head + body)
        return
    body = vertices.astype("<f4").tobytes()
    body += b"".join(struct.pack("<Biii", 3, *map(int, f)) for f in faces)
    path.write_bytes(head.encode() + body)


@pytest.mark.parametrize("ascii", [False, True])
def test_ply_face_past_the_vertices_is_a_format_error(tmp_path, ascii):
    path = tmp_path / "part.ply"
    ply_with_bad_face(path, ascii, 99)
    with pytest.raises(FormatError) as err:
        read_mesh(path)
    assert str(err.value) == f"{path}: face 12 refers to vertex 99, but there are only 40 vertices"


@pytest.mark.parametrize("ascii", [False, True])
def test_ply_negative_face_index_is_a_format_error(tmp_path, ascii):
    path = tmp_path / "part.ply"
    ply_with_bad_face(path, ascii, -3)
    with pytest.raises(FormatError) as err:
        read_mesh(path)
    assert str(err.value) == f"{path}: face 12 refers to vertex -3, but vertex indices start at 0"


@pytest.mark.parametrize("ascii", [False, True])
def test_ply_edge_past_the_vertices_is_a_format_error(tmp_path, ascii):
    head = (
        f"ply\nformat {'ascii' if ascii else 'binary_little_endian'} 1.0\n"
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "element edge 2\nproperty int vertex1\nproperty int vertex2\nend_header\n"
    )
    vertices = np.eye(3)
    edges = np.array([[0, 1], [1, 7]])
    path = tmp_path / "rings.ply"
    if ascii:
        body = "".join(f"{x} {y} {z}\n" for x, y, z in vertices)
        path.write_text(head + body + "0 1\n1 7\n")
    else:
        path.write_bytes(
            head.encode() + vertices.astype("<f4").tobytes() + edges.astype("<i4").tobytes()
        )
    with pytest.raises(FormatError) as err:
        read_mesh(path)
    assert str(err.value) == f"{path}: edge 1 refers to vertex 7, but there are only 3 vertices"


def test_check_names_the_bad_face_not_an_internal_error(tmp_path, capsys):
    path = tmp_path / "part.ply"
    ply_with_bad_face(path, False, 99)
    assert main(["check", str(path)]) == 1
    err = capsys.readouterr().err
    assert "face 12 refers to vertex 99, but there are only 40 vertices" in err
    assert "internal error" not in err and err.count("\n") == 1


def obj_text(faces: str, n: int = 40) -> str:
    return "# made by hand\n" + "".join(f"v {i} {i % 7} {i % 3}\n" for i in range(n)) + faces


@pytest.mark.parametrize(
    ("faces", "message"),
    [
        (
            "f 1 2 3\nf 4 5 99\n",
            "face 2 (line 43) refers to vertex 99, but there are only 40 vertices",
        ),
        ("f 1 2 3\nf 4/1 5/2 99/3\n", "face 2 (line 43) refers to vertex 99"),
        (
            "f 1 2 3\nf 0 1 2\n",
            "face 2 (line 43) refers to vertex 0, but OBJ vertex indices start at 1",
        ),
        ("f -1 -2 -41\n", "face 1 (line 42) refers to vertex -41, but only 40 vertices precede it"),
        ("l 1 2 77\n", "line 1 (line 42) refers to vertex 77, but there are only 40 vertices"),
    ],
)
def test_obj_index_that_does_not_exist_is_a_format_error(tmp_path, faces, message):
    path = tmp_path / "part.obj"
    path.write_text(obj_text(faces))
    with pytest.raises(FormatError) as err:
        read_mesh(path)
    assert str(err.value).startswith(f"{path}: {message}")
    assert "\n" not in str(err.value)


def test_obj_relative_indices_count_back_from_the_vertices_so_far(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text(
        "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n"
        "o b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\nf 4/1/1 5//2 6\n"
    )
    back = read_mesh(path)
    assert back.cells.tolist() == [[0, 1, 2], [3, 4, 5], [3, 4, 5]]


def test_polygons_become_fans_and_keep_the_file_indices(tmp_path):
    obj = tmp_path / "quads.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nf 1 2 3 4\nf 2 5 3\n")
    assert read_mesh(obj).cells.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    head = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 5\n"
        "property float x\nproperty float y\nproperty float z\n"
        "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], "<f4")
    body = struct.pack("<B4i", 4, 0, 1, 2, 3) + struct.pack("<B3i", 3, 1, 4, 9)
    ply = tmp_path / "quads.ply"
    ply.write_bytes(head.encode() + vertices.tobytes() + body)
    with pytest.raises(FormatError, match=r"face 1 refers to vertex 9, but there are only 5"):
        read_mesh(ply)


def test_writing_cells_that_refer_to_missing_vertices_is_a_format_error(tmp_path):
    mesh = Mesh(np.eye(3), np.array([[0, 1, 2], [0, 2, 5]]))
    for name in ("m.ply", "m.stl", "m.obj"):
        with pytest.raises(FormatError, match="triangle 1 of the mesh refers to vertex 5"):
            write_mesh(mesh, tmp_path / name)
    assert list(tmp_path.iterdir()) == []
