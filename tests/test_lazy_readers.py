"""Issue 10: readers that read a slab of z-layers at a time (NRRD, TIFF, Zarr / OME-Zarr).

Every lazy grid is checked against an eager read (numpy, pynrrd, tifffile, zarr):
slabs of one and two layers, slabs that do not line up with Zarr chunks, the
whole grid, and the same after a pickle round trip (what a Dask worker gets).
"""

from __future__ import annotations

import json
import pickle
import sys

import nrrd
import numpy as np
import pytest
import tifffile
from conftest import dataset
from test_readers_issue8 import compress, header, memory_mapped, one_line

from isoconvert import read_volume
from isoconvert.errors import FormatError, VolumeError, extra_hint
from isoconvert.grid import RawGrid
from isoconvert.readers import detect_format
from isoconvert.readers import nrrd as nrrd_reader
from isoconvert.readers import zarr as zarr_reader
from isoconvert.readers.nrrd import CompressedNrrdGrid
from isoconvert.readers.tiff import TiffStackGrid
from isoconvert.readers.zarr import ZarrGrid
from isoconvert.volume import Volume

try:
    import zarr
except ImportError:  # an optional extra: the NRRD and TIFF tests run without it
    zarr = None
needs_zarr = pytest.mark.skipif(
    zarr is None, reason="needs the zarr package: pip install isoconvert[zarr]"
)


@pytest.fixture
def zyx():
    """(11, 6, 7) int16 volume in C (z, y, x) order, distinct values."""
    return (np.arange(11 * 6 * 7, dtype=np.int16) * 3 - 200).reshape(11, 6, 7)


def slab_ranges(nz: int) -> list[tuple[int, int]]:
    """Slabs of 1 and 2 layers, at both ends and inside, long ones, and the whole."""
    return [(0, 1), (0, 2), (1, 3), (nz - 1, nz), (nz - 2, nz), (3, nz - 2), (0, nz), (5, 6)]


def check_grid(grid, expected_zyx: np.ndarray) -> None:
    """Every slab of ``grid`` (and of its pickled copy) equals the eager (Z, Y, X) array."""
    assert grid.shape == expected_zyx.shape[::-1]
    for copy in (grid, pickle.loads(pickle.dumps(grid))):
        for k0, k1 in slab_ranges(grid.shape[2]):
            slab = copy.read_zyx(k0, k1)
            assert slab.flags.c_contiguous and slab.dtype == grid.dtype, (k0, k1)
            assert np.array_equal(slab, expected_zyx[k0:k1]), (type(grid).__name__, k0, k1)
        assert np.array_equal(np.asarray(copy), expected_zyx.T)


# --- NRRD -----------------------------------------------------------------------------------


@pytest.mark.parametrize("detached", [False, True])
@pytest.mark.parametrize("skip", [0, 3, 4])
def test_nrrd_raw_single_file_is_a_raw_grid(tmp_path, zyx, detached, skip):
    """Any byte skip (aligned or not) and a line skip resolve to one byte offset."""
    data = b"two lines\nof text\n" + bytes(range(skip)) + zyx.astype(">i2").tobytes()
    fields = f"line skip: 2\nbyte skip: {skip}\n"
    if detached:
        (tmp_path / "v.raw").write_bytes(data)
        path = tmp_path / "v.nhdr"
        path.write_text(header(endian="big", sizes="7 6 11", extra=fields + "data file: v.raw\n"))
    else:
        path = tmp_path / "v.nrrd"
        head = header(endian="big", sizes="7 6 11", extra=fields + "\n").encode()
        path.write_bytes(head + data)
    vol = read_volume(path)
    assert isinstance(vol.grid, RawGrid) and vol.grid.dtype == np.dtype(">i2")
    check_grid(vol.grid, zyx)
    aligned = vol.grid.offset % 2 == 0
    assert np.array_equal(vol.data, zyx.T) and memory_mapped(vol.data) == aligned


def test_nrrd_byte_skip_minus_one_is_a_raw_grid(tmp_path, zyx):
    (tmp_path / "v.raw").write_bytes(b"another format's header" + zyx.tobytes())
    path = tmp_path / "v.nhdr"
    path.write_text(header(sizes="7 6 11", extra="byte skip: -1\ndata file: v.raw\n"))
    vol = read_volume(path)
    assert isinstance(vol.grid, RawGrid) and vol.grid.offset == len(b"another format's header")
    check_grid(vol.grid, zyx)


