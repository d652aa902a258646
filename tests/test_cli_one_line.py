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
