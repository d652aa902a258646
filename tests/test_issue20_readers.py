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
from isoconvert.errors import FormatError, IsoconvertError, VolumeError


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


# --- 4. DICOM without a usable PixelSpacing -------------------------------------------------


def _drop_pixel_spacing(files: list[Path]) -> None:
    import pydicom

    for f in files:
        ds = pydicom.dcmread(f)
        del ds.PixelSpacing
        ds.save_as(f)


@pytest.mark.parametrize("spacing", [(0.0, 0.0), (0.0, 0.5), None])
def test_dicom_without_pixel_spacing_takes_the_given_spacing(tmp_path, spacing):
    pytest.importorskip("pydicom")
    folder = tmp_path / "dicom"
    files = _dicom_series(folder, spacing=spacing or (0.5, 0.25))
    if spacing is None:
        _drop_pixel_spacing(files)
    vol = read_volume(folder, spacing=(0.7, 0.8, 2.0))
    assert vol.spacing.tolist() == [0.7, 0.8, 2.0]
    assert not any("PixelSpacing" in n or "set --spacing" in n for n in vol.notes)
    # the placement otherwise comes from the files: origin and axes, values
    assert vol.origin.tolist() == [0.0, 0.0, 0.0] and vol.frame == "LPS"
    assert np.array_equal(vol.data, zyx_field(3, 4, 6, np.int16).T)
    # without --spacing: 1 for x and y, a note naming the value; z from the positions
    alone = read_volume(folder)
    assert alone.spacing.tolist() == [1.0, 1.0, 2.0]
    shown = "missing" if spacing is None else "[" + ", ".join(map(str, spacing)) + "]"
    assert any(
        n.startswith(f"PixelSpacing {shown} in ")
        and n.endswith("using 1 for x and y; set --spacing")
        for n in alone.notes
    ), alone.notes


def test_dicom_with_pixel_spacing_still_uses_it(tmp_path):
    pytest.importorskip("pydicom")
    vol = read_volume(_dicom_series(tmp_path / "dicom", spacing=(0.5, 0.25))[0].parent)
    assert vol.spacing.tolist() == [0.25, 0.5, 2.0]
    assert not any("PixelSpacing" in n for n in vol.notes)


def test_dicom_multiframe_with_zero_pixel_spacing_takes_the_given_spacing(tmp_path):
    pytest.importorskip("pydicom")
    from test_dicom_multiframe import write_enhanced

    frames = zyx_field(3, 4, 6, np.int16)
    path = write_enhanced(
        tmp_path / "enhanced.dcm", frames, [(0.0, 0.0, 1.5 * k) for k in range(3)], spacing=(0, 0)
    )
    vol = read_volume(path, spacing=(0.3, 0.4, 1.5))
    assert vol.spacing.tolist() == [0.3, 0.4, 1.5]
    assert vol.files == tuple(_abs(path))  # a multi-frame file is read alone
    assert np.array_equal(vol.data, frames.T)
    assert not any("PixelSpacing" in n for n in vol.notes)
    alone = read_volume(path)
    assert alone.spacing.tolist() == [1.0, 1.0, 1.5]
    assert (
        "PixelSpacing [0.0, 0.0] of frame 1 (3 of 3 frames) is not two positive numbers; using 1 "
        "for x and y; set --spacing"
    ) in alone.notes


# --- 7. no "set --spacing" once spacing is set ----------------------------------------------


def _spacing_notes(vol) -> list[str]:
    return [n for n in vol.notes if "spacing" in n.lower() and "command line" not in n]