@pytest.mark.parametrize("encoding", ["gzip", "bzip2"])
@pytest.mark.parametrize("detached", [False, True])
def test_nrrd_compressed_single_file_is_a_compressed_grid(tmp_path, zyx, encoding, detached):
    data = b"a line\n" + compress(b"SKIP" + zyx.astype("<i2").tobytes(), encoding)
    fields = "line skip: 1\nbyte skip: 4\n"  # byte skip counts decompressed bytes
    if detached:
        (tmp_path / "v.data").write_bytes(data)
        path = tmp_path / "v.nhdr"
        path.write_text(header(encoding, sizes="7 6 11", extra=fields + "data file: v.data\n"))
    else:
        path = tmp_path / "v.nrrd"
        path.write_bytes(header(encoding, sizes="7 6 11", extra=fields + "\n").encode() + data)
    vol = read_volume(path)
    assert isinstance(vol.grid, CompressedNrrdGrid) and vol.grid.sequential
    check_grid(vol.grid, zyx)
    assert np.array_equal(vol.data, zyx.T)


def test_nrrd_compressed_reads_in_order_decode_the_stream_once(tmp_path, zyx):
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), zyx.T, {"encoding": "gzip"}, index_order="F")
    grid = read_volume(path).grid
    assert grid.opened == 0  # the check at open has its own stream
    for k0, k1 in [(0, 1), (1, 3), (3, 4), (4, 9), (9, 11)]:
        assert np.array_equal(grid.read_zyx(k0, k1), zyx[k0:k1])
    assert grid.opened == 1, "reads in increasing z must not restart the stream"
    # block-wise extraction's slabs overlap by one layer: the last layer read is kept
    for k0, k1 in [(0, 3), (2, 5), (4, 5), (4, 9), (8, 11)]:
        assert np.array_equal(grid.read_zyx(k0, k1), zyx[k0:k1])
    assert grid.opened == 2
    assert np.array_equal(grid.read_zyx(2, 4), zyx[2:4])  # back: decode again from the start
    assert grid.opened == 3
    assert np.array_equal(grid.read_zyx(4, 6), zyx[4:6])
    assert np.array_equal(grid.read_zyx(8, 9), zyx[8:9])  # forward, skipping layers 6..7
    assert grid.opened == 3
    worker = pickle.loads(pickle.dumps(grid))  # the open stream is not pickled
    assert worker.opened == 0 and worker._stream is None
    assert np.array_equal(worker.read_zyx(9, 11), zyx[9:11]) and worker.opened == 1


@pytest.fixture
def checked_lazily(monkeypatch):
    """Streams are checked by the reads that reach a problem, not when opened (as big ones)."""
    monkeypatch.setattr(nrrd_reader, "_CHECK_AT_OPEN", 0)


@pytest.mark.parametrize("encoding", ["gzip", "bzip2"])
def test_nrrd_compressed_stream_problems_found_by_the_reads(
    tmp_path, zyx, encoding, checked_lazily
):
    samples = zyx.astype("<i2").tobytes()  # 924 bytes, 84 per layer
    path = tmp_path / "v.nrrd"
    head = header(encoding, sizes="7 6 11", extra="\n").encode()
    # shorter than declared: the slabs before the gap read, the one reaching it fails
    path.write_bytes(head + compress(samples[:500], encoding))
    grid = read_volume(path).grid
    assert np.array_equal(grid.read_zyx(0, 5), zyx[:5])
    with pytest.raises(FormatError) as err:
        grid.read_zyx(5, 7)
    one_line(err.value, str(path), "holds 500 bytes, fewer than the 924 its header declares")
    # longer than declared (a bomb): the read of the last layer says so, having decoded
    # no more than one byte past the declared size
    path.write_bytes(head + compress(samples + bytes(50 << 20), encoding))
    grid = read_volume(path).grid
    assert np.array_equal(grid.read_zyx(0, 10), zyx[:10])
    with pytest.raises(FormatError) as err:
        grid.read_zyx(10, 11)
    one_line(err.value, str(path), "holds more than the 924 bytes its header declares")
    # corrupt: an invalid deflate block type (gzip), a wrong block magic (bzip2)
    body = bytearray(compress(samples, encoding))
    if encoding == "gzip":
        body[10] = 0xFF
    else:
        body[4:10] = bytes(6)
    path.write_bytes(head + bytes(body))
    with pytest.raises(FormatError) as err:
        np.asarray(read_volume(path).grid)
    one_line(err.value, str(path), "is corrupt or truncated")


