"""Every mistake is one line on stderr: usage errors too, and outputs that cannot be created."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SAMPLES

from isoconvert.cli import main


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["convert", "x.raw", "-o", "y.ply", "-l", "1", "--smooth", "abc"], "Invalid value for"),
        (["--bogus"], "No such option: --bogus"),
        (["info", "-q"], "No such option: -q"),
        (["convert", "x.raw", "-l", "1"], "Missing option"),
    ],
)
def test_usage_errors_are_one_line_with_exit_code_2(capsys, args, says):
    code = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0] and "--help" in err[0]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_an_output_folder_that_refuses_files_fails_before_the_work(tmp_path, capsys):
    """Permissions say yes (root), yet nothing can be created in /proc: the
    report's name is refused before the mesh is written, not after."""
    mesh = tmp_path / "s.ply"
    args = ["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(mesh)]
    code = main([*args, "--report", "/proc/report.json"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "cannot create files in the folder /proc" in err[0]
    assert not mesh.exists()


@pytest.mark.parametrize("name", ["tête.obj", "s.stl", "s.glb"])
def test_a_mesh_given_for_a_volume_is_said_to_be_a_mesh(tmp_path, capsys, name):
    """A mesh file where convert wants a volume (one isoconvert wrote: its suffix
    no volume reader claims) is one line naming it a mesh and what reads meshes,
    not "cannot tell the format"; its format given with --input-format is read as
    that format, which then refuses it in its own words."""
    mesh = tmp_path / name
    assert (
        main(["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(mesh), "-q"]) == 0
    )
    capsys.readouterr()
    code = main(["convert", str(mesh), "-l", "1", "-o", str(tmp_path / "x.ply")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "a mesh file" in err[0] and "isoconvert check" in err[0]
    assert not (tmp_path / "x.ply").exists()
    code = main(
        ["convert", str(mesh), "--input-format", "raw", "-l", "1", "-o", str(tmp_path / "x.ply")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "a mesh file" not in err[0]
