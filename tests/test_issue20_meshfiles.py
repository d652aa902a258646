"""Issue 20: mesh files that blow up, and readers whose errors name the wrong thing.

- Decompression bombs (a VTP zlib block that inflates past what its header
  declares, a 3MF model part that inflates a thousand times) are refused in one
  line, having inflated no more than the file declares: the tests' peak memory
  (tracemalloc, which numpy and zlib's bytes report to) stays a few MB while
  the bombs would inflate to 200 MB.
- Headers declaring more than the file holds (a GLB accessor of 10**12 zeros, a
  PLY element of 10**12 records, negative counts) are refused before anything
  is allocated.
- A garbage STL says what is wrong with the file, never which optional module
  a fallback reader lacked.
"""

from __future__ import annotations

import json
import struct
import tracemalloc
import zipfile
import zlib

import numpy as np
import pytest
import trimesh

from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.meshfile import read_mesh

MB = 1 << 20
#: What a bomb inflates to, were it let: far above the peak memory allowed.
BOMB = 200 * MB
#: Peak memory (traced) allowed while refusing a bomb.
PEAK = 8 * MB


def zlib_of_zeros(size: int, level: int = 9) -> bytes:
    """zlib stream of ``size`` zero bytes, made 1 MB at a time (about 1000:1)."""
    packer = zlib.compressobj(level)
    zeros = bytes(MB)
    parts = [packer.compress(zeros) for _ in range(size // MB)]
    parts.append(packer.compress(bytes(size % MB)))
    parts.append(packer.flush())
    return b"".join(parts)


def refused(path, *needles: str) -> tuple[str, int]:
    """Read ``path``: the FormatError's one-line message and the traced peak memory."""
    tracemalloc.start()
    try:
        with pytest.raises(FormatError) as caught:
            read_mesh(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(caught.value)
    assert "\n" not in message and message.startswith(str(path))
    for needle in needles:
        assert needle in message, message
    return message, peak


def one_line_cli(capsys, path) -> str:
    code = main(["check", str(path)])
    _, err = capsys.readouterr()
    assert code == 1 and err.count("\n") == 1 and "Traceback" not in err, err
    return err


# --- VTP ---------------------------------------------------------------------------------------

TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4")


def vtp_file(path, points_block: bytes, declared: int) -> None:
    """A VTP of one triangle, appended raw, zlib with UInt32 headers: the points are
    one block ``points_block`` whose header declares ``declared`` bytes."""

    def block(raw: bytes, size: int) -> bytes:
        return struct.pack("<4I", 1, size, size, len(raw)) + raw

    points = block(points_block, declared)
    connectivity = block(zlib.compress(np.arange(3, dtype="<i4").tobytes()), 12)
    offsets = block(zlib.compress(np.array([3], "<i4").tobytes()), 4)
    xml = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt32" compressor="vtkZLibDataCompressor">\n'
        '<PolyData><Piece NumberOfPoints="3" NumberOfPolys="1">\n'
        '<Points><DataArray type="Float32" NumberOfComponents="3" format="appended" '
        'offset="0"/></Points>\n'
        f'<Polys><DataArray type="Int32" Name="connectivity" format="appended" '
        f'offset="{len(points)}"/>\n'
        f'<DataArray type="Int32" Name="offsets" format="appended" '
        f'offset="{len(points) + len(connectivity)}"/></Polys>\n'
        "</Piece></PolyData>\n"
        '<AppendedData encoding="raw">\n_'
    )
    tail = b"\n</AppendedData>\n</VTKFile>\n"
    path.write_bytes(xml.encode() + points + connectivity + offsets + tail)


def test_a_vtp_of_honest_blocks_reads(tmp_path):
    """The control: the same file with a block that inflates to what it declares."""
    path = tmp_path / "ok.vtp"
    vtp_file(path, zlib.compress(TRIANGLE.tobytes()), 36)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, TRIANGLE)
    np.testing.assert_array_equal(mesh.cells, [[0, 1, 2]])


def test_a_vtp_zlib_bomb_is_refused_without_inflating_it(tmp_path, capsys):
    path = tmp_path / "bomb.vtp"
    vtp_file(path, zlib_of_zeros(BOMB), 36)
    assert path.stat().st_size < BOMB // 500
    message, peak = refused(
        path, "a zlib block", "inflates past the 36 bytes its header declares", "bomb"
    )
    assert peak < PEAK, f"{peak / MB:.1f} MB traced while refusing: {message}"
    assert "bomb" in one_line_cli(capsys, path)


def test_a_vtp_block_declaring_more_than_zlib_can_inflate_is_corrupt(tmp_path):
    """Deflate makes at most 1032 bytes of one: 4e9 bytes from 20 is no zlib data."""
    path = tmp_path / "liar.vtp"
    vtp_file(path, zlib.compress(TRIANGLE.tobytes()), 4_000_000_000)
    refused(path, "declares 4,000,000,000 bytes", "corrupt")


# --- 3MF ---------------------------------------------------------------------------------------

MODEL = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<model unit="millimeter" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">'
    '<resources><object id="1" type="model"><mesh><vertices>'
    '<vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" y="1" z="0"/>'
    '</vertices><triangles><triangle v1="0" v2="1" v3="2"/></triangles></mesh></object>'
    '</resources><build><item objectid="1"/></build></model>'
)


