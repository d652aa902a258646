"""Batch conversion: discovery, names, level mappings, resuming, workers, summaries."""

from __future__ import annotations

import csv
import json
import os

import nrrd
import numpy as np
import pytest
import tifffile
import trimesh

from isoconvert.batch import discover, read_mapping
from isoconvert.cli import EXIT_CHECK_FAILED, main
from isoconvert.errors import IsoconvertError


def ball(n=10, r=3.0):
    x, y, z = np.mgrid[:n, :n, :n]
    c = (n - 1) / 2
    return (r - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)


@pytest.fixture
def tree(tmp_path):
    """in/ with a raw file, a TIFF slice folder, a detached NRRD, a note, a sub-folder
    and a symbolic link back to the top."""
    root = tmp_path / "in"
    (root / "slices").mkdir(parents=True)
    (root / "sub").mkdir()
    data = ball()  # (x, y, z) symmetric, so order does not matter here
    np.ascontiguousarray(data.T).tofile(root / "ball_10x10x10_float32.raw")
    for k in range(10):
        tifffile.imwrite(root / "slices" / f"img{k}.tif", data[:, :, k].T)
    nrrd.write(
        str(root / "head.nhdr"), data, {"encoding": "raw"}, detached_header=True, index_order="F"
    )
    (root / "notes.txt").write_text("not a volume")
    np.ascontiguousarray(data.T).tofile(root / "sub" / "deep_10x10x10_float32.raw")
    os.symlink("..", root / "sub" / "loop")
    return root


def test_discovery_counts_stacks_and_headers_once(tree):
    # without --recursive only the folder's own files count
    found, skipped = discover([str(tree)], recursive=False)
    names = sorted(str(f.relative) for f in found)
    assert names == ["ball_10x10x10_float32.raw", "head.nhdr"]  # head.raw belongs to head.nhdr
    assert [s.path for s in skipped] == [str(tree / "notes.txt")]
    # a folder of slices named as an input is one volume
    found, _ = discover([str(tree / "slices")])
    assert [str(f.relative) for f in found] == ["slices"]


def test_recursive_discovery_survives_a_symlink_loop(tree):
    found, skipped = discover([str(tree)], recursive=True)
    names = sorted(str(f.relative) for f in found)
    assert names == [
        "ball_10x10x10_float32.raw",
        "head.nhdr",
        "slices",
        "sub/deep_10x10x10_float32.raw",
    ]
    assert any("already searched" in s.reason for s in skipped)


def test_a_layer_folder_met_while_searching_is_one_skipped_entry(tree):
    """A Neuroglancer layer an earlier run wrote into an input folder (batch -o
    given the input folder) is one skipped entry saying what it is, not a row for
    each of its files, and its files are never taken for volumes; a folder with
    an info file that is not a layer's is searched as before."""
    from isoconvert.batch import LAYER_REASON

    layer = tree / "sub" / "atlas"
    (layer / "mesh").mkdir(parents=True)
    (layer / "info").write_text(json.dumps({"@type": "neuroglancer_multiscale_volume"}))
    (layer / "mesh" / "info").write_text("{}")
    (layer / "mesh" / "3.index").write_bytes(b"\0" * 12)
    other = tree / "notes"
    other.mkdir()
    (other / "info").write_text("just notes")
    found, skipped = discover([str(tree)], recursive=True)
    assert not [f for f in found if "atlas" in str(f.relative)]
    mine = [s for s in skipped if "atlas" in s.path]
    assert [(s.path, s.reason, s.files) for s in mine] == [(str(layer), LAYER_REASON, 3)]
    assert str(other / "info") in [s.path for s in skipped]
    # not searching sub-folders, nothing is said of them
    _, skipped = discover([str(tree)], recursive=False)
    assert not [s for s in skipped if "atlas" in s.path or "notes/" in s.path]


def test_glob_and_missing_inputs(tree):
    found, _ = discover([str(tree / "*.raw")])
    assert [f.relative.name for f in found] == ["ball_10x10x10_float32.raw"]
    with pytest.raises(IsoconvertError, match="matches nothing"):
        discover([str(tree / "*.nothing")])
    with pytest.raises(IsoconvertError, match="no such file"):
        discover([str(tree / "absent")])


def test_batch_mirrors_names_and_writes_a_summary(tree, tmp_path, capsys):
    out = tmp_path / "out"
    summary = tmp_path / "summary.csv"
    code = main(
        [
            "batch",
            str(tree),
            "-o",
            str(out),
            "-l",
            "0.5",
            "-r",
            "--summary",
            str(summary),
            "--require",
            "watertight",
            "-j",
            "1",
        ]
    )
    assert code == 0
    made = sorted(str(p.relative_to(out)) for p in out.rglob("*.ply"))
    assert made == [
        "ball_10x10x10_float32.ply",
        "head.ply",
        "slices.ply",
        "sub/deep_10x10x10_float32.ply",
    ]
    for p in out.rglob("*.ply"):
        assert trimesh.load(p, process=False).is_watertight
    rows = list(csv.DictReader(summary.open()))
    statuses = {os.path.basename(r["input"]): r["status"] for r in rows}
    assert statuses["notes.txt"] == statuses["loop"] == "skipped"
    assert all(v == "ok" for k, v in statuses.items() if k not in ("notes.txt", "loop"))
    assert all(r["checks"] == "watertight=pass" for r in rows if r["status"] == "ok")
    table = capsys.readouterr().out
    assert "4 ok" in table and "2 skipped" in table