def test_nrrd_compressed_stream_checked_when_read_if_small(tmp_path, zyx):
    """Under 64 MiB, read_volume decodes the stream once to find these before any work."""
    path = tmp_path / "v.nrrd"
    path.write_bytes(
        header("gzip", sizes="7 6 11", extra="\n").encode() + compress(zyx.tobytes()[:500], "gzip")
    )
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, str(path), "holds 500 bytes, fewer than the 924")


def test_nrrd_huge_compressed_volume_needs_two_layers_of_memory(tmp_path):
    path = tmp_path / "huge.nrrd"
    path.write_bytes(
        header("gzip", sizes="1000000 1000000 10", type_="double", extra="\n").encode()
    )
    with pytest.raises(VolumeError) as err:
        read_volume(path)
    one_line(err.value, str(path), "a slab of two z-layers needs 14901.2 GiB", "memory available")


def test_nrrd_channels_multi_file_and_2d_stay_in_memory(tmp_path, zyx):
    vector = tmp_path / "rgb.nrrd"
    data = np.stack([zyx.T, zyx.T + 1])  # (2, X, Y, Z)
    nrrd.write(
        str(vector), data, {"kinds": ["vector", "domain", "domain", "domain"]}, index_order="F"
    )
    vol = read_volume(vector, channel=1)
    assert vol.grid is None and np.array_equal(vol.data, zyx.T + 1)
    for z in range(11):
        (tmp_path / f"part{z}.raw").write_bytes(zyx[z].tobytes())
    multi = tmp_path / "multi.nhdr"
    multi.write_text(header(sizes="7 6 11", extra="data file: part%d.raw 0 10 1\n"))
    vol = read_volume(multi)
    assert vol.grid is None and np.array_equal(vol.data, zyx.T)
    flat = tmp_path / "flat.nrrd"
    nrrd.write(str(flat), zyx[0].T, {"encoding": "gzip"}, index_order="F")
    vol = read_volume(flat)
    assert vol.grid is None and np.array_equal(vol.data, zyx[0].T)


@pytest.mark.parametrize("name", ["FLAIR.nrrd", "avf_float_32.nrrd"])
def test_real_gzip_nrrd_slabs_match_pynrrd(name):
    path = dataset(name)
    vol = read_volume(path)
    assert isinstance(vol.grid, CompressedNrrdGrid)
    check_grid(vol.grid, nrrd.read(str(path), index_order="C")[0])


def ball_zyx() -> np.ndarray:
    """(17, 14, 12) float32 ball, C (z, y, x) order: positive inside."""
    z, y, x = np.mgrid[:17, :14, :12]
    return (6.0 - np.sqrt((x - 5.5) ** 2 + (y - 6.5) ** 2 + (z - 8.2) ** 2)).astype(np.float32)


def write_ball(kind: str, folder) -> object:
    """The ball as a gzip NRRD, a multi-page TIFF, or a Zarr 3 store; returns the path."""
    zyx = ball_zyx()
    if kind == "nrrd":
        path = folder / "ball.nrrd"
        nrrd.write(str(path), zyx.T, {"encoding": "gzip"}, index_order="F")
    elif kind == "tiff":
        path = folder / "ball.tif"
        tifffile.imwrite(path, zyx, photometric="minisblack")
    else:
        path = folder / "ball.zarr"
        make_array(path, zyx, 3, chunks=(5, 5, 5))
    return path


@pytest.mark.parametrize("kind", ["nrrd", "tiff", pytest.param("zarr", marks=needs_zarr)])
def test_block_wise_extraction_of_lazy_volumes_matches_in_memory(tmp_path, kind):
    from isoconvert import extract
    from isoconvert.extract.blocks import Blocks

    vol = read_volume(write_ball(kind, tmp_path))
    assert vol.grid is not None
    whole = extract(Volume.from_zyx(ball_zyx()), 0.0)
    blocked = extract(vol, 0.0, blocks=Blocks(size=3))
    assert np.array_equal(blocked.vertices, whole.vertices)
    assert np.array_equal(blocked.cells, whole.cells)
    if kind == "nrrd":
        assert vol.grid.opened == 1, "the slabs decode the stream once"


