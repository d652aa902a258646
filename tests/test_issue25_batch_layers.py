"""Issue 25: batch writes a Neuroglancer precomputed layer per volume (``--format
precomputed``), the same bytes as convert writes for each, with the layer options
declared once for both commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from cloudvolume import CloudVolume

from isoconvert.cli import main


def _files(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _labels(seed: int, shape=(28, 24, 20)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    labels = np.zeros(shape, np.uint8)
    for value in range(1, 6):
        lo = rng.integers(0, 12, 3)
        hi = lo + rng.integers(4, 9, 3)
        labels[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = value
    return labels


@pytest.fixture
def volumes(tmp_path):
    folder = tmp_path / "in"
    (folder / "sub").mkdir(parents=True)
    np.save(folder / "a.npy", _labels(1))
    np.save(folder / "sub" / "b.npy", _labels(2))
    return folder


@pytest.mark.parametrize(
    "options",
    [["--labels", "--lods", "2"], ["--labels", "--with-volume", "--sharded"], ["--level", "2.5"]],
)
def test_batch_layers_are_convert_layers(tmp_path, volumes, options):
    out = tmp_path / "out"
    args = ["--format", "precomputed", *options]
    assert main(["batch", str(volumes), "-r", "-o", str(out), "-q", *args]) == 0
    for name in ("a", "sub/b"):
        alone = tmp_path / "alone" / name
        alone.parent.mkdir(parents=True, exist_ok=True)
        assert main(["convert", str(volumes / f"{name}.npy"), "-o", str(alone), "-q", *args]) == 0
        files = _files(out / name)
        assert "info" in files and any(f.startswith("mesh/") for f in files)
        assert files == _files(alone)
    # and the layer opens: cloud-volume reads every label's mesh back
    layer = CloudVolume(f"precomputed://file://{out / 'a'}")
    labels = [1] if "--level" in options else sorted(set(np.unique(_labels(1)).tolist()) - {0})
    for label in labels:
        mesh = layer.mesh.get(label)[label]
        assert len(mesh.faces) > 0


def test_batch_layers_are_not_rewritten_unless_asked(tmp_path, volumes, capsys):
    out = tmp_path / "out"
    base = ["batch", str(volumes), "-r", "-o", str(out), "--labels", "--format", "precomputed"]
    assert main([*base, "--lods", "1"]) == 0
    before = _files(out)
    capsys.readouterr()
    summary = tmp_path / "summary.json"
    # the layers exist: each file fails in its row
    assert main([*base, "--lods", "1", "--summary", str(summary)]) == 1
    rows = json.loads(summary.read_text())
    rows = rows["files"] if isinstance(rows, dict) else rows
    assert [r["status"] for r in rows] == ["failed", "failed"]
    assert all("already exists" in r["message"] for r in rows)
    assert main([*base, "--lods", "1", "--skip-existing"]) == 0
    assert _files(out) == before
    assert main([*base, "--lods", "2", "--force"]) == 0
    assert _files(out) != before  # two levels of detail now


@pytest.mark.parametrize(
    "args, message",
    [
        (["--labels", "--lods", "2"], "--lods is an option of --format precomputed"),
        (["--labels", "--format", "precomputed", "--previews"], "leave out --previews"),
        (["--level", "1", "--level", "2", "--format", "precomputed"], "one precomputed layer"),
    ],
)
def test_batch_layer_mistakes_are_one_line_before_any_work(
    tmp_path, volumes, capsys, args, message
):
    out = tmp_path / "out"
    assert main(["batch", str(volumes), "-r", "-o", str(out), *args]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_a_batch_row_counts_the_level_0_a_layer_stores(tmp_path):
    """A cut level 0 can hold fewer triangles than the mesh (corners within a
    quantization step merge: a float gyroid in 64-voxel nodes): the batch's row
    counts what cloud-volume reads back, as convert's "wrote" line does."""
    folder = tmp_path / "in"
    folder.mkdir()
    n = 96
    z, y, x = (a * (2 * np.pi / 24) for a in np.ogrid[:n, :n, :n])
    gyroid = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    np.save(folder / "g.npy", np.ascontiguousarray(gyroid.T.astype(np.float32)))
    summary = tmp_path / "summary.json"
    args = ["--level", "0.2", "--format", "precomputed", "--lods", "1", "--fragment-size", "64"]
    out = tmp_path / "out"
    assert main(["batch", str(folder), "-o", str(out), "-q", *args, "--summary", str(summary)]) == 0
    assert main(["batch", str(folder), "-o", str(tmp_path / "ply"), "-q", "--level", "0.2"]) == 0
    rows = json.loads(summary.read_text())
    (row,) = rows["files"] if isinstance(rows, dict) else rows
    back = CloudVolume(f"precomputed://file://{out / 'g'}").mesh.get(1, lod=0)[1]
    extracted = trimesh.load(tmp_path / "ply" / "g.ply", process=False)
    assert row["cells"] == len(back.faces) < len(extracted.faces), row
