"""Isosurfaces (``--level``) as a Neuroglancer precomputed layer (issue 25): level n of
the command is the layer's object n, read back by cloud-volume as the same surface as
the PLY of that level."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from isoconvert.convert import convert_levels
from isoconvert.meshfile import read_mesh

cloudvolume = pytest.importorskip("cloudvolume", reason="pip install cloud-volume")
pytest.importorskip("DracoPy", reason="pip install DracoPy")
pytest.importorskip(
    "meshoptimizer", reason='levels of detail need pip install "isoconvert[simplify]"'
)
pytest.importorskip("rtree", reason="trimesh.proximity needs rtree")


def _nested_balls(path):
    """A distance-like field of two nested shells (a ball at 60.5, a larger one at 30.5),
    anisotropic, saved as .npy (Z, Y, X)."""
    z, y, x = np.mgrid[:34, :40, :46].astype(np.float64)
    r = np.sqrt(((x - 22) / 1.0) ** 2 + ((y - 19) / 1.1) ** 2 + ((z - 16) / 0.9) ** 2)
    np.save(path, (100.0 - 5.0 * r).astype(np.float32))


def _cloud(folder):
    return cloudvolume.CloudVolume(f"precomputed://file://{folder}", progress=False)


def test_each_level_is_an_object_with_the_plys_surface(tmp_path):
    _nested_balls(tmp_path / "field.npy")
    common = {"spacing": (0.5, 0.4, 0.7), "force": True}
    levels = [60.5, 30.5]
    results = convert_levels(tmp_path / "field.npy", tmp_path / "layer", levels,
                             format="precomputed", lods=2, **common)  # fmt: skip
    plys = convert_levels(tmp_path / "field.npy", tmp_path / "f.ply", levels, **common)
    assert [r.output.name for r in results] == ["1", "2"]
    cv = _cloud(tmp_path / "layer")
    for n, ply in enumerate(plys, start=1):
        mesh = read_mesh(ply.output)
        back = cv.mesh.get(n, lod=0)[n]
        assert len(back.faces) == mesh.n_cells
        # the vertices within half a quantization step (16 bits over the object's box)
        # of the PLY's, in nanometres (the volume has no unit: 1 unit = 1 nm)
        world = np.asarray(back.vertices, np.float64)
        box = mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)
        distance, _ = cKDTree(mesh.vertices).query(world)
        assert distance.max() <= np.linalg.norm(0.5 * box / 65535) + 1e-4
        original = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
        decoded = trimesh.Trimesh(world, back.faces, process=False)
        assert original.is_watertight and decoded.is_watertight
        assert abs(decoded.volume / original.volume - 1) < 1e-4
        coarse = cv.mesh.get(n, lod=1)[n]
        assert 0 < len(coarse.faces) < len(back.faces)


def test_an_isosurface_cut_into_fragments_keeps_the_plys_triangles(tmp_path):
    """The cut planes go through the samples: every triangle of an isosurface lies in
    one cell between samples, so none crosses them, and level 0 in 8-voxel fragments
    has the PLY's triangles, closed across the seams. With the planes where the
    object's box began (a vertex between samples) the cuts added triangles; so they
    would a label net's, whose planes lie midway between samples (checked too: at
    --smooth 0 its vertices lie there, and its fragments keep its triangles)."""
    _nested_balls(tmp_path / "field.npy")
    common = {"spacing": (0.5, 0.4, 0.7), "force": True}
    plys = convert_levels(tmp_path / "field.npy", tmp_path / "f.ply", [60.5, 30.5], **common)
    convert_levels(tmp_path / "field.npy", tmp_path / "layer", [60.5, 30.5], format="precomputed",
                   lods=1, fragment_size=8.0, **common)  # fmt: skip
    cv = _cloud(tmp_path / "layer")
    for n, ply in enumerate(plys, start=1):
        mesh = read_mesh(ply.output)
        back = cv.mesh.get(n, lod=0)[n]
        union = trimesh.Trimesh(np.asarray(back.vertices, np.float64), back.faces, process=True)
        assert len(back.faces) == mesh.n_cells and union.is_watertight
    manifest = (tmp_path / "layer" / "mesh" / "2.index").read_bytes()
    assert np.frombuffer(manifest, "<u4", 1, 28 + 4 + 12)[0] > 8  # cut into many fragments
    # a label net at --smooth 0 in 8-voxel fragments: planes midway between samples
    from isoconvert.label_convert import convert_labels

    labels = (np.load(tmp_path / "field.npy") > 60.5).astype(np.uint8)
    np.save(tmp_path / "labels.npy", labels)
    ply = convert_labels(tmp_path / "labels.npy", tmp_path / "l.ply", label_smoothing=0)[0]
    convert_labels(tmp_path / "labels.npy", tmp_path / "labels", label_smoothing=0,
                   format="precomputed", lods=1, fragment_size=8.0)  # fmt: skip
    back = _cloud(tmp_path / "labels").mesh.get(1, lod=0)[1]
    assert len(back.faces) == read_mesh(ply.output).n_cells


def _isoconvert(*args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "isoconvert", *map(str, args)], capture_output=True, text=True,
        cwd=cwd,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--normals"], "--normals: a precomputed layer of isosurfaces holds no vertex"),
        (["--with-volume"], "holds no label voxels"),
        (["--level", "60.5"], "a level is given twice"),
        (["--legacy-mesh", "--lods", "2"], "one level of detail"),
    ],
)
def test_what_a_level_layer_cannot_hold_is_a_one_line_error(tmp_path, extra, message):
    _nested_balls(tmp_path / "field.npy")
    args = ["convert", "field.npy", "--level", "60.5", "--format", "precomputed", "-o", "layer"]
    done = _isoconvert(*args, *extra, cwd=tmp_path)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["field.npy"]


def test_the_command_writes_a_legacy_level_layer(tmp_path):
    _nested_balls(tmp_path / "field.npy")
    args = ["convert", "field.npy", "--level", "60.5", "--format", "precomputed", "--legacy-mesh"]
    done = _isoconvert(*args, "-o", "layer ñ", "-q", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    back = _cloud(tmp_path / "layer ñ").mesh.get(1)
    back = back[1] if isinstance(back, dict) else back
    assert trimesh.Trimesh(back.vertices, back.faces).is_watertight


@pytest.mark.parametrize(
    "flags",
    [
        ["--with-volume"],
        ["--legacy-mesh"],
        ["--lods", "2"],
        ["--fragment-size", "8"],
        ["--sharded"],
    ],
)
def test_layer_flags_without_a_layer_are_one_line_errors(tmp_path, flags):
    _nested_balls(tmp_path / "field.npy")
    done = _isoconvert(
        "convert", "field.npy", "--level", "60.5", *flags, "-o", "f.ply", cwd=tmp_path
    )
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert f"{flags[0]} is an option of --format precomputed" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["field.npy"]


@pytest.mark.parametrize("fragments", [8.0, None])
def test_large_isosurfaces_get_their_coarser_levels_from_slabs(tmp_path, monkeypatch, fragments):
    """An isosurface above LARGE_OBJECT triangles is collapsed a slab at a time and
    then as the slabs' union, never whole: every level closed, with fewer
    triangles than the one above, within its bound of level 0 (plus a quantization
    step) both ways; read in blocks, the same layer."""
    sys_convert = sys.modules["isoconvert.convert"]
    from isoconvert.extract.slabs import Blocks
    from isoconvert.writers.precomputed import tasks as precomputed

    monkeypatch.setattr(precomputed, "LARGE_OBJECT", 1000)
    monkeypatch.setattr(precomputed, "SLAB_TRIANGLES", 600)
    inputs = []
    real = sys_convert.bounded_collapse
    monkeypatch.setattr(
        sys_convert,
        "bounded_collapse",
        lambda mesh, bound, locked=None: inputs.append(mesh.n_cells) or real(mesh, bound, locked),
    )
    _nested_balls(tmp_path / "field.npy")
    common = {"spacing": (0.5, 0.4, 0.7), "force": True}
    levels = [60.5, 30.5]
    plys = convert_levels(tmp_path / "field.npy", tmp_path / "f.ply", levels, **common)
    surface, outer = (read_mesh(ply.output) for ply in plys)
    assert 2000 < surface.n_cells < outer.n_cells  # both in slabs
    options = {"format": "precomputed", "lods": 3, "fragment_size": fragments, **common}
    convert_levels(tmp_path / "field.npy", tmp_path / "layer", levels, **options)
    # no collapse of a whole surface: the inner one's slabs and union first
    slabs = next(n for n in range(len(inputs)) if sum(inputs[:n]) >= surface.n_cells)
    assert sum(inputs[:slabs]) == surface.n_cells and max(inputs[: slabs + 2]) < surface.n_cells
    assert max(inputs) < outer.n_cells and len(inputs) > 2 * 2
    convert_levels(tmp_path / "field.npy", tmp_path / "blocks", levels, blocks=Blocks(size=5),
                   **options)  # fmt: skip
    for path in (tmp_path / "layer").rglob("*"):
        if path.is_file():
            twin = tmp_path / "blocks" / path.relative_to(tmp_path / "layer")
            assert path.read_bytes() == twin.read_bytes(), path.name
    cv = _cloud(tmp_path / "layer")
    original = trimesh.Trimesh(surface.vertices, surface.cells)
    box = surface.vertices.max(axis=0) - surface.vertices.min(axis=0)
    previous = None
    for lod in range(3):
        back = cv.mesh.get(1, lod=lod)[1]
        union = trimesh.Trimesh(np.asarray(back.vertices, np.float64), back.faces, process=True)
        assert union.is_watertight, lod
        assert previous is None or len(union.faces) < previous
        previous = len(union.faces)
        # a step of 16 bits over the node: the fragment size, or the object's box
        node = np.full(3, fragments) * np.array(common["spacing"]) if fragments else box
        step = np.linalg.norm(node * 2.0**lod / 65535)
        bound = (2.0 ** (lod - 1) if lod else 0.0) * max(common["spacing"]) + step + 1e-6
        points = np.vstack([union.vertices, union.sample(2000, seed=1)])
        _, there, _ = trimesh.proximity.closest_point(original, points)
        points = np.vstack([original.vertices, original.sample(2000, seed=2)])
        _, back_there, _ = trimesh.proximity.closest_point(union, points)
        assert there.max() <= bound and back_there.max() <= bound, lod