# --- TIFF -----------------------------------------------------------------------------------


@pytest.fixture
def count_page_reads(monkeypatch):
    """Indices of the TIFF pages whose pixels are decoded (whole-series reads fail)."""
    read: list[int] = []
    page_asarray = tifffile.TiffPage.asarray

    def counting(self, *args, **kwargs):
        read.append(self.index)
        return page_asarray(self, *args, **kwargs)

    def refuse(*args, **kwargs):
        raise AssertionError("a lazy TIFF must not read a whole series")

    monkeypatch.setattr(tifffile.TiffPage, "asarray", counting)
    monkeypatch.setattr(tifffile.TiffPageSeries, "asarray", refuse)
    return read


def test_tiff_multipage_file_reads_only_the_pages_of_a_slab(tmp_path, zyx, count_page_reads):
    path = tmp_path / "v.tif"
    tifffile.imwrite(path, zyx, photometric="minisblack")
    vol = read_volume(path)
    assert isinstance(vol.grid, TiffStackGrid) and count_page_reads == []
    assert np.array_equal(vol.grid.read_zyx(4, 6), zyx[4:6])
    assert count_page_reads == [4, 5]
    check_grid(vol.grid, zyx)


@pytest.mark.parametrize(
    "kind, channel",
    [("imagej_zcyx", 1), ("ome_czyx", 1), ("rgb", 2), ("planar_rgb", 0), ("thumbnails", None)],
)
def test_tiff_page_layouts_match_tifffile(tmp_path, zyx, kind, channel):
    """Channels across pages (ImageJ, OME) or inside them (RGB), and pages between layers."""
    path = tmp_path / f"{kind}.tif"
    u8 = (zyx % 256).astype(np.uint8)
    if kind == "imagej_zcyx":
        data = np.stack([zyx, zyx + 1], axis=1)
        tifffile.imwrite(path, data, imagej=True, metadata={"axes": "ZCYX"})
        expected = data[:, channel]
    elif kind == "ome_czyx":
        data = np.stack([zyx, zyx + 1])
        tifffile.imwrite(path, data, ome=True, metadata={"axes": "CZYX"})
        expected = data[channel]
    elif kind == "rgb":
        data = np.stack([u8, u8 + 1, u8 + 2], axis=-1)
        tifffile.imwrite(path, data, photometric="rgb")
        expected = data[..., channel]
    elif kind == "planar_rgb":
        data = np.stack([u8, u8 + 1, u8 + 2], axis=1)
        tifffile.imwrite(path, data, photometric="rgb", planarconfig="separate")
        expected = data[:, channel]
    else:
        with tifffile.TiffWriter(path) as tw:  # a reduced-resolution page after each layer
            for img in zyx:
                tw.write(img, photometric="minisblack", metadata=None)
                tw.write(img[:2, :2].copy(), photometric="minisblack", subfiletype=1)
        expected = zyx
    vol = read_volume(path, channel=channel)
    assert isinstance(vol.grid, TiffStackGrid)
    check_grid(vol.grid, expected)


def test_tiff_folder_and_glob_read_one_file_per_layer(tmp_path, zyx, monkeypatch):
    folder = tmp_path / "slices"
    folder.mkdir()
    for z, img in enumerate(zyx):
        tifffile.imwrite(folder / f"s{z}.tif", img)
    opened = []
    real_init = tifffile.TiffFile.__init__

    def counting(self, file, *args, **kwargs):
        opened.append(file)
        real_init(self, file, *args, **kwargs)

    for spec in (folder, str(folder / "s*.tif")):
        vol = read_volume(spec)
        assert isinstance(vol.grid, TiffStackGrid) and vol.grid.pages is None
        monkeypatch.setattr(tifffile.TiffFile, "__init__", counting)
        opened.clear()
        assert np.array_equal(vol.grid.read_zyx(9, 11), zyx[9:11])
        assert [f.name for f in opened] == ["s9.tif", "s10.tif"]
        monkeypatch.undo()
        check_grid(vol.grid, zyx)


