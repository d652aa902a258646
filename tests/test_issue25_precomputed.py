"""Neuroglancer precomputed layers (issue 25): written by isoconvert, read back by
cloud-volume and DracoPy, their info files checked against the fields and types
Neuroglancer's specification gives (volume.md, meshes.md)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import typing

import numpy as np
import pytest
import trimesh
from conftest import small_tmpfs
from scipy.spatial import cKDTree

from isoconvert.errors import IsoconvertError, OutputError
from isoconvert.extract.labels import label_surfaces
from isoconvert.mesh import Mesh
from isoconvert.post.decimate import collapse
from isoconvert.volume import Volume
from isoconvert.writers.precomputed import write_precomputed

DracoPy = pytest.importorskip("DracoPy", reason="pip install DracoPy")
cloudvolume = pytest.importorskip("cloudvolume", reason="pip install cloud-volume")
pytest.importorskip(
    "meshoptimizer", reason='levels of detail need pip install "isoconvert[simplify]"'
)
pytest.importorskip("rtree", reason="trimesh.proximity needs rtree")

NM_PER_UM = 1000.0


def _atlas(n: int = 40, labels: int = 5, seed: int = 2) -> np.ndarray:
    """(n, n, n) uint16 (Z, Y, X): Voronoi cells of a ball, ids 1..labels (some not 1-based)."""
    rng = np.random.default_rng(seed)
    seeds = rng.uniform(0.25 * n, 0.75 * n, size=(labels, 3))
    z, y, x = np.mgrid[:n, :n, :n].astype(np.float64)
    d = np.stack([(x - a) ** 2 + (y - b) ** 2 + (z - c) ** 2 for a, b, c in seeds])
    out = (np.argmin(d, axis=0) * 3 + 2).astype(np.uint16)  # ids 2, 5, 8, ...
    out[(x - n / 2) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2 > (0.42 * n) ** 2] = 0
    return out


@pytest.fixture(scope="module")
def labelled():
    """Label meshes of an oblique, anisotropic volume in micrometres."""
    angle = 0.3
    direction = np.array(
        [[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1.0]]
    )
    volume = Volume.from_zyx(
        _atlas(),
        spacing=(0.5, 0.4, 1.2),
        origin=(100.0, -20.0, 7.5),
        direction=direction,
        unit="µm",
    )
    return volume, label_surfaces(volume, smoothing=16)


@pytest.fixture(scope="module")
def layer(tmp_path_factory, labelled):
    volume, result = labelled
    folder = tmp_path_factory.mktemp("layers") / "atlas ñ"
    grid = next(iter(result.meshes.values())).info["grid"]
    write_precomputed(
        folder, result.meshes, grid, unit="µm", data_type="uint16", lods=3, collapse=_bounded
    )
    return folder


def _bounded(mesh, bound, locked=None):
    return collapse(mesh, max_error=bound, locked=locked)[0]


def _cloud(folder):
    return cloudvolume.CloudVolume(f"precomputed://file://{folder}", progress=False)


def _half_step(mesh_vertices_index: np.ndarray, lod: int, bits: int = 16) -> np.ndarray:
    """Half a quantization step per index axis for an object's box at a level."""
    box = mesh_vertices_index.max(axis=0) - mesh_vertices_index.min(axis=0)
    return 0.5 * box * 2.0**lod / (2**bits - 1)


def _to_index(volume, world):
    affine = np.asarray(volume.direction) * np.asarray(volume.spacing)
    return (world - volume.origin) @ np.linalg.inv(affine).T


def test_cloud_volume_reads_every_label_at_level_0_as_the_ply_surface(labelled, layer):
    volume, result = labelled
    cv = _cloud(layer)
    for label, mesh in result.meshes.items():
        back = cv.mesh.get(int(label), lod=0)[int(label)]
        assert len(back.faces) == mesh.n_cells
        # in the volume's world frame, micrometres: each vertex within half a step
        # (per index axis) of the PLY's vertex at that place, plus the rounding of
        # cloud-volume's float32 nanometres
        world = np.asarray(back.vertices, np.float64) / NM_PER_UM
        index_back = _to_index(volume, world)
        index_ply = _to_index(volume, np.asarray(mesh.vertices))
        _, nearest = cKDTree(index_ply).query(index_back)
        error = np.abs(index_back - index_ply[nearest])
        float32 = 2 * np.finfo(np.float32).eps * np.abs(back.vertices).max()
        slack = float32 / (min(volume.spacing) * NM_PER_UM)
        assert (error <= _half_step(index_ply, 0) + slack).all()
        original = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
        decoded = trimesh.Trimesh(world, back.faces, process=False)
        assert decoded.is_watertight == original.is_watertight
        assert abs(decoded.volume - original.volume) < 1e-3 * abs(original.volume)


def test_vertices_quantized_to_one_position_keep_their_triangles(tmp_path):
    """Two vertices closer than a quantization step land on one position; Draco in
    its own order would merge them and drop the sliver between them as degenerate
    (the 40-label atlas had two such triangles)."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    vertices = np.vstack([sphere.vertices + 12.0, sphere.vertices[0] + 12.0 + 1e-7])
    n = len(sphere.vertices)
    b = int(sphere.faces[sphere.faces[:, 0] == 0][0, 1])
    cells = np.vstack([sphere.faces, [[0, n, b]]])
    grid = {"shape": [25, 25, 25], "origin": [0.0, 0.0, 0.0], "affine": np.eye(3).tolist()}
    mesh = Mesh(vertices, cells)
    write_precomputed(tmp_path / "layer", {1: mesh}, grid, unit="nm")
    back = _cloud(tmp_path / "layer").mesh.get(1, lod=0)[1]
    assert len(back.faces) == len(cells)


def test_fragments_of_distinct_positions_are_compressed_by_the_edgebreaker(tmp_path):
    """A fragment whose vertices each have a position of their own is encoded by
    Draco's edgebreaker: every triangle kept, and far smaller than the same
    fragment in its own order (the sequential encoding, kept only for fragments
    with vertices on one quantized position, as in the test above)."""
    import DracoPy

    sphere = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    grid = {"shape": [25, 25, 25], "origin": [0.0, 0.0, 0.0], "affine": np.eye(3).tolist()}
    mesh = Mesh(sphere.vertices + 12.0, sphere.faces)
    write_precomputed(tmp_path / "layer", {1: mesh}, grid, unit="nm", lods=1)
    data = (tmp_path / "layer" / "mesh" / "1").read_bytes()
    back = DracoPy.decode(data)
    assert len(back.faces) == len(sphere.faces)
    assert len(np.unique(np.asarray(back.points), axis=0)) == len(sphere.vertices)
    in_order = DracoPy.encode(
        np.asarray(back.points), np.asarray(back.faces), quantization_bits=16,
        quantization_range=65535.0, quantization_origin=[0.0, 0.0, 0.0],
        compression_level=7, preserve_order=True,
    )  # fmt: skip
    assert len(data) < 0.5 * len(in_order)


def test_coarser_levels_have_fewer_triangles_within_their_bound(labelled, layer):
    volume, result = labelled
    cv = _cloud(layer)
    rng = np.random.default_rng(0)
    for label, mesh in result.meshes.items():
        original = trimesh.Trimesh(_to_index(volume, np.asarray(mesh.vertices)), mesh.cells)
        previous = mesh.n_cells
        for lod in (1, 2):
            back = cv.mesh.get(int(label), lod=lod)[int(label)]
            index = _to_index(volume, np.asarray(back.vertices, np.float64) / NM_PER_UM)
            coarse = trimesh.Trimesh(index, back.faces, process=False)
            assert len(back.faces) < previous
            previous = len(back.faces)
            # the decimation bound (index units) plus the level's quantization
            bound = 2.0 ** (lod - 1) + np.linalg.norm(_half_step(original.vertices, lod)) + 1e-6
            points = np.vstack([coarse.vertices, coarse.sample(3000, seed=rng)])
            _, there, _ = trimesh.proximity.closest_point(original, points)
            points = np.vstack([original.vertices, original.sample(3000, seed=rng)])
            _, back_there, _ = trimesh.proximity.closest_point(coarse, points)
            assert there.max() <= bound and back_there.max() <= bound


def _manifest(path):
    """The manifest's fields, parsed as meshes.md lays them out."""
    raw = path.read_bytes()
    chunk = np.frombuffer(raw, "<f4", 3, 0)
    origin = np.frombuffer(raw, "<f4", 3, 12)
    (n,) = np.frombuffer(raw, "<u4", 1, 24)
    at = 28
    scales = np.frombuffer(raw, "<f4", n, at)
    at += 4 * n
    offsets = np.frombuffer(raw, "<f4", 3 * n, at).reshape(n, 3)
    at += 12 * n
    counts = np.frombuffer(raw, "<u4", n, at)
    at += 4 * n
    positions, sizes = [], []
    for lod in range(n):
        k = int(counts[lod])
        positions.append(np.frombuffer(raw, "<u4", 3 * k, at).reshape(3, k))
        at += 12 * k
        sizes.append(np.frombuffer(raw, "<u4", k, at))
        at += 4 * k
    assert at == len(raw)
    return chunk, origin, int(n), scales, offsets, positions, sizes


