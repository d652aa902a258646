"""Issue 11: NumPy (.npy, .npz) and MetaImage (.mhd, .mha) readers."""

from __future__ import annotations

import gzip
import zlib

import numpy as np
import pytest
from conftest import ball, dataset, edge_key

from isoconvert import extract, read_volume
from isoconvert.errors import FormatError, VolumeError
from isoconvert.extract.blocks import Blocks
from isoconvert.grid import RawGrid
from isoconvert.readers import detect_format, unsupported_format


@pytest.fixture
def zyx() -> np.ndarray:
    """A (z, y, x) = (6, 5, 7) float32 field with a closed surface at 0.5, all axes distinct."""
    x, y, z = np.meshgrid(np.arange(7.0), np.arange(5.0), np.arange(6.0), indexing="ij")
    field = 2.2 - np.sqrt((x - 3.1) ** 2 + (y - 2.2) ** 2 + (z - 2.6) ** 2)
    return np.ascontiguousarray(field.T, dtype=np.float32)


def same_mesh(a, b) -> None:
    assert (a.n_vertices, a.n_cells) == (b.n_vertices, b.n_cells)
    ka, ta = edge_key(a.vertices)
    kb, tb = edge_key(b.vertices)
    assert np.array_equal(ka, kb) and np.allclose(ta, tb)


# --- NumPy ----------------------------------------------------------------------------------


def test_npy_c_order_is_zyx_and_lazy(tmp_path, zyx):
    path = tmp_path / "v.npy"
    np.save(path, zyx)
    assert detect_format(str(path)) == "numpy"
    vol = read_volume(path)
    assert isinstance(vol.grid, RawGrid) and vol.shape == (7, 5, 6)
    assert np.array_equal(vol.data, zyx.T)
    assert vol.data[3, 1, 4] == zyx[4, 1, 3]
    assert any("using 1" in n and "--spacing" in n for n in vol.notes)
    whole = extract(read_volume(path), 0.5)
    assert whole.n_cells > 0
    same_mesh(extract(vol, 0.5, blocks=Blocks(size=3)), whole)


def test_npy_fortran_order_is_xyz(tmp_path, zyx):
    xyz = zyx.T  # F-contiguous: np.save writes it in Fortran order
    assert xyz.flags.f_contiguous and not xyz.flags.c_contiguous
    path = tmp_path / "f.npy"
    np.save(path, xyz)
    with open(path, "rb") as fh:
        np.lib.format.read_magic(fh)
        assert np.lib.format.read_array_header_1_0(fh)[1] is True
    vol = read_volume(path)
    assert isinstance(vol.grid, RawGrid)
    assert np.array_equal(vol.data, xyz)  # a[i, j, k] is (x, y, z)
    assert any("Fortran" in n for n in vol.notes)
    # the same volume as the C-ordered (z, y, x) file
    np.save(tmp_path / "c.npy", zyx)
    same_mesh(extract(vol, 0.5), extract(read_volume(tmp_path / "c.npy"), 0.5))
    same_mesh(extract(vol, 0.5, blocks=Blocks(size=2)), extract(vol, 0.5))


def test_npy_2d_images_and_spacing(tmp_path):
    img = np.arange(12, dtype=np.uint16).reshape(3, 4)  # (y, x)
    np.save(tmp_path / "c.npy", img)
    np.save(tmp_path / "f.npy", np.asfortranarray(img.T))  # (x, y) in Fortran order
    for name in ("c.npy", "f.npy"):
        vol = read_volume(tmp_path / name, spacing=(0.5, 2.0))
        assert vol.shape == (4, 3) and vol.data[3, 1] == img[1, 3], name
        assert vol.spacing.tolist() == [0.5, 2.0]


