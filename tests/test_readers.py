"""Readers: raw, NRRD and TIFF, against hand-made files and the real scans."""

from __future__ import annotations

import gzip

import nrrd
import numpy as np
import pytest
import tifffile
from conftest import dataset

from isoconvert import IsoconvertError, read_volume
from isoconvert.errors import FormatError, InputNotFoundError, VolumeError


@pytest.fixture
def zyx():
    """(4, 3, 5) int16 array in C (z, y, x) order with distinct values."""
    return (np.arange(60, dtype=np.int16) * 7 - 100).reshape(4, 3, 5)


# --- raw ----------------------------------------------------------------------


def test_raw_x_varies_fastest_and_is_memory_mapped(tmp_path, zyx):
    path = tmp_path / "v.raw"
    zyx.tofile(path)
    vol = read_volume(path, shape=(5, 3, 4), dtype="int16")
    assert vol.shape == (5, 3, 4)
    assert vol.data[4, 2, 3] == zyx[3, 2, 4]
    assert vol.data.base is not None  # a view on the mapping, not a copy
    assert vol.data.flags.f_contiguous


def test_raw_shape_and_dtype_from_the_file_name(tmp_path, zyx):
    path = tmp_path / "scan_5x3x4_int16.raw"
    zyx.tofile(path)
    vol = read_volume(path)
    assert vol.data.dtype == np.int16 and vol.shape == (5, 3, 4)
    assert any("file name" in n for n in vol.notes)


def test_raw_big_endian_and_header_bytes(tmp_path, zyx):
    path = tmp_path / "v.raw"
    path.write_bytes(b"HEADER!!" + zyx.astype(">i2").tobytes())
    vol = read_volume(path, shape=(5, 3, 4), dtype="short", endian="big", header_bytes=8)
    assert np.array_equal(vol.data, zyx.T)


def test_raw_2d(tmp_path):
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    path = tmp_path / "img.raw"
    img.tofile(path)
    vol = read_volume(path, shape=(4, 3), dtype="float32")
    assert vol.ndim == 2 and vol.data[3, 2] == img[2, 3]


def test_raw_size_mismatch_names_expected_and_actual_bytes(tmp_path, zyx):
    path = tmp_path / "v.raw"
    zyx.tofile(path)
    with pytest.raises(VolumeError, match=r"has 120 bytes .* needs 122") as err:
        read_volume(path, shape=(61, 1, 1), dtype="int16")
    assert str(path) in str(err.value)


def test_raw_unknown_dtype_lists_the_choices(tmp_path, zyx):
    path = tmp_path / "v.raw"
    zyx.tofile(path)
    with pytest.raises(VolumeError, match="choose one of: uint8, int8"):
        read_volume(path, shape=(5, 3, 4), dtype="complex64")


def test_raw_without_shape_says_what_to_give(tmp_path, zyx):
    path = tmp_path / "v.raw"
    zyx.tofile(path)
    with pytest.raises(VolumeError, match="--shape X Y Z and --dtype"):
        read_volume(path)


def test_option_that_does_not_apply_is_an_error(tmp_path, zyx):
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), zyx.T, index_order="F")
    with pytest.raises(VolumeError, match="--shape .*not apply to nrrd"):
        read_volume(path, shape=(5, 3, 4))


def test_missing_input():
    with pytest.raises(InputNotFoundError, match="no such file"):
        read_volume("does/not/exist.raw")


def test_unknown_input_suffix_lists_formats(tmp_path):
    path = tmp_path / "v.xyz"
    path.write_bytes(b"1234")
    with pytest.raises(FormatError, match=r"known input formats: raw .*nrrd .*tiff"):
        read_volume(path)


def test_spacing_and_origin_override(tmp_path, zyx):
    path = tmp_path / "v_5x3x4_int16.raw"
    zyx.tofile(path)
    vol = read_volume(path, spacing=(0.5, 0.5, 2), origin=(1, 2, 3))
    assert vol.spacing.tolist() == [0.5, 0.5, 2] and vol.origin.tolist() == [1, 2, 3]
    with pytest.raises(VolumeError, match="spacing needs 3"):
        read_volume(path, spacing=(1, 2))


# --- NRRD ---------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
@pytest.mark.parametrize("detached", [False, True])
def test_nrrd_attached_and_detached(tmp_path, zyx, encoding, detached):
    path = tmp_path / ("v.nhdr" if detached else "v.nrrd")
    header = {
        "encoding": encoding,
        "space": "left-posterior-superior",
        "space directions": np.diag([0.5, 0.25, 2.0]),
        "space origin": np.array([10.0, -5.0, 3.0]),
    }
    nrrd.write(str(path), zyx.T, header, detached_header=detached, index_order="F")
    vol = read_volume(path)
    assert np.array_equal(vol.data, zyx.T)
    assert vol.spacing.tolist() == [0.5, 0.25, 2.0]
    assert vol.origin.tolist() == [10.0, -5.0, 3.0]
    assert np.array_equal(vol.direction, np.eye(3))


def test_nrrd_spacings_field(tmp_path, zyx):
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), zyx.T, {"spacings": [1.5, 2.5, 3.5]}, index_order="F")
    assert read_volume(path).spacing.tolist() == [1.5, 2.5, 3.5]


def test_nrrd_multi_file_headsq_matches_the_slices():
    path = dataset("headsq_vtk/quarter.nhdr")
    vol = read_volume(path)
    assert vol.shape == (64, 64, 93) and vol.data.dtype == np.int16
    assert vol.spacing.tolist() == [3.2, 3.2, 1.5]
    for k in (0, 46, 92):
        raw = np.fromfile(path.parent / f"quarter.{k + 1}", dtype="<i2").reshape(64, 64)
        assert np.array_equal(vol.data[:, :, k], raw.T)


