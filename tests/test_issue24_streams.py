"""Issue 24, part 4: a stream output needs ``--format`` (one line otherwise), a
mesh piped to standard input is read with ``read_mesh("-", format=...)``
(convert piped into a reader), and ``-o -`` will be standard output (binary
formats too, messages on stderr) once cli.py tells it from ``--report -``."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import check_mesh, write_mesh
from isoconvert.atomic import output_stream
from isoconvert.errors import FormatError
from isoconvert.meshfile import read_mesh

SPHERE = str(SAMPLES / "sphere.nrrd")


def isoconvert(*args: str, cwd: Path, stdin: bytes | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "isoconvert", *args], cwd=cwd, input=stdin, capture_output=True
    )


def test_dash_is_standard_output():
    assert output_stream("-") == 1
    assert output_stream(Path("-")) == 1
    assert output_stream("./-") is None  # a file named "-" is still one, when spelled so


@pytest.mark.parametrize("fmt", ["ply", "stl", "obj", "vtu", "vtk"])
def test_convert_to_dash_writes_the_file_s_bytes_to_stdout(tmp_path, fmt):
    to_file = isoconvert("convert", SPHERE, "-l", "100.5", "-o", f"a.{fmt}", cwd=tmp_path)
    assert to_file.returncode == 0, to_file.stderr
    piped = isoconvert("convert", SPHERE, "-l", "100.5", "-o", "-", "--format", fmt, cwd=tmp_path)
    assert piped.returncode == 0, piped.stderr
    assert piped.stdout == (tmp_path / f"a.{fmt}").read_bytes()
    assert b"wrote" in piped.stderr  # every message on stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"a.{fmt}"]  # no file named "-"


@pytest.mark.parametrize("stream", ["/dev/stdout", "-"])
def test_a_stream_without_format_is_one_line_and_writes_nothing(tmp_path, stream):
    run = isoconvert("convert", SPHERE, "-l", "100.5", "-o", stream, cwd=tmp_path)
    assert run.returncode == 1 and run.stdout == b""
    err = run.stderr.decode()
    assert err.count("\n") == 1 and "give --format" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []
    # the formats it offers are those a stream can hold: a layer is a folder
    offered = err.rsplit("(", 1)[1].split(")")[0].split(", ")
    assert "ply" in offered and "precomputed" not in offered


def test_convert_piped_into_a_reader_gives_the_same_mesh_and_report(tmp_path):
    """``convert ... -o /dev/stdout --format ply | (read_mesh("-", format="ply"))``:
    what ``check - --format ply`` would read, once check has a --format option."""
    reader = (
        "import json, sys\n"
        "from isoconvert import check_mesh\n"
        "from isoconvert.meshfile import read_mesh\n"
        "mesh = read_mesh('-', format=sys.argv[1])\n"
        "report = check_mesh(mesh).to_dict()\n"
        "report.pop('source')\n"
        "print(json.dumps([mesh.n_vertices, mesh.n_cells, report]))\n"
    )
    for fmt in ("ply", "vtu"):
        convert = subprocess.Popen(
            [sys.executable, "-m", "isoconvert", "convert", SPHERE, "-l", "100.5"]
            + ["-o", "/dev/stdout"]
            + ["--format", fmt],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            cwd=tmp_path,
        )
        check = subprocess.run(
            [sys.executable, "-c", reader, fmt],
            stdin=convert.stdout,
            capture_output=True,
            text=True,
            cwd=tmp_path,
        )
        convert.stdout.close()
        assert convert.wait() == 0 and check.returncode == 0, check.stderr
        written = read_mesh(write_mesh_of_sphere(tmp_path, fmt))
        expected = check_mesh(written).to_dict()
        expected.pop("source")
        assert json.loads(check.stdout) == [written.n_vertices, written.n_cells, expected]


def write_mesh_of_sphere(folder: Path, fmt: str) -> Path:
    from isoconvert import extract, read_volume

    return write_mesh(extract(read_volume(SPHERE), 100.5), folder / f"ref.{fmt}", force=True)


def test_read_mesh_of_stdin_needs_a_format_and_some_bytes(monkeypatch):
    with pytest.raises(FormatError, match="give --format"):
        read_mesh("-")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"")))
    with pytest.raises(FormatError, match="standard input is empty"):
        read_mesh("-", format="ply")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(b"ply\nnonsense\n")))
    with pytest.raises(FormatError, match="not a readable PLY mesh|PLY"):
        read_mesh("-", format="ply")


def test_format_overrides_the_suffix(tmp_path):
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)
    meshio.write(tmp_path / "t.vtu", meshio.Mesh(corners, [("triangle", faces)]))
    (tmp_path / "t.vtu").rename(tmp_path / "t.dat")
    mesh = read_mesh(tmp_path / "t.dat", format="vtu")
    np.testing.assert_array_equal(mesh.cells, faces)
    with pytest.raises(FormatError, match="unknown mesh format 'xyz'"):
        read_mesh(tmp_path / "t.dat", format="xyz")


@pytest.mark.parametrize("fmt", ["ply", "stl", "vtu"])
def test_convert_piped_into_check_reads_standard_input(tmp_path, fmt):
    """`convert -o - | check - --format F`: the report of the piped mesh is the
    report of the same mesh written to a file."""
    command = [sys.executable, "-m", "isoconvert"]
    producer = subprocess.Popen(
        [*command, "convert", SPHERE, "-l", "100.5", "-o", "-", "--format", fmt],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        cwd=tmp_path,
    )
    piped = subprocess.run(
        [*command, "check", "-", "--format", fmt, "--json", "--require", "watertight"],
        stdin=producer.stdout,
        capture_output=True,
        cwd=tmp_path,
        check=False,
    )
    producer.stdout.close()
    assert producer.wait() == 0 and piped.returncode == 0, piped.stderr
    isoconvert("convert", SPHERE, "-l", "100.5", "-o", f"m.{fmt}", cwd=tmp_path)
    on_file = isoconvert("check", f"m.{fmt}", "--json", cwd=tmp_path)
    ours, theirs = json.loads(piped.stdout), json.loads(on_file.stdout)
    for report in (ours, theirs):
        report.pop("source", None)
    assert ours == theirs