def test_npy_bool_is_a_mask_and_complex_is_refused(tmp_path):
    mask = ball(7, 2.5) > 0
    np.save(tmp_path / "m.npy", mask)
    vol = read_volume(tmp_path / "m.npy")
    assert vol.dtype == np.uint8 and np.array_equal(vol.data, mask.T.astype(np.uint8))
    assert extract(vol, 0.5).n_cells > 0
    np.save(tmp_path / "c.npy", np.ones((3, 4, 5), np.complex64))
    with pytest.raises(VolumeError, match=r"c\.npy: .*complex64.*np\.abs"):
        read_volume(tmp_path / "c.npy")
    np.save(tmp_path / "o.npy", np.array([[None, 1], [2, 3]], dtype=object), allow_pickle=True)
    with pytest.raises(VolumeError, match=r"o\.npy: .*object"):
        read_volume(tmp_path / "o.npy")
    np.save(tmp_path / "v.npy", np.ones(5))
    with pytest.raises(VolumeError, match=r"shape \(5,\), not a 2D or 3D"):
        read_volume(tmp_path / "v.npy")


def test_npy_truncated_or_not_npy(tmp_path, zyx):
    path = tmp_path / "t.npy"
    np.save(path, zyx)
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(FormatError, match=r"t\.npy: .*truncated") as err:
        read_volume(path)
    assert "\n" not in str(err.value)
    (tmp_path / "x.npy").write_bytes(b"not numpy at all")
    with pytest.raises(FormatError, match=r"x\.npy: not a readable \.npy"):
        read_volume(tmp_path / "x.npy")
    with pytest.raises(VolumeError, match="--key picks an array of a .npz"):
        read_volume(tmp_path / "x.npy", key="a")


def test_npz_one_array_several_and_key(tmp_path, zyx):
    one = tmp_path / "one.npz"
    np.savez_compressed(one, volume=zyx)
    assert detect_format(str(one)) == "numpy"
    assert np.array_equal(read_volume(one).data, zyx.T)
    many = tmp_path / "many.npz"
    np.savez(many, image=zyx, labels=(zyx > 0.5).astype(np.uint8), x=np.arange(3))
    with pytest.raises(VolumeError) as err:
        read_volume(many)
    msg = str(err.value)
    assert "\n" not in msg and "many.npz" in msg and "--key" in msg
    assert "image (6, 5, 7) float32" in msg and "labels (6, 5, 7) uint8" in msg
    vol = read_volume(many, key="labels")
    assert vol.dtype == np.uint8 and np.array_equal(vol.data, (zyx.T > 0.5))
    assert any("'labels'" in n for n in vol.notes)
    with pytest.raises(VolumeError, match=r"no array 'nope'; it holds image"):
        read_volume(many, key="nope")
    with pytest.raises(VolumeError, match=r"'x' has shape \(3,\)"):
        read_volume(many, key="x")
    with pytest.raises(VolumeError, match="do not apply|do\\(es\\) not apply"):
        read_volume(tmp_path / "one.npz", shape=(1, 2, 3))


def test_npz_bomb_is_not_inflated_past_the_header(tmp_path):
    import zipfile

    path = tmp_path / "bomb.npz"
    header = tmp_path / "h.npy"
    np.save(header, np.zeros((4, 4, 4), np.uint8))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("volume.npy", header.read_bytes() + bytes(64 << 20))
    vol = read_volume(path)  # reads the 64 declared bytes, not 64 MiB
    assert vol.shape == (4, 4, 4)


# --- MetaImage ------------------------------------------------------------------------------


def mhd_text(**fields) -> str:
    base = {"ObjectType": "Image", "NDims": 3}
    base.update(fields)
    data = base.pop("ElementDataFile")
    lines = [f"{k} = {v}" for k, v in base.items()] + [f"ElementDataFile = {data}"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("met", "dtype"),
    [
        ("MET_UCHAR", "u1"),
        ("MET_CHAR", "i1"),
        ("MET_USHORT", "u2"),
        ("MET_SHORT", "i2"),
        ("MET_UINT", "u4"),
        ("MET_INT", "i4"),
        ("MET_LONG", "i4"),
        ("MET_LONG_LONG", "i8"),
        ("MET_FLOAT", "f4"),
        ("MET_DOUBLE", "f8"),
    ],
)
@pytest.mark.parametrize("msb", [False, True])
def test_mhd_types_and_byte_order(tmp_path, zyx, met, dtype, msb):
    values = (zyx * 40 + 50).astype(dtype)
    order = ">" if msb else "<"
    values.astype(values.dtype.newbyteorder(order)).tofile(tmp_path / "v.raw")
    (tmp_path / "v.mhd").write_text(
        mhd_text(
            DimSize="7 5 6",
            ElementType=met,
            ElementSpacing="0.5 1 2",
            BinaryDataByteOrderMSB=str(msb),
            ElementDataFile="v.raw",
        )
    )
    vol = read_volume(tmp_path / "v.mhd")
    assert isinstance(vol.grid, RawGrid)
    assert vol.spacing.tolist() == [0.5, 1.0, 2.0]
    assert np.array_equal(np.asarray(vol.data, dtype=np.float64), values.T.astype(np.float64))