def test_tiff_stack_checks_use_headers_only(tmp_path, zyx, monkeypatch):
    """Mismatched slices are found from the headers; no pixel is read when opening."""
    for z, img in enumerate(zyx):
        tifffile.imwrite(tmp_path / f"s{z}.tif", img)

    def refuse(*args, **kwargs):
        raise AssertionError("opening a stack must not read pixels")

    monkeypatch.setattr(tifffile.TiffFile, "asarray", refuse)
    monkeypatch.setattr(tifffile.TiffPage, "asarray", refuse)
    assert read_volume(tmp_path).shape == (7, 6, 11)
    tifffile.imwrite(tmp_path / "s7.tif", zyx[7, :4])
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path)
    one_line(err.value, "s7.tif: slice is 7x4 int16, but s0.tif is 7x6 int16")
    tifffile.imwrite(tmp_path / "s7.tif", np.stack([zyx[7]] * 3, axis=-1), photometric="rgb")
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path)
    one_line(err.value, "s7.tif: 3 channels (RGB or multi-channel); choose one with --channel")


def test_tiff_slice_changed_after_opening_is_a_format_error(tmp_path, zyx):
    for z, img in enumerate(zyx):
        tifffile.imwrite(tmp_path / f"s{z}.tif", img)
    grid = read_volume(tmp_path).grid
    tifffile.imwrite(tmp_path / "s3.tif", zyx[3].astype(np.float32))
    with pytest.raises(FormatError) as err:
        grid.read_zyx(2, 5)
    one_line(err.value, "s3.tif: the slice is now 7x6 float32, not 7x6 int16")
    (tmp_path / "s3.tif").write_bytes(b"II*\x00 not a TIFF any more")
    with pytest.raises(FormatError) as err:
        grid.read_zyx(3, 4)
    one_line(err.value, "s3.tif: not a readable TIFF")


def test_tiff_2d_and_truncated_imagej_stay_in_memory(tmp_path, zyx):
    flat = tmp_path / "flat.tif"
    tifffile.imwrite(flat, zyx[0])
    vol = read_volume(flat)
    assert vol.grid is None and np.array_equal(vol.data, zyx[0].T)
    # one page header for all images (how big ImageJ stacks are written): not pages per layer
    trunc = tmp_path / "trunc.tif"
    tifffile.imwrite(trunc, zyx, imagej=True, metadata={"axes": "ZYX"}, truncate=True)
    vol = read_volume(trunc)
    assert vol.grid is None and np.array_equal(vol.data, zyx.T)


@pytest.mark.parametrize("name", ["mri-stack.tif", "XYZ_organ-of-corti_confocal.tif"])
def test_real_tiff_stack_slabs_match_tifffile(name):
    path = dataset(name)
    vol = read_volume(path)
    assert isinstance(vol.grid, TiffStackGrid)
    check_grid(vol.grid, tifffile.imread(path))


# --- Zarr -----------------------------------------------------------------------------------


def make_array(path, data: np.ndarray, zarr_format: int, chunks, **kwargs):
    """A Zarr array at ``path`` holding ``data``, every chunk written (none left out as
    "only fill value", which zarr 3 does by default)."""
    array = zarr.create_array(
        str(path),
        shape=data.shape,
        chunks=chunks,
        dtype=data.dtype,
        zarr_format=zarr_format,
        config={"write_empty_chunks": True},
        **kwargs,
    )
    array[...] = data
    return array


@needs_zarr
@pytest.mark.parametrize("zarr_format", [2, 3])
def test_zarr_plain_array_chunks_not_dividing_the_shape(tmp_path, zyx, zarr_format):
    path = tmp_path / "volume"  # no .zarr suffix: recognised by its metadata
    make_array(path, zyx, zarr_format, chunks=(4, 4, 3))
    assert detect_format(str(path)) == "zarr"
    vol = read_volume(path)
    assert isinstance(vol.grid, ZarrGrid) and vol.grid.dtype == np.int16
    assert vol.spacing.tolist() == [1, 1, 1] and any("no spacing" in n for n in vol.notes)
    check_grid(vol.grid, zyx)


