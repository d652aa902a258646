"""The command line: results, and one clear line for every kind of bad input."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES, ball

from isoconvert.cli import gather_multi_values, main

TORUS = str(SAMPLES / "torus_20x20x20_float32.raw")
SPHERE = str(SAMPLES / "sphere.nrrd")


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *needles):
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("isoconvert: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def assert_no_output(folder):
    assert not [p for p in folder.iterdir() if p.suffix in (".ply", ".stl", ".obj", ".part")]


def test_convert_writes_a_closed_mesh(tmp_path, capsys):
    out = tmp_path / "torus.ply"
    code, stdout, _ = run(capsys, "convert", TORUS, "--level", "3", "-o", out, "--flip")
    assert code == 0
    assert "wrote" in stdout and "triangles" in stdout
    mesh = trimesh.load(out, process=False)
    assert mesh.is_watertight and mesh.euler_number == 0 and mesh.volume > 0


def test_convert_stl_ascii_and_obj(tmp_path, capsys):
    for name, extra in (("s.stl", ["--ascii"]), ("s.obj", [])):
        code, _, _ = run(
            capsys, "convert", SPHERE, "--level", "127.5", "-o", tmp_path / name, *extra
        )
        assert code == 0
        # STL stores each triangle's corners: let trimesh merge them (process=True)
        merged = trimesh.load(tmp_path / name, process=name.endswith(".stl"), force="mesh")
        assert merged.is_watertight and merged.volume > 0


def test_level_auto_prints_the_otsu_value(tmp_path, capsys):
    code, _, err = run(capsys, "convert", SPHERE, "--level", "auto", "-o", tmp_path / "s.ply")
    assert code == 0 and "Otsu threshold" in err


def test_quiet_prints_nothing(tmp_path, capsys):
    code, out, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", tmp_path / "s.ply", "-q")
    assert code == 0 and out == "" and err == ""


def test_shape_spacing_origin_take_several_values(tmp_path, capsys):
    data = ball(10, 3.0).astype(np.float32)
    raw = tmp_path / "ball.dat"
    np.ascontiguousarray(data.T).tofile(raw)
    out = tmp_path / "b.obj"
    code, _, _ = run(
        capsys,
        "convert",
        raw,
        "--shape",
        10,
        10,
        10,
        "--dtype",
        "float32",
        "--spacing",
        2,
        2,
        2,
        "--origin",
        -10,
        0,
        0.5,
        "-l",
        0,
        "-o",
        out,
    )
    assert code == 0
    v = trimesh.load(out, process=False).vertices
    center = v.mean(axis=0)
    assert np.allclose(center, [-10 + 9, 9, 9.5], atol=0.2)
    assert gather_multi_values(["--shape", "4", "5", "6", "x.raw"]) == ["--shape", "4,5,6", "x.raw"]
    assert gather_multi_values(["--shape=4x5x6"]) == ["--shape=4x5x6"]


def test_info_text_and_json(capsys):
    code, out, _ = run(capsys, "info", SPHERE)
    assert code == 0
    assert "40 x 40 x 40" in out and "suggested levels: otsu" in out and "histogram" in out
    code, out, _ = run(capsys, "info", SPHERE, "--json")
    info = json.loads(out)
    assert info["shape"] == [40, 40, 40] and info["dtype"] == "uint8"
    assert info["min"] == 0 and info["max"] == 233
    assert info["min"] < info["suggested_levels"]["otsu"] < info["max"]


def test_formats_lists_the_registries(capsys):
    code, out, _ = run(capsys, "formats")
    assert code == 0
    for name in ("raw", "nrrd", "tiff", "ply", "obj", "stl", "cubes"):
        assert name in out


# --- bad input: one line, non-zero exit, no output ------------------------------


def test_missing_input(tmp_path, capsys):
    code, _, err = run(capsys, "convert", tmp_path / "nope.raw", "-l", 1, "-o", tmp_path / "o.ply")
    assert_one_line_error(code, err, "nope.raw", "no such file")
    assert_no_output(tmp_path)


def test_check_of_a_folder_says_it_is_a_folder(tmp_path, capsys):
    """check given a folder (a precomputed layer, say) says so, not "no such file"."""
    (tmp_path / "layer").mkdir()
    code, _, err = run(capsys, "check", tmp_path / "layer")
    assert_one_line_error(code, err, "layer is a folder, not a mesh file", ".ply")


def test_raw_size_mismatch(tmp_path, capsys):
    raw = tmp_path / "v.raw"
    raw.write_bytes(bytes(100))
    code, _, err = run(
        capsys,
        "convert",
        raw,
        "--shape",
        4,
        5,
        6,
        "--dtype",
        "uint8",
        "-l",
        1,
        "-o",
        tmp_path / "o.ply",
    )
    assert_one_line_error(code, err, "100 bytes", "needs 120", "--shape")
    assert_no_output(tmp_path)


def test_unknown_dtype(tmp_path, capsys):
    raw = tmp_path / "v.raw"
    raw.write_bytes(bytes(120))
    code, _, err = run(
        capsys,
        "convert",
        raw,
        "--shape",
        4,
        5,
        6,
        "--dtype",
        "float128",
        "-l",
        1,
        "-o",
        tmp_path / "o.ply",
    )
    assert_one_line_error(code, err, "float128", "uint8")
    assert_no_output(tmp_path)


@pytest.mark.parametrize(
    "level, where", [("300", "outside the data range"), ("0", "at the data's minimum"),
                     ("-5", "outside the data range")],
)  # fmt: skip
def test_level_outside_the_range_gives_the_range(tmp_path, capsys, level, where):
    """0 is the sphere's minimum: inside its range, but every sample is positive
    there (>= level), so the line says so rather than "outside"."""
    code, _, err = run(capsys, "convert", SPHERE, "-l", level, "-o", tmp_path / "o.ply")
    assert_one_line_error(code, err, where, "0 < level <= 233")
    assert_no_output(tmp_path)


def test_level_not_a_number(tmp_path, capsys):
    code, _, err = run(capsys, "convert", SPHERE, "-l", "high", "-o", tmp_path / "o.ply")
    # a word where a number goes: a command line that cannot be parsed, exit 2
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "'high'" in lines[0] and "auto" in lines[0]


def write_raw(tmp_path, data, name="v"):
    path = tmp_path / f"{name}_{'x'.join(map(str, data.shape))}_{data.dtype.name}.raw"
    np.ascontiguousarray(data.T).tofile(path)
    return path


def test_constant_volume_has_no_surface(tmp_path, capsys):
    raw = write_raw(tmp_path, np.full((4, 4, 4), 7, np.uint8))
    code, _, err = run(capsys, "convert", raw, "-l", 7, "-o", tmp_path / "o.ply")
    assert_one_line_error(code, err, "constant", "7")
    assert_no_output(tmp_path)


def test_nan_is_an_error_unless_nan_as(tmp_path, capsys):
    data = ball(8, 2.5).astype(np.float32)
    data[0, 0, 0] = np.nan
    data[1, 0, 0] = np.inf
    raw = write_raw(tmp_path, data)
    code, _, err = run(capsys, "convert", raw, "-l", 0, "-o", tmp_path / "o.ply")
    assert_one_line_error(code, err, "2 samples are NaN or infinite", "--nan-as")
    assert_no_output(tmp_path)
    code, _, _ = run(capsys, "convert", raw, "-l", 0, "-o", tmp_path / "o.ply", "--nan-as", -10)
    assert code == 0
    assert trimesh.load(tmp_path / "o.ply", process=False).is_watertight


def test_dimension_of_one(tmp_path, capsys):
    raw = write_raw(tmp_path, np.arange(20, dtype=np.uint8).reshape(4, 5, 1))
    code, _, err = run(capsys, "convert", raw, "-l", 5, "-o", tmp_path / "o.ply")
    assert_one_line_error(code, err, "(4, 5, 1)", "at least 2 samples")
    assert_no_output(tmp_path)


def test_2d_input_to_cubes_says_what_to_do(tmp_path, capsys):
    raw = write_raw(tmp_path, np.arange(20, dtype=np.uint8).reshape(4, 5))
    code, _, err = run(
        capsys, "convert", raw, "-l", 5, "-o", tmp_path / "o.ply", "--method", "cubes"
    )
    assert_one_line_error(code, err, "3D volume", "--method squares")
    assert_no_output(tmp_path)
    # without --method, a 2D image is contoured with squares
    assert run(capsys, "convert", raw, "-l", 5, "-o", tmp_path / "o.ply")[0] == 0


def test_unwritable_output_folder(tmp_path, capsys):
    # /proc refuses new files even to root
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", "/proc/isoconvert-test.ply")
    assert_one_line_error(code, err, "/proc/isoconvert-test.ply", "cannot")
    # a layer's folder there, and a report there: each says what to do, not "-o"
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "--format", "precomputed",
                       "-o", "/proc/isoconvert-layer")  # fmt: skip
    assert_one_line_error(code, err, "/proc/isoconvert-layer", "a folder you can write to")
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", tmp_path / "o.ply",
                       "--report", "/proc/isoconvert-r.json")  # fmt: skip
    assert_one_line_error(code, err, "/proc/isoconvert-r.json", "cannot")
    assert "-o" not in err.split("error: ", 1)[1] and not (tmp_path / "o.ply").exists()
    if os.geteuid() != 0:  # root ignores permission bits
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", locked / "o.ply")
        assert_one_line_error(code, err, "permission denied")


def test_missing_output_folder(tmp_path, capsys):
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", tmp_path / "a" / "o.ply")
    assert_one_line_error(code, err, "does not exist")


def test_unknown_output_extension_lists_formats(tmp_path, capsys):
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", tmp_path / "o.xyz")
    assert_one_line_error(code, err, "'.xyz'", "ply (.ply)", "obj (.obj)", "stl (.stl)")
    assert_no_output(tmp_path)


def test_existing_output_is_kept_without_force(tmp_path, capsys):
    out = tmp_path / "o.ply"
    out.write_bytes(b"precious")
    code, _, err = run(capsys, "convert", SPHERE, "-l", 127.5, "-o", out)
    assert_one_line_error(code, err, "already exists", "--force")
    assert out.read_bytes() == b"precious"
    assert run(capsys, "convert", SPHERE, "-l", 127.5, "-o", out, "--force")[0] == 0
    assert out.read_bytes().startswith(b"ply")


@pytest.mark.parametrize("force", [["--force"], []])
@pytest.mark.parametrize("what", ["mesh", "labels", "report"])
def test_output_equal_to_input(tmp_path, capsys, force, what):
    """Said the same with or without --force: "already exists; pass --force" would
    send the user to a flag that is then refused."""
    raw = write_raw(tmp_path, ball(6, 2).astype(np.uint8))
    args = {
        "mesh": ["-l", 0, "-o", raw, "--format", "ply"],
        "labels": ["--labels", "--single-file", "-o", raw, "--format", "ply"],
        "report": ["-l", 0, "-o", tmp_path / "o.ply", f"--report={raw}"],
    }[what]
    code, _, err = run(capsys, "convert", raw, *args, *force)
    assert_one_line_error(code, err, "is the input")
    assert raw.stat().st_size == 6**3
    assert not (tmp_path / "o.ply").exists()


def test_subprocess_no_traceback_and_debug_shows_one(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "isoconvert",
        "convert",
        str(tmp_path / "x.raw"),
        "-l",
        "1",
        "-o",
        str(tmp_path / "o.ply"),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    proc = subprocess.run(cmd + ["--debug"], capture_output=True, text=True)
    assert proc.returncode != 0 and "Traceback" in proc.stderr
    assert "InputNotFoundError" in proc.stderr


def test_help_and_info_do_not_import_numba():
    code = (
        f"import sys; from isoconvert.cli import main; main(['info', {SPHERE!r}]); "
        "assert 'numba' not in sys.modules, 'numba imported'"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_the_runs_time_is_said_once_for_many_meshes(tmp_path, capsys):
    """One line per mesh written, then the run's time once: on every line it read as
    each file's own time."""
    labels = np.zeros((12, 10, 8), np.uint8)
    labels[1:5, 1:5, 1:5], labels[6:10, 2:8, 2:6], labels[2:4, 6:9, 5:7] = 1, 2, 3
    np.save(tmp_path / "l.npy", labels)
    code, out, _ = run(capsys, "convert", tmp_path / "l.npy", "--labels", "-o", tmp_path / "l.ply")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == 4
    assert [line.split(":")[0] for line in lines[:3]] == [
        f"wrote {tmp_path / f'l_label{n}.ply'}" for n in (1, 2, 3)
    ]
    assert all(line.endswith(f"(label {n})") for n, line in zip((1, 2, 3), lines, strict=False))
    assert re.fullmatch(r"3 meshes written in \d+\.\d\d s", lines[3])
    one = ["convert", tmp_path / "l.npy", "--label", "2", "-o", tmp_path / "2.ply"]
    code, out, _ = run(capsys, *one)
    assert code == 0 and re.search(r"\(label 2, \d+\.\d\d s\)$", out.strip())
