"""GLB and 3MF writers (issue 11): read back by trimesh (GLB) and the standard
library's ZIP and XML parsers (3MF; trimesh's 3MF loader needs lxml)."""

from __future__ import annotations

import importlib.util
import json
import struct
import zipfile
from xml.etree import ElementTree

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES

from isoconvert import Mesh, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.extract.blocks import Blocks
from isoconvert.writers import WRITERS
from isoconvert.writers.header import parse_grid_comment
from isoconvert.writers.threemf import CORE_NAMESPACE, MODEL_PART, UNITS_3MF

NS = {"m": CORE_NAMESPACE}


@pytest.fixture(scope="module")
def sphere() -> Mesh:
    return extract(read_volume(SAMPLES / "sphere.nrrd"), 100.5)


def float32(vertices) -> np.ndarray:
    return np.asarray(vertices, dtype=np.float64).astype(np.float32)


def glb_parts(path) -> tuple[dict, bytes, bytes]:
    """The JSON and BIN chunks of a GLB, checking the container's framing."""
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<III", data)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    text = data[20 : 20 + json_length]
    start = 20 + json_length
    if start == len(data):
        return json.loads(text), text, b""
    bin_length, bin_type = struct.unpack_from("<II", data, start)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0
    assert start + 8 + bin_length == len(data)
    return json.loads(text), text, data[start + 8 :]


def read_3mf(path) -> tuple[ElementTree.Element, np.ndarray, np.ndarray]:
    with zipfile.ZipFile(path) as package:
        assert package.testzip() is None
        names = package.namelist()
        assert names == ["[Content_Types].xml", "_rels/.rels", MODEL_PART]
        assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in package.infolist())
        types = ElementTree.fromstring(package.read("[Content_Types].xml"))
        assert {e.get("Extension") for e in types} == {"rels", "model"}
        rels = ElementTree.fromstring(package.read("_rels/.rels"))
        assert [r.get("Target") for r in rels] == ["/" + MODEL_PART]
        model = ElementTree.fromstring(package.read(MODEL_PART))
    assert model.tag == f"{{{CORE_NAMESPACE}}}model" and model.get("unit") in UNITS_3MF.values()
    vertices = np.array(
        [
            [float(v.get(a)) for a in "xyz"]
            for v in model.iterfind("m:resources/m:object/m:mesh/m:vertices/m:vertex", NS)
        ]
    )
    triangles = np.array(
        [
            [int(t.get(a)) for a in ("v1", "v2", "v3")]
            for t in model.iterfind("m:resources/m:object/m:mesh/m:triangles/m:triangle", NS)
        ],
        dtype=np.int64,
    )
    return model, vertices, triangles


# --- registration -----------------------------------------------------------------------------


def test_the_writers_are_registered_before_svg():
    names = list(WRITERS.names())
    assert names.index("vtp") < names.index("glb") < names.index("3mf") < names.index("svg")
    for name, suffix in (("glb", ".glb"), ("3mf", ".3mf")):
        writer = WRITERS.get(name)
        assert writer.suffixes == (suffix,) and writer.cell_sizes == {3}
        assert writer.precision == "float32" and writer.streams and writer.records_grid
        assert not writer.has_binary  # one form only: --ascii claims nothing


# --- GLB --------------------------------------------------------------------------------------


def test_glb_reads_back_with_trimesh(tmp_path, sphere):
    path = write_mesh(sphere, tmp_path / "m.glb")
    back = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_array_equal(back.vertices, float32(sphere.vertices))
    np.testing.assert_array_equal(back.faces, sphere.cells)
    assert back.is_watertight and back.is_winding_consistent and back.volume > 0


def test_glb_json_has_the_required_fields(tmp_path, sphere):
    path = write_mesh(sphere, tmp_path / "m.glb")
    gltf, text, binary = glb_parts(path)
    assert text.decode("utf-8").rstrip(" ") == text.decode("utf-8").rstrip()
    n_vertices, n_cells = len(sphere.vertices), len(sphere.cells)
    assert gltf["asset"]["version"] == "2.0"
    assert gltf["asset"]["generator"].startswith("isoconvert ")
    assert gltf["scenes"][gltf["scene"]]["nodes"] == [0] and gltf["nodes"][0]["mesh"] == 0
    [primitive] = gltf["meshes"][0]["primitives"]
    assert primitive["mode"] == 4
    position = gltf["accessors"][primitive["attributes"]["POSITION"]]
    indices = gltf["accessors"][primitive["indices"]]
    stored = float32(sphere.vertices)
    assert position["componentType"] == 5126 and position["type"] == "VEC3"
    assert position["count"] == n_vertices
    assert position["min"] == stored.min(axis=0).tolist()
    assert position["max"] == stored.max(axis=0).tolist()
    assert indices["componentType"] == 5125 and indices["type"] == "SCALAR"
    assert indices["count"] == 3 * n_cells
    views = gltf["bufferViews"]
    assert views[position["bufferView"]]["byteLength"] == 12 * n_vertices
    assert views[indices["bufferView"]]["byteLength"] == 12 * n_cells
    assert all(v["byteOffset"] % 4 == 0 for v in views)
    assert gltf["buffers"] == [{"byteLength": len(binary)}]
    view = views[position["bufferView"]]
    raw = binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
    np.testing.assert_array_equal(np.frombuffer(raw, "<f4").reshape(-1, 3), stored)
    view = views[indices["bufferView"]]
    raw = binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
    np.testing.assert_array_equal(np.frombuffer(raw, "<u4").reshape(-1, 3), sphere.cells)