@needs_zarr
def test_zarr_sharded_big_endian_and_bool(tmp_path, zyx):
    make_array(tmp_path / "s.zarr", zyx, 3, chunks=(2, 3, 7), shards=(4, 6, 7))
    check_grid(read_volume(tmp_path / "s.zarr").grid, zyx)
    make_array(tmp_path / "be.zarr", zyx.astype(">i4"), 2, chunks=(3, 6, 7))
    check_grid(read_volume(tmp_path / "be.zarr").grid, zyx.astype(">i4"))
    mask = zyx > 0
    make_array(tmp_path / "mask.zarr", mask, 3, chunks=(5, 5, 5))
    grid = read_volume(tmp_path / "mask.zarr").grid
    assert grid.dtype == np.uint8
    check_grid(grid, mask.view(np.uint8))


@needs_zarr
def test_zarr_group_with_one_array_and_2d(tmp_path, zyx):
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w", zarr_format=2)
    group.create_array("volume", shape=zyx.shape, chunks=(3, 3, 3), dtype=zyx.dtype)[...] = zyx
    vol = read_volume(tmp_path / "g.zarr")
    assert vol.grid.path == tmp_path / "g.zarr" / "volume"
    check_grid(vol.grid, zyx)
    make_array(tmp_path / "image.zarr", zyx[0], 3, chunks=(4, 4))
    vol = read_volume(tmp_path / "image.zarr")
    assert vol.grid is None and np.array_equal(vol.data, zyx[0].T)


@needs_zarr
def test_detect_format_zarr_store_and_tiff_folder(tmp_path, zyx):
    slices = tmp_path / "slices"
    slices.mkdir()
    tifffile.imwrite(slices / "s0.tif", zyx[0])
    assert detect_format(str(slices)) == "tiff"
    for zarr_format in (2, 3):
        group = tmp_path / f"group{zarr_format}"
        zarr.open_group(str(group), mode="w", zarr_format=zarr_format)
        assert detect_format(str(group)) == "zarr"
    (tmp_path / "empty.zarr").mkdir()
    assert detect_format(str(tmp_path / "empty.zarr")) == "zarr"


def write_ome(path, levels: list[np.ndarray], version: str, axes, transforms, top=None):
    """An OME-Zarr image: NGFF 0.4 in a Zarr 2 store, 0.5 in a Zarr 3 store."""
    zarr_format = 2 if version == "0.4" else 3
    group = zarr.open_group(str(path), mode="w", zarr_format=zarr_format)
    multiscale = {
        "name": "test image",
        "axes": axes,
        "datasets": [
            {"path": str(i), "coordinateTransformations": t} for i, t in enumerate(transforms)
        ],
    }
    if top:
        multiscale["coordinateTransformations"] = top
    if version == "0.4":
        group.attrs["multiscales"] = [{"version": "0.4", **multiscale}]
    else:
        group.attrs["ome"] = {"version": "0.5", "multiscales": [multiscale]}
    for i, data in enumerate(levels):
        chunks = (1,) * (data.ndim - 3) + (4, 4, 4)
        group.create_array(
            str(i),
            shape=data.shape,
            chunks=chunks,
            dtype=data.dtype,
            config={"write_empty_chunks": True},
        )[...] = data


CZYX = [
    {"name": "c", "type": "channel"},
    {"name": "z", "type": "space", "unit": "micrometer"},
    {"name": "y", "type": "space", "unit": "micrometer"},
    {"name": "x", "type": "space", "unit": "micrometer"},
]


@pytest.fixture
def ome_levels():
    """Two levels of a (c, z, y, x) image with one channel: 12x10x8 and 6x5x4 (z, y, x)."""
    fine = np.random.default_rng(1).integers(0, 4000, (1, 12, 10, 8)).astype(np.uint16)
    return [fine, fine[:, ::2, ::2, ::2].copy()]


