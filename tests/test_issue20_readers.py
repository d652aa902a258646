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
