"""Enhanced multi-frame DICOM: frames placed from functional groups, sorted, rescaled, errors."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import dataset

from isoconvert import extract, read_volume
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.readers import detect_format

pydicom = pytest.importorskip("pydicom")
from pydicom.data import get_testdata_file  # noqa: E402
from pydicom.dataset import Dataset, FileMetaDataset  # noqa: E402
from pydicom.sequence import Sequence  # noqa: E402
from pydicom.uid import (  # noqa: E402
    EnhancedCTImageStorage,
    ExplicitVRLittleEndian,
    JPEG2000Lossless,
    generate_uid,
)

AXIAL = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
CORONAL = (1.0, 0.0, 0.0, 0.0, 0.0, -1.0)


def item(**attributes) -> Sequence:
    """A functional-group macro: a sequence of one item holding ``attributes``."""
    ds = Dataset()
    for keyword, value in attributes.items():
        setattr(ds, keyword, value)
    return Sequence([ds])


def write_enhanced(
    path,
    frames,
    positions,
    iop=AXIAL,
    *,
    spacing=(0.5, 0.25),
    rescale=None,
    shared_rescale=None,
    top_rescale=None,
    per_frame_iop=None,
    content=None,
    series=None,
    description="synthetic",
    bits=(16, 16, 1),
    syntax=ExplicitVRLittleEndian,
    pixel_data=None,
):
    """An Enhanced CT file of ``frames`` (2D stored arrays), frame i at ``positions[i]``.

    ``rescale``: per-frame (slope, intercept) in PixelValueTransformationSequence;
    ``shared_rescale``: one in the shared groups; ``top_rescale``: top-level attributes.
    ``per_frame_iop``: orientations in the per-frame groups instead of the shared one.
    ``content``: per-frame FrameContentSequence attributes. ``bits``: (BitsAllocated,
    BitsStored, PixelRepresentation).
    """
    frames = np.asarray(frames)
    allocated, stored, signed = bits
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = EnhancedCTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = syntax
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID = EnhancedCTImageStorage
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.SeriesInstanceUID = series or generate_uid()
    ds.SeriesDescription = description
    ds.Modality = "CT"
    ds.NumberOfFrames = len(frames)
    ds.Rows, ds.Columns = frames.shape[1:]
    ds.BitsAllocated, ds.BitsStored, ds.HighBit = allocated, stored, stored - 1
    ds.PixelRepresentation = signed
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME2"
    if top_rescale is not None:
        ds.RescaleSlope, ds.RescaleIntercept = top_rescale
    shared = Dataset()
    shared.PixelMeasuresSequence = item(PixelSpacing=list(spacing), SliceThickness=1.0)
    if per_frame_iop is None:
        shared.PlaneOrientationSequence = item(ImageOrientationPatient=[float(v) for v in iop])
    if shared_rescale is not None:
        slope, intercept = shared_rescale
        shared.PixelValueTransformationSequence = item(
            RescaleSlope=slope, RescaleIntercept=intercept, RescaleType="HU"
        )
    ds.SharedFunctionalGroupsSequence = Sequence([shared])
    groups = []
    for i, position in enumerate(positions):
        frame = Dataset()
        if position is not None:
            frame.PlanePositionSequence = item(ImagePositionPatient=[float(v) for v in position])
        if per_frame_iop is not None:
            frame.PlaneOrientationSequence = item(
                ImageOrientationPatient=[float(v) for v in per_frame_iop[i]]
            )
        if rescale is not None:
            slope, intercept = rescale[i]
            frame.PixelValueTransformationSequence = item(
                RescaleSlope=slope, RescaleIntercept=intercept, RescaleType="HU"
            )
        if content is not None:
            frame.FrameContentSequence = item(**content[i])
        groups.append(frame)
    ds.PerFrameFunctionalGroupsSequence = Sequence(groups)
    if pixel_data is None:
        kind = f"<{'i' if signed else 'u'}{allocated // 8}"
        pixel_data = np.ascontiguousarray(frames, dtype=kind).tobytes()
    ds.PixelData = pixel_data
    ds.save_as(path, enforce_file_format=True)
    return path


def zyx_data(nz=5, ny=4, nx=6) -> np.ndarray:
    z, y, x = np.mgrid[:nz, :ny, :nx]
    return (100 * z + 10 * y + x).astype(np.int16)


def shuffled(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).permutation(n)


def test_shuffled_frames_are_sorted_and_rescaled_per_frame(tmp_path):
    zyx = zyx_data()
    order = shuffled(len(zyx))  # frame i of the file is layer order[i]
    origin, dz = np.array([10.0, -20.0, 30.0]), 2.0
    positions = [origin + k * dz * np.array([0, 0, 1]) for k in order]
    # each layer k its own intercept: a reader that does not sort them with their frames fails
    rescale = [(1, -1000 - 7 * int(k)) for k in order]
    path = write_enhanced(tmp_path / "mf.dcm", zyx[order], positions, rescale=rescale)
    assert detect_format(str(path)) == "dicom"
    vol = read_volume(path)
    expect = zyx.astype(np.int32) - 1000 - 7 * np.arange(len(zyx))[:, None, None]
    assert vol.shape == (6, 4, 5) and vol.frame == "LPS" and vol.unit == "mm"
    assert vol.dtype == np.int32  # the whole int16 stored range, shifted, leaves int16
    np.testing.assert_array_equal(np.asarray(vol.data), expect.T)
    np.testing.assert_allclose(vol.spacing, (0.25, 0.5, 2.0))  # x = column spacing
    np.testing.assert_allclose(vol.origin, origin)
    np.testing.assert_allclose(vol.direction, np.eye(3))
    # lazy: the grid decodes only the frames of a slab, and pickles
    assert type(vol.grid).__name__ == "DicomFramesGrid"
    again = pickle.loads(pickle.dumps(vol.grid))
    np.testing.assert_array_equal(again.read_zyx(1, 3), expect[1:3])
    # the folder holding it reads the same volume
    folder_vol = read_volume(tmp_path)
    np.testing.assert_array_equal(np.asarray(folder_vol.data), expect.T)
    np.testing.assert_array_equal(folder_vol.origin, vol.origin)


def test_oblique_decreasing_positions_and_per_frame_orientation(tmp_path):
    c, s = np.cos(0.3), np.sin(0.3)
    row = np.array([c, s, 0.0])
    col = np.array([0.0, np.cos(0.2), np.sin(0.2)])
    col = col - (col @ row) * row
    col /= np.linalg.norm(col)
    normal = np.cross(row, col)
    zyx = zyx_data()
    order = shuffled(len(zyx), seed=3)
    origin = np.array([10.0, -20.0, 30.0])
    # positions decrease along the normal as k grows: layer 4 must come first
    positions = [origin - k * 1.5 * normal for k in order]
    iops = [(*row, *col)] * len(zyx)
    path = write_enhanced(tmp_path / "o.dcm", zyx[order], positions, per_frame_iop=iops)
    vol = read_volume(path)
    np.testing.assert_array_equal(np.asarray(vol.data), zyx[::-1].T)
    np.testing.assert_allclose(vol.direction, np.column_stack([row, col, normal]), atol=1e-9)
    np.testing.assert_allclose(vol.spacing, (0.25, 0.5, 1.5))
    np.testing.assert_allclose(vol.origin, origin - 4 * 1.5 * normal, atol=1e-9)
    corner = vol.index_to_world(np.array([[5.0, 3.0, 4.0]]))[0]
    expect = origin + 5 * 0.25 * row + 3 * 0.5 * col
    np.testing.assert_allclose(corner, expect, atol=1e-6)


def test_shared_and_top_level_rescale(tmp_path):
    zyx = zyx_data()
    positions = [(0, 0, k) for k in range(len(zyx))]
    path = write_enhanced(tmp_path / "s.dcm", zyx, positions, shared_rescale=(0.5, -10.25))
    vol = read_volume(path)
    assert vol.dtype == np.float32
    np.testing.assert_allclose(np.asarray(vol.data), zyx.T * 0.5 - 10.25)
    # 12 stored bits, top-level rescale only: fits int16 after the shift
    path = write_enhanced(
        tmp_path / "t.dcm", zyx, positions, top_rescale=(1, -1024), bits=(16, 12, 1)
    )
    vol = read_volume(path)
    assert vol.dtype == np.int16
    np.testing.assert_array_equal(np.asarray(vol.data), zyx.T.astype(np.int32) - 1024)
    # the functional groups win over the top-level attributes
    path = write_enhanced(
        tmp_path / "u.dcm", zyx, positions, top_rescale=(1, -1024), shared_rescale=(2, 5)
    )
    np.testing.assert_array_equal(
        np.asarray(read_volume(path).data), zyx.T.astype(np.int32) * 2 + 5
    )


def test_multiframe_files_are_series_in_the_listing(tmp_path):
    a, b = zyx_data(nz=3), zyx_data(nz=4) + 7
    write_enhanced(tmp_path / "a.dcm", a, [(0, 0, k) for k in range(3)], series="1.2.3.1")
    write_enhanced(
        tmp_path / "b.dcm", b, [(0, 0, k) for k in range(4)], series="1.2.3.2", description="bone"
    )
    with pytest.raises(FormatError) as e:
        read_volume(tmp_path)
    message = str(e.value)
    assert "\n" not in message and "--series UID" in message
    assert "1.2.3.2 (bone, one multi-frame file of 4 frames)" in message
    np.testing.assert_array_equal(np.asarray(read_volume(tmp_path, series="1.2.3.2").data), b.T)
    # a file is its own volume
    np.testing.assert_array_equal(np.asarray(read_volume(tmp_path / "a.dcm").data), a.T)


def test_two_multiframe_files_of_one_series_are_refused(tmp_path):
    a = zyx_data(nz=3)
    for name in ("a.dcm", "b.dcm"):
        write_enhanced(tmp_path / name, a, [(0, 0, k) for k in range(3)], series="1.2.3.1")
    with pytest.raises(FormatError, match=r"2 of them multi-frame \(a\.dcm, b\.dcm\).*give one"):
        read_volume(tmp_path)


def run_cli(capsys, tmp_path, path):
    out = tmp_path / "out.ply"
    code = main(["convert", str(path), "-o", str(out), "--level", "0.5"])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code != 0
    assert len(lines) == 1 and lines[0].startswith("isoconvert: error: "), err
    assert "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob("*.ply*"))
    return lines[0]


def bad_repeated(path):
    # two temporal positions of 3 slices each, frames interleaved
    zyx = zyx_data(nz=6)
    positions = [(0, 0, k % 3) for k in range(6)]
    content = [{"TemporalPositionIndex": 1 + k // 3} for k in range(6)]
    return write_enhanced(path, zyx, positions, content=content)


def bad_orientations(path):
    zyx = zyx_data(nz=4)
    iops = [AXIAL, AXIAL, CORONAL, AXIAL]
    return write_enhanced(path, zyx, [(0, 0, k) for k in range(4)], per_frame_iop=iops)


def bad_missing_position(path):
    positions = [(0, 0, 0), (0, 0, 1), None, (0, 0, 3)]
    return write_enhanced(path, zyx_data(nz=4), positions)


def bad_uneven(path):
    positions = [(0, 0, z) for z in (0.0, 1.0, 2.0, 3.5, 4.5)]
    return write_enhanced(path, zyx_data(nz=5), positions[::-1])


@pytest.mark.parametrize(
    ("make", "needles"),
    [
        (
            bad_repeated,
            ["6 frames at only 3 distinct positions", "2 temporal positions", "--volume-index"],
        ),
        (
            bad_orientations,
            ["2 different orientations", "frame 3 [1, 0, 0, 0, 0, -1]", "read one stack"],
        ),
        (bad_missing_position, ["frame 3 of 4 has no valid ImagePositionPatient"]),
        (bad_uneven, ["uneven frame spacing: median gap 1 mm", "max 1.5 mm", "resample"]),
    ],
)
def test_bad_files_give_one_line(capsys, tmp_path, make, needles):
    path = make(tmp_path / "bad.dcm")
    line = run_cli(capsys, tmp_path, path)
    assert str(path) in line
    for needle in needles:
        assert needle in line, (needle, line)


def test_multiframe_without_functional_groups_is_refused(capsys, tmp_path):
    path = get_testdata_file("rtdose.dcm", download=False)  # 15 frames, GridFrameOffsetVector
    if path is None:
        pytest.skip("pydicom's test file rtdose.dcm is not available offline")
    line = run_cli(capsys, tmp_path, path)
    assert "15 frames" in line and "without per-frame functional groups" in line


def test_compressed_frames_name_the_decoder(tmp_path):
    zyx = zyx_data(nz=2)
    fake = pydicom.encaps.encapsulate([b"\xff\x4f\xff\x51" + bytes(20)] * 2)
    path = write_enhanced(
        tmp_path / "c.dcm",
        zyx,
        [(0, 0, 0), (0, 0, 1)],
        syntax=JPEG2000Lossless,
        pixel_data=fake,
    )
    vol = read_volume(path)  # headers only: nothing decoded yet
    with pytest.raises(FormatError, match=r"JPEG 2000.*pylibjpeg") as e:
        vol.grid.read_zyx(0, 1)
    assert "\n" not in str(e.value)


def test_enhanced_mr_test_file_against_functional_groups():
    path = get_testdata_file("emri_small.dcm", download=False)
    if path is None:
        pytest.skip("pydicom's test file emri_small.dcm is not available offline")
    ds = pydicom.dcmread(path)
    shared = ds.SharedFunctionalGroupsSequence[0]

    def macro(frame, name):
        return (frame.get(name) or shared.get(name))[0]

    frames = ds.PerFrameFunctionalGroupsSequence
    ipp = np.array(
        [[float(v) for v in macro(f, "PlanePositionSequence").ImagePositionPatient] for f in frames]
    )
    iop = np.array(
        [float(v) for v in macro(frames[0], "PlaneOrientationSequence").ImageOrientationPatient]
    )
    normal = np.cross(iop[:3], iop[3:])
    along = ipp @ normal
    order = np.argsort(along, kind="stable")
    if np.any(np.diff(along[order]) <= 0.01):
        with pytest.raises(FormatError, match="distinct positions"):
            read_volume(path)
        return
    stored = ds.pixel_array.reshape(len(frames), ds.Rows, ds.Columns)
    expect = stored[order].astype(np.float64)
    for z, k in enumerate(order):
        seq = frames[k].get("PixelValueTransformationSequence") or shared.get(
            "PixelValueTransformationSequence"
        )
        if seq:
            expect[z] = expect[z] * float(seq[0].RescaleSlope) + float(seq[0].RescaleIntercept)
    vol = read_volume(path)
    np.testing.assert_allclose(np.asarray(vol.data, dtype=np.float64), expect.T)
    pixel = [float(v) for v in macro(frames[0], "PixelMeasuresSequence").PixelSpacing]
    dz = float(np.median(np.diff(along[order])))
    np.testing.assert_allclose(vol.spacing, (pixel[1], pixel[0], dz), rtol=1e-6)
    np.testing.assert_allclose(vol.origin, ipp[order[0]])
    np.testing.assert_allclose(vol.direction, np.column_stack([iop[:3], iop[3:], normal]))


def test_real_ct_as_enhanced_file_matches_the_series(tmp_path):
    folder = dataset("ct_chest_LIDC-IDRI-0314_dicom")
    files = sorted(p for p in folder.iterdir() if p.is_file())
    slices = [pydicom.dcmread(p) for p in files]
    order = shuffled(len(slices), seed=11)  # frames written in an order unrelated to position
    first = slices[0]
    frames = np.stack([slices[k].pixel_array for k in order])
    bits = (int(first.BitsAllocated), int(first.BitsStored), int(first.PixelRepresentation))
    path = write_enhanced(
        tmp_path / "ct_enhanced.dcm",
        frames,
        [slices[k].ImagePositionPatient for k in order],
        [float(v) for v in first.ImageOrientationPatient],
        spacing=[float(v) for v in first.PixelSpacing],
        rescale=[(slices[k].RescaleSlope, slices[k].RescaleIntercept) for k in order],
        bits=bits,
    )
    del slices, frames
    series = read_volume(folder)
    multi = read_volume(path)
    assert multi.shape == series.shape == (512, 512, 64)
    assert multi.dtype == series.dtype
    np.testing.assert_array_equal(multi.spacing, series.spacing)
    np.testing.assert_array_equal(multi.origin, series.origin)
    np.testing.assert_array_equal(multi.direction, series.direction)
    a = multi.grid.read_zyx(0, 64)
    b = series.grid.read_zyx(0, 64)
    np.testing.assert_array_equal(a, b)
    assert a.min() == -1000  # rescaled to HU from the functional groups
    mesh_multi = extract(multi, 300.5)
    mesh_series = extract(series, 300.5)
    assert len(mesh_series.cells) > 1000
    np.testing.assert_array_equal(mesh_multi.vertices, mesh_series.vertices)
    np.testing.assert_array_equal(mesh_multi.cells, mesh_series.cells)