@needs_zarr
@pytest.mark.parametrize("version", ["0.4", "0.5"])
def test_ome_zarr_levels_placement_and_units(tmp_path, ome_levels, version):
    path = tmp_path / "image.ome.zarr"
    transforms = [
        [
            {"type": "scale", "scale": [1, 2.0, 0.5, 0.25]},
            {"type": "translation", "translation": [0, 10, 20, 30]},
        ],
        [
            {"type": "scale", "scale": [1, 4.0, 1.0, 0.5]},
            {"type": "translation", "translation": [0, 11, 20.25, 30.125]},
        ],
    ]
    # the multiscale's own transformation applies after each level's (x doubled)
    top = [{"type": "scale", "scale": [1, 1, 1, 2]}]
    write_ome(path, ome_levels, version, CZYX, transforms, top)
    fine = read_volume(path)
    assert isinstance(fine.grid, ZarrGrid) and fine.shape == (8, 10, 12)
    assert fine.spacing.tolist() == [0.5, 0.5, 2.0]
    assert fine.origin.tolist() == [60.0, 20.0, 10.0]
    assert fine.unit == "micrometer"
    assert any("level 0 of 0..1" in n for n in fine.notes)
    check_grid(fine.grid, ome_levels[0][0])
    coarse = read_volume(path, scale=1)
    assert coarse.shape == (4, 5, 6)
    assert coarse.spacing.tolist() == [1.0, 1.0, 4.0]
    assert coarse.origin.tolist() == [60.25, 20.25, 11.0]
    check_grid(coarse.grid, ome_levels[1][0])
    with pytest.raises(VolumeError) as err:
        read_volume(path, scale=2)
    one_line(err.value, str(path), "--scale 2 is out of range", "0 (8x10x12), 1 (4x5x6)")


@needs_zarr
def test_ome_zarr_channels_and_time(tmp_path, ome_levels):
    two = np.concatenate([ome_levels[0], ome_levels[0] + 1])  # c = 2
    scale = [[{"type": "scale", "scale": [1, 1, 1, 1]}]]
    write_ome(tmp_path / "c2.zarr", [two], "0.4", CZYX, scale)
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path / "c2.zarr")
    one_line(err.value, "2 channels (axis c of size 2); choose one with --channel 0..1")
    check_grid(read_volume(tmp_path / "c2.zarr", channel=1).grid, two[1])
    tzyx = [{"name": "t", "type": "time"}] + CZYX[1:]
    write_ome(tmp_path / "t3.zarr", [np.concatenate([ome_levels[0]] * 3)], "0.5", tzyx, scale)
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path / "t3.zarr")
    one_line(err.value, str(tmp_path / "t3.zarr" / "0"), "axis t has size 3")


@needs_zarr
def test_zarr_missing_chunk_is_an_error(tmp_path, zyx, monkeypatch):
    path = tmp_path / "v.zarr"
    make_array(path, zyx, 3, chunks=(4, 4, 3))
    (path / "c" / "1" / "0" / "2").unlink()  # z-layers 4..7, y 0..3, x 6
    with pytest.raises(FormatError) as err:
        read_volume(path)  # a small store is checked whole when opened
    one_line(err.value, f"{path}: chunk 1/0/2 is missing; if its writer leaves out chunks")
    assert "--allow-missing-chunks" in str(err.value)
    # a big store is checked by the reads: layers of complete chunk rows still read
    monkeypatch.setattr(zarr_reader, "_CHECK_AT_OPEN", 0)
    grid = read_volume(path).grid
    assert np.array_equal(grid.read_zyx(0, 4), zyx[:4])
    assert np.array_equal(grid.read_zyx(8, 11), zyx[8:])
    with pytest.raises(FormatError) as err:
        grid.read_zyx(3, 5)
    one_line(err.value, "chunk 1/0/2 is missing")
    # zarr's own behaviour on request: the fill value
    vol = read_volume(path, allow_missing_chunks=True)
    expected = zyx.copy()
    expected[4:8, 0:4, 6:7] = 0
    check_grid(vol.grid, expected)
    # a chunk that is there but cannot be decoded
    (path / "c" / "2" / "1" / "0").write_bytes(b"not compressed data")
    grid = read_volume(path, allow_missing_chunks=True).grid
    assert np.array_equal(grid.read_zyx(0, 8), expected[:8])
    with pytest.raises(FormatError) as err:
        grid.read_zyx(7, 9)
    one_line(err.value, f"{path}: z-layers 7..8 cannot be read (a chunk is corrupt?")


@needs_zarr
def test_zarr_v2_missing_chunk(tmp_path, zyx):
    path = tmp_path / "v2"
    make_array(path, zyx, 2, chunks=(4, 4, 3))
    (path / "2.1.0").unlink()
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, f"{path}: chunk 2/1/0 is missing; if its writer leaves out chunks")


