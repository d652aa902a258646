"""--close, the post-processing options of convert and batch, several levels (issue 12)."""

from __future__ import annotations

import nrrd
import numpy as np
import pytest
from conftest import SAMPLES, dataset
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert import check_mesh, extract, read_volume
from isoconvert.cli import main
from isoconvert.convert import convert, convert_levels
from isoconvert.errors import IsoconvertError, OutputError
from isoconvert.extract.blocks import Blocks
from isoconvert.meshfile import read_mesh
from isoconvert.post.cap import close_at_grid
from isoconvert.volume import Volume


def cut_ball(n=40, radius=15.0, centre=(5.0, 20.0, 36.0)) -> np.ndarray:
    """(n, n, n) float64, radius - |p - centre|: a ball cut by the x = 0 and z = n - 1 faces."""
    x, y, z = np.meshgrid(*(np.arange(n, dtype=float),) * 3, indexing="ij")
    return radius - np.sqrt((x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2)


def counted_volume(f: np.ndarray, level: float, spacing) -> float:
    """The positive samples' volume by the trapezoidal rule: a sample on a face
    of the grid stands for half a cell's volume, on a grid edge a quarter, at a
    corner an eighth (the part of its voxel inside the grid)."""
    weight = np.ones(f.shape)
    for axis, n in enumerate(f.shape):
        w = np.ones(n)
        w[[0, -1]] = 0.5
        weight *= w.reshape([-1 if a == axis else 1 for a in range(3)])
    return float(((f >= level) * weight).sum() * np.prod(spacing))


def closed_ok(mesh) -> dict:
    report = check_mesh(mesh).to_dict()
    assert report["checks"]["watertight"] and report["checks"]["manifold"]
    assert report["checks"]["oriented"] and report["checks"]["no-degenerate"]
    return report


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.5, 1.2, 2.0)])
def test_close_gives_a_watertight_mesh_with_the_voxel_counted_volume(spacing):
    f = cut_ball()
    volume = Volume(f, spacing=spacing, origin=(3.0, -4.0, 10.0))
    mesh = extract(volume, 0.0)
    assert check_mesh(mesh).to_dict()["problems"]["boundary_edges_on_domain_boundary"]["count"]
    closed = close_at_grid(mesh, volume, 0.0)
    closed_ok(closed)
    assert abs(closed.signed_volume() / counted_volume(f, 0.0, spacing) - 1) < 0.01
    # the surface is kept as it was; the cap lies exactly in the two cut faces
    assert np.array_equal(closed.vertices[: mesh.n_vertices], mesh.vertices)
    assert np.array_equal(closed.cells[: mesh.n_cells], mesh.cells)
    cap = np.unique(closed.cells[mesh.n_cells :])
    index = (closed.vertices[cap] - volume.origin) / np.asarray(spacing)
    on_face = np.isclose(index[:, 0], 0, atol=1e-9) | np.isclose(index[:, 2], 39, atol=1e-9)
    assert on_face.all()


def test_close_follows_flip_and_a_mirrored_grid():
    f = cut_ball()
    mirrored = Volume(f, direction=np.diag([1.0, -1.0, 1.0]))
    mesh = close_at_grid(extract(mirrored, 0.0), mirrored, 0.0)
    closed_ok(mesh)
    volume = mesh.signed_volume()
    assert volume > 0
    flipped = close_at_grid(extract(mirrored, 0.0, flip=True), mirrored, 0.0, flip=True)
    closed_ok(flipped)
    assert np.isclose(flipped.signed_volume(), -volume)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shape=st.tuples(st.integers(2, 7), st.integers(2, 7), st.integers(2, 7)),
    rule=st.sampled_from(["separate-positive", "separate-negative", "trilinear"]),
)
def test_closed_random_fields_are_watertight_manifold_and_oriented(seed, shape, rule):
    """Every cut of the grid's faces is capped, whatever the signs: the book's
    manifold and orientation properties carry over to the closed surface."""
    f = np.random.default_rng(seed).random(shape)
    if (f >= 0.5).all() or (f < 0.5).all():
        return  # no surface at this level: extraction refuses it (tested elsewhere)
    volume = Volume(f)
    mesh = extract(volume, 0.5, ambiguity=rule)
    closed = close_at_grid(mesh, volume, 0.5, ambiguity=rule)
    report = check_mesh(closed).to_dict()
    assert report["checks"]["watertight"] and report["checks"]["oriented"]
    assert report["problems"]["non_manifold_edges"]["count"] == 0
    # the enclosed volume is that of a region inside the grid
    assert 0 < closed.signed_volume() <= np.prod(np.array(shape) - 1) + 1e-9


def test_close_block_wise_equals_in_memory(tmp_path):
    f = cut_ball().astype(np.float32)
    path = tmp_path / "ball.nrrd"
    nrrd.write(str(path), f, {"spacings": [0.5, 0.5, 1.0]}, index_order="F")
    lazy = read_volume(path)
    assert lazy.grid is not None
    blocks = close_at_grid(extract(lazy, 0.0, blocks=Blocks(size=5)), lazy, 0.0)
    memory = Volume(f, spacing=(0.5, 0.5, 1.0))
    whole = close_at_grid(extract(memory, 0.0), memory, 0.0)
    assert np.array_equal(blocks.vertices, whole.vertices)
    assert np.array_equal(blocks.cells, whole.cells)