def _inputs_without_spacing(tmp_path) -> list[tuple[Path, dict]]:
    """Files of every reader that says something about the spacing it lacks, and their
    read options."""
    tifffile = pytest.importorskip("tifffile")
    data = zyx_field()
    found = []
    slices = tmp_path / "slices"
    slices.mkdir()
    for k in range(len(data)):
        tifffile.imwrite(slices / f"s{k}.tif", data[k], photometric="minisblack")
    found.append((slices, {}))
    ij = tmp_path / "ij.tif"  # ImageJ z spacing 0 (ignored) and resolution tags
    tifffile.imwrite(
        ij, data, imagej=True, resolution=(2.0, 4.0), metadata={"axes": "ZYX", "spacing": 0}
    )
    found.append((ij, {}))
    ome = tmp_path / "v.ome.tif"
    tifffile.imwrite(
        ome,
        data,
        ome=True,
        metadata={"axes": "ZYX", "PhysicalSizeX": 0, "PhysicalSizeY": 1, "PhysicalSizeZ": 1},
    )
    found.append((ome, {}))
    npy = tmp_path / "v.npy"
    np.save(npy, data)
    found.append((npy, {}))
    header = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 4\nencoding: raw\n"
    for name, extra in (("none", ""), ("nan", "spacings: nan 1 0\n")):
        path = tmp_path / f"{name}.nrrd"
        path.write_bytes((header + extra).encode() + b"\n" + data.tobytes())
        found.append((path, {}))
    common = "ObjectType = Image\nNDims = 3\nDimSize = 5 3 4\nElementType = MET_UCHAR\n"
    for name, extra in (("none", ""), ("zero", "ElementSpacing = 0 1 1\n")):
        path = tmp_path / f"{name}.mha"
        path.write_bytes((common + extra + "ElementDataFile = LOCAL\n").encode() + data.tobytes())
        found.append((path, {}))
    zarr = pytest.importorskip("zarr")
    store = tmp_path / "v.zarr"
    zarr.save_array(str(store), data)
    found.append((store, {}))
    return found


def test_no_missing_spacing_notes_when_spacing_is_given(tmp_path):
    for path, options in _inputs_without_spacing(tmp_path):
        alone = read_volume(path, **options)
        assert any("--spacing" in n for n in alone.notes), (path, alone.notes)
        given = read_volume(path, spacing=(0.5, 0.5, 2), **options)
        assert given.spacing.tolist() == [0.5, 0.5, 2.0]
        assert _spacing_notes(given) == [], (path, given.notes)
        assert "spacing/origin set on the command line" in given.notes
        # the notes that are not about spacing stay
        assert [n for n in alone.notes if n not in _spacing_notes(alone)] == [
            n for n in given.notes if "command line" not in n
        ]


def test_tiff_folder_note_goes_with_spacing(tmp_path):
    """The issue's case: ``convert slices/ --spacing 0.5 0.5 2``."""
    tifffile = pytest.importorskip("tifffile")
    folder = tmp_path / "slices"
    folder.mkdir()
    for k in range(3):
        tifffile.imwrite(folder / f"s{k}.tif", zyx_field()[k], photometric="minisblack")
    assert any(n.startswith("no z spacing in the TIFF") for n in read_volume(folder).notes)
    vol = read_volume(folder, spacing=(0.5, 0.5, 2))
    assert not any("z spacing" in n for n in vol.notes)
    assert vol.notes[0] == "3 slices, s0.tif .. s2.tif"


def test_spacing_notes_stay_when_only_the_origin_is_given_and_origin_notes_go(tmp_path):
    path = tmp_path / "v.nrrd"
    path.write_bytes(
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 4\nencoding: raw\n"
        b"space origin: (1,2)\n\n" + zyx_field().tobytes()
    )
    alone = read_volume(path).notes
    assert "space origin ignored (does not match the volume's axes)" in alone
    assert "no spacing in the file; using 1 (set --spacing)" in alone
    notes = read_volume(path, origin=(1, 2, 3)).notes
    assert "no spacing in the file; using 1 (set --spacing)" in notes
    assert not any("space origin" in n for n in notes)


def test_placement_notes_pickle_as_they_are():
    import pickle

    from isoconvert.readers.options import PlacementNote, without_overridden

    note = PlacementNote("spacing and origin from somewhere", "spacing origin")
    again = pickle.loads(pickle.dumps(note))
    assert again == note and again.about == {"spacing", "origin"}
    assert without_overridden([note, "other"], {"spacing"}) == [note, "other"]
    assert without_overridden([note, "other"], {"spacing", "origin"}) == ["other"]


# --- 5. ASCII NRRD numbers must fit the sample type -----------------------------------------


