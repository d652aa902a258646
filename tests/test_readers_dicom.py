"""DICOM series: sorting by position, placement (LPS), rescaling, series choice, errors."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import dataset, vtk_flying_edges

from isoconvert import extract, read_volume
from isoconvert.errors import FormatError
from isoconvert.readers import detect_format, unsupported_format

pydicom = pytest.importorskip("pydicom")
from pydicom.dataset import Dataset, FileMetaDataset  # noqa: E402
from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid  # noqa: E402

AXIAL = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


def write_slice(
    path,
    image,
    position,
    iop=AXIAL,
    series="1.2.3.4",
    instance=1,
    slope=None,
    intercept=None,
    description="synthetic",
    spacing=(0.5, 0.25),
    bits=16,
    number=None,
):
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = CTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = CTImageStorage
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID = series
    ds.SeriesDescription = description
    if number is not None:
        ds.SeriesNumber = number
    ds.InstanceNumber = instance
    ds.ImagePositionPatient = [float(v) for v in position]
    ds.ImageOrientationPatient = [float(v) for v in iop]
    ds.PixelSpacing = list(spacing)  # [row spacing (y), column spacing (x)]
    ds.Rows, ds.Columns = image.shape
    ds.BitsAllocated = 16
    ds.BitsStored = bits
    ds.HighBit = bits - 1
    ds.PixelRepresentation = 1
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    if slope is not None:
        ds.RescaleSlope = slope
        ds.RescaleIntercept = intercept
    ds.PixelData = np.ascontiguousarray(image, dtype="<i2").tobytes()
    ds.save_as(path, enforce_file_format=True)


def zyx_data(nz=5, ny=4, nx=6) -> np.ndarray:
    z, y, x = np.mgrid[:nz, :ny, :nx]
    return (100 * z + 10 * y + x).astype(np.int16)


def write_series(folder, zyx, iop=AXIAL, dz=2.0, origin=(10.0, -20.0, 30.0), seed=0, **kw):
    """Slice k at origin + k * dz * normal, in files named and numbered in shuffled order."""
    folder.mkdir(parents=True, exist_ok=True)
    normal = np.cross(iop[:3], iop[3:])
    order = np.random.default_rng(seed).permutation(len(zyx))
    for name, k in enumerate(order):
        position = np.asarray(origin) + k * dz * normal
        instance = int(order[-1 - name]) + 1
        write_slice(folder / f"IM{name:03d}", zyx[k], position, iop, instance=instance, **kw)
    return folder


def test_shuffled_files_are_sorted_by_position(tmp_path):
    zyx = zyx_data()
    folder = write_series(tmp_path / "s", zyx)
    assert detect_format(str(folder)) == "dicom"
    vol = read_volume(folder)
    assert vol.shape == (6, 4, 5) and vol.frame == "LPS" and vol.unit == "mm"
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T)
    np.testing.assert_allclose(vol.spacing, (0.25, 0.5, 2.0))  # x = column spacing
    np.testing.assert_allclose(vol.origin, (10, -20, 30))
    assert vol.grid is not None
    again = pickle.loads(pickle.dumps(vol.grid))
    np.testing.assert_array_equal(again.read_zyx(1, 3), zyx[1:3])
    # one file of the series reads the whole series
    one = read_volume(folder / "IM002")
    np.testing.assert_array_equal(np.asarray(one.data), zyx.T)


def test_oblique_orientation_places_corners(tmp_path):
    c, s = np.cos(0.3), np.sin(0.3)
    iop = (c, s, 0.0, 0.0, c * 0 + np.cos(0.2), np.sin(0.2))
    row = np.array(iop[:3])
    col = np.array(iop[3:])
    col = col - (col @ row) * row
    col /= np.linalg.norm(col)
    iop = (*row, *col)
    zyx = zyx_data()
    vol = read_volume(write_series(tmp_path / "s", zyx, iop=iop, dz=1.5))
    normal = np.cross(row, col)
    np.testing.assert_allclose(vol.direction, np.column_stack([row, col, normal]), atol=1e-9)
    corner = vol.index_to_world(np.array([[5.0, 3.0, 4.0]]))[0]
    expect = np.array([10, -20, 30]) + 5 * 0.25 * row + 3 * 0.5 * col + 4 * 1.5 * normal
    np.testing.assert_allclose(corner, expect, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T)


def test_positions_decreasing_along_normal(tmp_path):
    zyx = zyx_data()
    vol = read_volume(write_series(tmp_path / "s", zyx, dz=-1.0))
    # sorted so that positions increase along the normal: slice 4 comes first
    np.testing.assert_array_equal(np.asarray(vol.data), zyx[::-1].T)
    np.testing.assert_allclose(vol.origin, (10, -20, 26))
    np.testing.assert_allclose(vol.spacing[2], 1.0)


def test_slope_and_intercept(tmp_path):
    zyx = zyx_data()
    # the type holds the whole stored range (BitsStored) rescaled, not just these values
    vol = read_volume(write_series(tmp_path / "i", zyx, slope=1, intercept=-1024, bits=12))
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T.astype(np.int32) - 1024)
    vol = read_volume(write_series(tmp_path / "j", zyx, slope=1, intercept=-1024))
    assert vol.dtype == np.int32  # -32768 - 1024 does not fit int16
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T.astype(np.int32) - 1024)
    vol = read_volume(write_series(tmp_path / "f", zyx, slope=0.5, intercept=-10.25))
    assert vol.dtype == np.float32
    np.testing.assert_allclose(np.asarray(vol.data), zyx.T * 0.5 - 10.25)
    # a slope that takes int16 beyond its range widens the type
    vol = read_volume(write_series(tmp_path / "w", zyx, slope=4, intercept=0))
    assert vol.dtype == np.int32
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T.astype(np.int32) * 4)


def test_missing_slice_is_an_error(tmp_path):
    folder = write_series(tmp_path / "s", zyx_data(nz=6))
    files = sorted(folder.iterdir())
    by_z = sorted(files, key=lambda f: float(pydicom.dcmread(f).ImagePositionPatient[2]))
    by_z[3].unlink()
    with pytest.raises(FormatError, match=r"uneven slice spacing: median gap 2 mm.*max 4 mm") as e:
        read_volume(folder)
    assert "\n" not in str(e.value) and by_z[2].name in str(e.value)


def test_uneven_spacing_is_an_error(tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    for k, z in enumerate([0.0, 1.0, 2.0, 3.1, 4.1]):
        write_slice(folder / f"{k}.dcm", zyx_data()[k], (0, 0, z))
    with pytest.raises(FormatError, match=r"uneven slice spacing.*min 0\.9|uneven.*max 1\.1"):
        read_volume(folder)


def test_duplicate_positions_are_an_error(tmp_path):
    folder = write_series(tmp_path / "s", zyx_data())
    write_slice(folder / "extra", zyx_data()[0], (10.0, -20.0, 30.0))
    with pytest.raises(FormatError, match="duplicate slice position"):
        read_volume(folder)


def test_two_series_need_series_option(tmp_path):
    folder = tmp_path / "s"
    a, b = zyx_data(nz=3), zyx_data(nz=4) + 7
    write_series(folder, a, series="1.2.3.1", description="lung")
    for k in range(4):
        write_slice(folder / f"B{k}", b[k], (0, 0, k), series="1.2.3.2", description="bone")
    with pytest.raises(FormatError) as e:
        read_volume(folder)
    message = str(e.value)
    assert "\n" not in message and "--series UID" in message
    assert "1.2.3.1 (lung, 3 slices)" in message and "1.2.3.2 (bone, 4 slices)" in message
    vol = read_volume(folder, series="1.2.3.2")
    np.testing.assert_array_equal(np.asarray(vol.data), b.T)
    # a file picks its own series
    np.testing.assert_array_equal(np.asarray(read_volume(folder / "B1").data), b.T)
    with pytest.raises(FormatError, match="no series 9.9"):
        read_volume(folder, series="9.9")


def test_series_option_is_refused_elsewhere(tmp_path):
    from isoconvert.errors import VolumeError

    path = tmp_path / "a.npy"
    np.save(path, np.zeros((2, 2, 2)))
    with pytest.raises(VolumeError, match="--series do"):
        read_volume(path, series="1.2")


def test_non_dicom_files_are_ignored_with_a_note(tmp_path):
    zyx = zyx_data()
    folder = write_series(tmp_path / "s", zyx)
    (folder / "README").write_text("scanned on a Tuesday\n")
    (folder / "DICOMDIR").write_bytes(bytes(200))
    assert unsupported_format(folder) is None
    vol = read_volume(folder)
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T)
    assert any("README" in n and "not DICOM" in n for n in vol.notes)


def test_compressed_syntax_names_the_plugin(tmp_path, monkeypatch):
    from pydicom.uid import JPEG2000Lossless

    folder = write_series(tmp_path / "s", zyx_data(nz=2))
    for f in folder.iterdir():
        ds = pydicom.dcmread(f)
        ds.file_meta.TransferSyntaxUID = JPEG2000Lossless
        ds.PixelData = pydicom.encaps.encapsulate([b"\xff\x4f\xff\x51" + bytes(20)])
        ds.save_as(f)
    with pytest.raises(FormatError, match=r"JPEG 2000.*pylibjpeg") as e:
        np.asarray(read_volume(folder).data)
    assert "\n" not in str(e.value)


def test_real_ct_series():
    folder = dataset("ct_chest_LIDC-IDRI-0314_dicom")
    vol = read_volume(folder)
    assert vol.shape == (512, 512, 64) and vol.frame == "LPS"
    np.testing.assert_allclose(vol.spacing, (0.78125, 0.78125, 1.0), rtol=1e-6)
    zyx = vol.grid.read_zyx(0, 64)
    assert zyx.min() == -1000 and zyx.max() == 1761  # HU, air at -1000
    # slices in increasing z: the origin is the lowest slice's IPP
    files = sorted(p for p in folder.iterdir() if p.is_file())
    headers = [pydicom.dcmread(p, stop_before_pixels=True) for p in files]
    ipps = np.array([[float(v) for v in h.ImagePositionPatient] for h in headers])
    low, high = ipps[np.argmin(ipps[:, 2])], ipps[np.argmax(ipps[:, 2])]
    np.testing.assert_allclose(vol.origin, low, atol=1e-4)
    far = vol.index_to_world(np.array([[511.0, 511.0, 63.0]]))[0]
    np.testing.assert_allclose(far, high + [511 * 0.78125, 511 * 0.78125, 0], atol=1e-3)
    # a half-integer HU level: VTK's vertex and triangle counts on the same samples
    whole = extract(vol, -400.5)
    points, triangles = vtk_flying_edges(zyx, -400.5)
    assert len(whole.vertices) == len(points) and len(whole.cells) == len(triangles)
    lo, hi = whole.vertices.min(axis=0), whole.vertices.max(axis=0)
    assert np.all(lo >= vol.origin - 1e-3) and np.all(hi <= far + 1e-3)