def test_close_on_a_real_scan_cut_by_the_field_of_view(tmp_path):
    """The engine block touches the grid's faces: --close makes it watertight."""
    src = dataset("engine_256x256x128_uint8.raw")
    out = tmp_path / "engine.ply"
    result = convert(src, out, 80.5, close=True)
    report = closed_ok(read_mesh(out))
    assert report["measures"]["volume"] > 0
    assert result.extracted is not None and result.extracted.n_cells < result.mesh.n_cells


def test_close_needs_cubes_and_surfaces(tmp_path, capsys):
    out = tmp_path / "t.ply"
    code = main(
        ["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(out), "-l", "127.5", "--close",
         "--method", "tetra"]
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "--close caps cubes surfaces" in err[0]
    code = main(
        ["convert", str(SAMPLES / "figure_2_4.nrrd"), "-o", str(tmp_path / "c.svg"), "-l",
         "5.5", "--smooth", "10"]
    )  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "squares gives contours" in err[0]
    assert not list(tmp_path.iterdir())


def test_require_applies_to_the_final_mesh(tmp_path, capsys):
    path = tmp_path / "ball.nrrd"
    nrrd.write(str(path), cut_ball().astype(np.float32), index_order="F")
    args = ["convert", str(path), "-l", "0", "--require", "no-holes,watertight", "--force"]
    assert main([*args, "-o", str(tmp_path / "open.ply")]) == 4
    assert "required check failed: watertight" in capsys.readouterr().err
    assert main([*args, "-o", str(tmp_path / "closed.ply"), "--close", "--report"]) == 0
    captured = capsys.readouterr()
    assert "post-processing changed:" in captured.err
    assert "watertight: FAIL -> PASS" in captured.err
    assert "boundary edges on the grid:" in captured.err
    # a report file keeps what post-processing changed, also with --quiet
    import json

    import jsonschema

    from isoconvert.report import SCHEMA_PATH

    out = tmp_path / "closed2.ply"
    for report in (tmp_path / "r.json", tmp_path / "r.txt"):
        assert main([*args, "-o", str(out), "--close", "--report", str(report), "-q"]) == 0
    data = json.loads((tmp_path / "r.json").read_text())
    jsonschema.validate(data, json.loads(SCHEMA_PATH.read_text()))
    assert "watertight: FAIL -> PASS" in data["post_processing"]["changed"]
    text = (tmp_path / "r.txt").read_text(encoding="utf-8")
    assert "post-processing changed:\n" in text and "  watertight: FAIL -> PASS" in text
    assert main(["check", str(out), "--report", str(tmp_path / "c.json"), "-q"]) == 0
    assert "post_processing" not in json.loads((tmp_path / "c.json").read_text())


def test_largest_and_min_size_from_the_command_line(tmp_path):
    import trimesh

    x, y, z = np.meshgrid(*(np.arange(30.0),) * 3, indexing="ij")
    big = 7.0 - np.sqrt((x - 10) ** 2 + (y - 12) ** 2 + (z - 14) ** 2)
    small = 3.0 - np.sqrt((x - 23) ** 2 + (y - 20) ** 2 + (z - 15) ** 2)
    src = tmp_path / "balls.nrrd"
    nrrd.write(str(src), np.maximum(big, small).astype(np.float32), index_order="F")
    out = tmp_path / "out.ply"
    whole = convert(src, tmp_path / "all.ply", 0.0).mesh
    parts = trimesh.Trimesh(whole.vertices, whole.cells, process=False).split(only_watertight=False)
    sizes = sorted(len(p.faces) for p in parts)
    assert len(sizes) == 2 and sizes[0] < sizes[1]
    args = ["convert", str(src), "-o", str(out), "-l", "0", "-q", "-f"]
    assert main([*args, "--largest"]) == 0
    kept = read_mesh(out)
    assert kept.n_cells == sizes[1]
    assert abs(kept.signed_volume() - 4 / 3 * np.pi * 7**3) < 0.05 * 4 / 3 * np.pi * 7**3
    assert main([*args, "--min-size", str(sizes[0])]) == 0
    assert read_mesh(out).n_cells == whole.n_cells
    assert main([*args, "--min-size", str(sizes[0] + 1)]) == 0
    assert read_mesh(out).n_cells == sizes[1]
    assert main([*args, "--keep", "2"]) == 0
    assert read_mesh(out).n_cells == whole.n_cells
    # the small ball encloses about 113, the big one about 1437 cubic units
    assert main([*args, "--min-volume", "500"]) == 0
    assert read_mesh(out).n_cells == sizes[1]
    assert main([*args, "--min-volume", "50"]) == 0
    assert read_mesh(out).n_cells == whole.n_cells


def test_smooth_and_decimate_from_the_command_line(tmp_path):
    pytest.importorskip("meshoptimizer")
    src = SAMPLES / "sphere.nrrd"
    raw = convert(src, tmp_path / "raw.ply", 127.5).mesh
    out = tmp_path / "s.ply"
    args = ["convert", str(src), "-o", str(out), "-l", "127.5", "-q"]
    assert main([*args, "--smooth", "30", "--decimate", "0.8"]) == 0
    done = read_mesh(out)
    assert abs(done.n_cells / raw.n_cells - 0.2) < 0.03
    assert abs(done.signed_volume() / raw.signed_volume() - 1) < 0.02
    closed_ok(done)


@pytest.mark.parametrize("bad", [["--decimate", "1.5"], ["--keep", "0"], ["--smooth", "-2"],
                                 ["--smooth", "5", "--smooth-method", "gauss"],
                                 ["--largest", "--keep", "2"], ["--max-error", "0"],
                                 ["--min-volume", "-1"]])  # fmt: skip
def test_bad_post_options_are_one_line_errors_before_the_work(tmp_path, capsys, bad):
    out = tmp_path / "s.ply"
    code = main(["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(out), "-l", "127.5", *bad])
    err = capsys.readouterr().err.strip().splitlines()
    assert code in (1, 2) and len(err) == 1 and "Traceback" not in err[0]
    assert not out.exists()


def test_several_levels_read_once_and_equal_single_runs(tmp_path, monkeypatch):
    src = dataset("engine_256x256x128_uint8.raw")
    from isoconvert.grid import RawGrid

    calls = {"whole": 0, "slabs": 0}
    whole, slab = RawGrid.__array__, RawGrid.read_zyx

    def count_whole(self, *args, **kwargs):
        calls["whole"] += 1
        return whole(self, *args, **kwargs)

    def count_slabs(self, *args, **kwargs):
        calls["slabs"] += 1
        return slab(self, *args, **kwargs)

    monkeypatch.setattr(RawGrid, "__array__", count_whole)
    monkeypatch.setattr(RawGrid, "read_zyx", count_slabs)
    results = convert_levels(src, tmp_path / "engine.ply", [80.5, 180.5])
    assert [r.output.name for r in results] == ["engine_level80.5.ply", "engine_level180.5.ply"]
    # the samples are taken from the file once, for both levels
    assert calls == {"whole": 1, "slabs": 0}
    for result, level in zip(results, (80.5, 180.5), strict=True):
        single = convert(src, tmp_path / f"single{level}.ply", level).mesh
        assert np.array_equal(read_mesh(result.output).cells, single.cells)
        assert np.array_equal(result.mesh.vertices, single.vertices)


def test_several_levels_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "s.ply"
    args = ["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(out)]
    assert main([*args, "-l", "100.5", "-l", "200.5"]) == 0
    written = capsys.readouterr().out
    assert "s_level100.5.ply" in written and "s_level200.5.ply" in written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s_level100.5.ply", "s_level200.5.ply"]
    with pytest.raises(OutputError, match="given twice"):
        convert_levels(SAMPLES / "sphere.nrrd", out, [100.5, 100.5])
    assert main([*args, "-l", "100.5", "-l", "100.5", "--force"]) == 1
    assert "given twice" in capsys.readouterr().err


def test_post_steps_refuse_contours():
    with pytest.raises(IsoconvertError, match="squares gives contours"):
        convert(SAMPLES / "figure_2_4.nrrd", "unused.svg", 5.5, smooth=10)


def test_batch_writes_one_mesh_per_level_like_convert(tmp_path, capsys):
    src = SAMPLES / "sphere.nrrd"
    out = tmp_path / "out"
    args = ["batch", str(src), "-o", str(out), "-l", "100.5", "-l", "200.5", "--smooth", "5"]
    assert main([*args, "-q"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["sphere_level100.5.ply", "sphere_level200.5.ply"]
    for level in (100.5, 200.5):
        single = convert(src, tmp_path / f"one{level}.ply", level, smooth=5).mesh
        read = read_mesh(out / f"sphere_level{level:g}.ply")
        assert np.array_equal(read.cells, single.cells)
        assert np.allclose(read.vertices, single.vertices, atol=1e-4)
    summary = tmp_path / "s.json"
    assert main([*args, "-q", "-f", "-l", "60.5", "--summary", str(summary)]) == 0
    import json

    rows = json.loads(summary.read_text())["files"]
    assert [r["level"] for r in rows] == [60.5, 100.5, 200.5]  # by level, not by text
    assert main(["batch", str(src), "-o", str(tmp_path / "o2"), "-l", "1", "-l", "1"]) == 1
    assert "given twice" in capsys.readouterr().err


def test_changed_lines_give_the_unit():
    from isoconvert.post.pipeline import changes

    before = {"measures": {"area": 10.0, "volume": 4.0, "unit": "mm"}, "checks": {}}
    after = {"measures": {"area": 9.0, "volume": 4.0, "unit": "mm"}, "checks": {}}
    assert changes(before, after) == ["area: 10 -> 9 mm² (-10.00%)"]
    del before["measures"]["unit"], after["measures"]["unit"]
    assert changes(before, after) == ["area: 10 -> 9 (-10.00%)"]
