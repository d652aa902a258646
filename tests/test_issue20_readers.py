"""Issue 20, readers: the files each volume is read from, truncated TIFFs, NIfTI sform
fallback, DICOM without PixelSpacing, ASCII NRRD ranges, huge declared sizes, and no
"set --spacing" notes once spacing is set."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from isoconvert import read_volume
from isoconvert.errors import FormatError


def _abs(*paths) -> set[str]:
    return {os.path.abspath(os.fspath(p)) for p in paths}


def zyx_field(nz=4, ny=3, nx=5, dtype=np.uint8) -> np.ndarray:
    z, y, x = np.mgrid[:nz, :ny, :nx]
    return (x + 10 * y + 40 * z).astype(dtype)


# --- 1. Volume.files ------------------------------------------------------------------------


def test_files_of_raw(tmp_path):
    path = tmp_path / "v_5x3x4_uint8.raw"
    zyx_field().tofile(path)
    vol = read_volume(path)
    assert set(vol.files) == _abs(path)
    assert len(vol.files) == 1


def test_files_of_attached_and_detached_nrrd(tmp_path):
    data = zyx_field()
    attached = tmp_path / "a.nrrd"
    header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 4\nencoding: raw\n"
    attached.write_bytes(header.encode() + b"\n" + data.tobytes())
    assert read_volume(attached).files == tuple(_abs(attached))

    one = tmp_path / "one.nhdr"
    (tmp_path / "one.raw").write_bytes(data.tobytes())
    one.write_text(header + "data file: one.raw\n\n")
    assert set(read_volume(one).files) == _abs(one, tmp_path / "one.raw")


def test_files_of_numbered_and_listed_nrrd(tmp_path):
    """``data file: quarter.%d 1 3 1`` gives the header and its three data files (as VTK's
    headsq names them), a LIST its listed files."""
    data = zyx_field(nz=3)
    for k in range(3):
        (tmp_path / f"quarter.{k + 1}").write_bytes(data[k].tobytes())
    header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 3\nencoding: raw\n"
    numbered = tmp_path / "quarter.nhdr"
    numbered.write_text(header + "data file: quarter.%d 1 3 1\n\n")
    vol = read_volume(numbered)
    assert np.array_equal(vol.data, data.T)
    expected = _abs(numbered, *(tmp_path / f"quarter.{k}" for k in (1, 2, 3)))
    assert set(vol.files) == expected and len(vol.files) == 4

    listed = tmp_path / "listed.nhdr"
    listed.write_text(header + "data file: LIST\nquarter.3\nquarter.1\nquarter.2\n\n")
    vol = read_volume(listed)
    assert set(vol.files) == (expected - _abs(numbered)) | _abs(listed)


def test_files_of_metaimage(tmp_path):
    data = zyx_field(nz=3)
    common = "ObjectType = Image\nNDims = 3\nDimSize = 5 3 3\nElementType = MET_UCHAR\n"
    (tmp_path / "v.raw").write_bytes(data.tobytes())
    one = tmp_path / "one.mhd"
    one.write_text(common + "ElementDataFile = v.raw\n")
    assert set(read_volume(one).files) == _abs(one, tmp_path / "v.raw")

    for k in range(3):
        (tmp_path / f"s{k:02d}.raw").write_bytes(data[k].tobytes())
    numbered = tmp_path / "numbered.mhd"
    numbered.write_text(common + "ElementDataFile = s%02d.raw 0 2 1\n")
    vol = read_volume(numbered)
    assert np.array_equal(vol.data, data.T)
    slices = _abs(*(tmp_path / f"s{k:02d}.raw" for k in range(3)))
    assert set(vol.files) == slices | _abs(numbered)
    listed = tmp_path / "listed.mhd"
    listed.write_text(common + "ElementDataFile = LIST\ns00.raw\ns01.raw\ns02.raw\n")
    assert set(read_volume(listed).files) == slices | _abs(listed)

    local = tmp_path / "local.mha"
    local.write_bytes((common + "ElementDataFile = LOCAL\n").encode() + data.tobytes())
    assert read_volume(local).files == tuple(_abs(local))


def test_files_of_tiff_file_folder_and_glob(tmp_path, monkeypatch):
    tifffile = pytest.importorskip("tifffile")
    data = zyx_field()
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, data, photometric="minisblack")
    assert read_volume(stack).files == tuple(_abs(stack))

    folder = tmp_path / "slices"
    folder.mkdir()
    for k in range(len(data)):
        tifffile.imwrite(folder / f"s{k}.tif", data[k])
    (folder / "README.txt").write_text("not a slice")
    expected = _abs(*(folder / f"s{k}.tif" for k in range(len(data))))
    assert set(read_volume(folder).files) == expected
    # a relative glob: the files are made absolute, not resolved
    monkeypatch.chdir(tmp_path)
    assert set(read_volume("slices/s*.tif").files) == expected


def test_files_are_absolute_but_not_resolved_through_symlinks(tmp_path, monkeypatch):
    real = tmp_path / "real_5x3x4_uint8.raw"
    zyx_field().tofile(real)
    link = tmp_path / "link_5x3x4_uint8.raw"
    link.symlink_to(real)
    monkeypatch.chdir(tmp_path)
    assert read_volume("link_5x3x4_uint8.raw").files == (str(link),)


def test_files_of_zarr_is_the_store_folder(tmp_path):
    zarr = pytest.importorskip("zarr")
    store = tmp_path / "v.zarr"
    zarr.save_array(str(store), zyx_field())
    assert read_volume(store).files == tuple(_abs(store))


def test_files_of_numpy_nifti_and_image(tmp_path):
    npy = tmp_path / "v.npy"
    np.save(npy, zyx_field())
    npz = tmp_path / "v.npz"
    np.savez(npz, a=zyx_field())
    npy2 = tmp_path / "image.npy"
    np.save(npy2, zyx_field()[0])
    for path in (npy, npz, npy2):
        assert read_volume(path).files == tuple(_abs(path))
    nib = pytest.importorskip("nibabel")
    nii = tmp_path / "v.nii"
    nib.save(nib.Nifti1Image(zyx_field().T.copy(), np.eye(4)), nii)
    niigz = tmp_path / "v.nii.gz"
    nib.save(nib.Nifti1Image(zyx_field().T.copy(), np.eye(4)), niigz)
    for path in (nii, niigz):
        assert read_volume(path).files == tuple(_abs(path))
    image = pytest.importorskip("PIL.Image")
    png = tmp_path / "v.png"
    image.fromarray(zyx_field()[0]).save(png)
    assert read_volume(png).files == tuple(_abs(png))


def _dicom_series(folder: Path, nz=3, spacing=(0.5, 0.25), series="1.2.3.4") -> list[Path]:
    from test_readers_dicom import write_slice

    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for k in range(nz):
        f = folder / f"{series}-IM{k}"
        write_slice(
            f,
            zyx_field(nz, 4, 6, np.int16)[k],
            (0.0, 0.0, 2.0 * k),
            spacing=spacing,
            series=series,
            instance=k + 1,
        )
        files.append(f)
    return files


def test_files_of_dicom_are_the_chosen_series(tmp_path):
    pytest.importorskip("pydicom")
    folder = tmp_path / "dicom"
    mine = _dicom_series(folder, series="1.2.3.4")
    _dicom_series(folder, series="1.2.3.5")
    (folder / "README").write_text("not DICOM")
    vol = read_volume(folder, series="1.2.3.4")
    assert set(vol.files) == _abs(*mine)
    # one file given: its folder's series
    assert set(read_volume(mine[1], format="dicom", series="1.2.3.4").files) == _abs(*mine)


def test_files_survive_copies(tmp_path):
    path = tmp_path / "v.nhdr"
    (tmp_path / "v.raw").write_bytes(zyx_field().tobytes())
    path.write_text(
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 4\nencoding: raw\n"
        "space: left-posterior-superior\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n"
        "data file: v.raw\n\n"
    )
    vol = read_volume(path)
    expected = _abs(path, tmp_path / "v.raw")
    assert set(vol.files) == expected
    assert set(read_volume(path, spacing=(1, 2, 3), origin=(4, 5, 6)).files) == expected
    assert set(vol.in_frame("ras").files) == expected
    assert set(vol.with_placement(spacing=(2, 2, 2)).files) == expected
    assert set(dataclasses.replace(vol, data=vol.data).files) == expected


# --- 2. truncated TIFFs ---------------------------------------------------------------------


def _stack(nz=27, ny=20, nx=30) -> np.ndarray:
    return (np.arange(nz * ny * nx) % 251).astype(np.uint8).reshape(nz, ny, nx)


def _cut(path: Path, size: int) -> Path:
    data = path.read_bytes()
    assert size < len(data)
    path.write_bytes(data[:size])
    return path


def test_truncated_imagej_stack_is_corrupt_not_a_2d_image(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    path = tmp_path / "X.tif"
    tifffile.imwrite(path, _stack(), imagej=True, metadata={"axes": "ZYX"})
    with tifffile.TiffFile(path) as tif:
        assert tif.imagej_metadata["images"] == 27 and len(tif.pages) == 27
        first = tif.pages[0]
        start, per_page = first.dataoffsets[0], first.databytecounts[0]
    _cut(path, start + per_page * 3 // 2)  # about 1.5 pages of samples
    with tifffile.TiffFile(path) as tif:  # what tifffile makes of it: one 2D page
        assert tif.series[0].shape == (20, 30)
    with pytest.raises(FormatError) as err:
        read_volume(path)
    assert str(err.value) == (
        f"{path}: corrupt TIFF: its ImageJ metadata declares 27 images but the file holds 1 "
        "(truncated?); copy or save the file again"
    )
    from isoconvert.batch import _is_2d_image

    assert not _is_2d_image(path, "tiff")


def test_tiff_whose_ome_metadata_declares_more_planes_is_corrupt(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    full = tmp_path / "full.ome.tif"
    tifffile.imwrite(full, _stack(), ome=True, metadata={"axes": "ZYX"})
    with tifffile.TiffFile(full) as tif:
        xml = tif.ome_metadata
    assert 'SizeZ="27"' in xml
    assert read_volume(full).shape == (30, 20, 27)
    path = tmp_path / "three.ome.tif"  # three pages under metadata declaring 27
    tifffile.imwrite(path, _stack()[:3], photometric="minisblack", description=xml, metadata=None)
    with pytest.raises(
        FormatError,
        match=r"three\.ome\.tif: corrupt TIFF: its OME metadata "
        r"declares 27 planes but the file holds 3 \(truncated\?\)",
    ):
        read_volume(path)


def test_tiff_page_data_past_the_end_is_corrupt(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    one = tmp_path / "one.tif"
    tifffile.imwrite(one, _stack()[0], photometric="minisblack")
    with tifffile.TiffFile(one) as tif:
        end = tif.pages[0].dataoffsets[0] + tif.pages[0].databytecounts[0]
    assert end == one.stat().st_size  # tifffile writes the samples last
    _cut(one, end - 100)
    with pytest.raises(FormatError) as err:
        read_volume(one)
    assert str(err.value) == (
        f"{one}: corrupt TIFF: the image data of page 1 of 1 runs to byte {end}, past the end "
        f"of the file ({end - 100} bytes) (truncated?); copy or save the file again"
    )
    # one cut slice of a folder is found when the folder is opened, before any work
    folder = tmp_path / "slices"
    folder.mkdir()
    for k in range(4):
        tifffile.imwrite(folder / f"s{k}.tif", _stack()[k], photometric="minisblack")
    _cut(folder / "s2.tif", end - 1)
    with pytest.raises(FormatError, match=r"s2\.tif: corrupt TIFF: the image data of page 1"):
        read_volume(folder)


def test_tiff_pointing_to_a_page_past_the_end_is_corrupt(tmp_path):
    """A multi-page file cut after its first page header: the header's pointer to the
    next page leads past the end."""
    tifffile = pytest.importorskip("tifffile")
    path = tmp_path / "cut.tif"
    tifffile.imwrite(path, _stack()[:5], photometric="minisblack", metadata=None)
    with tifffile.TiffFile(path) as tif:
        second = tif.pages[1].offset
        first_end = tif.pages[0].dataoffsets[0] + tif.pages[0].databytecounts[0]
    assert first_end <= second
    _cut(path, first_end)
    with pytest.raises(
        FormatError,
        match=r"cut\.tif: corrupt TIFF: page 1 points to a next "
        rf"page at byte {second}, past the end of the file",
    ):
        read_volume(path)


def test_whole_tiffs_still_read(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    path = tmp_path / "ij.tif"
    tifffile.imwrite(path, _stack(), imagej=True, metadata={"axes": "ZYX"})
    assert np.array_equal(read_volume(path).data, _stack().T)
    compressed = tmp_path / "z.tif"
    tifffile.imwrite(compressed, _stack()[:4], photometric="minisblack", compression="zlib")
    assert np.array_equal(read_volume(compressed).data, _stack()[:4].T)


# --- 3. NIfTI: an unusable sform falls back to the qform ------------------------------------


def _rotation_z(degrees: float) -> np.ndarray:
    t = np.radians(degrees)
    return np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])


def _corners(shape) -> np.ndarray:
    """(8, 3) grid corners (i, j, k) of a grid of ``shape`` (x, y, z)."""
    return np.array(
        [
            [i, j, k]
            for i in (0, shape[0] - 1)
            for j in (0, shape[1] - 1)
            for k in (0, shape[2] - 1)
        ],
        dtype=np.float64,
    )


@pytest.mark.parametrize(
    "sform, why",
    [
        (np.zeros((4, 4)), "zero"),
        (np.diag([2.0, 0.0, 1.0, 1.0]), "singular"),  # an axis of zero length
        (np.array([[1, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float), "singular"),
        (np.diag([np.nan, 1.0, 1.0, 1.0]), "not finite"),
    ],
)
def test_nifti_unusable_sform_is_placed_by_the_qform(tmp_path, sform, why):
    nib = pytest.importorskip("nibabel")
    data = zyx_field(nz=4, ny=5, nx=6).T.copy()  # (x, y, z) = (6, 5, 4)
    qform = np.eye(4)
    qform[:3, :3] = _rotation_z(30) @ np.diag([3.0, 2.5, 1.5])
    qform[:3, 3] = (5.0, 7.0, 9.0)
    img = nib.Nifti1Image(data, qform)
    img.set_qform(qform, code=1)
    img.set_sform(qform, code=2)
    path = tmp_path / "v.nii"
    nib.save(img, path)
    # then the sform written over (nibabel refuses to set a NaN one): NIfTI-1 keeps
    # sform_code at byte 254 and srow_x, srow_y, srow_z (4 float32 each) from byte 280
    with open(path, "r+b") as fh:
        fh.seek(280)
        fh.write(np.asarray(sform[:3], dtype="<f4").tobytes())
    header = nib.load(path).header
    assert int(header["sform_code"]) == 2 and int(header["qform_code"]) == 1
    assert np.array_equal(header.get_sform()[:3], sform[:3], equal_nan=True)
    expected = nib.affines.apply_affine(header.get_qform(), _corners(data.shape))
    assert np.allclose(header.get_qform(), qform, atol=1e-5)  # nibabel keeps our qform

    vol = read_volume(path)
    assert np.allclose(vol.index_to_world(_corners(vol.shape)), expected, atol=1e-9)
    assert np.allclose(vol.spacing, [3.0, 2.5, 1.5], atol=1e-5)
    assert f"sform unusable ({why}); placed by the qform (qform_code 1)" in vol.notes
    assert not any("degenerate" in n for n in vol.notes)


def test_nifti_unusable_sform_and_no_qform_is_placed_by_the_voxel_sizes(tmp_path):
    nib = pytest.importorskip("nibabel")
    data = zyx_field(nz=4, ny=5, nx=6).T.copy()
    img = nib.Nifti1Image(data, np.diag([3.0, 2.5, 1.5, 1.0]))
    img.set_qform(None, code=0)
    img.set_sform(np.diag([3.0, 2.5, 1.5, 1.0]), code=1)
    path = tmp_path / "v.nii"
    nib.save(img, path)
    with open(path, "r+b") as fh:  # the sform zeroed (srow_x, srow_y, srow_z from byte 280)
        fh.seek(280)
        fh.write(bytes(48))
    header = nib.load(path).header
    vol = read_volume(path)
    expected = nib.affines.apply_affine(header.get_base_affine(), _corners(data.shape))
    assert np.allclose(vol.index_to_world(_corners(vol.shape)), expected)
    assert any(
        n.startswith("placement from the voxel sizes only (sform unusable (zero)")
        for n in vol.notes
    )


def test_nifti_usable_sform_still_wins(tmp_path):
    nib = pytest.importorskip("nibabel")
    data = zyx_field(nz=4, ny=5, nx=6).T.copy()
    sform = np.diag([2.0, 3.0, 4.0, 1.0])
    sform[:3, 3] = (-1, -2, -3)
    img = nib.Nifti1Image(data, None)
    img.set_qform(np.eye(4), code=1)
    img.set_sform(sform, code=2)
    path = tmp_path / "v.nii"
    nib.save(img, path)
    vol = read_volume(path)
    expected = nib.affines.apply_affine(sform, _corners(data.shape))
    assert np.allclose(vol.index_to_world(_corners(vol.shape)), expected)
    assert "placement from the sform (sform_code 2)" in vol.notes
