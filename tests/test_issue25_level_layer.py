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