def _ascii_nrrd(path: Path, kind: str, text: str, sizes="3 2") -> Path:
    path.write_text(
        f"NRRD0004\ntype: {kind}\ndimension: 2\nsizes: {sizes}\nencoding: ascii\n\n{text}\n"
    )
    return path


@pytest.mark.parametrize(
    "kind, text, index, shown, why",
    [
        ("uint8", "1 2 3\n4 300 6", 4, "300", "outside the range 0..255 of type uint8"),
        ("uchar", "1 2 -1 4 5 6", 2, "-1", "outside the range 0..255 of type uchar"),
        ("short", "1 2 3 4 5 40000", 5, "40000", "outside the range -32768..32767 of type short"),
        ("int", "1 2 3 4 2147483648 6", 4, "2147483648", "outside the range -2147483648.."),
        ("int8", "1 99999999999999999999 3 4 5 6", 1, "99999999999999999999", "outside the"),
        ("uint8", "1 2 3.5 4 5 6", 2, "3.5", "not a whole number, as type uint8 needs"),
        ("int16", "1 2 3 4 x 6", 4, "x", "not a whole number, as type int16 needs"),
        ("float", "1 2 3 4 5 1e39", 5, "1e39", "beyond the range of type float"),
        ("double", "1 1e999 3 4 5 6", 1, "1e999", "beyond the range of type double"),
        ("float", "1 2 abc 4 5 6", 2, "abc", "not a number, as type float needs"),
    ],
)
def test_ascii_nrrd_value_the_type_cannot_hold_is_refused(tmp_path, kind, text, index, shown, why):
    path = _ascii_nrrd(tmp_path / "v.nrrd", kind, text)
    with pytest.raises(FormatError) as err:
        read_volume(path)
    message = str(err.value)
    assert message.startswith(
        f"{path}: the NRRD data cannot be read: the ascii data in the file holds {shown} at "
        f"sample index {index} (0-based, in file order), {why}"
    ), message
    assert "\n" not in message


def test_ascii_nrrd_values_at_the_ends_of_the_range_read_exactly(tmp_path):
    cases = {
        "uint8": ("0 255 1 2 3 4", np.uint8),
        "int8": ("-128 127 0 1 2 3", np.int8),
        "uint16": ("0 65535 1 2 3 4", np.uint16),
        "int32": ("-2147483648 2147483647 0 1 2 3", np.int32),
        "uint32": ("0 4294967295 1 2 3 4", np.uint32),
        "float": ("-3.4e38 3.4e38 inf -inf 0.5 1e-3", np.float32),
        "double": ("1e308 -1e308 nan 1 2 3", np.float64),
    }
    for kind, (text, dtype) in cases.items():
        vol = read_volume(_ascii_nrrd(tmp_path / f"{kind}.nrrd", kind, text))
        expected = np.array(text.split(), dtype=np.float64).astype(dtype).reshape(2, 3)
        assert vol.data.dtype == dtype
        assert np.array_equal(vol.data, expected.T, equal_nan=True), kind
    # commas and any whitespace separate numbers
    vol = read_volume(_ascii_nrrd(tmp_path / "commas.nrrd", "short", "1, 2,3\n\t4 5\r\n6"))
    assert vol.data.T.ravel().tolist() == [1, 2, 3, 4, 5, 6]


def test_ascii_nrrd_count_must_match(tmp_path):
    with pytest.raises(FormatError, match="holds 5 numbers, but sizes 3 2 of uint8 need 6"):
        read_volume(_ascii_nrrd(tmp_path / "v.nrrd", "uint8", "1 2 3 4 5"))
    with pytest.raises(FormatError, match="holds 7 numbers, but sizes 3 2 of uint8 need 6"):
        read_volume(_ascii_nrrd(tmp_path / "w.nrrd", "uint8", "1 2 3 4 5 6 7"))


# --- 6. sizes whose product overflows 64 bits -----------------------------------------------

# 2**32 * 2**32 * 2 samples: the product wraps to 0 in int64 (as "need 0" said)
HUGE = (2**32, 2**32, 2)
HUGE_SAMPLES = 2**65


