"""batch converts every image series of a DICOM folder, as dcm2niix does."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_readers_dicom import write_series, write_slice, zyx_data

from isoconvert import extract, read_volume
from isoconvert.cli import main
from isoconvert.meshfile import read_mesh

pytest.importorskip("pydicom")

LEVEL = 150.5


def study(tmp_path, numbers=(3, 7, 1)):
    """A folder ``study/scan`` of three series: 3 and 4 slices, and a lone localizer."""
    folder = tmp_path / "study" / "scan"
    write_series(folder, zyx_data(nz=3), series="1.2.3.1", description="lung", number=numbers[0])
    tall = zyx_data(nz=4) + 7
    for k in range(4):
        write_slice(folder / f"B{k}", tall[k], (0, 0, 2 * k), series="1.2.3.2", number=numbers[1])
    write_slice(folder / "LOC", zyx_data(nz=1)[0], (0, 0, 0), series="1.2.3.9", number=numbers[2])
    return folder


def test_each_series_is_one_mesh(tmp_path, capsys):
    folder = study(tmp_path)
    out, summary = tmp_path / "out", tmp_path / "summary.json"
    args = ["batch", str(tmp_path / "study"), "-r", "-o", str(out), "-l", str(LEVEL)]
    assert main([*args, "--summary", str(summary)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["scan_series3.ply", "scan_series7.ply"]
    for uid, name in (("1.2.3.1", "scan_series3.ply"), ("1.2.3.2", "scan_series7.ply")):
        expected = extract(read_volume(folder, series=uid), LEVEL)
        written = read_mesh(out / name)
        assert written.n_cells == expected.n_cells > 0
        np.testing.assert_allclose(written.vertices, expected.vertices, rtol=1e-6)
    rows = {r["input"]: r for r in json.loads(summary.read_text())["files"]}
    assert rows[f"{folder} (series 3)"]["status"] == "ok"
    assert rows[f"{folder} (series 7)"]["status"] == "ok"
    lone = rows[f"{folder} (series 1)"]
    assert lone["status"] == "skipped" and "not a volume" in lone["message"]
    # each mesh says which series it came from
    header = (out / "scan_series7.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"comment source {folder} (series 1.2.3.2)\n" in header


def test_repeated_series_numbers_name_the_meshes_by_uid(tmp_path):
    study(tmp_path, numbers=(5, 5, 5))
    out = tmp_path / "out"
    args = ["batch", str(tmp_path / "study"), "-r", "-o", str(out), "-l", str(LEVEL), "-q"]
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["scan_1-2-3-1.ply", "scan_1-2-3-2.ply"]


def test_convert_still_asks_which_series(tmp_path, capsys):
    folder = study(tmp_path)
    code = main(["convert", str(folder), "-l", str(LEVEL), "-o", str(tmp_path / "x.ply")])
    err = capsys.readouterr().err
    assert code != 0 and "--series UID" in err and len(err.strip().splitlines()) == 1
    assert err.count(str(folder)) == 1 and "(synthetic, 1 slice)" in err
    assert not (tmp_path / "x.ply").exists()
    # the localizer alone is refused in one line that says why
    args = ["convert", str(folder), "--series", "1.2.3.9", "-l", str(LEVEL)]
    assert main([*args, "-o", str(tmp_path / "x.ply")]) == 1
    err = capsys.readouterr().err
    assert "is one slice, an image rather than a volume" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.ply").exists()
