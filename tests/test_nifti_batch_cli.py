"""NIfTI in batch (found, 2D skipped, output names) and on the command line (--volume-index)."""

from __future__ import annotations

import numpy as np
import pytest

from isoconvert.batch import discover
from isoconvert.cli import main

nib = pytest.importorskip("nibabel")


def _ball(n=9):
    x, y, z = np.meshgrid(*(np.arange(n, dtype=np.float32),) * 3, indexing="ij")
    return 3.2 - np.sqrt((x - 4.1) ** 2 + (y - 3.9) ** 2 + (z - 4.2) ** 2)


def test_batch_finds_nii_gz_and_skips_2d_nifti(tmp_path):
    folder = tmp_path / "scans"
    folder.mkdir()
    nib.save(nib.Nifti1Image(_ball(), np.eye(4)), str(folder / "t1.nii.gz"))
    nib.save(nib.Nifti1Image(_ball(), np.eye(4)), str(folder / "t2.nii"))
    nib.save(nib.Nifti1Image(_ball()[:, :, 4], np.eye(4)), str(folder / "slice.nii.gz"))
    found, skipped = discover([str(folder)])
    assert sorted(str(f.relative) for f in found) == ["t1.nii.gz", "t2.nii"]
    assert [s.path.endswith("slice.nii.gz") for s in skipped] == [True]
    code = main(["batch", str(folder), "-o", str(tmp_path / "out"), "-l", "0.5", "-q"])
    assert code == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["t1.ply", "t2.ply"]


def test_cli_volume_index(tmp_path, capsys):
    four = np.stack([_ball(), _ball() - 10], axis=-1)
    path = tmp_path / "series.nii.gz"
    nib.save(nib.Nifti1Image(four, np.eye(4)), str(path))
    out = tmp_path / "a.ply"
    code = main(["convert", str(path), "--level", "0.5", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 1 and "2 volumes; choose one with --volume-index 0..1" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    code = main(["convert", str(path), "--level", "0.5", "-o", str(out), "--volume-index", "0"])
    assert code == 0 and out.stat().st_size > 0
    code = main(["info", str(path), "--volume-index", "1"])
    assert code == 0 and "volume 1 of 2" in capsys.readouterr().out


def test_a_level_mapping_picks_a_4d_volume_per_file(tmp_path):
    """`volume_index` in --levels is a number, per file, as --volume-index is."""
    from isoconvert.batch import read_mapping

    mapping = tmp_path / "levels.toml"
    mapping.write_text('[[volume]]\npattern = "*.nii"\nlevel = 0.5\nvolume_index = "1"\n')
    assert read_mapping(mapping)[0].options == {"volume_index": 1}
    series = np.stack([_ball(), _ball() - 1.0], axis=-1)  # the second volume is smaller
    folder = tmp_path / "in"
    folder.mkdir()
    nib.save(nib.Nifti1Image(series, np.eye(4)), str(folder / "fmri.nii"))
    code = main(["batch", str(folder), "-o", str(tmp_path / "out"), "--levels", str(mapping), "-q"])
    assert code == 0
    code = main(["convert", str(folder / "fmri.nii"), "-o", str(tmp_path / "one.ply"), "-l", "0.5",
                 "--volume-index", "1"])  # fmt: skip
    assert code == 0
    body = (tmp_path / "out" / "fmri.ply").read_bytes().split(b"end_header")[1]
    assert body == (tmp_path / "one.ply").read_bytes().split(b"end_header")[1]