def test_nrrd_huge_sizes_give_the_true_byte_count(tmp_path):
    path = tmp_path / "huge.nrrd"
    path.write_bytes(
        b"NRRD0004\ntype: short\nendian: little\ndimension: 3\nsizes: 4294967296 4294967296 2\n"
        b"encoding: raw\n\n" + bytes(100)
    )
    with pytest.raises(FormatError) as err:
        read_volume(path)
    assert (
        f"the file holds 100 bytes of samples, but sizes 4294967296 4294967296 2 of short "
        f"need {HUGE_SAMPLES * 2};" in str(err.value)
    )
    # split over data files: the count of slices is exact too
    detached = tmp_path / "huge.nhdr"
    (tmp_path / "part.1").write_bytes(bytes(100))
    (tmp_path / "part.2").write_bytes(bytes(100))
    (tmp_path / "part.3").write_bytes(bytes(100))
    detached.write_text(
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 4294967296 4294967296\nencoding: raw\n"
        "data file: part.%d 1 3 1 1\n\n"
    )
    with pytest.raises(FormatError, match=f"3 data files cannot split {2**64} slices evenly"):
        read_volume(detached)


def test_metaimage_huge_dimsize_gives_the_true_byte_count(tmp_path):
    path = tmp_path / "huge.mha"
    path.write_bytes(
        b"NDims = 3\nDimSize = 4294967296 4294967296 2\nElementType = MET_USHORT\n"
        b"ElementDataFile = LOCAL\n" + bytes(100)
    )
    with pytest.raises(FormatError) as err:
        read_volume(path)
    assert f"DimSize 4294967296 4294967296 2 of MET_USHORT need {HUGE_SAMPLES * 2};" in str(
        err.value
    )


def test_raw_huge_shape_gives_the_true_byte_count(tmp_path):
    path = tmp_path / "huge.raw"
    path.write_bytes(bytes(100))
    with pytest.raises(VolumeError) as err:
        read_volume(path, shape=HUGE, dtype="float32")
    assert f"with 0 header bytes needs {HUGE_SAMPLES * 4};" in str(err.value)


def test_npy_huge_shape_gives_the_true_byte_count(tmp_path):
    path = tmp_path / "huge.npy"
    with open(path, "wb") as fh:
        header = {"descr": "<u2", "fortran_order": False, "shape": HUGE[::-1]}
        np.lib.format.write_array_header_1_0(fh, header)
        fh.write(bytes(100))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    assert f"({HUGE_SAMPLES * 2} bytes)" in str(err.value)


def test_nifti2_huge_dims_give_the_true_byte_count(tmp_path):
    nib = pytest.importorskip("nibabel")
    header = nib.Nifti2Header()
    header.set_data_dtype(np.uint8)
    header.set_data_shape(HUGE)
    header["vox_offset"] = 544
    path = tmp_path / "huge.nii"
    path.write_bytes(header.binaryblock + bytes(4) + bytes(100))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    assert f"4294967296x4294967296x2 of uint8 ({HUGE_SAMPLES} bytes)" in str(err.value)


def test_lazy_grid_size_never_wraps():
    from isoconvert.grid import RawGrid

    grid = RawGrid(Path("nothing.raw"), np.dtype(np.uint16), HUGE, 0)
    assert grid.size == HUGE_SAMPLES and grid.nbytes == 2 * HUGE_SAMPLES


def test_nrrd_ignored_directions_keep_their_note_but_not_the_spacing_advice(tmp_path):
    path = tmp_path / "v.nrrd"
    path.write_bytes(
        b"NRRD0004\ntype: uint8\ndimension: 3\nsizes: 5 3 4\nencoding: raw\n"
        b"space: left-posterior-superior\nspace directions: (0.5,0,0) (0,0.25,0) (0,0,0)\n\n"
        + zyx_field().tobytes()
    )
    alone = read_volume(path)
    assert alone.spacing.tolist() == [1, 1, 1]
    assert "no spacing in the file; using 1 (set --spacing)" in alone.notes
    given = read_volume(path, spacing=(1, 2, 3)).notes
    assert not any("--spacing" in n for n in given)
    assert any(n.startswith("space directions in the NRRD header ignored") for n in given)