def test_dracopy_decodes_each_fragment_within_half_a_step_of_the_mesh(labelled, layer):
    """Level 0 dequantized in float64 as meshes.md gives it: each vertex within
    half a step, per index axis, of the mesh's."""
    volume, result = labelled
    info = json.loads((layer / "mesh" / "info").read_text())
    top = 2 ** info["vertex_quantization_bits"]
    for index in sorted((layer / "mesh").glob("*.index")):
        chunk, origin, n, scales, offsets, positions, sizes = _manifest(index)
        mesh = result.meshes[int(index.stem)]
        data = (layer / "mesh" / index.stem).read_bytes()
        assert sum(int(s.sum()) for s in sizes) == len(data)
        assert (chunk > 0).all() and n == 3 and (np.diff(scales) > 0).all()
        assert not offsets.any()
        start = 0
        for lod in range(n):
            assert positions[lod].shape == (3, 1) and not positions[lod].any()
            for size in sizes[lod]:
                fragment = DracoPy.decode(data[start : start + int(size)])
                start += int(size)
                points = np.asarray(fragment.points)
                assert len(fragment.faces) > 0
                assert points.min() >= 0 and points.max() < top
                assert np.array_equal(points, np.rint(points))  # integer positions
                if lod == 0:
                    step = chunk.astype(np.float64) / (top - 1)
                    place = origin.astype(np.float64) + points * step
                    index_ply = _to_index(volume, np.asarray(mesh.vertices))
                    _, nearest = cKDTree(index_ply).query(place)
                    assert (np.abs(place - index_ply[nearest]) <= 0.5 * step + 1e-9).all()
                    assert len(fragment.faces) == mesh.n_cells


def test_a_cut_moves_no_vertex_more_than_half_a_step():
    """Worked by hand in 4-voxel nodes (a step s = 4 / 65535): a vertex 0.7 s from a
    plane is not snapped onto it (once it was, from within a whole step: 0.7 s off)
    but rounded, 0.3 s; and a cut's new vertex is where the edge as extracted
    crosses the plane, not where the edge between snapped ends does: here an end
    0.3 s off the x = 4 plane is snapped onto it, which moved the new vertex on
    the y = 4 plane by 0.15 s in x, from 0.42 s past a step to 0.57 s, so that it
    rounded to the far step (0.58 s off)."""
    from isoconvert.writers.precomputed.octree import cut_level, level_frame

    top = 65535.0
    s = 4.0 / top
    frame = level_frame(np.zeros(3), np.full(3, 4.0), 0, top, np.zeros(3), np.full(3, 8.0))
    u = np.array([4.0 - 0.3 * s, 3.0, 1.0])
    crossing = np.array([(49151 + 0.42) * s, 4.0, 1.0])  # where u-w crosses y = 4
    w = 2 * crossing - u  # (t = 1/2 along u-w)
    far = np.array([4.0 - 0.7 * s, 1.0, 3.0])  # 0.7 s from x = 4
    vertices = np.array([u, w, [2.0, 3.0, 2.0], far, [1.0, 1.0, 3.0], [6.0, 1.5, 3.5]])
    cells = np.array([[0, 1, 2], [3, 4, 5]])
    level = cut_level(vertices.copy(), cells, frame)
    places = np.vstack([np.asarray(q, np.float64) * s + np.array(node) * 4.0
                        for node, (q, _) in level.items()])  # fmt: skip

    def off(point):  # per axis, from the nearest vertex of the fragments
        return np.abs(places - point)[np.argmin(np.linalg.norm(places - point, axis=1))]

    assert (off(crossing) <= 0.5 * s + 1e-12).all()
    assert np.isclose(off(far)[0], 0.3 * s) and (off(far) <= 0.5 * s + 1e-12).all()


# the fields and types of volume.md's info and meshes.md's mesh info, written out
_UINT3 = {"type": "array", "items": {"type": "integer", "minimum": 0}, "minItems": 3, "maxItems": 3}
_NUM3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
LAYER_SCHEMA = {
    "type": "object",
    "required": ["type", "data_type", "num_channels", "scales"],
    "properties": {
        "@type": {"const": "neuroglancer_multiscale_volume"},
        "type": {"enum": ["image", "segmentation"]},
        "data_type": {
            "enum": ["uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "float32"]
        },
        "num_channels": {"type": "integer", "minimum": 1},
        "mesh": {"type": "string"},
        "scales": {
            "type": "array",
            "minItems": 1,
            "items": {
                "type": "object",
                "required": [
                    "key",
                    "size",
                    "resolution",
                    "voxel_offset",
                    "chunk_sizes",
                    "encoding",
                ],
                "properties": {
                    "key": {"type": "string", "minLength": 1},
                    "size": _UINT3,
                    "resolution": {**_NUM3, "items": {"type": "number", "exclusiveMinimum": 0}},
                    "voxel_offset": {**_UINT3, "items": {"type": "integer"}},
                    "chunk_sizes": {"type": "array", "minItems": 1, "items": _UINT3},
                    "encoding": {
                        "enum": ["raw", "jpeg", "png", "compressed_segmentation", "compresso"]
                    },
                },
            },
        },
    },
}
MESH_SCHEMA = {
    "type": "object",
    "required": ["@type", "vertex_quantization_bits", "transform", "lod_scale_multiplier"],
    "properties": {
        "@type": {"const": "neuroglancer_multilod_draco"},
        "vertex_quantization_bits": {"enum": [10, 16]},
        "transform": {"type": "array", "items": {"type": "number"}, "minItems": 12, "maxItems": 12},
        "lod_scale_multiplier": {"type": "number"},
        "sharding": {
            "type": "object",
            "required": ["@type", "preshift_bits", "hash", "minishard_bits", "shard_bits"],
            "properties": {
                "@type": {"const": "neuroglancer_uint64_sharded_v1"},
                "preshift_bits": {"type": "integer", "minimum": 0, "maximum": 64},
                "hash": {"enum": ["identity", "murmurhash3_x86_128"]},
                "minishard_bits": {"type": "integer", "minimum": 0, "maximum": 64},
                "shard_bits": {"type": "integer", "minimum": 0, "maximum": 64},
                "minishard_index_encoding": {"enum": ["raw", "gzip"]},
                "data_encoding": {"enum": ["raw", "gzip"]},
            },
        },
    },
}


def test_info_files_follow_the_specification(labelled, layer):
    import jsonschema

    volume, _ = labelled
    info = json.loads((layer / "info").read_text())
    jsonschema.validate(info, LAYER_SCHEMA)
    jsonschema.validate(json.loads((layer / "mesh" / "info").read_text()), MESH_SCHEMA)
    assert info["type"] == "segmentation" and info["data_type"] == "uint16"
    assert info["scales"][0]["size"] == list(volume.shape)
    assert np.allclose(info["scales"][0]["resolution"], np.asarray(volume.spacing) * NM_PER_UM)
    mesh_info = json.loads((layer / info["mesh"] / "info").read_text())
    transform = np.array(mesh_info["transform"]).reshape(3, 4)
    affine = np.asarray(volume.direction) * np.asarray(volume.spacing) * NM_PER_UM
    assert np.allclose(transform[:, :3], affine) and np.allclose(
        transform[:, 3], volume.origin * 1e3
    )
    assert oct(os.stat(layer).st_mode & 0o777) == oct(0o777 & ~_umask())


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_failed_write_leaves_nothing_and_an_existing_layer_needs_force(tmp_path, labelled):
    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    meshes = dict(result.meshes)
    bad = next(iter(meshes.values()))
    meshes[999] = type(bad)(bad.vertices, np.array([[0, 1, 10**9]]), None, bad.info)
    with pytest.raises(IsoconvertError, match="999"):
        write_precomputed(tmp_path / "layer", meshes, grid, unit="µm")
    assert list(tmp_path.iterdir()) == []
    write_precomputed(tmp_path / "layer", result.meshes, grid, unit="µm")
    with pytest.raises(OutputError, match="exists"):
        write_precomputed(tmp_path / "layer", result.meshes, grid, unit="µm")
    before = sorted(p.name for p in (tmp_path / "layer" / "mesh").iterdir())
    write_precomputed(tmp_path / "layer", {2: result.meshes[2]}, grid, unit="µm", force=True)
    after = sorted(p.name for p in (tmp_path / "layer" / "mesh").iterdir())
    assert after == ["2", "2.index", "info"] and len(before) > len(after)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layer"]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"bits": 12}, "10 or 16"),
        ({"lods": 0}, "1 level of detail or more"),
        ({"data_type": "float32"}, "cannot be a segmentation"),
    ],
)
def test_bad_options_are_errors(tmp_path, labelled, kwargs, message):
    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    with pytest.raises(IsoconvertError, match=message):
        write_precomputed(tmp_path / "layer", result.meshes, grid, **kwargs)
    assert list(tmp_path.iterdir()) == []