@needs_zarr
def test_zarr_bad_inputs_one_line_each(tmp_path, zyx, monkeypatch):
    empty = tmp_path / "empty.zarr"
    zarr.open_group(str(empty), mode="w", zarr_format=3)
    with pytest.raises(FormatError) as err:
        read_volume(empty)
    one_line(err.value, str(empty), "holds no array", "the store is empty")
    zarr.open_group(str(empty), mode="a").create_group("labels")
    with pytest.raises(FormatError) as err:
        read_volume(empty)
    one_line(err.value, "holds no array (only groups: labels)", f"e.g. {empty / 'labels'}")
    two = zarr.open_group(str(tmp_path / "two.zarr"), mode="w", zarr_format=2)
    for name in ("a", "b"):
        two.create_array(name, shape=(2, 2, 2), dtype="u1")
    with pytest.raises(FormatError) as err:
        read_volume(tmp_path / "two.zarr")
    one_line(err.value, "holds 2 arrays (a, b)", f"e.g. {tmp_path / 'two.zarr' / 'a'}")
    folder = tmp_path / "plain.zarr"
    folder.mkdir()
    with pytest.raises(FormatError) as err:
        read_volume(folder)
    one_line(err.value, str(folder), "not a Zarr store (no zarr.json, .zarray or .zgroup")
    afile = tmp_path / "file.zarr"
    afile.write_bytes(b"not a folder")
    with pytest.raises(FormatError) as err:
        read_volume(afile)
    one_line(err.value, str(afile), "not a Zarr store; a Zarr store is a folder")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "zarr.json").write_text("{ not json")
    with pytest.raises(FormatError) as err:
        read_volume(broken)
    one_line(err.value, str(broken), "not a readable Zarr store")
    make_array(tmp_path / "complex.zarr", np.ones((2, 3, 4), np.complex64), 3, chunks=(2, 2, 2))
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path / "complex.zarr")
    one_line(err.value, "complex64 are not real numbers")
    make_array(tmp_path / "plain3.zarr", zyx, 3, chunks=(4, 4, 4))
    with pytest.raises(VolumeError) as err:
        read_volume(tmp_path / "plain3.zarr", scale=1)
    one_line(err.value, "--scale 1 given, but the store holds one resolution level")
    raw = tmp_path / "v_7x6x11_int16.raw"
    zyx.tofile(raw)
    with pytest.raises(VolumeError, match="--scale do"):
        read_volume(raw, scale=1)
    monkeypatch.setitem(sys.modules, "zarr", None)  # as if not installed
    with pytest.raises(FormatError) as err:
        read_volume(tmp_path / "plain3.zarr")
    one_line(err.value, f"reading Zarr needs the zarr package: {extra_hint('zarr')}")


@needs_zarr
def test_ome_zarr_malformed_metadata(tmp_path, zyx):
    path = tmp_path / "bad.zarr"
    group = zarr.open_group(str(path), mode="w", zarr_format=2)
    group.create_array("0", shape=zyx.shape, dtype=zyx.dtype)
    group.attrs["multiscales"] = [{"axes": ["z", "y", "x"]}]  # no datasets
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, str(path), "'multiscales' metadata is malformed")
    attrs = json.loads((path / ".zattrs").read_text())
    attrs["multiscales"] = [{"axes": ["y", "x"], "datasets": [{"path": "0"}]}]
    (path / ".zattrs").write_text(json.dumps(attrs))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, "names 2 axes but the array has 3")


def test_batch_takes_a_zarr_store_as_one_volume(tmp_path, zyx):
    """A store inside a searched folder is one volume (its chunk files are not
    listed as skipped files), named after the store, and converts as
    ``convert`` does."""
    zarr = pytest.importorskip("zarr")
    from isoconvert import batch
    from isoconvert.convert import convert

    store = tmp_path / "in" / "sub" / "cells.zarr"
    array = zarr.create_array(str(store), shape=zyx.shape, chunks=(2, 3, 3), dtype=zyx.dtype)
    array[:] = zyx
    found, skipped = batch.discover([str(tmp_path / "in")], recursive=True)
    assert [(f.spec, str(f.relative)) for f in found] == [(str(store), "sub/cells")]
    assert skipped == []
    level = float(np.median(zyx))
    jobs, _ = batch.plan(found, tmp_path / "out", ".ply", level, None)
    [outcome] = batch.run_jobs(jobs, batch.BatchSettings())
    assert outcome.status == "ok" and outcome.output.endswith("sub/cells.ply")
    convert(store, tmp_path / "direct.ply", level)
    assert (tmp_path / "direct.ply").read_bytes() == (tmp_path / "out/sub/cells.ply").read_bytes()
