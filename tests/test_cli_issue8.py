"""What a new user hit (issue 8), through the command line: special output
files, output folders, --nan-as, integer levels, flags in help."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
from conftest import SAMPLES
from test_cli import assert_one_line_error, run

from isoconvert.cli import main

SPHERE = str(SAMPLES / "sphere.nrrd")


def test_output_onto_a_fifo_is_refused_and_the_fifo_stays(tmp_path, capsys):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    code, _, err = run(
        capsys, "convert", SPHERE, "-l", "127.5", "-o", fifo, "--format", "ply", "--force"
    )
    # writing would block until something reads it: standard output is the way
    assert_one_line_error(code, err, "named pipe", "/dev/stdout")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_output_onto_dev_null_is_written_in_place(capsys):
    before = os.stat("/dev/null")
    code, _, err = run(
        capsys, "convert", SPHERE, "-l", "127.5", "-o", "/dev/null", "--format", "ply", "--force"
    )
    assert code == 0, err
    after = os.stat("/dev/null")  # the device node itself is never replaced
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


def test_report_onto_a_fifo_is_refused(tmp_path, capsys):
    fifo = tmp_path / "report.json"
    os.mkfifo(fifo)
    out = tmp_path / "s.ply"
    code, _, err = run(
        capsys, "convert", SPHERE, "-l", "127.5", "-o", out, "--report", fifo, "--force"
    )
    assert code == 1 and "named pipe" in err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_output_folder_is_called_a_folder(tmp_path, capsys):
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", tmp_path)
    assert_one_line_error(code, err, "is a folder")
    assert "extension" not in err


@pytest.mark.parametrize("value", ["nan", "-inf", "inf"])
def test_nan_as_takes_a_finite_number(tmp_path, capsys, value):
    raw = tmp_path / "nan_4x4x4_float32.raw"
    data = np.zeros((4, 4, 4), np.float32)
    data[1:3, 1:3, 1:3] = 2
    data[0, 0, 0] = np.nan
    data.tofile(raw)
    out = tmp_path / "o.ply"
    code, _, err = run(capsys, "convert", raw, "-l", "1", "-o", out, "--nan-as", value)
    assert_one_line_error(code, err, "--nan-as takes a finite number")
    assert not out.exists()


def test_integer_level_says_how_many_samples_equal_it(tmp_path, capsys):
    out = tmp_path / "s.ply"
    code, _, err = run(capsys, "convert", SPHERE, "-l", "128", "-o", out, "--report", "-q")
    assert code == 0
    code, stdout, err = run(capsys, "convert", SPHERE, "-l", "128", "-o", out, "--force")
    assert code == 0
    from isoconvert import read_volume

    equal = int(np.count_nonzero(read_volume(SPHERE).data == 128))
    assert equal > 0
    assert f"level 128 equals {equal:,} samples" in err
    code, _, err = run(
        capsys, "convert", SPHERE, "-l", "128", "-o", out, "--force", "--exact-placement"
    )
    assert code == 0
    assert "--level 127.5" in err


def test_exact_placement_and_no_degenerate_contradict(tmp_path, capsys):
    code = main(
        [
            "convert",
            SPHERE,
            "-l",
            "128",
            "-o",
            str(tmp_path / "s.ply"),
            "--exact-placement",
            "--no-degenerate",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and "contradict" in err


def test_integer_level_report_is_clean_by_default(tmp_path, capsys):
    out = tmp_path / "s.ply"
    code, _, err = run(
        capsys,
        "convert",
        SPHERE,
        "-l",
        "128",
        "-o",
        out,
        "--require",
        "watertight,manifold,no-zero-length,no-degenerate",
    )
    assert code == 0, err
    code, _, err = run(
        capsys,
        "convert",
        SPHERE,
        "-l",
        "128",
        "-o",
        out,
        "--force",
        "--exact-placement",
        "--require",
        "no-zero-length",
    )
    assert code == 4


@pytest.mark.parametrize("command", ["convert", "check", "batch", "info"])
def test_help_shows_flags_as_flags(capsys, command, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    code = main([command, "--help"])
    out = capsys.readouterr().out
    assert code == 0
    flags = ("--quiet", "--force", "--json", "--ascii", "--help")
    flag_lines = [line for line in out.splitlines() if any(f in line for f in flags)]
    assert flag_lines
    assert not any("<bool>" in line for line in flag_lines), flag_lines
    if command in ("convert", "batch", "info", "check"):
        shape = next(line for line in out.splitlines() if "--shape" in line)
        assert "(and z)" in shape  # not eaten as rich markup, as "[z]" was


def test_check_grid_judges_holes_against_the_volume_grid(tmp_path, capsys):
    """FLAIR's oblique grid, cut at z index 60 so the surface meets the grid's
    boundary: in an STL (which records no grid) those boundary edges look like
    holes against the bounding box; `check --grid VOLUME` knows better, and
    agrees with `convert --report`."""
    import nrrd
    from conftest import dataset

    data, header = nrrd.read(str(dataset("FLAIR.nrrd")), index_order="F")
    cut = tmp_path / "flair_cut.nrrd"
    origin = header["space origin"] + 60 * header["space directions"][2]
    nrrd.write(
        str(cut),
        data[:, :, 60:],
        {
            "space": header["space"],
            "space directions": header["space directions"],
            "space origin": origin,
        },
        index_order="F",
    )
    out = tmp_path / "flair.stl"
    code, _, err = run(
        capsys, "convert", cut, "-l", "60.5", "-o", out, "--require", "no-holes", "-q"
    )
    assert code == 0, err
    code, stdout, _ = run(capsys, "check", out, "--require", "no-holes")
    assert code == 4
    assert "--grid" in stdout  # the bounding-box fallback is said
    code, stdout, err = run(capsys, "check", out, "--grid", cut, "--require", "no-holes")
    assert code == 0, err
    assert "bounding box" not in stdout


@pytest.mark.parametrize("suffix", ["ply", "obj", "stl"])
@pytest.mark.parametrize(
    ("volume", "args"),
    [
        # vertices very close to grid vertices: float32 merges them
        ("hydrogen_vtk_64x64x64_float32.raw", ["-l", "0.001"]),
        # scanner-sized coordinates: float32 steps of 0.5
        ("sphere.nrrd", ["-l", "127.5", "--origin", "5000000", "5000000", "0"]),
    ],
)
def test_convert_report_and_check_of_the_file_agree(tmp_path, capsys, suffix, volume, args):
    import json

    from conftest import dataset

    source = SAMPLES / volume if (SAMPLES / volume).exists() else dataset(volume)
    out = tmp_path / f"mesh.{suffix}"
    written = tmp_path / "convert.json"
    code, _, convert_err = run(capsys, "convert", source, *args, "-o", out, "--report", written)
    assert code == 0, convert_err
    grid = ["--grid", source, *args[2:]] if suffix == "stl" else []
    code, stdout, err = run(capsys, "check", out, "--json", *grid)
    assert code == 0, err
    from_convert = json.loads(written.read_text())
    from_check = json.loads(stdout)
    from_convert.pop("source"), from_check.pop("source")
    assert from_convert == from_check
    if suffix == "stl":  # float32 only: the loss is said, and the report shows it
        assert "STL stores float32" in convert_err
        assert from_check["problems"]["zero_length_edges"]["count"] > 0
    else:  # PLY switches to doubles, OBJ is exact: nothing is lost
        assert from_check["problems"]["zero_length_edges"]["count"] == 0
        assert from_check["problems"]["degenerate_triangles"]["count"] == 0


def test_info_and_auto_level_on_values_near_the_largest_doubles(tmp_path, capsys):
    raw = tmp_path / "huge_6x6x6_float64.raw"
    data = np.full((6, 6, 6), -1.7e308)
    data[2:4, 2:4, 2:4] = 1.7e308
    data.tofile(raw)
    code, stdout, err = run(capsys, "info", raw)
    assert code == 0, err
    import re

    assert not re.search(r"(?<![\w/])-?(inf|nan)\b", stdout, re.IGNORECASE), stdout
    assert "Traceback" not in err and "Warning" not in err
    out = tmp_path / "huge.ply"
    code, _, err = run(capsys, "convert", raw, "-l", "auto", "-o", out, "--report", "-q")
    assert code == 0, err
    import trimesh

    mesh = trimesh.load(out, process=False)
    assert mesh.is_watertight and np.isfinite(mesh.vertices).all()


def test_a_bad_report_name_fails_before_the_mesh_is_written(tmp_path, capsys):
    out = tmp_path / "s.ply"
    fifo = tmp_path / "report.txt"
    os.mkfifo(fifo)
    code, _, err = run(
        capsys, "convert", SPHERE, "-l", "127.5", "-o", out, f"--report={fifo}", "--force"
    )
    assert_one_line_error(code, err, str(fifo), "named pipe")
    assert not out.exists()


def test_batch_summary_that_is_not_a_regular_file(tmp_path, capsys):
    batch = ["batch", SPHERE, "-o", tmp_path / "out", "-l", "127.5", "--force", "--summary"]
    code, _, err = run(capsys, *batch, "/dev/null")
    assert_one_line_error(code, err, "/dev/null", ".json or .csv")
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    code, _, err = run(capsys, *batch, fifo)
    assert_one_line_error(code, err, "named pipe")
    assert not (tmp_path / "out").exists()


def test_a_glob_of_dicom_files_is_named_as_dicom(tmp_path, capsys):
    for n in range(3):
        (tmp_path / f"{n:06d}.dcm").write_bytes(bytes(128) + b"DICM" + bytes(64))
    code, _, err = run(capsys, "convert", f"{tmp_path}/*.dcm", "-l", "1", "-o", tmp_path / "o.ply")
    # read by the dicom reader: the magic alone, without a header, is no DICOM image
    assert_one_line_error(code, err, "no DICOM image files among the files")


def test_format_that_contradicts_the_extension_is_said(tmp_path, capsys):
    import trimesh

    out = tmp_path / "s.stl"
    code, _, err = run(capsys, "convert", SPHERE, "-l", "127.5", "-o", out, "--format", "ply")
    assert code == 0, err
    assert "writing ply into" in err and "extension says stl" in err
    assert len(trimesh.load(out, file_type="ply", process=False).faces) > 0


@pytest.mark.parametrize("command", ["info", "convert", "check-grid", "batch"])
def test_data_outside_the_header_folder_needs_the_flag_everywhere(tmp_path, capsys, command):
    """A detached header naming ../secret.raw: refused by every command that
    reads volumes, each of which offers --allow-outside-data."""
    data = np.zeros((4, 4, 4), np.uint8)
    data[1:3, 1:3, 1:3] = 200
    (tmp_path / "secret.raw").write_bytes(data.tobytes())
    inner = tmp_path / "headers"
    inner.mkdir()
    header = inner / "scan.nhdr"
    header.write_text(
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: raw\n"
        "data file: ../secret.raw\n"
    )
    out = tmp_path / "out"
    out.mkdir()
    args = {
        "info": ["info", header],
        "convert": ["convert", header, "-l", "100", "-o", out / "s.ply"],
        "check-grid": ["check", SAMPLES / "figure_2_4.nrrd", "--grid", header],
        "batch": ["batch", header, "-l", "100", "-o", out / "b"],
    }[command]
    if command == "check-grid":  # check needs a mesh: make one first
        mesh = out / "m.ply"
        assert run(capsys, "convert", SPHERE, "-l", "127.5", "-o", mesh)[0] == 0
        args = ["check", mesh, "--grid", header]
    code, stdout, err = run(capsys, *args)
    assert code == 1
    assert "outside the header's folder" in err + stdout
    code, stdout, err = run(capsys, *args, "--allow-outside-data")
    assert code == 0, err


def test_the_old_warmup_command_says_it_has_nothing_to_do(capsys):
    """CI scripts written when numba compiled on first use keep running."""
    assert main(["warmup"]) == 0
    assert "nothing to do" in capsys.readouterr().err
    assert main(["--help"]) == 0
    assert "warmup" not in capsys.readouterr().out