def test_convert_labels_writes_a_layer_cloud_volume_reads(tmp_path, capsys):
    """The command: a NRRD label volume in millimetres to a layer in a folder
    whose name is not ASCII; each label's mesh at level 0 is its PLY's."""
    import nrrd

    from isoconvert.cli import main
    from isoconvert.meshfile import read_mesh

    labels = np.ascontiguousarray(_atlas(24, 3).T.astype(np.uint8))  # x fastest, as NRRD
    path = tmp_path / "atlas.nrrd"
    nrrd.write(str(path), labels, {"spacings": [0.5, 0.5, 1.0], "space units": ["mm"] * 3})
    layer = tmp_path / "layér"
    assert main(["convert", str(path), "--labels", "-o", str(layer), "--format", "precomputed",
                 "--lods", "2", "-q", "--report", str(tmp_path / "r.json")]) == 0  # fmt: skip
    assert main(["convert", str(path), "--labels", "-o", str(tmp_path / "a.ply"), "-q"]) == 0
    cv = _cloud(layer)
    assert json.loads((layer / "info").read_text())["scales"][0]["resolution"] == [5e5, 5e5, 1e6]
    for value in np.unique(labels[labels > 0]):
        ply = read_mesh(tmp_path / f"a_label{value}.ply")
        back = cv.mesh.get(int(value), lod=0)[int(value)]
        assert len(back.faces) == ply.n_cells
        _, nearest = cKDTree(ply.vertices * 1e6).query(back.vertices)
        assert np.abs(back.vertices - ply.vertices[nearest] * 1e6).max() < 0.5e6 * 0.01
        assert len(cv.mesh.get(int(value), lod=1)[int(value)].faces) < ply.n_cells
        report = json.loads((tmp_path / f"r_{value}.json").read_text())
        assert report["checks"]["watertight"] and report["counts"]["triangles"] == ply.n_cells
    # taken, then replaced with --force; the wrong uses are one line each
    capsys.readouterr()
    assert (
        main(["convert", str(path), "--labels", "-o", str(layer), "--format", "precomputed"]) == 1
    )
    assert "exists" in capsys.readouterr().err
    args = ["convert", str(path), "-o", str(tmp_path / "x"), "--format", "precomputed"]
    for extra, message in [
        (["--labels", "--lods", "0"], "--lods: a precomputed layer has 1 level of detail or more"),
        (["--labels", "--single-file"], "leave out --single-file"),
        (["--labels", "--fragment-size", "0"], "--fragment-size: precomputed fragments are 1"),
        (["--labels", "--fragment-size", "nan"], "(inf: one per object and level; auto, the"),
    ]:
        assert main(args + extra) == 1
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    # a missing parent folder is said as for mesh files
    assert main([*args[:3], str(tmp_path / "no" / "x"), *args[4:], "--labels"]) == 1
    assert "the folder" in (err := capsys.readouterr().err) and "does not exist" in err
    # a layer folder holding the input is never replaced
    inside = layer / "atlas.nrrd"
    inside.write_bytes(path.read_bytes())
    assert main(["convert", str(inside), "--labels", "-o", str(layer), "--format", "precomputed",
                 "-f"]) == 1  # fmt: skip
    assert "holds the input" in capsys.readouterr().err and inside.exists()
    # batch, which writes layers too (tests/test_issue25_batch_layers.py), refuses it alike
    holder = tmp_path / "atlas"  # batch's layer of holder/atlas.nrrd in tmp_path
    holder.mkdir()
    (holder / "atlas.nrrd").write_bytes(path.read_bytes())
    summary = tmp_path / "s.json"
    assert main(["batch", str(holder / "atlas.nrrd"), "-o", str(tmp_path), "--format",
                 "precomputed", "--labels", "-f", "--summary", str(summary)]) == 1  # fmt: skip
    assert "holds the input" in summary.read_text()
    assert (holder / "atlas.nrrd").read_bytes() == path.read_bytes()