def test_mhd_header_size_minus_one_and_local_mha(tmp_path, zyx):
    (tmp_path / "v.raw").write_bytes(b"junk" * 5 + zyx.tobytes())
    (tmp_path / "v.mhd").write_text(
        mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", HeaderSize=-1, ElementDataFile="v.raw")
    )
    vol = read_volume(tmp_path / "v.mhd")
    assert vol.grid.offset == 20 and np.array_equal(vol.data, zyx.T)
    (tmp_path / "w.mhd").write_text(
        mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", HeaderSize=20, ElementDataFile="v.raw")
    )
    assert np.array_equal(read_volume(tmp_path / "w.mhd").data, zyx.T)
    mha = tmp_path / "v.mha"
    head = mhd_text(
        DimSize="7 5 6", ElementType="MET_FLOAT", Offset="1 2 3", ElementDataFile="LOCAL"
    )
    mha.write_bytes(head.encode() + zyx.tobytes())
    vol = read_volume(mha)
    assert isinstance(vol.grid, RawGrid) and np.array_equal(vol.data, zyx.T)
    assert vol.origin.tolist() == [1.0, 2.0, 3.0]
    same_mesh(extract(vol, 0.5, blocks=Blocks(size=3)), extract(read_volume(mha), 0.5))


@pytest.mark.parametrize("suffix", [".mha", ".mhd"])
def test_compressed(tmp_path, zyx, suffix):
    stream = zlib.compress(zyx.astype(">i2").tobytes())
    fields = dict(
        DimSize="7 5 6",
        ElementType="MET_SHORT",
        ElementByteOrderMSB="True",
        CompressedData="True",
        CompressedDataSize=len(stream),
    )
    path = tmp_path / f"v{suffix}"
    if suffix == ".mha":
        path.write_bytes(mhd_text(**fields, ElementDataFile="LOCAL").encode() + stream)
    else:
        (tmp_path / "v.zraw").write_bytes(stream)
        path.write_text(mhd_text(**fields, ElementDataFile="v.zraw"))
    vol = read_volume(path)
    assert np.array_equal(vol.data, zyx.astype(np.int16).T)


def test_list_and_numbered_slice_files(tmp_path, zyx):
    for k, layer in enumerate(zyx):
        layer.tofile(tmp_path / f"s{k:02d}.raw")
    names = "\n".join(f"s{k:02d}.raw" for k in range(6))
    (tmp_path / "l.mhd").write_text(
        mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", ElementDataFile="LIST") + names + "\n"
    )
    assert np.array_equal(read_volume(tmp_path / "l.mhd").data, zyx.T)
    (tmp_path / "n.mhd").write_text(
        mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", ElementDataFile="s%02d.raw 0 5 1")
    )
    assert np.array_equal(read_volume(tmp_path / "n.mhd").data, zyx.T)
    (tmp_path / "s03.raw").unlink()
    with pytest.raises(
        FormatError, match=r"l\.mhd: its data file s03\.raw is missing.*ElementDataFile"
    ):
        read_volume(tmp_path / "l.mhd")