def test_dicom_one_frame_with_negative_slice_thickness_takes_the_given_spacing(tmp_path):
    pydicom = pytest.importorskip("pydicom")
    from test_dicom_multiframe import write_enhanced

    frames = zyx_field(1, 4, 6, np.int16)
    path = write_enhanced(tmp_path / "one.dcm", frames, [(0.0, 0.0, 0.0)])
    ds = pydicom.dcmread(path)
    ds.SharedFunctionalGroupsSequence[0].PixelMeasuresSequence[0].SliceThickness = -1
    ds.save_as(path)
    vol = read_volume(path, spacing=(0.3, 0.4, 1.5))
    assert vol.spacing.tolist() == [0.3, 0.4, 1.5]
    assert not any("SliceThickness" in n for n in vol.notes)
    alone = read_volume(path)
    assert alone.spacing.tolist() == [0.25, 0.5, 1.0]
    assert (
        "one frame; SliceThickness -1.0 is not a positive number, so z spacing 1; set --spacing"
        in alone.notes
    ), alone.notes


def test_metaimage_non_finite_offset_can_be_set_with_origin(tmp_path):
    path = tmp_path / "v.mha"
    path.write_bytes(
        b"ObjectType = Image\nNDims = 3\nDimSize = 5 3 4\nElementType = MET_UCHAR\n"
        b"Offset = nan 0 inf\nElementDataFile = LOCAL\n" + zyx_field().tobytes()
    )
    vol = read_volume(path, origin=(1, 2, 3))
    assert vol.origin.tolist() == [1, 2, 3]
    assert not any("Offset" in n for n in vol.notes)
    alone = read_volume(path)
    assert alone.origin.tolist() == [0, 0, 0]
    assert "Offset [nan, 0.0, inf] in the MetaImage header ignored; using 0; set --origin" in (
        alone.notes
    )


@pytest.mark.parametrize(
    ("pixdim", "spacing", "says"),
    [
        (0.0, 1.0, "pixdim x 0 is not a voxel size; using 1"),
        (-3.0, 3.0, "pixdim x -3 is negative; using 3"),
        (float("nan"), 1.0, "pixdim x nan is not a voxel size"),
    ],
)
def test_nifti_voxel_size_that_is_none_is_named_in_a_note(tmp_path, pixdim, spacing, says):
    """nibabel replaces such a pixdim while loading (0 by 1, -3 by 3) and only logs it:
    the volume's notes must say what became of it (README: metadata that makes no
    sense is ignored with a note)."""
    nib = pytest.importorskip("nibabel")
    img = nib.Nifti1Image(np.zeros((4, 5, 6), np.uint8), np.diag([2.0, 2.0, 2.0, 1.0]))
    img.header["sform_code"] = 0
    img.header["qform_code"] = 1
    img.header["pixdim"][1] = pixdim
    path = tmp_path / "v.nii"
    # written byte by byte: nibabel's own save would check (and fix) pixdim first
    path.write_bytes(img.header.binaryblock + b"\0" * 4 + bytes(4 * 5 * 6))
    vol = read_volume(path)
    assert vol.spacing[0] == spacing and list(vol.spacing[1:]) == [2.0, 2.0]
    assert any(says in note for note in vol.notes), vol.notes
    placement = [n for n in vol.notes if "placement" in n or "degenerate" in n]
    assert len(placement) == 1, vol.notes  # one word on where it is, not two that disagree


@pytest.mark.parametrize("size", [2**53 + 1, 2**63 - 1, 2**64, 10**23 - 1])
def test_nrrd_sizes_past_64_bit_floats_are_named_exactly(tmp_path, size):
    """pynrrd reads sizes through 64-bit numbers: 2**53 + 1 came out as 2**53 and
    2**63 - 1 or more as -9223372036854775808 ("all must be >= 1")."""
    path = tmp_path / "big.nrrd"
    path.write_text(
        f"NRRD0004\ntype: uint8\ndimension: 3\nsizes: {size} 1 1\nencoding: raw\nendian: little\n\n"
    )
    with pytest.raises(IsoconvertError) as caught:
        read_volume(path)
    message = str(caught.value)
    assert f"sizes {size} 1 1" in message and f"need {size}" in message, message