def test_one_failure_never_stops_the_others(tree, tmp_path, capsys):
    (tree / "broken.nrrd").write_bytes(b"NRRD0004\ngarbage")
    out = tmp_path / "out"
    summary = tmp_path / "s.json"
    code = main(
        ["batch", str(tree), "-o", str(out), "-l", "0.5", "--summary", str(summary), "-j", "1"]
    )
    assert code == 1
    data = json.loads(summary.read_text())
    assert data["totals"]["failed"] == 1 and data["totals"]["ok"] == 2
    (failed,) = [f for f in data["files"] if f["status"] == "failed"]
    assert failed["input"].endswith("broken.nrrd") and "broken.nrrd" in failed["message"]
    assert "broken.nrrd" in capsys.readouterr().err


def test_require_failure_gives_exit_code_4(tree, tmp_path):
    cut = ball(10, 6.0)  # a ball bigger than the grid: its surface is cut open
    np.ascontiguousarray(cut.T).tofile(tmp_path / "cut_10x10x10_float32.raw")
    code = main(
        [
            "batch",
            str(tmp_path / "cut_10x10x10_float32.raw"),
            "-o",
            str(tmp_path / "o2"),
            "-l",
            "0.5",
            "--require",
            "watertight",
        ]
    )
    assert code == EXIT_CHECK_FAILED


def test_skip_existing_resumes_and_force_is_needed_to_overwrite(tree, tmp_path):
    out = tmp_path / "out"
    args = ["batch", str(tree), "-o", str(out), "-l", "0.5", "-j", "1"]
    assert main(args) == 0
    first = {p.name: p.stat().st_mtime_ns for p in out.glob("*.ply")}
    (out / "head.ply").unlink()  # as if the first run had stopped before it
    summary = tmp_path / "s.json"
    assert main([*args, "--skip-existing", "--summary", str(summary)]) == 0
    statuses = {
        os.path.basename(f["input"]): f["status"] for f in json.loads(summary.read_text())["files"]
    }
    assert statuses["head.nhdr"] == "ok"
    assert statuses["ball_10x10x10_float32.raw"] == "skipped"
    for name, mtime in first.items():
        if name != "head.ply":
            assert (out / name).stat().st_mtime_ns == mtime
    # without --force or --skip-existing, existing outputs are failures, kept intact
    assert main(args) == 1
    assert all((out / n).stat().st_mtime_ns == m for n, m in first.items() if n != "head.ply")


def test_level_mapping_toml_and_csv(tmp_path):
    raw = tmp_path / "in" / "scan.dat"  # no layout in the name: the mapping gives it
    raw.parent.mkdir()
    np.ascontiguousarray(ball().T).tofile(raw)
    toml = tmp_path / "levels.toml"
    toml.write_text(
        '[[volume]]\npattern = "scan*"\nlevel = 0.5\nshape = [10, 10, 10]\n'
        'dtype = "float32"\nflip = true\n'
    )
    out = tmp_path / "out"
    assert main(["batch", str(raw.parent), "-o", str(out), "--levels", str(toml)]) == 0
    mesh = trimesh.load(out / "scan.ply", process=False)
    assert mesh.volume < 0  # flipped
    table = tmp_path / "levels.csv"
    table.write_text("pattern,level,shape,dtype\nscan.dat,1.5,10x10x10,float32\n")
    assert main(["batch", str(raw.parent), "-o", str(out), "--levels", str(table), "--force"]) == 0
    smaller = trimesh.load(out / "scan.ply", process=False)
    assert len(smaller.faces) < len(mesh.faces)
    rules = read_mapping(table)
    assert rules[0].options == {"shape": (10, 10, 10), "dtype": "float32"}
    bad = tmp_path / "bad.toml"
    bad.write_text('[[volume]]\npattern = "x"\ncolour = "red"\n')
    with pytest.raises(IsoconvertError, match="unknown key"):
        read_mapping(bad)


def test_worker_processes_give_the_same_files(tree, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["batch", str(tree), "-o", str(one), "-l", "0.5", "-j", "1", "-q"]) == 0
    assert (
        main(
            ["batch", str(tree), "-o", str(two), "-l", "0.5", "-j", "2", "-q", "--max-memory", "1K"]
        )
        == 0
    )  # a budget below every estimate: one at a time
    for p in one.glob("*.ply"):
        assert (two / p.name).read_bytes() == p.read_bytes()