def test_transform_matrix_rows_are_axis_directions(tmp_path, zyx):
    """ITK writes the direction of grid axis i as the i-th triple of TransformMatrix."""
    # axis x -> world (0, 1, 0), axis y -> world (0, 0, 1)... a non-symmetric matrix
    ax, ay, az = (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
    matrix = " ".join(map(str, ax + ay + az))
    zyx.tofile(tmp_path / "v.raw")
    (tmp_path / "v.mhd").write_text(
        mhd_text(
            DimSize="7 5 6",
            ElementType="MET_FLOAT",
            ElementSpacing="2 3 4",
            Offset="10 20 30",
            TransformMatrix=matrix,
            ElementDataFile="v.raw",
        )
    )
    vol = read_volume(tmp_path / "v.mhd")
    assert not np.allclose(vol.direction, vol.direction.T)
    # grid vertex (1, 0, 0) lies one x step (2) along ax; (0, 1, 0) one y step (3) along ay
    world = vol.index_to_world(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [6, 4, 5]]))
    expected = [
        [10, 22, 30],
        [10, 20, 33],
        [14, 20, 30],
        [10 + 5 * 4, 20 + 6 * 2, 30 + 4 * 3],
    ]
    assert np.allclose(world, expected)


def test_channels_need_channel(tmp_path, zyx):
    rgb = np.stack([zyx, -zyx, 2 * zyx], axis=-1)  # channels fastest
    rgb.tofile(tmp_path / "c.raw")
    (tmp_path / "c.mhd").write_text(
        mhd_text(
            DimSize="7 5 6",
            ElementType="MET_FLOAT",
            ElementNumberOfChannels=3,
            ElementDataFile="c.raw",
        )
    )
    with pytest.raises(VolumeError, match=r"3 values per sample.*--channel 0\.\.2"):
        read_volume(tmp_path / "c.mhd")
    assert np.array_equal(read_volume(tmp_path / "c.mhd", channel=2).data, 2 * zyx.T)


def test_2d_metaimage(tmp_path):
    img = np.arange(12, dtype=np.uint8).reshape(3, 4)
    img.tofile(tmp_path / "i.raw")
    (tmp_path / "i.mhd").write_text(
        mhd_text(NDims=2, DimSize="4 3", ElementType="MET_UCHAR", ElementDataFile="i.raw")
    )
    vol = read_volume(tmp_path / "i.mhd")
    assert vol.shape == (4, 3) and vol.data[3, 1] == img[1, 3]


@pytest.mark.parametrize("compress", [False, True])
def test_vtk_metaimage_writer_reads_back(tmp_path, zyx, compress):
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(7, 5, 6)
    image.SetSpacing(0.5, 1.5, 2.5)
    image.SetOrigin(-1, 2, 3)
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.ravel(), deep=True))
    writer = vtk.vtkMetaImageWriter()
    writer.SetInputData(image)
    writer.SetFileName(str(tmp_path / "w.mhd"))
    writer.SetCompression(compress)
    writer.Write()
    vol = read_volume(tmp_path / "w.mhd")
    assert np.array_equal(vol.data, zyx.T)
    assert vol.spacing.tolist() == [0.5, 1.5, 2.5] and vol.origin.tolist() == [-1, 2, 3]
    assert isinstance(vol.grid, RawGrid) != compress


def test_real_metaimage_head_matches_vtk():
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    path = dataset("HeadMRVolume/HeadMRVolume.mhd")
    vol = read_volume(path)
    assert vol.shape == (48, 62, 42) and vol.spacing.tolist() == [4.0, 4.0, 4.0]
    assert unsupported_format(path) is None
    reader = vtk.vtkMetaImageReader()
    reader.SetFileName(str(path))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputConnection(reader.GetOutputPort())
    fe.SetValue(0, 60.5)
    fe.ComputeNormalsOff()
    fe.ComputeGradientsOff()
    fe.Update()
    out = fe.GetOutput()
    points = numpy_support.vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    cells = numpy_support.vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    mesh = extract(vol, 60.5)
    assert (mesh.n_vertices, mesh.n_cells) == (len(points), len(cells)) and len(cells) > 1000
    ours_k, ours_t = edge_key(mesh.vertices, vol.spacing)
    vtk_k, vtk_t = edge_key(points, vol.spacing)
    assert np.array_equal(ours_k, vtk_k) and np.abs(ours_t - vtk_t).max() < 1e-5
    same_mesh(extract(vol, 60.5, blocks=Blocks(size=5)), mesh)


