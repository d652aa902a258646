"""One world frame (issue 11): readers state LPS or RAS, --space converts, headers record it."""

from __future__ import annotations

import nrrd
import numpy as np
import pytest
from conftest import ball

from isoconvert import read_volume
from isoconvert.cli import main
from isoconvert.convert import convert
from isoconvert.errors import VolumeError

nib = pytest.importorskip("nibabel")

ORIGIN = (-12.5, 30.25, 7.0)
SPACING = (0.5, 0.75, 1.25)


@pytest.fixture
def lps_and_ras(tmp_path):
    """One off-centre ball as an LPS NRRD and as the RAS NIfTI of the same
    physical points (x and y negated), as a DICOM and its NIfTI conversion are."""
    xyz = ball(12, 4.2, center=(4.0, 6.5, 5.0)).astype(np.float32)
    path_nrrd = tmp_path / "ball.nrrd"
    nrrd.write(
        str(path_nrrd),
        xyz,
        {
            "space": "left-posterior-superior",
            "space directions": np.diag(SPACING),
            "space origin": np.array(ORIGIN),
            "space units": ["mm", "mm", "mm"],
        },
        index_order="F",
    )
    affine = np.diag([-SPACING[0], -SPACING[1], SPACING[2], 1.0])
    affine[:3, 3] = (-ORIGIN[0], -ORIGIN[1], ORIGIN[2])
    image = nib.Nifti1Image(xyz, affine)
    image.header.set_xyzt_units("mm")
    image.set_sform(affine, code=1)
    path_nii = tmp_path / "ball.nii"
    nib.save(image, str(path_nii))
    return path_nrrd, path_nii


def test_readers_state_their_frame(lps_and_ras):
    path_nrrd, path_nii = lps_and_ras
    assert read_volume(path_nrrd).frame == "LPS"
    assert read_volume(path_nii).frame == "RAS"


def test_a_scan_and_its_nifti_conversion_overlay_exactly_in_either_frame(lps_and_ras, tmp_path):
    path_nrrd, path_nii = lps_and_ras
    for space in ("ras", "lps"):
        a = convert(path_nrrd, tmp_path / f"a_{space}.ply", 0.0, space=space).mesh
        b = convert(path_nii, tmp_path / f"b_{space}.ply", 0.0, space=space).mesh
        assert np.array_equal(a.cells, b.cells)
        assert np.allclose(a.vertices, b.vertices, rtol=0, atol=1e-12)
        assert a.signed_volume() > 0 and b.signed_volume() > 0  # still outward
        assert a.info["frame"] == b.info["frame"] == space.upper()
    kept = convert(path_nrrd, tmp_path / "kept.ply", 0.0).mesh
    turned = convert(path_nrrd, tmp_path / "turned.ply", 0.0, space="ras").mesh
    assert np.array_equal(turned.vertices[:, :2], -kept.vertices[:, :2])
    assert np.array_equal(turned.vertices[:, 2], kept.vertices[:, 2])


def test_headers_record_the_frame_and_unit(lps_and_ras, tmp_path):
    path_nrrd, _ = lps_and_ras
    convert(path_nrrd, tmp_path / "m.ply", 0.0, space="ras")
    convert(path_nrrd, tmp_path / "m.obj", 0.0)
    head = (tmp_path / "m.ply").read_bytes().split(b"end_header")[0].decode()
    assert "comment frame RAS\n" in head and "comment unit mm\n" in head
    obj = (tmp_path / "m.obj").read_text()
    assert "# frame LPS\n" in obj and "# unit mm\n" in obj


def test_space_needs_a_stated_frame(tmp_path, capsys):
    raw = tmp_path / "v_8x8x8_float32.raw"
    ball(8, 2.5).astype(np.float32).tofile(raw)
    with pytest.raises(VolumeError, match="does not say which anatomical frame"):
        read_volume(raw).in_frame("ras")
    code = main(["convert", str(raw), "-o", str(tmp_path / "o.ply"), "-l", "0", "--space", "ras"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "drop --space" in err[0]
    assert not (tmp_path / "o.ply").exists()
    code = main(["convert", str(raw), "-o", str(tmp_path / "o.ply"), "-l", "0", "--space", "xyz"])
    assert code == 1 and "--space takes lps or ras" in capsys.readouterr().err