def threemf_file(path, padding: int) -> None:
    """A 3MF whose model part is the triangle above and ``padding`` spaces (after
    the root element: still well-formed XML), written 1 MB at a time."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as package:
        with package.open("3D/3dmodel.model", "w", force_zip64=True) as fh:
            fh.write(MODEL.encode())
            spaces = b" " * MB
            for _ in range(padding // MB):
                fh.write(spaces)


def test_a_3mf_of_an_ordinary_model_reads(tmp_path):
    path = tmp_path / "ok.3mf"
    threemf_file(path, 2 * MB)
    mesh = read_mesh(path)
    np.testing.assert_array_equal(mesh.vertices, TRIANGLE)


def test_a_3mf_bomb_is_refused_before_it_is_inflated(tmp_path, capsys):
    path = tmp_path / "bomb.3mf"
    threemf_file(path, BOMB)
    with zipfile.ZipFile(path) as package:
        entry = package.getinfo("3D/3dmodel.model")
    assert entry.file_size > BOMB and entry.file_size > 500 * entry.compress_size
    message, peak = refused(path, "3D/3dmodel.model", f"{entry.file_size:,} bytes", "bomb")
    assert peak < PEAK, f"{peak / MB:.1f} MB traced while refusing: {message}"
    assert "bomb" in one_line_cli(capsys, path)


# --- GLB ---------------------------------------------------------------------------------------


def glb_file(path, gltf: dict, binary: bytes = b"") -> None:
    body = json.dumps(gltf).encode()
    body += b" " * (-len(body) % 4)
    chunks = struct.pack("<II", len(body), 0x4E4F534A) + body
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)


def test_a_glb_accessor_of_a_trillion_zeros_is_refused(tmp_path):
    """An accessor with no bufferView is all zeros: 10**12 of them would be 12 TB."""
    gltf = {
        "asset": {"version": "2.0"},
        "accessors": [{"componentType": 5126, "type": "VEC3", "count": 10**12}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }
    path = tmp_path / "zeros.glb"
    glb_file(path, gltf)
    _, peak = refused(path, "1,000,000,000,000 elements", "corrupt")
    assert peak < PEAK


def test_a_glb_that_requires_draco_says_so(tmp_path):
    gltf = {
        "asset": {"version": "2.0"},
        "extensionsRequired": ["KHR_draco_mesh_compression"],
        "accessors": [{"componentType": 5126, "type": "VEC3", "count": 3}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }
    path = tmp_path / "draco.glb"
    glb_file(path, gltf)
    refused(path, "KHR_draco_mesh_compression")


# --- PLY and OFF -------------------------------------------------------------------------------


def test_a_ply_face_count_the_file_cannot_hold_is_refused_at_once(tmp_path):
    """10**12 faces of at least 1 byte each (the list's count) in a file of 100 bytes."""
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {10**12}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path = tmp_path / "many.ply"
    path.write_bytes(header.encode() + TRIANGLE.tobytes() + b"\x03" + bytes(12))
    refused(path, "declares 1,000,000,000,000 records", "13 bytes left")


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_a_negative_ply_count_is_refused(tmp_path, fmt):
    """A count of -1 made numpy read the rest of the file as vertices."""
    header = (
        f"ply\nformat {fmt} 1.0\nelement vertex -1\n"
        "property float x\nproperty float y\nproperty float z\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    body = b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n" if fmt == "ascii" else TRIANGLE.tobytes()
    path = tmp_path / "negative.ply"
    path.write_bytes(header.encode() + body)
    refused(path, "negative count")


def test_a_negative_off_count_is_refused(tmp_path):
    path = tmp_path / "negative.off"
    path.write_text("OFF\n-1 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    refused(path, "negative vertex or face count")


# --- STL ---------------------------------------------------------------------------------------


def test_a_garbage_binary_stl_says_what_is_wrong(tmp_path, capsys):
    """80 bytes, a count of 123456, and 1000 bytes: 84 + 50 * 123456 are needed."""
    path = tmp_path / "garbage.stl"
    path.write_bytes(bytes(range(80)) + struct.pack("<I", 123456) + b"\x8f" * 1000)
    message, _ = refused(
        path,
        "not a binary STL (80-byte header + count 123,456 needs 6,172,884 bytes, "
        "the file has 1,084)",
        "nor an ASCII STL (no 'solid' line)",
    )
    assert "module" not in message
    assert "garbage.stl" in one_line_cli(capsys, path)


def test_a_file_shorter_than_a_binary_stl_header(tmp_path):
    path = tmp_path / "short.stl"
    path.write_bytes(b"\x00\x01garbage")
    refused(path, "not a binary STL (9 bytes", "nor an ASCII STL")


def test_garbage_after_a_solid_line_says_both_readings_fail(tmp_path):
    """'solid', then 200 bytes of no facet: neither ASCII nor (84 + 50 n bytes) binary."""
    path = tmp_path / "solid_garbage.stl"
    path.write_bytes(b"solid x\n" + bytes(range(1, 201)))
    refused(
        path,
        "not an ASCII STL (a 'solid' line, but no 'facet' or 'vertex' lines)",
        "nor a binary STL (80-byte header + count",
        "the file has 208)",
    )


def test_an_ascii_stl_with_a_broken_vertex_line_names_it(tmp_path):
    path = tmp_path / "broken.stl"
    path.write_text(
        "solid x\nfacet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 zero\n"
        "  vertex 0 1 0\n endloop\nendfacet\nendsolid x\n"
    )
    refused(path, "line 5 is not 'vertex x y z'")


@pytest.mark.parametrize("file_type", ["stl", "stl_ascii"])
def test_stl_reads_as_trimesh_writes_it(tmp_path, file_type):
    """Binary and ASCII STL from trimesh: three corners per triangle, in order."""
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    path = tmp_path / "box.stl"
    box.export(path, file_type=file_type)
    mesh = read_mesh(path)
    corners = box.vertices[box.faces].reshape(-1, 3).astype(np.float32)
    np.testing.assert_array_equal(mesh.vertices, corners)
    np.testing.assert_array_equal(mesh.cells, np.arange(36).reshape(-1, 3))
    assert mesh.info["stored_precision"] == "float32"


def test_a_binary_stl_whose_header_starts_with_solid_reads(tmp_path):
    """Some exporters begin the 80-byte header with 'solid': the size tells."""
    box = trimesh.creation.box()
    path = tmp_path / "solid_header.stl"
    box.export(path)
    data = bytearray(path.read_bytes())
    data[:80] = b"solid but binary".ljust(80, b" ")
    path.write_bytes(bytes(data))
    assert read_mesh(path).cells.shape == (12, 3)