# --- bad MetaImage --------------------------------------------------------------------------


def one_line_error(path, kind, *says, **options):
    with pytest.raises(kind) as err:
        read_volume(path, **options)
    msg = str(err.value)
    assert "\n" not in msg and path.name in msg, msg
    for part in says:
        assert part in msg, msg
    return msg


def test_bad_metaimages(tmp_path, zyx):
    zyx.tofile(tmp_path / "v.raw")

    def header(name, **fields):
        fields.setdefault("DimSize", "7 5 6")
        fields.setdefault("ElementType", "MET_FLOAT")
        fields.setdefault("ElementDataFile", "v.raw")
        path = tmp_path / name
        path.write_text(mhd_text(**fields))
        return path

    one_line_error(header("big.mhd", DimSize="7 5 7"), FormatError, "DimSize 7 5 7", "check")
    one_line_error(header("type.mhd", ElementType="MET_HALF"), FormatError, "MET_HALF", "MET_UCHAR")
    one_line_error(header("dims.mhd", DimSize="7 5"), FormatError, "DimSize", "3 numbers")
    one_line_error(header("nd.mhd", NDims=4), FormatError, "NDims = 2 or 3")
    one_line_error(
        header("miss.mhd", ElementDataFile="nope.raw"), FormatError, "nope.raw is missing"
    )
    outside = tmp_path / "sub"
    outside.mkdir()
    (outside / "o.mhd").write_text(
        mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", ElementDataFile="../v.raw")
    )
    one_line_error(
        outside / "o.mhd", FormatError, "outside the header's folder", "--allow-outside-data"
    )
    assert np.array_equal(read_volume(outside / "o.mhd", allow_outside_data=True).data, zyx.T)
    (tmp_path / "noend.mhd").write_text("NDims = 3\nDimSize = 7 5 6\n")
    one_line_error(tmp_path / "noend.mhd", FormatError, "no ElementDataFile")
    # truncated .mha and compressed data
    mha = tmp_path / "t.mha"
    head = mhd_text(DimSize="7 5 6", ElementType="MET_FLOAT", ElementDataFile="LOCAL").encode()
    mha.write_bytes(head + zyx.tobytes()[:-8])
    one_line_error(mha, FormatError, "truncated")
    zmha = tmp_path / "tz.mha"
    fields = dict(DimSize="7 5 6", ElementType="MET_FLOAT", CompressedData="True")
    zhead = mhd_text(**fields, ElementDataFile="LOCAL").encode()
    zmha.write_bytes(zhead + zlib.compress(zyx.tobytes())[:-20])
    one_line_error(zmha, FormatError, "corrupt or truncated")
    short = tmp_path / "short.mha"
    short.write_bytes(zhead + zlib.compress(zyx.tobytes()[:100]))
    one_line_error(short, FormatError, "holds 100 bytes, fewer than the 840")


def test_zip_bomb_stops_at_the_declared_size(tmp_path):
    import time
    import tracemalloc

    bomb = zlib.compress(bytes(256 << 20), 9)  # 256 MiB of zeros in about 250 kB
    path = tmp_path / "bomb.mha"
    head = mhd_text(
        DimSize="4 4 4", ElementType="MET_UCHAR", CompressedData="True", ElementDataFile="LOCAL"
    )
    path.write_bytes(head.encode() + bomb)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        one_line_error(path, FormatError, "holds more than the 64 bytes")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - start < 2 and peak < 32 << 20
    # a gzip member is accepted too (the stream is told apart by its header)
    gz = tmp_path / "gz.mha"
    gz.write_bytes(head.encode() + gzip.compress(bytes(64)))
    assert read_volume(gz).shape == (4, 4, 4)