def test_glb_extras_record_provenance_grid_and_frame(tmp_path, sphere):
    mesh = Mesh(sphere.vertices, sphere.cells, None, {**sphere.info, "source": "a\nb.nrrd"})
    gltf, _, _ = glb_parts(write_mesh(mesh, tmp_path / "m.glb"))
    extras = gltf["asset"]["extras"]["isoconvert"]
    assert extras["provenance"][0].startswith("made by isoconvert")
    assert "source a\\nb.nrrd" in extras["provenance"]  # escaped as in PLY/OBJ headers
    assert extras["grid"]["shape"] == [40, 40, 40]
    assert "no swap" in extras["frame"] and "meters" in extras["frame"]


def test_an_empty_mesh_is_a_glb_with_an_empty_scene(tmp_path):
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    gltf, _, binary = glb_parts(write_mesh(empty, tmp_path / "e.glb"))
    assert gltf["scenes"] == [{}] and "meshes" not in gltf and binary == b""


# --- 3MF --------------------------------------------------------------------------------------


def test_3mf_reads_back(tmp_path, sphere):
    path = write_mesh(sphere, tmp_path / "m.3mf")
    model, vertices, triangles = read_3mf(path)
    # 9 significant digits: parsed as float32 they give the float32 values back exactly
    np.testing.assert_array_equal(vertices.astype(np.float32), float32(sphere.vertices))
    np.testing.assert_array_equal(triangles, sphere.cells)
    back = trimesh.Trimesh(vertices, triangles, process=False)
    assert back.is_watertight and back.is_winding_consistent and back.volume > 0
    [item] = model.iterfind("m:build/m:item", NS)
    assert item.get("objectid") == "1"
    metadata = {m.get("name"): m.text for m in model.iterfind("m:metadata", NS)}
    assert metadata["Application"].startswith("isoconvert ")
    assert metadata["Description"].startswith("made by isoconvert")
    assert parse_grid_comment(metadata["isoconvert:grid"])["shape"] == [40, 40, 40]


@pytest.mark.skipif(importlib.util.find_spec("lxml") is None, reason="trimesh's 3MF needs lxml")
def test_3mf_reads_back_with_trimesh(tmp_path, sphere):
    back = trimesh.load(write_mesh(sphere, tmp_path / "m.3mf"), force="mesh", process=False)
    assert len(back.vertices) == len(sphere.vertices) and back.is_watertight


def test_3mf_metadata_is_escaped_xml(tmp_path, sphere):
    mesh = Mesh(sphere.vertices, sphere.cells, None, {**sphere.info, "source": "<a&b>\x00.nrrd"})
    model, _, _ = read_3mf(write_mesh(mesh, tmp_path / "m.3mf"))
    metadata = {m.get("name"): m.text for m in model.iterfind("m:metadata", NS)}
    assert "source <a&b>\\x00.nrrd" in metadata["Description"].split("\n")


# --- both -------------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".glb", ".3mf"])
def test_contour_segments_are_refused(tmp_path, suffix):
    segments = Mesh(np.zeros((2, 3)), np.array([[0, 1]]))
    name = suffix[1:]
    with pytest.raises(FormatError, match=f"{name} cannot hold contour segments; write "):
        write_mesh(segments, tmp_path / f"c{suffix}")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", [".glb", ".3mf"])
def test_float32_loss_is_noted(tmp_path, suffix):
    from conftest import ball

    from isoconvert import Volume

    far = extract(Volume(ball(14, 4.7), spacing=(1e-3,) * 3, origin=(5e6, 0.0, 0.0)), 0.0)
    notes = []
    write_mesh(far, tmp_path / f"f{suffix}", on_status=notes.append)
    assert any(n.startswith(f"note: {suffix[1:].upper()} stores float32") for n in notes)


@pytest.fixture(scope="module")
def raw_volume(tmp_path_factory):
    """A float32 raw file with a bumpy surface."""
    n = 96
    r = np.arange(n, dtype=np.float32) - (n - 1) / 2
    z, y, x = np.meshgrid(r[:48], r, r, indexing="ij")
    zyx = 40 - np.sqrt(x**2 + y**2 + (z + 24) ** 2) + 3 * np.sin(x / 3) * np.cos(y / 4)
    path = tmp_path_factory.mktemp("raw") / f"bumps_{n}x{n}x48_float32.raw"
    zyx.astype(np.float32).tofile(path)
    return path