def test_batch_needs_a_level_and_a_good_summary_name(tree, tmp_path, capsys):
    assert main(["batch", str(tree), "-o", str(tmp_path / "o")]) == 1
    assert "--level" in capsys.readouterr().err
    assert (
        main(
            [
                "batch",
                str(tree),
                "-o",
                str(tmp_path / "o"),
                "-l",
                "1",
                "--summary",
                str(tmp_path / "s.txt"),
            ]
        )
        == 1
    )
    assert ".json or .csv" in capsys.readouterr().err


def test_global_raw_options_apply_to_raw_files_only(tree, tmp_path):
    plain = tmp_path / "mixed"
    plain.mkdir()
    np.ascontiguousarray(ball().T).tofile(plain / "scan.dat")  # no layout in the name
    nrrd.write(str(plain / "other.nrrd"), ball(), index_order="F")
    out = tmp_path / "out"
    code = main(
        [
            "batch",
            str(plain),
            "-o",
            str(out),
            "-l",
            "0.5",
            "--shape",
            "10",
            "10",
            "10",
            "--dtype",
            "float32",
            "-q",
        ]
    )
    assert code == 0
    assert sorted(p.name for p in out.glob("*.ply")) == ["other.ply", "scan.ply"]


DYING_PLUGIN = '''
import os
from isoconvert.extract.cubes import marching_cubes


def run(volume, level, **kw):
    """Marching Cubes, except that it kills its process on 7-wide volumes."""
    if volume.shape[0] == 7:
        os._exit(3)
    return marching_cubes(volume, level, **kw)
'''


def test_a_dying_worker_fails_only_its_file(tmp_path, monkeypatch):
    from isoconvert import EXTRACTORS

    (tmp_path / "dying.py").write_text(DYING_PLUGIN)
    dist = tmp_path / "dying-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: dying\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[isoconvert.extractors]\ndying = dying:run\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # spawned workers get the parent's sys.path
    EXTRACTORS.reload_plugins()
    try:
        inputs = tmp_path / "in"
        inputs.mkdir()
        for n in (7, 10, 11, 12):
            np.ascontiguousarray(ball(n).T).tofile(inputs / f"b{n}_{n}x{n}x{n}_float32.raw")
        summary = tmp_path / "s.json"
        code = main(
            [
                "batch",
                str(inputs),
                "-o",
                str(tmp_path / "out"),
                "-l",
                "0.5",
                "--method",
                "dying",
                "-j",
                "2",
                "-q",
                "--summary",
                str(summary),
            ]
        )
        assert code == 1
        rows = {os.path.basename(r["input"]): r for r in json.loads(summary.read_text())["files"]}
        assert rows["b7_7x7x7_float32.raw"]["status"] == "failed"
        assert "worker process died" in rows["b7_7x7x7_float32.raw"]["message"]
        # files running beside it when it died are run again alone: all convert
        ok = sorted(k for k, r in rows.items() if r["status"] == "ok")
        assert ok == [
            "b10_10x10x10_float32.raw",
            "b11_11x11x11_float32.raw",
            "b12_12x12x12_float32.raw",
        ]
        for name in ok:
            assert (tmp_path / "out" / name.replace(".raw", ".ply")).exists()
    finally:
        monkeypatch.undo()
        EXTRACTORS.reload_plugins()


def test_table_collapses_many_skipped_files_of_one_kind(tree, tmp_path, capsys):
    for n in range(5):  # files of one unknown kind (.dcm was one until DICOM was read)
        (tree / f"slice{n}.xyz").write_bytes(b"DICM")
    json_summary = tmp_path / "s.json"
    main(
        [
            "batch",
            str(tree),
            "-o",
            str(tmp_path / "o"),
            "-l",
            "0.5",
            "-j",
            "1",
            "--summary",
            str(json_summary),
        ]
    )
    table = capsys.readouterr().out
    assert "*.xyz (5 files)" in table and "slice3.xyz" not in table
    # the summary file keeps every file
    files = [f["input"] for f in json.loads(json_summary.read_text())["files"]]
    assert sum(f.endswith(".xyz") for f in files) == 5


def test_quiet_batch_still_prints_its_failures(tmp_path, capsys):
    """--quiet prints only errors: a failed file is one, and says so."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    np.zeros((4, 4, 4), dtype=np.uint8).tofile(inputs / "flat_4x4x4_uint8.raw")
    np.arange(64, dtype=np.uint8).tofile(inputs / "ramp_4x4x4_uint8.raw")
    code = main(["batch", str(inputs), "-o", str(tmp_path / "out"), "-l", "10.5", "-q", "-j", "1"])
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "flat_4x4x4_uint8.raw" in lines[0] and "constant" in lines[0]