def test_vtk_writes_transform_matrix_transposed_from_itk(tmp_path):
    """VTK (9.x) writes its direction matrix row by row; ITK, whose format MetaImage is,
    writes axis directions one after the other. isoconvert follows ITK, so a rotation
    written by VTK reads back transposed (VTK reads its own files back as written)."""
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(3, 4, 5)
    rows = (0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0)  # VTK: columns are axis directions
    image.SetDirectionMatrix(*rows)
    image.GetPointData().SetScalars(
        numpy_support.numpy_to_vtk(np.arange(60, dtype=np.uint8), deep=True)
    )
    writer = vtk.vtkMetaImageWriter()
    writer.SetInputData(image)
    writer.SetFileName(str(tmp_path / "d.mhd"))
    writer.SetCompression(False)
    writer.Write()
    assert "TransformMatrix = 0 0 1 1 0 0 0 1 0" in (tmp_path / "d.mhd").read_text()
    vol = read_volume(tmp_path / "d.mhd")
    assert np.array_equal(vol.direction, np.reshape(rows, (3, 3)).T)


def test_metaimage_data_files(tmp_path):
    from isoconvert.readers.metaimage import metaimage_data_files

    (tmp_path / "a.mhd").write_text(
        mhd_text(DimSize="2 2 3", ElementType="MET_UCHAR", ElementDataFile="s%d.raw 1 3 1")
    )
    assert metaimage_data_files(tmp_path / "a.mhd") == [
        (tmp_path / f"s{k}.raw").resolve() for k in (1, 2, 3)
    ]
    (tmp_path / "b.mha").write_text(
        mhd_text(DimSize="2 2 3", ElementType="MET_UCHAR", ElementDataFile="LOCAL")
    )
    assert metaimage_data_files(tmp_path / "b.mha") == []


def test_ndim_from_headers_for_batch(tmp_path):
    from isoconvert.readers.metaimage import image_ndim
    from isoconvert.readers.numpy import array_ndim

    np.save(tmp_path / "a.npy", np.zeros((3, 4)))
    np.savez(tmp_path / "b.npz", v=np.zeros((2, 3, 4)))
    np.savez(tmp_path / "c.npz", v=np.zeros((2, 3, 4)), w=np.zeros(2))
    (tmp_path / "d.mhd").write_text(
        mhd_text(NDims=2, DimSize="2 2", ElementType="MET_UCHAR", ElementDataFile="d.raw")
    )
    (tmp_path / "e.mhd").write_text("junk\n")
    assert array_ndim(tmp_path / "a.npy") == 2 and array_ndim(tmp_path / "b.npz") == 3
    assert array_ndim(tmp_path / "c.npz") is None and array_ndim(tmp_path / "d.mhd") is None
    assert image_ndim(tmp_path / "d.mhd") == 2 and image_ndim(tmp_path / "e.mhd") is None


def test_cli_key_chooses_an_npz_array_and_batch_skips_2d_arrays(tmp_path, capsys):
    """`--key` reaches the reader from the command line; in a batch a 2D .npy
    is an image (skipped without --images) and a 3D one a volume."""
    from isoconvert.batch import discover
    from isoconvert.cli import main

    rng = np.random.default_rng(0)
    image = rng.random((6, 5, 7)).astype(np.float32)
    np.savez(tmp_path / "two.npz", image=image, labels=np.zeros((6, 5, 7), np.uint8))
    assert (
        main(["convert", str(tmp_path / "two.npz"), "-o", str(tmp_path / "a.ply"), "-l", "0.5"])
        == 1
    )
    assert "--key NAME" in capsys.readouterr().err
    code = main(["convert", str(tmp_path / "two.npz"), "-o", str(tmp_path / "a.ply"), "-l", "0.5",
                 "--key", "image"])  # fmt: skip
    assert code == 0
    np.save(tmp_path / "vol.npy", image)
    main(["convert", str(tmp_path / "vol.npy"), "-o", str(tmp_path / "b.ply"), "-l", "0.5"])
    assert (tmp_path / "a.ply").read_bytes().split(b"end_header")[1] == (
        tmp_path / "b.ply"
    ).read_bytes().split(b"end_header")[1]
    folder = tmp_path / "batch"
    folder.mkdir()
    np.save(folder / "flat.npy", image[0])
    np.save(folder / "vol.npy", image)
    found, skipped = discover([str(folder)])
    assert [f.relative.name for f in found] == ["vol.npy"]
    assert [s.path for s in skipped] == [str(folder / "flat.npy")]