@pytest.mark.parametrize("fmt", ["glb", "3mf"])
def test_a_mesh_larger_than_the_budget_streams_to_the_same_file(raw_volume, tmp_path, fmt):
    from isoconvert.convert import convert
    from isoconvert.extract.blocks import BlockMesh

    convert(raw_volume, tmp_path / f"a.{fmt}", 0.5)
    streamed = convert(raw_volume, tmp_path / f"b.{fmt}", 0.5, blocks=Blocks(max_memory=1 << 17))
    assert isinstance(streamed.mesh, BlockMesh) and streamed.mesh.info["blocks"] > 5
    assert (tmp_path / f"a.{fmt}").read_bytes() == (tmp_path / f"b.{fmt}").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"a.{fmt}", f"b.{fmt}"]


@pytest.mark.parametrize("suffix", [".glb", ".3mf"])
def test_the_cli_converts_and_lists_them(tmp_path, capsys, suffix):
    out = tmp_path / f"s{suffix}"
    assert main(["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(out), "--level", "100.5"]) == 0
    if suffix == ".glb":
        back = trimesh.load(out, force="mesh", process=False)
        assert back.is_watertight
    else:
        _, vertices, triangles = read_3mf(out)
        assert trimesh.Trimesh(vertices, triangles, process=False).is_watertight
    capsys.readouterr()
    assert main(["formats"]) == 0
    listing = capsys.readouterr().out
    rows = [line.split()[:2] for line in listing.splitlines() if line.startswith("  ")]
    assert ["glb", ".glb"] in rows and ["3mf", ".3mf"] in rows  # name, then its suffix


@pytest.mark.parametrize("suffix", [".glb", ".3mf"])
def test_ascii_changes_nothing(tmp_path, sphere, suffix):
    a = write_mesh(sphere, tmp_path / f"a{suffix}").read_bytes()
    assert write_mesh(sphere, tmp_path / f"b{suffix}", ascii=True).read_bytes() == a


@pytest.mark.parametrize(("unit", "meters"), [("mm", 1e-3), ("µm", 1e-6), ("m", 1.0)])
def test_glb_is_in_meters_where_the_unit_is_known(tmp_path, sphere, unit, meters):
    """glTF means meters: the node scales the volume's unit to them, so trimesh (which
    applies node transforms) sees meters, and isoconvert reads the volume's units back."""
    mesh = Mesh(sphere.vertices, sphere.cells, info={**sphere.info, "unit": unit})
    path = write_mesh(mesh, tmp_path / "s.glb")
    gltf, _, _ = glb_parts(path)
    ours = gltf["asset"]["extras"]["isoconvert"]
    assert (ours["unit"], ours["meters_per_unit"]) == (unit, meters)
    assert gltf["nodes"][0].get("scale", [1.0, 1.0, 1.0]) == [meters] * 3
    seen = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(seen.vertices, float32(sphere.vertices) * meters, rtol=1e-6)
    from isoconvert.meshfile import read_mesh

    back = read_mesh(path)
    np.testing.assert_array_equal(back.vertices, float32(sphere.vertices))
    assert back.info["stored_precision"] == "float32"


def test_glb_without_a_unit_is_not_scaled(tmp_path, sphere):
    assert sphere.info.get("unit") is None
    gltf, _, _ = glb_parts(write_mesh(sphere, tmp_path / "s.glb"))
    assert "scale" not in gltf["nodes"][0]
    assert "not known" in gltf["asset"]["extras"]["isoconvert"]["unit"]


@pytest.mark.parametrize(
    ("unit", "model_unit"),
    [("mm", "millimeter"), ("µm", "micron"), ("micrometer", "micron"), ("cm", "centimeter"),
     (None, "millimeter"), ("nm", "millimeter")],
)  # fmt: skip
def test_3mf_states_the_volume_unit(tmp_path, sphere, unit, model_unit):
    mesh = Mesh(sphere.vertices, sphere.cells, info={**sphere.info, "unit": unit})
    model, vertices, _ = read_3mf(write_mesh(mesh, tmp_path / "s.3mf"))
    assert model.get("unit") == model_unit
    np.testing.assert_array_equal(vertices.astype(np.float32), float32(sphere.vertices))
    note = next(m.text for m in model.findall("m:metadata", NS) if "coordinates" in m.get("name"))
    assert ("not converted" in note) == (model_unit == "millimeter" and unit != "mm")


def test_real_scans_carry_their_units_to_glb_and_3mf(tmp_path):
    """A DICOM CT (mm) and a confocal TIFF stack (µm), through the command line."""
    from conftest import dataset

    cases = [("ct_chest_LIDC-IDRI-0314_dicom", "1300.5", 1e-3, "millimeter"),
             ("XYZ_organ-of-corti_confocal.tif", "auto", 1e-6, "micron")]  # fmt: skip
    for name, level, meters, model_unit in cases:
        source = dataset(name)
        glb, tmf = tmp_path / f"{name}.glb", tmp_path / f"{name}.3mf"
        for out in (glb, tmf):
            assert main(["convert", str(source), "-l", level, "-o", str(out), "-q"]) == 0
        gltf, _, _ = glb_parts(glb)
        assert gltf["nodes"][0]["scale"] == [meters] * 3
        assert read_3mf(tmf)[0].get("unit") == model_unit
        # the check of the GLB judges the holes against the grid in the volume's units
        assert main(["check", str(glb), "-q"]) == main(["check", str(tmf), "-q"])
