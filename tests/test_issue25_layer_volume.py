"""Precomputed layers with the labels' own voxels (``--with-volume``) and in the legacy
single-resolution mesh format (``--legacy-mesh``), issue 25: the chunks decoded by the
compressed_segmentation package and read back by cloud-volume equal to the labels, the
meshes placed on their voxels in the layer's frame, legacy meshes read back by
cloud-volume equal to the PLY's, and the info files checked against the fields and types
of Neuroglancer's specification (volume.md, meshes.md)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from isoconvert.errors import IsoconvertError
from isoconvert.extract.labels import label_surfaces
from isoconvert.volume import Volume
from isoconvert.writers.precomputed import write_precomputed
from isoconvert.writers.precomputed.volume import compressed_segmentation

cloudvolume = pytest.importorskip("cloudvolume", reason="pip install cloud-volume")
cseg = pytest.importorskip("compressed_segmentation", reason="pip install compressed-segmentation")

NM_PER_UM = 1000.0


def _labels(shape=(30, 36, 44), seed=4) -> np.ndarray:
    """(Z, Y, X) uint16: three overlapping balls (ids 2, 9, 700) and a slab touching
    the grid's edge, background 0; not a multiple of the 64-voxel chunks or 8-voxel blocks."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[: shape[0], : shape[1], : shape[2]].astype(np.float64)
    out = np.zeros(shape, np.uint16)
    for label in (2, 9, 700):
        c = rng.uniform(0.3, 0.7, 3) * shape
        out[(z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2 < (0.22 * min(shape)) ** 2] = label
    out[:, :4, :] = 5
    return out


@pytest.fixture(scope="module")
def oblique():
    """An oblique, anisotropic label volume in micrometres with an origin."""
    angle = 0.4
    direction = np.array(
        [[np.cos(angle), 0, np.sin(angle)], [0, 1.0, 0], [-np.sin(angle), 0, np.cos(angle)]]
    )
    return Volume.from_zyx(
        _labels(), spacing=(0.5, 0.8, 1.5), origin=(12.0, -3.0, 40.0), direction=direction,
        unit="µm",
    )  # fmt: skip


def _cloud(folder):
    return cloudvolume.CloudVolume(f"precomputed://file://{folder}", progress=False)


def _write(folder, source, surfaces, **kwargs):
    grid = surfaces.combined.info["grid"]
    notes: list[str] = []
    write_precomputed(folder, surfaces.meshes, grid, unit=source.unit, on_status=notes.append,
                      **kwargs)  # fmt: skip
    return notes


# --- the encoding -------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.uint32, np.uint64])
@pytest.mark.parametrize("shape", [(64, 64, 64), (13, 7, 29), (8, 8, 8), (1, 1, 1), (9, 64, 3)])
def test_compressed_segmentation_decodes_with_the_reference_decoder(shape, dtype):
    """Blocks of 1, 2, 3, 5, 17 and up to 512 distinct labels (0 to 16 bits a voxel),
    uint64 labels beyond 32 bits, chunks cut at the volume's edge."""
    rng = np.random.default_rng(sum(shape))
    for distinct in (1, 2, 3, 5, 17, 300, 10**6):
        chunk = rng.integers(0, distinct, shape).astype(dtype)
        if dtype == np.uint64:
            chunk = chunk * np.uint64(2**35) + np.uint64(3)
        data = compressed_segmentation(chunk)
        back = cseg.decompress(data, shape[::-1], dtype, (8, 8, 8), order="F")
        assert np.array_equal(back, chunk.T)
        # each block uses the fewest bits its labels allow (the channel's data starts
        # after its offset word; headers are two words per block)
        words = np.frombuffer(data, "<u4")
        gz, gy, gx = (-(-n // 8) for n in shape)
        bits = words[1 : 1 + 2 * gz * gy * gx : 2] >> 24
        padded = np.pad(chunk, [(0, -n % 8) for n in shape], mode="edge")
        blocks = padded.reshape(gz, 8, gy, 8, gx, 8).transpose(0, 2, 4, 1, 3, 5)
        counts = [len(np.unique(b)) for b in blocks.reshape(-1, 512)]
        fewest = [next(k for k in (0, 1, 2, 4, 8, 16, 32) if 2**k >= c) for c in counts]
        assert bits.tolist() == fewest


# --- the labels' voxels -------------------------------------------------------------------


def test_cloud_volume_reads_the_labels_back(tmp_path, oblique):
    surfaces = label_surfaces(oblique, smoothing=16)
    notes = _write(tmp_path / "layer", oblique, surfaces, data_type="uint32", volume=oblique)
    cv = _cloud(tmp_path / "layer")
    assert np.array_equal(np.asarray(cv[:, :, :])[..., 0], oblique.data)
    assert cv.info["scales"][0]["encoding"] == "compressed_segmentation"
    assert any("no origin or direction" in note for note in notes)


def test_the_background_is_stored_as_no_segment(tmp_path):
    labels = _labels()
    labels[labels == 0] = 7  # background 7
    volume = Volume.from_zyx(labels, spacing=(1.0, 1.0, 1.0), unit="nm")
    surfaces = label_surfaces(volume, background=7, smoothing=0)
    _write(tmp_path / "layer", volume, surfaces, data_type="uint32", volume=volume, background=7)
    stored = np.asarray(_cloud(tmp_path / "layer")[:, :, :])[..., 0]
    assert np.array_equal(stored, np.where(volume.data == 7, 0, volume.data))


def test_labels_a_segmentation_cannot_hold_are_errors(tmp_path):
    labels = _labels().astype(np.int32)
    labels[labels == 5] = -5
    volume = Volume.from_zyx(labels, spacing=(1.0, 1.0, 1.0))
    surfaces = label_surfaces(volume, labels=[2, 9], smoothing=0)
    with pytest.raises(IsoconvertError, match="label -5 is negative"):
        _write(tmp_path / "a", volume, surfaces, data_type="uint32", volume=volume)
    assert not (tmp_path / "a").exists()
    zero = Volume.from_zyx(np.where(_labels() == 5, 3, _labels()), spacing=(1.0, 1.0, 1.0))
    surfaces = label_surfaces(zero, labels=[2, 9], background=3, smoothing=0)
    with pytest.raises(IsoconvertError, match="label 0 would read as no segment"):
        _write(tmp_path / "b", zero, surfaces, data_type="uint32", volume=zero, background=3)
    with pytest.raises(IsoconvertError, match="uint32 or uint64"):
        _write(tmp_path / "c", zero, surfaces, data_type="uint16", volume=zero, background=3)
    # a negative background is stored as 0, but another negative label cannot be stored
    shifted = _labels().astype(np.int32)
    shifted[shifted == 0] = -3
    shifted[shifted == 5] = -1
    below = Volume.from_zyx(shifted, spacing=(1.0, 1.0, 1.0))
    surfaces = label_surfaces(below, labels=[2, 9], background=-3, smoothing=0)
    with pytest.raises(IsoconvertError, match="label -1 is negative"):
        _write(tmp_path / "d", below, surfaces, data_type="uint32", volume=below, background=-3)
    assert not any(tmp_path.iterdir())


def test_meshes_lie_on_their_voxels_in_the_layer_frame(tmp_path, oblique):
    """With the voxels in the layer, Neuroglancer puts voxel (i, j, k) at [i, i + 1) x
    resolution: the voxel-face surfaces (--smooth 0) must enclose exactly the voxels of
    their label there, so the solid's volume is the voxel count and its centroid the
    voxels' centroid (half a voxel off if the frame were the samples' positions)."""
    surfaces = label_surfaces(oblique, smoothing=0)
    _write(tmp_path / "layer", oblique, surfaces, data_type="uint32", volume=oblique, lods=1)
    cv = _cloud(tmp_path / "layer")
    resolution = np.asarray(cv.info["scales"][0]["resolution"], np.float64)
    stored = np.asarray(cv[:, :, :])[..., 0]
    for label in surfaces.labels:
        back = cv.mesh.get(int(label), lod=0)[int(label)]
        voxels = np.asarray(back.vertices, np.float64) / resolution  # voxel units
        solid = trimesh.Trimesh(voxels, back.faces, process=False)
        assert solid.is_watertight
        inside = np.argwhere(stored == label)
        # split vertices move 1/64 voxel into their sheet: < 0.05 voxel of volume each
        assert abs(solid.volume - len(inside)) < 0.05 * surfaces.split_vertices + 0.01
        assert np.allclose(solid.center_mass, inside.mean(axis=0) + 0.5, atol=0.02)


# --- the legacy format --------------------------------------------------------------------


@pytest.mark.parametrize("with_volume", [False, True])
def test_cloud_volume_reads_legacy_meshes_as_the_ply_surface(tmp_path, oblique, with_volume):
    surfaces = label_surfaces(oblique, smoothing=16)
    _write(tmp_path / "layer", oblique, surfaces, data_type="uint32", legacy=True,
           volume=oblique if with_volume else None)  # fmt: skip
    cv = _cloud(tmp_path / "layer")
    mesh_info = json.loads((tmp_path / "layer" / "mesh" / "info").read_text())
    assert mesh_info == {"@type": "neuroglancer_legacy_mesh"}
    resolution = np.asarray(oblique.spacing) * NM_PER_UM
    for label, mesh in surfaces.meshes.items():
        if with_volume:  # the layer's voxel frame: index plus half a voxel, times resolution
            affine = np.asarray(oblique.direction) * np.asarray(oblique.spacing)
            index = (mesh.vertices - oblique.origin) @ np.linalg.inv(affine).T
            expected = (index + 0.5) * resolution
        else:  # the world frame, in nanometres
            expected = np.asarray(mesh.vertices) * NM_PER_UM
        # the fragment as meshes.md lays it out: the vertex count, float32 nanometres,
        # uint32 triangles
        data = (tmp_path / "layer" / "mesh" / f"{label}:0:0").read_bytes()
        n = int(np.frombuffer(data, "<u4", 1)[0])
        vertices = np.frombuffer(data, "<f4", 3 * n, 4).reshape(-1, 3)
        step = np.spacing(np.abs(expected).astype(np.float32)).astype(np.float64)
        # float32, rounded once (plus float64 noise: the frames are computed differently)
        assert (np.abs(vertices - expected) <= step + 1e-9 * np.abs(expected).max()).all()
        assert np.array_equal(np.frombuffer(data, "<u4", offset=4 + 12 * n), mesh.cells.ravel())
        # cloud-volume merges and renumbers vertices: the same triangles by position
        back = cv.mesh.get(int(label))
        back = back[int(label)] if isinstance(back, dict) else back
        ours = {tuple(map(tuple, t)) for t in vertices[mesh.cells].tolist()}
        theirs = {tuple(map(tuple, t)) for t in np.asarray(back.vertices)[back.faces].tolist()}
        assert len(back.faces) == mesh.n_cells and ours == theirs


# --- info files ---------------------------------------------------------------------------

_UINT3 = {"type": "array", "minItems": 3, "maxItems": 3, "items": {"type": "integer", "minimum": 0}}
VOLUME_SCALE_SCHEMA = {
    "type": "object",
    "required": ["key", "size", "resolution", "voxel_offset", "chunk_sizes", "encoding"],
    "properties": {
        "key": {"type": "string", "minLength": 1},
        "size": _UINT3,
        "resolution": {
            "type": "array",
            "minItems": 3,
            "maxItems": 3,
            "items": {"type": "number", "exclusiveMinimum": 0},
        },
        "voxel_offset": {**_UINT3, "items": {"type": "integer"}},
        "chunk_sizes": {"type": "array", "minItems": 1, "items": _UINT3},
        "encoding": {"enum": ["raw", "jpeg", "compressed_segmentation"]},
        "compressed_segmentation_block_size": _UINT3,
    },
    # the block size if, and only if, the encoding is compressed_segmentation
    "if": {"properties": {"encoding": {"const": "compressed_segmentation"}}},
    "then": {"required": ["compressed_segmentation_block_size"]},
    "else": {"not": {"required": ["compressed_segmentation_block_size"]}},
}
LAYER_SCHEMA = {
    "type": "object",
    "required": ["type", "data_type", "num_channels", "scales"],
    "properties": {
        "@type": {"const": "neuroglancer_multiscale_volume"},
        "type": {"const": "segmentation"},
        # compressed_segmentation holds uint32 or uint64 only
        "data_type": {"enum": ["uint32", "uint64"]},
        "num_channels": {"const": 1},
        "mesh": {"type": "string", "minLength": 1},
        "scales": {"type": "array", "minItems": 1, "items": VOLUME_SCALE_SCHEMA},
    },
}
LEGACY_MESH_SCHEMA = {
    "type": "object",
    "required": ["@type"],
    "properties": {"@type": {"const": "neuroglancer_legacy_mesh"}},
}
MANIFEST_SCHEMA = {
    "type": "object",
    "required": ["fragments"],
    "properties": {"fragments": {"type": "array", "items": {"type": "string", "minLength": 1}}},
}


def test_info_files_follow_the_specification(tmp_path, oblique):
    import jsonschema

    surfaces = label_surfaces(oblique, smoothing=0)
    folder = tmp_path / "layer"
    _write(folder, oblique, surfaces, data_type="uint32", volume=oblique, legacy=True)
    info = json.loads((folder / "info").read_text())
    jsonschema.validate(info, LAYER_SCHEMA)
    jsonschema.validate(json.loads((folder / "mesh" / "info").read_text()), LEGACY_MESH_SCHEMA)
    scale = info["scales"][0]
    assert scale["size"] == list(oblique.shape)
    assert np.allclose(scale["resolution"], np.asarray(oblique.spacing) * NM_PER_UM)
    # one chunk file per 64-voxel cell of the grid, named by its voxel ranges
    names = {p.name for p in (folder / scale["key"]).iterdir()}
    x, y, z = oblique.shape
    assert names == {f"0-{x}_0-{y}_0-{z}"}
    for label in surfaces.labels:
        manifest = json.loads((folder / "mesh" / f"{label}:0").read_text())
        jsonschema.validate(manifest, MANIFEST_SCHEMA)
        for fragment in manifest["fragments"]:
            data = (folder / "mesh" / fragment).read_bytes()
            n = int(np.frombuffer(data, "<u4", 1)[0])
            assert (len(data) - 4 - 12 * n) % 12 == 0  # the triangles fill the rest


# --- the command --------------------------------------------------------------------------


def _isoconvert(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "isoconvert", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
    )


def test_the_command_writes_a_layer_with_voxels_and_legacy_meshes(tmp_path):
    np.save(tmp_path / "seg.npy", _labels())
    flags = ["--format", "precomputed", "--with-volume", "--legacy-mesh"]
    done = _isoconvert(
        "convert", "seg.npy", "--labels", *flags, "-o", "layer ñ", "-q", cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    cv = _cloud(tmp_path / "layer ñ")
    assert np.array_equal(np.asarray(cv[:, :, :])[..., 0], _labels().T)
    manifests = [
        p.name for p in (tmp_path / "layer ñ" / "mesh").glob("*:0") if p.name.count(":") == 1
    ]
    assert sorted(int(name[:-2]) for name in manifests) == [2, 5, 9, 700]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--format", "precomputed", "--legacy-mesh", "--lods", "3"], "one level of detail"),
        (["--format", "precomputed", "--legacy-mesh", "--sharded"], "no shards"),
        (["--format", "precomputed", "--legacy-mesh", "--fragment-size", "16"], "one fragment"),
        (["--with-volume"], "--with-volume is an option of --format precomputed"),
        (["--legacy-mesh"], "--legacy-mesh is an option of --format precomputed"),
        (["--lods", "2"], "--lods is an option of --format precomputed"),
        (["--fragment-size", "32"], "--fragment-size is an option of --format precomputed"),
        (["--sharded"], "--sharded is an option of --format precomputed"),
    ],
)
def test_options_the_layer_cannot_hold_are_one_line_errors(tmp_path, extra, message):
    np.save(tmp_path / "seg.npy", _labels())
    out = "layer" if "precomputed" in extra else "seg.ply"
    done = _isoconvert("convert", "seg.npy", "--labels", *extra, "-o", out, cwd=tmp_path)
    assert done.returncode != 0
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert "Traceback" not in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seg.npy"]