def test_a_real_label_volume_becomes_a_layer(tmp_path):
    """The bat cochlea (a binary segmentation, 121 x 154 x 114): its surface at
    every level of detail, read back by cloud-volume, closed as its PLY is, by
    position too (its decimated levels have vertices 0.0025 voxel apart, which
    quantize to one position: left apart, they pinched the level, 36 uses of an
    edge and two fins)."""
    from conftest import dataset

    from isoconvert.label_convert import convert_labels

    path = dataset("bat-cochlea-volume.tif")
    results = convert_labels(path, tmp_path / "layer", format="precomputed", lods=3)
    (mesh,) = [r.mesh for r in results]
    cv = _cloud(tmp_path / "layer")
    label = int(results[0].output.name)
    counts = [len(cv.mesh.get(label, lod=k)[label].faces) for k in range(3)]
    assert counts[0] == mesh.n_cells and counts[0] > counts[1] > counts[2]
    back = cv.mesh.get(label, lod=0)[label]
    original = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    decoded = trimesh.Trimesh(back.vertices, back.faces, process=False)
    assert decoded.is_watertight == original.is_watertight
    assert original.is_watertight
    for k in range(3):
        back = cv.mesh.get(label, lod=k)[label]
        joined = trimesh.Trimesh(np.asarray(back.vertices, np.float64), back.faces, process=True)
        assert joined.is_watertight and joined.is_winding_consistent, k


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_while_the_layer_is_written_leaves_nothing(tmp_path, signum):
    """Stopped while it decimates the levels of detail into the temporary folder:
    the exit status of the signal, one line, and nothing in the output folder."""
    atlas = tmp_path / "atlas.npy"
    np.save(atlas, _atlas(96, 24))
    out = tmp_path / "out"
    out.mkdir()
    args = ["convert", str(atlas), "--labels", "--format", "precomputed", "--lods", "4"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "isoconvert", *args, "-o", str(out / "layer"), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    end = time.monotonic() + 90
    while not any(p.name.endswith(".part") for p in out.iterdir()):
        assert proc.poll() is None, proc.communicate()[1].decode()
        assert time.monotonic() < end, "no temporary folder appeared"
        time.sleep(0.01)
    time.sleep(0.2)  # inside the writing
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum, err.decode()
    assert len(err.decode().strip().splitlines()) == 1
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("chunk", [None, 2.0])
def test_an_objects_levels_end_before_its_bound_passes_it_or_its_triangles_stop_falling(
    tmp_path, chunk
):
    """--lods 12 on a 4-voxel cube and a ball 17 voxels across, whole or cut into
    2-voxel fragments (whose cuts add triangles): each object's manifest lists only
    levels whose bound, 2^(k-1) voxels, is shorter than the object (a level
    allowed farther could be a point, and from level 10 on its quantization step
    passes the object), each with fewer triangles, as read back, than the level
    before; cloud-volume reads every level closed, within its bound of level 0."""
    z, y, x = np.mgrid[:32, :32, :32]
    volume = np.zeros((32, 32, 32), np.uint16)
    volume[(x - 20) ** 2 + (y - 20) ** 2 + (z - 20) ** 2 < 8.5**2] = 5
    volume[2:6, 2:6, 2:6] = 9
    result = label_surfaces(Volume(volume), smoothing=16)
    layer = write_precomputed(tmp_path / "layer", result.meshes, result.grid, lods=12,
                              collapse=_bounded, chunk=chunk)  # fmt: skip
    cv = _cloud(layer)
    for label in (5, 9):
        original = trimesh.Trimesh(np.asarray(result[label].vertices), result[label].cells)
        side = float(np.ptp(original.vertices, axis=0).max())
        _, _, n, scales, *_ = _manifest(layer / "mesh" / f"{label}.index")
        assert 1 <= n < 12 and list(scales) == [2.0**k for k in range(n)], label
        assert n == 1 or 2.0 ** (n - 2) < side, label
        faces = []
        for lod in range(n):
            back = cv.mesh.get(label, lod=lod)[label]
            mesh = trimesh.Trimesh(np.asarray(back.vertices, np.float64), back.faces, process=True)
            assert mesh.is_watertight, (label, lod)
            faces.append(len(mesh.faces))
            bound = (2.0 ** (lod - 1) if lod else 0.0) + 0.05 * 2.0**lod
            _, far, _ = trimesh.proximity.closest_point(original, mesh.vertices)
            assert far.max() <= bound, (label, lod)
        assert (np.diff(faces) < 0).all(), (label, faces)
    assert _manifest(layer / "mesh" / "9.index")[2] < _manifest(layer / "mesh" / "5.index")[2]


@pytest.mark.parametrize("chunk", [None, 8.0])
def test_a_level_cut_into_no_fewer_triangles_than_the_one_before_ends_the_levels(chunk):
    """encode_levels given a level 1 with more triangles than level 0 (a sphere
    subdivided once more) and a level 2 with fewer: the manifest lists level 0
    alone, whole or cut, since a viewer would load more for less detail; so it
    does for a level 1 that quantizes to a point."""
    from isoconvert.writers.precomputed.fragments import dracopy, encode_levels

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    finer = sphere.subdivide()
    coarse = trimesh.creation.icosahedron()
    levels = [Mesh(np.asarray(m.vertices) * (20.0 if m is coarse else 1.0) + 24.0,
                   np.asarray(m.faces, np.int64)) for m in (sphere, finer, coarse)]  # fmt: skip
    manifest, _ = encode_levels(levels, 10, dracopy(), chunk)
    (n,) = np.frombuffer(manifest, "<u4", 1, 24)
    assert n == 1
    manifest, _ = encode_levels([levels[0], levels[2]], 10, dracopy(), chunk)
    assert np.frombuffer(manifest, "<u4", 1, 24)[0] == 2
    # a level whose corners all quantize to one position has nothing left: it ends too
    speck = Mesh(np.asarray(coarse.vertices) * 1e-4 + 24.0, np.asarray(coarse.faces, np.int64))
    manifest, _ = encode_levels([levels[0], speck], 10, dracopy(), chunk)
    assert np.frombuffer(manifest, "<u4", 1, 24)[0] == 1


def test_label_zero_as_an_object_is_refused_with_the_fix(tmp_path):
    """--background 3 makes label 0 an object, which a layer cannot hold (0 is
    Neuroglancer's no object): one line saying how to leave it out, nothing written."""
    volume = np.zeros((12, 12, 12), np.uint16)
    volume[3:8, 3:8, 3:8] = 3
    np.save(tmp_path / "labels.npy", volume)
    run = subprocess.run(
        [sys.executable, "-m", "isoconvert", "convert", str(tmp_path / "labels.npy"), "--labels",
         "--background", "3", "--format", "precomputed", "-o", str(tmp_path / "layer"), "-q"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode != 0 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "got 0" in run.stderr and "--background 0" in run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labels.npy"]


def test_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, labelled, monkeypatch):
    import errno
    from pathlib import Path

    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    real = Path.write_bytes

    def full(self, data):
        if self.suffix == ".index":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(OutputError, match="disk full at"):
        write_precomputed(tmp_path / "layer", result.meshes, grid, unit="µm")
    assert list(tmp_path.iterdir()) == []


def test_force_replaces_a_layer_never_a_folder_of_other_files(tmp_path, labelled):
    """--force on a folder that is no layer (someone's files) is a one-line error that
    leaves every file, and so is the same without --force, which it would not
    help; an empty folder and an earlier layer are replaced."""
    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    mine = tmp_path / "documents"
    (mine / "sub").mkdir(parents=True)
    (mine / "thesis.txt").write_text("important")
    (mine / "sub" / "a").write_text("x")
    (mine / "info").write_text("not a layer's")
    with pytest.raises(OutputError, match="not a Neuroglancer layer"):
        write_precomputed(mine, result.meshes, grid, unit="µm", force=True)
    assert (mine / "thesis.txt").read_text() == "important"
    assert sorted(p.name for p in mine.rglob("*")) == ["a", "info", "sub", "thesis.txt"]
    np.save(tmp_path / "labels.npy", _atlas(16, 2))
    run = subprocess.run(
        [sys.executable, "-m", "isoconvert", "convert", str(tmp_path / "labels.npy"), "--labels",
         "--format", "precomputed", "-o", str(mine), "--force", "-q"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert run.returncode != 0 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "not a Neuroglancer layer" in run.stderr and (mine / "sub" / "a").exists()
    with pytest.raises(OutputError, match="not a Neuroglancer layer"):
        write_precomputed(mine, result.meshes, grid, unit="µm")
    (tmp_path / "empty").mkdir()
    for _ in range(2):  # an empty folder, then the layer written there
        write_precomputed(tmp_path / "empty", result.meshes, grid, unit="µm", force=True)
        assert (tmp_path / "empty" / "mesh" / "info").is_file()


def test_force_keeps_a_users_files_kept_beside_a_layer_and_an_empty_folder_needs_none(
    tmp_path, labelled
):
    """An empty folder (made first, as users do) takes a layer without --force; a
    layer folder with someone's file beside the layer's own (info, mesh, a scale's
    chunks) is not replaced, --force or not, and the error names the file; moved
    out, --force replaces the layer."""
    from isoconvert.cli import main

    np.save(tmp_path / "labels.npy", _atlas(16, 2))
    layer = tmp_path / "layer"
    layer.mkdir()
    command = ["convert", str(tmp_path / "labels.npy"), "--labels", "--format", "precomputed"]
    command += ["--with-volume", "-q", "-o", str(layer)]
    assert main(command) == 0
    entries = sorted(p.name for p in layer.iterdir())
    assert "info" in entries and "mesh" in entries and len(entries) == 3  # and the voxels
    before = _layer_bytes(layer)
    (layer / "notes.txt").write_text("mine")
    for force in ([], ["--force"]):
        run = subprocess.run(
            [sys.executable, "-m", "isoconvert", *command, *force],
            capture_output=True, text=True,
        )  # fmt: skip
        assert run.returncode == 1 and len(run.stderr.strip().splitlines()) == 1, run.stderr
        assert "notes.txt" in run.stderr and "move it out" in run.stderr
        assert (layer / "notes.txt").read_text() == "mine"
        assert {k: v for k, v in _layer_bytes(layer).items() if k != "notes.txt"} == before
    (layer / "notes.txt").rename(tmp_path / "notes.txt")
    assert main([*command, "--force"]) == 0 and _layer_bytes(layer) == before


def test_the_part_folder_of_a_killed_run_is_removed(tmp_path, labelled):
    from isoconvert.atomic import _owner_tag

    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    host = _owner_tag().split("~")[0]
    stale = tmp_path / f".layer.{host}~99999999-abcd1234.part"
    (stale / "mesh").mkdir(parents=True)
    other = tmp_path / f".layer.{_owner_tag()}-live0000.part"  # this process: alive
    other.mkdir()
    write_precomputed(tmp_path / "layer", result.meshes, grid, unit="µm")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([other.name, "layer"])


def _morton(x, y, z):
    return sum(((v >> b) & 1) << (3 * b + a) for b in range(10) for a, v in enumerate((x, y, z)))


@pytest.mark.parametrize("size", [5.0, 8.0])
def test_fragments_are_an_octree_whose_seams_stay_closed(tmp_path, labelled, size):
    """--fragment-size: each level cut into octree nodes; cloud-volume's union of
    the fragments is the label's closed surface (seams included) at every level,
    level 0 within half a quantization step of the PLY's surface both ways (of
    rounding; snapping to a fragment's side moves a vertex only from within half a
    step, where rounding would put it)."""
    volume, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    layer = tmp_path / "layer"
    write_precomputed(layer, result.meshes, grid, unit="µm", lods=3, collapse=_bounded, chunk=size)
    cv = _cloud(layer)
    for label, mesh in result.meshes.items():
        chunk, _, n, _, _, positions, sizes = _manifest(layer / "mesh" / f"{label}.index")
        assert np.allclose(chunk, size) and n == 3
        assert positions[0].shape[1] > 1  # cut into several fragments
        for lod in range(n):
            keys = [_morton(*p) for p in positions[lod].T]
            assert keys == sorted(keys) and len(set(keys)) == len(keys)  # Z-curve order
            if lod + 1 < n:  # every node's parent is listed at the next level
                parents = {tuple(p) for p in positions[lod + 1].T}
                assert {tuple(p // 2) for p in positions[lod].T} <= parents
        original = trimesh.Trimesh(_to_index(volume, np.asarray(mesh.vertices)), mesh.cells)
        for lod in range(n):
            back = cv.mesh.get(int(label), lod=lod)[int(label)]
            index = _to_index(volume, np.asarray(back.vertices, np.float64) / NM_PER_UM)
            union = trimesh.Trimesh(index, back.faces, process=True)  # fragments joined
            assert union.is_watertight
            if lod == 0:
                assert abs(union.area / original.area - 1) < 1e-4
                # and half a float32 spacing of the nanometres read back, per axis
                nm32 = np.spacing(np.float32(np.abs(back.vertices).max()))
                slack = np.sqrt(3) * 0.5 * nm32 / NM_PER_UM / min(volume.spacing)
                step = np.linalg.norm(0.5 * chunk / (2**16 - 1)) + slack
                _, there, _ = trimesh.proximity.closest_point(original, union.vertices)
                _, back_there, _ = trimesh.proximity.closest_point(union, original.vertices)
                assert there.max() <= step and back_there.max() <= step


def test_the_default_fragment_size_cuts_only_objects_of_many_triangles():
    """--fragment-size auto: 128-voxel nodes above 524,288 triangles, one fragment
    a level at or below; a number is itself; inf (or None) is never a cut; and the
    option's help gives the same numbers."""
    from isoconvert.cli.options import LayerArgs
    from isoconvert.writers.precomputed.octree import (
        AUTO_CUT,
        AUTO_FINEST,
        AUTO_FRAGMENT,
        AUTO_NODE_VERTICES,
        fragment_size,
    )

    assert (AUTO_CUT, AUTO_FRAGMENT) == (524_288, 128.0)
    assert (AUTO_NODE_VERTICES, AUTO_FINEST) == (131_072, 32.0)
    assert fragment_size("auto", AUTO_CUT) is None
    assert fragment_size("auto", AUTO_CUT + 1) == AUTO_FRAGMENT
    # halved while the densest node holds too many vertices, never below the finest
    asked = []

    def densest(side):
        asked.append(side)
        return AUTO_NODE_VERTICES + (side > 32)

    assert fragment_size("auto", AUTO_CUT + 1, densest) == 32.0 and asked == [128.0, 64.0]
    assert fragment_size("auto", AUTO_CUT, densest) is None
    assert fragment_size("auto", AUTO_CUT + 1, lambda side: 10**9) == AUTO_FINEST
    assert fragment_size(64.0, 10, densest) == 64.0 and fragment_size(np.float32(5), 10**9) == 5.0
    assert fragment_size(float("inf"), 10**9) is None and fragment_size(None, 10**9) is None
    option = typing.get_type_hints(LayerArgs, include_extras=True)["fragment_size"]
    help_text = " ".join(option.__metadata__[0].help.split())
    assert f"{AUTO_CUT:,} triangles" in help_text and f"default: {AUTO_FRAGMENT:g} " in help_text
    assert f"down to {AUTO_FINEST:g}" in help_text
    assert f"{AUTO_NODE_VERTICES:,} vertices" in help_text


@pytest.mark.parametrize("phase", [0.0, 0.5])
def test_the_densest_node_is_counted_as_by_brute_force(phase):
    """densest_node against every node's count worked out point by point, for a
    cut box, a box inside one node (every vertex) and a box of too many nodes to
    count (0: the side is not halved further)."""
    from isoconvert.writers.precomputed import octree

    rng = np.random.default_rng(5)
    points = np.concatenate([rng.uniform(3.3, 200.7, (4000, 3)), rng.normal(60, 4, (3000, 3))])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pieces = lambda: np.array_split(points, 3)  # noqa: E731
    for side in (16.0, 32.0, 64.0):
        origin = np.floor(lo - phase) + phase  # the cut's planes, by hand
        cell = np.floor((points - origin) / side).astype(int)
        _, counts = np.unique(cell, axis=0, return_counts=True)
        assert octree.densest_node(pieces, lo, hi, side, phase) == counts.max()
    assert octree.densest_node(pieces, lo, hi, 256.0, phase) == len(points)
    assert octree.densest_node(pieces, lo, hi, 1.0, phase) == 0  # 198^3 nodes


@pytest.mark.parametrize("sharded", [False, True])
def test_the_wrote_line_and_the_report_of_a_layer_are_of_the_level_0_it_stores(tmp_path, sharded):
    """A cut level 0 can hold fewer triangles than the mesh (corners within a
    quantization step of each other merge: a float gyroid in 64-voxel nodes): the
    "wrote" line and --report count what cloud-volume reads back, its vertices
    joined by position, not the mesh as extracted."""
    n = 96
    z, y, x = (a * (2 * np.pi / 24) for a in np.ogrid[:n, :n, :n])
    gyroid = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    path = tmp_path / "gyroid.npy"
    np.save(path, np.ascontiguousarray(gyroid.T.astype(np.float32)))
    base = [sys.executable, "-m", "isoconvert", "convert", str(path), "--level", "0.2"]
    subprocess.run([*base, "-q", "-o", str(tmp_path / "g.ply")], check=True)
    extracted = trimesh.load(tmp_path / "g.ply", process=False)
    layer = [*base, "--format", "precomputed", "--lods", "1", "--fragment-size", "64"]
    layer += ["-o", str(tmp_path / "layer"), "--report", str(tmp_path / "r.json")]
    run = subprocess.run(layer + ["--sharded"] * sharded, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    back = _cloud(tmp_path / "layer").mesh.get(1, lod=0)[1]
    triangles = len(back.faces)
    # the fragments joined where their vertices are one quantization step apart
    vertices = len(np.unique(np.rint(back.vertices / (64 / 65535)), axis=0))
    assert triangles < len(extracted.faces)  # the merges this is about
    assert f": {vertices:,} vertices, {triangles:,} triangles" in run.stdout, run.stdout
    counts = json.loads((tmp_path / "r.json").read_text())["counts"]
    assert (counts["vertices"], counts["triangles"]) == (vertices, triangles)


def _node_vertices(vertices, side, phase):
    """The most of ``vertices`` (index coordinates) one node of ``side`` holds, the
    nodes starting at ``phase`` past a whole index below them all."""
    origin = np.floor(vertices.min(axis=0) - phase) + phase
    _, counts = np.unique(np.floor((vertices - origin) / side), axis=0, return_counts=True)
    return counts.max()


@pytest.mark.parametrize("labels", [False, True])
def test_by_default_a_dense_surface_is_cut_into_smaller_fragments(tmp_path, monkeypatch, labels):
    """--fragment-size auto halves 128 while one node would hold more than the rule's
    vertices: a gyroid (a dense isosurface, and as a label its net's surface, given
    to the layer in parts) comes out in 64- or 32-voxel fragments as its PLY's
    vertices, counted node by node here, say (a node of exactly the rule's count
    is not halved), the bytes of that --fragment-size given, and for the
    unsmoothed net (planes midway between samples) the PLY's triangles at level 0."""
    from isoconvert.cli import main
    from isoconvert.meshfile import read_mesh
    from isoconvert.writers.precomputed import octree

    monkeypatch.setattr(octree, "AUTO_CUT", 1000)
    n = 96
    z, y, x = (a * (2 * np.pi / 24) for a in np.ogrid[:n, :n, :n])
    gyroid = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    path = tmp_path / "gyroid.npy"
    if labels:
        np.save(path, np.ascontiguousarray((gyroid > 0.2).astype(np.uint8).T))
        given, ply = ["--labels", "--smooth", "0"], tmp_path / "g_label1.ply"
    else:
        np.save(path, np.ascontiguousarray(gyroid.T.astype(np.float32)))
        given, ply = ["--level", "0.2"], tmp_path / "g.ply"
    base = ["convert", str(path), *given, "-q"]
    assert main([*base, "-o", str(tmp_path / "g.ply")]) == 0
    surface = read_mesh(ply)
    phase = 0.5 if labels else 0.0
    counts = {side: _node_vertices(surface.vertices, side, phase) for side in (64, 32)}
    assert len(surface.vertices) > counts[64] > counts[32]
    layer = [*base, "--format", "precomputed", "--lods", "1", "-o"]
    for side in (64, 32):
        assert main([*layer, str(tmp_path / f"said{side}"), "--fragment-size", str(side)]) == 0
    limits = ((len(surface.vertices) - 1, 64), (counts[64], 64), (counts[64] - 1, 32))
    for n, (limit, side) in enumerate(limits):
        monkeypatch.setattr(octree, "AUTO_NODE_VERTICES", int(limit))
        folder = tmp_path / f"auto{n}"
        assert main([*layer, str(folder)]) == 0
        chunk, *_ = _manifest(folder / "mesh" / "1.index")
        assert np.array_equal(chunk, [side] * 3)
        assert _layer_bytes(folder) == _layer_bytes(tmp_path / f"said{side}")
        if labels:  # an isosurface's corners within a step of each other merge
            assert len(_cloud(folder).mesh.get(1, lod=0)[1].faces) == surface.n_cells


def _layer_bytes(folder) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_by_default_a_large_label_is_cut_into_fragments_and_a_small_one_is_not(
    tmp_path, monkeypatch
):
    """The command without --fragment-size: a ball of about 170,000 triangles (more
    than the rule's count, set to 100,000 here to keep the test small) and 136
    voxels wide is cut into 128-voxel fragments that cloud-volume joins into its
    closed surface at every level (level 0 its PLY's area), a small cube beside it
    is one fragment a level, its PLY's triangles; --fragment-size inf leaves the
    ball whole (one node, its box); the layer made in slabs within --max-memory is
    the same, and so is the one of --fragment-size auto said (a word else is a
    command line that cannot be parsed)."""
    from isoconvert.cli import main
    from isoconvert.meshfile import read_mesh
    from isoconvert.writers.precomputed import octree

    monkeypatch.setattr(octree, "AUTO_CUT", 100_000)
    n = 150
    z, y, x = np.ogrid[:n, :n, :n]
    labels = (((x - 75) ** 2 + (y - 75) ** 2 + (z - 75) ** 2) < 68**2).astype(np.uint8)
    labels[2:8, 2:8, 2:8] = 2
    path = tmp_path / "balls.npy"
    np.save(path, np.ascontiguousarray(labels.T))
    common = ["convert", str(path), "--labels", "--format", "precomputed", "--lods", "2", "-q"]
    assert main([*common, "-o", str(tmp_path / "auto")]) == 0
    assert main([*common, "-o", str(tmp_path / "whole"), "--fragment-size", "inf"]) == 0
    assert main([*common, "-o", str(tmp_path / "slabs"), "--max-memory", "2M"]) == 0
    assert main([*common, "-o", str(tmp_path / "said"), "--fragment-size", "Auto"]) == 0
    assert _layer_bytes(tmp_path / "said") == _layer_bytes(tmp_path / "auto")
    assert main([*common, "-o", str(tmp_path / "word"), "--fragment-size", "big"]) == 2
    assert main(["convert", str(path), "--labels", "-q", "-o", str(tmp_path / "b.ply")]) == 0
    ball, cube = read_mesh(tmp_path / "b_label1.ply"), read_mesh(tmp_path / "b_label2.ply")
    assert ball.n_cells > 100_000 and cube.n_cells < 1000
    for label in (1, 2):
        index = f"mesh/{label}.index"
        assert (tmp_path / "slabs" / index).read_bytes() == (tmp_path / "auto" / index).read_bytes()
    chunk, _, n_lods, _, _, positions, _ = _manifest(tmp_path / "auto" / "mesh" / "1.index")
    # the ball's box is 136 wide: its far 8 voxels hold caps along x, y and z only
    assert np.allclose(chunk, 128.0) and n_lods == 2 and positions[0].shape[1] == 4
    original = trimesh.Trimesh(ball.vertices, ball.cells)
    cv = _cloud(tmp_path / "auto")
    for lod in range(2):
        back = cv.mesh.get(1, lod=lod)[1]
        union = trimesh.Trimesh(back.vertices, back.faces, process=True)
        assert union.is_watertight
        if lod == 0:
            assert len(back.faces) > ball.n_cells  # the cuts add triangles
            assert abs(union.area / original.area - 1) < 1e-4
    chunk, _, _, _, _, positions, _ = _manifest(tmp_path / "auto" / "mesh" / "2.index")
    assert chunk.max() < 10 and [p.shape[1] for p in positions] == [1, 1]
    assert len(cv.mesh.get(2, lod=0)[2].faces) == cube.n_cells
    chunk, _, _, _, _, positions, _ = _manifest(tmp_path / "whole" / "mesh" / "1.index")
    assert chunk.min() > 128 and [p.shape[1] for p in positions] == [1, 1]
    assert len(_cloud(tmp_path / "whole").mesh.get(1, lod=0)[1].faces) == ball.n_cells


@pytest.mark.parametrize("chunk", [8.0, None])
def test_large_objects_coarser_levels_are_collapsed_in_slabs_within_their_bound(
    tmp_path, labelled, monkeypatch, chunk
):
    """Objects above LARGE_OBJECT triangles given in parts, cut into fragments or
    not: no label's whole surface is collapsed (each collapse gets one slab, or
    the slabs' union, or one slab of it when it is large itself, fewer triangles
    than the label's), nor, cut, built; cloud-
    volume reads each coarser level closed, with fewer triangles than the level
    above, and within its bound of level 0 both ways (plus a quantization step)."""
    from isoconvert.writers.precomputed import tasks as precomputed

    volume, _ = labelled
    monkeypatch.setattr(precomputed, "LARGE_OBJECT", 500)
    monkeypatch.setattr(precomputed, "SLAB_TRIANGLES", 400)
    parted = label_surfaces(volume, smoothing=16)
    whole = label_surfaces(volume, smoothing=16)
    sizes = {label: whole[label].n_cells for label in whole.labels}
    assert min(sizes.values()) > 1000  # each in three slabs or more
    built, inputs, current = [], {}, []
    real = type(parted)._build
    monkeypatch.setattr(
        type(parted), "_build", lambda self, label: built.append(label) or real(self, label)
    )

    def parts(label):
        current.append(label)
        return parted.parts(label)

    def recorded(mesh, bound, locked=None):
        inputs.setdefault(current[-1], []).append((mesh.n_cells, bound, locked is not None))
        return _bounded(mesh, bound, locked)

    layer = tmp_path / "layer"
    write_precomputed(layer, parted.meshes, parted.grid, unit="µm", lods=3, collapse=recorded,
                      chunk=chunk, parts=parts, object_threads=1)  # fmt: skip
    # uncut, level 0 is one fragment of the whole surface
    assert built == ([] if chunk else list(sizes))
    unions_in_slabs = 0
    for label, count in sizes.items():
        calls = inputs[label]  # in order: the slabs', then each level's union's
        first = next(k for k in range(len(calls) + 1) if sum(n for n, _, _ in calls[:k]) >= count)
        slabs, rest = calls[:first], calls[first:]
        # every triangle in one slab, each slab with its shared vertices kept
        assert len(slabs) >= 3 and sum(n for n, _, _ in slabs) == count
        assert max(n for n, _, _ in slabs) < count and all(locked for *_, locked in slabs)
        # then for each coarser level the slabs' union, fewer triangles: whole, or
        # (above LARGE_OBJECT) in slabs again, each with its shared vertices kept;
        # the bounds add up to each level's: the slabs' and then the union's
        (slab_bound,) = {bound for _, bound, _ in slabs}
        stages: dict[float, list] = {}
        for n, bound, locked in rest:
            stages.setdefault(slab_bound + bound, []).append((n, locked))
        assert sorted(stages) == [1.0, 2.0]
        (union,) = {sum(n for n, _ in stage) for stage in stages.values()}
        assert union < count
        for stage in stages.values():
            at_once = stage == [(union, False)]
            assert at_once or (len(stage) > 1 and all(locked for _, locked in stage)), label
            assert at_once == (union <= precomputed.LARGE_OBJECT), label
            unions_in_slabs += not at_once
    assert unions_in_slabs  # some unions were larger than LARGE_OBJECT
    cv = _cloud(layer)
    for label, mesh in whole.meshes.items():
        original = trimesh.Trimesh(_to_index(volume, np.asarray(mesh.vertices)), mesh.cells)
        previous = None
        for lod in range(3):
            back = cv.mesh.get(int(label), lod=lod)[int(label)]
            index = _to_index(volume, np.asarray(back.vertices, np.float64) / NM_PER_UM)
            union = trimesh.Trimesh(index, back.faces, process=True)  # fragments joined
            assert union.is_watertight, (label, lod)
            if previous is not None:
                assert len(union.faces) < previous
            previous = len(union.faces)
            step = (
                np.full(3, 8.0 * 2.0**lod / (2**16 - 1))
                if chunk
                else 2 * _half_step(original.vertices, lod)
            )
            bound = (2.0 ** (lod - 1) if lod else 0.0) + np.linalg.norm(step) + 1e-5
            points = np.vstack([union.vertices, union.sample(3000, seed=1)])
            _, there, _ = trimesh.proximity.closest_point(original, points)
            points = np.vstack([original.vertices, original.sample(3000, seed=2)])
            _, back_there, _ = trimesh.proximity.closest_point(union, points)
            assert there.max() <= bound and back_there.max() <= bound, (label, lod)


def _voronoi_ball(draw: int) -> np.ndarray:
    """(40, 40, 40) uint16: six random Voronoi cells in a ball, the ``draw``-th of
    the seeds generator 1 gives."""
    rng = np.random.default_rng(1)
    for _ in range(draw + 1):
        seeds = rng.uniform(8, 32, size=(6, 3))
    z, y, x = np.mgrid[:40, :40, :40].astype(float)
    d = np.stack([(x - a) ** 2 + (y - b) ** 2 + (z - c) ** 2 for a, b, c in seeds])
    labels = (np.argmin(d, axis=0) + 1).astype(np.uint16)
    labels[(x - 20) ** 2 + (y - 20) ** 2 + (z - 20) ** 2 > 17**2] = 0
    return labels


@pytest.mark.parametrize("draw", [3, 4])
def test_slabs_collapsed_apart_meet_in_a_manifold_union(tmp_path, monkeypatch, draw):
    """Each slab keeps the vertices it shares and their neighbours: with the shared
    ones alone, collapses on the two sides of a cut could both join the same two
    shared vertices, an edge of four triangles (one label of each of these volumes
    had one, in slabs of 150 triangles). Every label's union of slabs uses each
    edge twice, and its coarser level is closed (by index)."""
    from isoconvert.writers.precomputed import tasks as precomputed

    monkeypatch.setattr(precomputed, "LARGE_OBJECT", 300)
    monkeypatch.setattr(precomputed, "SLAB_TRIANGLES", 150)
    unions = []
    real = precomputed._coarse_levels

    def seen(slabs, *args):
        unions.append(np.concatenate([cells for _, _, cells in slabs]))
        return real(slabs, *args)

    monkeypatch.setattr(precomputed, "_coarse_levels", seen)
    surfaces = label_surfaces(Volume(_voronoi_ball(draw)), smoothing=16)
    write_precomputed(tmp_path / "layer", surfaces.meshes, surfaces.grid, lods=2,
                      collapse=_bounded, parts=surfaces.parts)  # fmt: skip
    assert len(unions) == len(surfaces.labels)
    for label, cells in zip(surfaces.labels, unions, strict=True):
        edges = np.sort(cells[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, uses = np.unique(edges, axis=0, return_counts=True)
        assert (uses == 2).all(), label
        # closed by its vertices' indices (two of the net's split vertices a hair
        # apart may share a quantized position: see the README)
        back = _cloud(tmp_path / "layer").mesh.get(label, lod=1)[label]
        assert trimesh.Trimesh(back.vertices, back.faces, process=False).is_watertight, label


def test_merged_positions_drop_what_has_no_area_and_fins_that_cancel():
    """Corners that quantize to one position become one vertex: a triangle
    between two of them goes, and so do two triangles left over the same three
    vertices (either orientation); the others stay, in order."""
    from isoconvert.writers.precomputed.octree import merged_positions

    q = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 4, 0], [0, 0, 4], [4, 4, 4]], float)
    corners = np.array([[0, 1, 2], [0, 3, 1], [1, 2, 3], [0, 1, 4], [4, 1, 5], [1, 0, 4]])
    positions, kept = merged_positions(q, corners)
    assert positions.tolist() == [[0, 0, 0], [0, 0, 4], [0, 4, 0], [4, 0, 0], [4, 4, 4]]
    # [0, 1, 2] and [0, 3, 1] are one fin (2 and 3 are one position), [1, 2, 3]
    # has no area, [0, 1, 4] and [1, 0, 4] are another fin: only [4, 1, 5] stays
    assert positions[kept].tolist() == [[[0, 0, 4], [4, 0, 0], [4, 4, 4]]]


def test_triangles_crossing_several_rows_of_fragments_are_cut_alike_in_each(tmp_path):
    """Fragments are made one row of nodes at a time: a triangle taller than a
    row is taken by every row it reaches, and each must cut it at the same planes
    in the same order (one cut only at a row's own planes gives different seam
    vertices, and cracks). An icosahedron of 20 triangles, 40 voxels across, in
    4-voxel fragments: cloud-volume's union of them is closed, with its area."""
    sphere = trimesh.creation.icosahedron()
    vertices = np.asarray(sphere.vertices) * 20.0 + 24.0
    mesh = Mesh(vertices, np.asarray(sphere.faces, np.int64))
    grid = {"shape": (48, 48, 48), "origin": (0.0, 0.0, 0.0), "affine": np.eye(3)}
    layer = write_precomputed(tmp_path / "layer", {1: mesh}, grid, unit="nm", chunk=4.0)
    *_, positions, _ = _manifest(layer / "mesh" / "1.index")
    assert len(np.unique(positions[0][2])) >= 8  # many rows of fragments
    back = _cloud(layer).mesh.get(1, lod=0)[1]
    union = trimesh.Trimesh(np.asarray(back.vertices, np.float64), back.faces, process=True)
    assert union.is_watertight
    assert abs(union.area / trimesh.Trimesh(vertices, mesh.cells).area - 1) < 1e-4


@pytest.mark.parametrize("sharded", [False, True])
def test_fragments_made_from_each_labels_parts_are_those_of_its_whole_surface(
    tmp_path, labelled, monkeypatch, sharded
):
    """One level cut into fragments, from each label's parts (the net's quads that
    reach each row of fragments): the same bytes as from the whole surfaces, on
    the oblique volume (index coordinates from a rotation), while no label's whole
    surface is built; the summaries are the surfaces' counts."""
    volume, _ = labelled
    common = dict(unit="µm", data_type="uint16", chunk=6.0, sharded=sharded)
    whole = label_surfaces(volume, smoothing=16)
    grid = next(iter(whole.meshes.values())).info["grid"]
    expected = {label: (m.n_vertices, m.n_cells) for label, m in whole.meshes.items()}
    write_precomputed(tmp_path / "whole", whole.meshes, grid, **common)
    parted = label_surfaces(volume, smoothing=16)
    built = []
    real = type(parted)._build
    monkeypatch.setattr(
        type(parted), "_build", lambda self, label: built.append(label) or real(self, label)
    )
    write_precomputed(tmp_path / "parts", parted.meshes, grid, parts=parted.parts, **common)
    assert built == []  # every label is larger than one fragment
    for path in sorted((tmp_path / "whole").rglob("*")):
        if path.is_file():
            twin = tmp_path / "parts" / path.relative_to(tmp_path / "whole")
            assert twin.read_bytes() == path.read_bytes(), path.name
    assert {label: (parted.summary(label).n_vertices, parted.summary(label).n_cells)
            for label in parted.labels} == expected  # fmt: skip
    assert built == []


@pytest.mark.parametrize("given", ["net", "whole"])
def test_a_row_of_fragments_is_given_every_triangle_reaching_it_in_y_and_z(labelled, given):
    """A row of nodes (along x) is made from the triangles its object's parts say
    reach it: every triangle of the whole surface whose y- and z-ranges (index
    coordinates, exact) meet the row's box must be among them, in the whole
    surface's order, and few others (the y-ranges are held in float32, rounded
    outward): a z-layer of rows would take several times as many. From
    the net's quads (a label's parts) and from a whole mesh's triangles (a large
    isosurface's)."""
    from isoconvert.writers.precomputed.tasks import _WholeParts, index_of

    volume, result = labelled
    grid = result.grid
    origin = np.asarray(grid["origin"], np.float64)
    inverse = np.linalg.inv(np.asarray(grid["affine"], np.float64))

    def to_index(world):
        return index_of(world, origin, inverse)

    for label in result.labels:
        mesh = result[label]
        parts = result.parts(label) if given == "net" else _WholeParts(mesh)
        index = to_index(np.asarray(mesh.vertices, np.float64))
        corners = index[mesh.cells]  # (C, 3, 3)
        low, high = corners.min(axis=1), corners.max(axis=1)
        middle = (low.min(axis=0) + high.max(axis=0)) / 2
        box_low = np.array([-np.inf, middle[1] - 3.0, middle[2] - 2.5])
        box_high = np.array([np.inf, middle[1] + 3.0, middle[2] + 2.5])
        meets = ((high >= box_low) & (low <= box_high)).all(axis=1)
        in_layer = (high[:, 2] >= box_low[2]) & (low[:, 2] <= box_high[2])
        assert 0 < meets.sum() < in_layer.sum() / 2, label
        part = parts.reaching(to_index, box_low, box_high)
        # triangles as their corners' positions, to find them in the whole surface
        mine = np.asarray(part.vertices)[np.asarray(part.cells)].reshape(len(part.cells), 9)
        theirs = np.asarray(mesh.vertices)[mesh.cells].reshape(len(mesh.cells), 9)
        where = {row.tobytes(): n for n, row in enumerate(theirs)}
        found = np.array([where[row.tobytes()] for row in mine])
        assert (np.diff(found) > 0).all(), label  # the whole surface's, in its order
        assert set(np.flatnonzero(meets)) <= set(found.tolist()), label
        assert len(found) < in_layer.sum() / 2, label
        # the others: a whole mesh's within float32 rounding of the box; the net's
        # are the other triangle of a quad whose y- and z-ranges meet it (the net
        # holds a quad's ranges), within a voxel of it
        extra = np.setdiff1d(found, np.flatnonzero(meets))
        near = (1e-4, 0.01) if given == "whole" else (1.0, 0.2)
        reach = np.maximum(box_low - high[extra], low[extra] - box_high)[:, 1:].max(axis=1)
        assert (reach < near[0]).all() and len(extra) <= near[1] * meets.sum(), label


def test_an_objects_rows_are_planned_as_tasks_of_neighbouring_rows_triangles_reach(labelled):
    """The plan of a label's level 0 (:func:`row_tasks`): every row of nodes
    that a triangle of its whole surface reaches (exact index coordinates) is in
    one task, rows no triangle comes near are in none, a task's rows are one
    z-layer's, y increasing, and its rows' triangles (as many as ``reaching``
    gives each row, which is what ``reaching_counts`` says) add up to at most
    ``most`` unless it is one row; 0 gives each row its own."""
    from isoconvert.writers.precomputed import tasks
    from isoconvert.writers.precomputed.octree import (
        level_frame,
        node_rows,
        object_frame,
        row_span,
        row_spans,
    )

    volume, result = labelled
    grid = result.grid
    origin = np.asarray(grid["origin"], np.float64)
    inverse = np.linalg.inv(np.asarray(grid["affine"], np.float64))

    def to_index(world):
        return tasks.index_of(world, origin, inverse)

    left_out = 0
    for label in result.labels:
        mesh = result[label]
        parts = result.parts(label)
        corners = to_index(np.asarray(mesh.vertices, np.float64))[mesh.cells]
        low, high = corners.min(axis=1), corners.max(axis=1)
        lo, hi = parts.extent(to_index)
        grid_origin, shape, cut = object_frame(lo, hi, 6.0)
        assert cut, label
        frame = level_frame(grid_origin, shape, 0, 1023.0, lo, hi)
        rows = node_rows(frame)
        spans = [row_span(frame, row) for row in rows]
        counts = parts.reaching_counts(to_index, *row_spans(frame, rows))
        for (start, end), count in zip(spans, counts, strict=True):
            assert count == len(parts.reaching(to_index, start, end).cells), label
        # rows a triangle reaches, exactly; rows nothing comes within a voxel of
        reached = {row for row, (start, end) in zip(rows, spans, strict=True)
                   if ((high >= start) & (low <= end))[:, 1:].all(axis=1).any()}  # fmt: skip
        near = {row for row, (start, end) in zip(rows, spans, strict=True)
                if ((high + 1 >= start) & (low - 1 <= end))[:, 1:].all(axis=1).any()}  # fmt: skip
        count_of = dict(zip(rows, counts.tolist(), strict=True))
        for most in (0, int(counts.max()), 1 << 30):
            plan = tasks.row_tasks(parts, to_index, frame, most)
            planned = [row for task in plan for row in task]
            assert len(planned) == len(set(planned)), label
            assert reached <= set(planned) <= near, label
            for task in plan:
                ys, zs = zip(*task, strict=True)
                assert len(set(zs)) == 1 and list(ys) == sorted(set(ys)), label
                assert len(task) == 1 or sum(count_of[row] for row in task) <= most, label
            if most == 0:
                assert all(len(task) == 1 for task in plan), label
            if most == 1 << 30:  # one task a z-layer
                assert len(plan) == len({z for _, z in planned}), label
        left_out += len(rows) - len(planned)
    assert left_out > 0  # the corners of the labels' boxes


def test_a_sharded_layer_holds_the_same_objects(tmp_path):
    """--sharded: 150 labels in shard files; cloud-volume reads every label at every
    level as from the unsharded layer, and the mesh info validates."""
    import jsonschema

    volume = Volume.from_zyx(_atlas(48, 150), spacing=(0.5, 0.4, 1.2), unit="µm")
    result = label_surfaces(volume, smoothing=16)
    grid = next(iter(result.meshes.values())).info["grid"]
    for sharded in (False, True):
        write_precomputed(tmp_path / f"s{sharded}", result.meshes, grid, unit="µm", lods=2,
                          collapse=_bounded, chunk=8.0, sharded=sharded)  # fmt: skip
    info = json.loads((tmp_path / "sTrue" / "mesh" / "info").read_text())
    jsonschema.validate(info, MESH_SCHEMA)
    assert info["sharding"]["minishard_bits"] > 0
    files = sorted(p.name for p in (tmp_path / "sTrue" / "mesh").iterdir())
    assert files == ["0.shard", "info"]
    plain, shards = _cloud(tmp_path / "sFalse"), _cloud(tmp_path / "sTrue")
    assert len(result.meshes) > 100
    for label in result.meshes:
        for lod in (0, 1):
            a = plain.mesh.get(int(label), lod=lod)[int(label)]
            b = shards.mesh.get(int(label), lod=lod)
            b = b[int(label)] if isinstance(b, dict) else b
            assert np.array_equal(a.faces, b.faces) and np.array_equal(a.vertices, b.vertices)


def _balls(n: int = 10) -> dict:
    """The meshes of n^3 labels, a ball of its own in each 8^3 cell."""
    z, y, x = np.mgrid[: 8 * n, : 8 * n, : 8 * n]
    cell = (z // 8) * n * n + (y // 8) * n + x // 8 + 1
    ball = ((z % 8 - 3.5) ** 2 + (y % 8 - 3.5) ** 2 + (x % 8 - 3.5) ** 2) < 3.2**2
    result = label_surfaces(Volume.from_zyx(np.where(ball, cell, 0).astype(np.uint16)))
    assert len(result.meshes) == n**3
    return dict(result.meshes)


def test_a_sharded_layer_does_not_hold_its_objects_in_memory(tmp_path):
    """The objects' bytes wait on disk until the shards are put together: writing
    1000 small objects allocates (tracemalloc) well under the layer's size, where
    holding every object's bytes, then joining a shard from them, takes twice it;
    cloud-volume reads the objects back."""
    import tracemalloc

    n = 10
    meshes = _balls(n)
    grid = next(iter(meshes.values())).info["grid"]
    tracemalloc.start()
    try:
        write_precomputed(tmp_path / "layer", meshes, grid, sharded=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    files = sorted((tmp_path / "layer" / "mesh").iterdir())
    assert [f.name for f in files] == ["0.shard", "info"]  # the spill file is gone
    assert peak < 0.6 * files[0].stat().st_size
    cv = _cloud(tmp_path / "layer")
    for label in (1, 500, n**3):
        back = cv.mesh.get(label, lod=0)
        back = back[label] if isinstance(back, dict) else back
        assert len(back.faces) == meshes[label].n_cells


@pytest.mark.parametrize("size", ["1m", "2m"])
def test_a_full_disk_while_objects_wait_for_their_shard_is_one_line(tmp_path, size):
    """A 1.2 MB sharded layer on a tmpfs of 1 MiB (full while the objects wait on
    disk) or 2 MiB (full while the shard is put together from them): the one-line
    disk-full error, and the tmpfs is empty again."""
    meshes = _balls()
    grid = next(iter(meshes.values())).info["grid"]
    with small_tmpfs(tmp_path / "full", size) as disk:
        with pytest.raises(OutputError, match="disk full at"):
            write_precomputed(disk / "layer", meshes, grid, sharded=True)
        assert list(disk.iterdir()) == []


def test_a_full_disk_while_threads_write_objects_is_one_line(tmp_path):
    """Unsharded, each thread writes its object's fragments: a 1 MiB tmpfs fills
    while they do, the one-line disk-full error naming the layer, the tmpfs empty."""
    meshes = _balls()
    grid = next(iter(meshes.values())).info["grid"]
    with small_tmpfs(tmp_path / "full", "1m") as disk:
        with pytest.raises(OutputError, match=f"^disk full at {disk / 'layer'}") as caught:
            write_precomputed(disk / "layer", meshes, grid, object_threads=2)
        assert "\n" not in str(caught.value)
        assert list(disk.iterdir()) == []


@pytest.mark.parametrize("lods", [1, 3])
def test_the_layer_does_not_depend_on_the_thread_count(tmp_path, labelled, monkeypatch, lods):
    """Objects are encoded (and unsharded, written) side by side on threads; the
    files are the same bytes."""
    _, result = labelled
    grid = next(iter(result.meshes.values())).info["grid"]
    for threads in ("1", "2"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        write_precomputed(tmp_path / threads, result.meshes, grid, unit="µm", lods=lods,
                          collapse=_bounded, chunk=8.0, object_threads=int(threads))  # fmt: skip
    one = sorted(p.relative_to(tmp_path / "1") for p in (tmp_path / "1").rglob("*"))
    two = sorted(p.relative_to(tmp_path / "2") for p in (tmp_path / "2").rglob("*"))
    assert one == two
    for name in one:
        if (tmp_path / "1" / name).is_file():
            assert (tmp_path / "1" / name).read_bytes() == (tmp_path / "2" / name).read_bytes()


@pytest.mark.parametrize("form", ["plain", "sharded", "legacy"])
def test_each_objects_result_names_the_file_that_holds_it(tmp_path, form):
    """What a run reports as written (``wrote ...``) is the file holding the object:
    its fragments, its legacy manifest, or the shard its id hashes to (4913 objects
    need two shards: the spec's identity hash, shard = id >> minishard bits)."""
    from isoconvert.label_convert import convert_labels

    n = 17 if form == "sharded" else 3
    z, y, x = np.mgrid[: 8 * n, : 8 * n, : 8 * n]
    cell = (z // 8) * n * n + (y // 8) * n + x // 8 + 1
    ball = ((z % 8 - 3.5) ** 2 + (y % 8 - 3.5) ** 2 + (x % 8 - 3.5) ** 2) < 3.2**2
    np.save(tmp_path / "balls.npy", np.where(ball, cell, 0).astype(np.uint16).T)
    options = {"sharded": form == "sharded", "legacy_mesh": form == "legacy"}
    results = convert_labels(tmp_path / "balls.npy", tmp_path / "layer", format="precomputed",
                             lods=1, **options)  # fmt: skip
    assert len(results) == n**3
    mesh = tmp_path / "layer" / "mesh"
    if form == "sharded":
        spec = json.loads((mesh / "info").read_text())["sharding"]
        shards = sorted(p.name for p in mesh.glob("*.shard"))
        assert len(shards) == 2 and sorted({r.output.name for r in results}) == shards
        for label, result in enumerate(results, start=1):
            number = (label >> spec["minishard_bits"]) & ((1 << spec["shard_bits"]) - 1)
            assert int(result.output.name.removesuffix(".shard"), 16) == number
    else:
        names = [f"{label}:0" if form == "legacy" else str(label) for label in range(1, 28)]
        assert [r.output.name for r in results] == names
    assert all(r.output.is_file() and r.output.parent == mesh for r in results)


def test_a_worker_that_may_not_write_the_folder_sends_the_object_back(tmp_path, monkeypatch):
    """write_object, a cluster's task: where it sees the part folder but may not write
    there (a worker of another user, a read-only mount) it sends the fragment data
    back for the client to write, as where it does not see the folder at all."""
    from pathlib import Path

    from isoconvert.writers.precomputed import encode_object, write_object

    mesh = _balls(1)[1]
    args = (mesh.vertices, mesh.cells, np.zeros(3), np.eye(3), 1, 16, None, None)
    expected = encode_object(*args)
    task = (encode_object, *args)
    assert write_object(str(tmp_path / "1"), "layer", *task) == (expected[0], len(expected[1]))
    assert (tmp_path / "1").read_bytes() == expected[1]
    assert write_object(str(tmp_path / "elsewhere" / "2"), "layer", *task) == expected

    def refused(self, data):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "write_bytes", refused)
    assert write_object(str(tmp_path / "3"), "layer", *task) == expected
    assert not (tmp_path / "3").exists()


def test_fragment_size_inf_within_max_memory_says_the_budget_does_not_hold(tmp_path, capsys):
    """--fragment-size inf encodes each object's surface as one fragment, which no
    slab bounds: within --max-memory a note says so (for labels and for levels), and
    only there (not in memory, not with the default fragment size)."""
    from isoconvert.cli import main

    labels = np.zeros((12, 12, 12), np.uint8)
    labels[3:9, 3:9, 3:9] = 1
    path = tmp_path / "cube.npy"
    np.save(path, labels)
    said = "--fragment-size inf encodes each object's whole surface as one fragment"
    runs = {
        ("--labels", "--fragment-size", "inf", "--max-memory", "64M"): True,
        ("--level", "0.5", "--fragment-size", "inf", "--max-memory", "64M"): True,
        ("--labels", "--fragment-size", "inf"): False,
        ("--labels", "--max-memory", "64M"): False,
    }
    for n, (flags, noted) in enumerate(runs.items()):
        layer = tmp_path / f"layer{n}"
        assert (
            main(["convert", str(path), "-o", str(layer), "--format", "precomputed", *flags]) == 0
        )
        assert (said in capsys.readouterr().err) == noted, flags
        assert (layer / "mesh" / "info").is_file()


def test_a_legacy_fragment_written_in_blocks_holds_every_vertex_in_nanometres(tmp_path):
    """The legacy fragment is written a block of rows at a time (memory.ROWS): an
    object of more vertices than two blocks, in an oblique frame, holds its count,
    every vertex at ``transform @ (inverse @ (world - origin))`` (numpy's matrix
    products on the whole array, to float32 rounding) and its triangles as uint32."""
    from isoconvert.memory import ROWS
    from isoconvert.mesh import Mesh
    from isoconvert.writers.precomputed.legacy import write_legacy

    rng = np.random.default_rng(5)
    n = 2 * ROWS + 123
    world = rng.uniform(-50, 400, (n, 3))
    cells = rng.integers(0, n, (n // 2, 3))
    origin = np.array([3.0, -7.5, 11.25])
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    inverse = np.linalg.inv(q * [0.5, 0.8, 2.0])
    transform = np.hstack([np.diag([4.0, 4.0, 40.0]), [[10.0], [-20.0], [30.0]]])
    write_legacy(tmp_path, 7, Mesh(world, cells), origin, inverse, transform)
    data = (tmp_path / "7:0:0").read_bytes()
    assert np.frombuffer(data[:4], "<u4")[0] == n
    nm = np.frombuffer(data[4 : 4 + 12 * n], "<f4").reshape(n, 3)
    expected = ((world - origin) @ inverse.T) @ transform[:, :3].T + transform[:, 3]
    assert np.allclose(nm, expected, rtol=2e-7, atol=1e-3)
    assert (np.frombuffer(data[4 + 12 * n :], "<u4").reshape(-1, 3) == cells).all()
    assert json.loads((tmp_path / "7:0").read_text()) == {"fragments": ["7:0:0"]}


def test_a_row_cut_a_run_of_nodes_at_a_time_gives_the_fragments_of_the_whole_row(monkeypatch):
    """A row that many triangles reach is cut a run of its nodes (along x) at a
    time, each run given the triangles reaching it: every node's fragment must
    be the one the whole row gives (a run that left out a triangle reaching it
    across its ends, or a piece whose centroid lies in the run beside it, would
    change a fragment or lose a piece). A sphere of 5,120 triangles, 30 voxels
    across and off the grid, in 4-voxel nodes: its rows cut whole, and cut in
    runs of at most 64 triangles."""
    from isoconvert.writers.precomputed import octree

    sphere = trimesh.creation.icosphere(subdivisions=4)
    vertices = np.asarray(sphere.vertices) * 15.0 + np.array([20.3, 19.1, 21.7])
    cells = np.asarray(sphere.faces, np.int64)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    origin, shape, _ = octree.object_frame(lo, hi, 4.0)
    frame = octree.level_frame(origin, shape, 0, 65535.0, lo, hi)
    whole = octree.cut_level(vertices.copy(), cells, frame)
    runs = []
    real = octree._cut_nodes
    monkeypatch.setattr(octree, "RUN_TRIANGLES", 64)
    monkeypatch.setattr(octree, "_cut_nodes", lambda *args: runs.append(args[4]) or real(*args))
    parted = octree.cut_level(vertices.copy(), cells, frame)
    assert sum(run != (None, None) for run in runs) > 2 * len(octree.node_rows(frame))
    assert list(parted) == list(whole) and len(whole) > 100
    for node, (q, corners) in whole.items():
        assert np.array_equal(parted[node][0], q) and np.array_equal(parted[node][1], corners)


@pytest.mark.parametrize("n", [10, 100_000])
def test_the_vertices_a_cut_takes_are_those_np_unique_gives(n):
    """The cut's compaction of a part's vertices, by a table where that holds
    less than a sort of every corner and by the sort elsewhere: the vertices in
    increasing order and the triangles over them, np.unique's answer."""
    from isoconvert.writers.precomputed.octree import _compact

    cells = np.random.default_rng(n).integers(0, n, size=(500, 3))
    used, local = _compact(cells, n)
    expected, inverse = np.unique(cells, return_inverse=True)
    assert np.array_equal(used, expected)
    assert np.array_equal(local, inverse.reshape(-1, 3))


def test_read_back_vertices_are_joined_as_np_unique_joins_rows():
    """The read-back's join of fragment vertices by position gives np.unique's
    rows and inverse, by one key a row and, where the grid of steps is too large
    for one int64 key, row by row."""
    from isoconvert.writers.precomputed.readback import _joined

    rng = np.random.default_rng(4)
    steps = rng.integers(0, 6, (500, 3))
    for rows in (steps, np.concatenate([steps, [[2**40, 2**30, 7]]])):
        joined, where = _joined(rows)
        expected, inverse = np.unique(rows, axis=0, return_inverse=True)
        assert np.array_equal(joined, expected) and np.array_equal(where, inverse.reshape(-1))