def test_nrrd_multi_file_gzip_and_missing_part(tmp_path, zyx):
    for z in range(4):
        with gzip.open(tmp_path / f"part{z:02d}.gz", "wb") as fh:
            fh.write(zyx[z].astype("<i2").tobytes())
    (tmp_path / "v.nhdr").write_text(
        "NRRD0004\ndimension: 3\ntype: short\nsizes: 5 3 4\nendian: little\n"
        "encoding: gzip\ndata file: part%02d.gz 0 3 1\n"
    )
    assert np.array_equal(read_volume(tmp_path / "v.nhdr").data, zyx.T)
    (tmp_path / "part02.gz").unlink()
    with pytest.raises(FormatError, match="part02.gz is missing"):
        read_volume(tmp_path / "v.nhdr")


def test_nrrd_truncated_is_a_format_error(tmp_path, zyx):
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), zyx.T, {"encoding": "raw"}, index_order="F")
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(IsoconvertError, match=str(path)):
        read_volume(path)


def test_nrrd_not_nrrd(tmp_path):
    path = tmp_path / "v.nrrd"
    path.write_bytes(b"\x00\x01garbage")
    with pytest.raises(FormatError, match="not a readable NRRD"):
        read_volume(path)


def test_nrrd_vector_axis_needs_channel(tmp_path, zyx):
    path = tmp_path / "rgb.nrrd"
    data = np.stack([zyx.T, zyx.T + 1, zyx.T + 2])  # (3, X, Y, Z)
    nrrd.write(
        str(path), data, {"kinds": ["vector", "domain", "domain", "domain"]}, index_order="F"
    )
    with pytest.raises(VolumeError, match="--channel 0..2"):
        read_volume(path)
    assert np.array_equal(read_volume(path, channel=1).data, zyx.T + 1)


# --- TIFF ---------------------------------------------------------------------


def test_tiff_multipage_with_imagej_spacing(tmp_path, zyx):
    path = tmp_path / "v.tif"
    tifffile.imwrite(
        path,
        zyx,
        imagej=True,
        resolution=(1 / 0.5, 1 / 0.25),
        metadata={"spacing": 2.0, "unit": "um", "axes": "ZYX"},
    )
    vol = read_volume(path)
    assert np.array_equal(vol.data, zyx.T)
    assert np.allclose(vol.spacing, [0.5, 0.25, 2.0])
    assert vol.unit == "um"


def test_tiff_folder_in_natural_order_and_glob(tmp_path, zyx):
    folder = tmp_path / "slices"
    folder.mkdir()
    big = np.concatenate([zyx] * 3)  # 12 slices: slice2 must come before slice10
    for z, img in enumerate(big):
        tifffile.imwrite(folder / f"slice{z}.tif", img)
    (folder / "notes.txt").write_text("not a slice")
    assert np.array_equal(read_volume(folder).data, big.T)
    assert np.array_equal(read_volume(str(folder / "slice*.tif")).data, big.T)


def test_tiff_folder_mismatched_slice_names_the_file(tmp_path, zyx):
    for z, img in enumerate(zyx):
        tifffile.imwrite(tmp_path / f"s{z}.tif", img)
    tifffile.imwrite(tmp_path / "s2.tif", zyx[2, :2])
    with pytest.raises(VolumeError, match=r"s2.tif: slice is 5x2 int16, but s0.tif is 5x3"):
        read_volume(tmp_path)
    tifffile.imwrite(tmp_path / "s2.tif", zyx[2].astype(np.float32))
    with pytest.raises(VolumeError, match="s2.tif.*float32"):
        read_volume(tmp_path)


def test_tiff_rgb_needs_a_channel(tmp_path):
    rgb = np.zeros((4, 6, 8, 3), np.uint8)
    rgb[..., 1] = 9
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, rgb, photometric="rgb")
    with pytest.raises(VolumeError, match=r"rgb.tif: .*3 channels.*--channel 0..2"):
        read_volume(path)
    vol = read_volume(path, channel=1)
    assert vol.shape == (8, 6, 4) and (vol.data == 9).all()


def test_tiff_without_z_spacing_uses_one_and_says_so(tmp_path, zyx):
    path = tmp_path / "v.tif"
    tifffile.imwrite(path, zyx, resolution=(4.0, 4.0), photometric="minisblack")
    vol = read_volume(path)
    assert vol.spacing.tolist() == [1, 1, 1]
    assert any("no z spacing" in n and "0.25" in n for n in vol.notes)


def test_tiff_empty_folder(tmp_path):
    with pytest.raises(InputNotFoundError, match="holds no .tif"):
        read_volume(tmp_path)


def test_tiff_corrupt(tmp_path):
    path = tmp_path / "v.tif"
    path.write_bytes(b"II*\x00garbage")
    with pytest.raises(FormatError, match="not a readable TIFF"):
        read_volume(path)


def test_real_imagej_stacks_spacing():
    mri = read_volume(dataset("mri-stack.tif"))
    assert mri.shape == (186, 226, 27) and mri.spacing.tolist() == [1, 1, 7]
    corti = read_volume(dataset("XYZ_organ-of-corti_confocal.tif"))
    assert corti.shape == (548, 249, 15) and corti.data.dtype == np.uint16
    assert np.allclose(corti.spacing, 0.315, rtol=1e-5) and corti.unit == "µm"
    ref = tifffile.imread(dataset("XYZ_organ-of-corti_confocal.tif"))
    assert np.array_equal(corti.data, ref.T)
