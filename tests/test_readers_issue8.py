"""Issue 8: NRRD LIST/block/untrusted data/gzip bombs, TIFF odd pages and bad spacing,
byte order of raw files, and formats recognised but not read yet."""

from __future__ import annotations

import bz2
import gzip
import time
import tracemalloc
from pathlib import Path

import nrrd
import numpy as np
import pytest
import tifffile
from conftest import DATASETS, dataset
from make_bad_inputs import gzip_bomb

from isoconvert import read_volume
from isoconvert.errors import FormatError, VolumeError
from isoconvert.readers import detect_format, unsupported_format


@pytest.fixture
def zyx():
    """(4, 3, 5) int16 array in C (z, y, x) order with distinct values."""
    return (np.arange(60, dtype=np.int16) * 7 - 100).reshape(4, 3, 5)


def header(encoding="raw", endian="little", extra="", sizes="5 3 4", type_="short") -> str:
    return (
        f"NRRD0004\ndimension: {len(sizes.split())}\ntype: {type_}\nsizes: {sizes}\n"
        f"endian: {endian}\nencoding: {encoding}\n{extra}"
    )


def compress(data: bytes, encoding: str) -> bytes:
    return {"raw": lambda b: b, "gzip": gzip.compress, "bzip2": bz2.compress}[encoding](data)


def one_line(exc: Exception, *needles: str) -> str:
    text = str(exc)
    assert "\n" not in text, text
    for needle in needles:
        assert needle in text, (needle, text)
    return text


# --- NRRD: data file LIST, type block ---------------------------------------------------------


@pytest.mark.parametrize("encoding", ["raw", "gzip", "bzip2", "ascii", "hex"])
def test_nrrd_list_of_data_files_is_read(tmp_path, zyx, encoding):
    (tmp_path / "parts").mkdir()
    names = []
    for z in range(4):
        name = f"parts/slice {z}.{encoding}"  # names may hold spaces
        if encoding == "ascii":
            data = " ".join(map(str, zyx[z].ravel())).encode()
        elif encoding == "hex":
            data = zyx[z].astype("<i2").tobytes().hex().encode()
        else:
            data = compress(zyx[z].astype("<i2").tobytes(), encoding)
        (tmp_path / name).write_bytes(data)
        names.append(name)
    path = tmp_path / "v.nhdr"
    path.write_text(header(encoding, extra="spacings: 1 2 3\ndata file: LIST\n" + "\n".join(names)))
    vol = read_volume(path)
    assert np.array_equal(vol.data, zyx.T)
    assert vol.spacing.tolist() == [1, 2, 3]
    # two files of two slices each, and an explicit subdim of 2 (one slice per file)
    pairs = [f"pair{i}.raw" for i in range(2)]
    for i, name in enumerate(pairs):
        (tmp_path / name).write_bytes(zyx[2 * i : 2 * i + 2].astype("<i2").tobytes())
    path.write_text(header(extra="data file: LIST\n" + "\n".join(pairs) + "\n"))
    assert np.array_equal(read_volume(path).data, zyx.T)
    path.write_text(header(encoding, extra="data file: LIST 2\n" + "\n".join(names) + "\n"))
    assert np.array_equal(read_volume(path).data, zyx.T)


def test_nrrd_list_errors_are_one_clear_line(tmp_path, zyx):
    for z in range(3):
        (tmp_path / f"s{z}.raw").write_bytes(zyx[z].astype("<i2").tobytes())
    path = tmp_path / "v.nhdr"
    path.write_text(header(extra="data file: LIST\ns0.raw\ns1.raw\ns2.raw\ns3.raw\n"))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, str(path), "s3.raw is missing")
    path.write_text(header(extra="data file: LIST\ns0.raw\ns1.raw\ns2.raw\n"))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, "3 data files cannot split 4 slices")
    path.write_text(header(extra="data file: LIST\n"))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, "names no files")


def test_nrrd_type_block_is_refused_clearly(tmp_path):
    path = tmp_path / "blocks.nrrd"
    path.write_bytes(header(type_="block", extra="block size: 16\n\n").encode() + bytes(16 * 60))
    with pytest.raises(VolumeError) as err:
        read_volume(path)
    one_line(err.value, str(path), "type 'block'", "16 bytes", "not numbers")


# --- NRRD: data files outside the header's folder -------------------------------------------


def test_nrrd_data_outside_the_header_folder_needs_permission(tmp_path, zyx):
    folder = tmp_path / "headers"
    (folder / "deeper").mkdir(parents=True)
    secret = tmp_path / "secret.raw"
    zyx.astype("<i2").tofile(secret)
    zyx.astype("<i2").tofile(folder / "deeper" / "inside.raw")
    (folder / "link.raw").symlink_to(secret)
    (folder / "dirlink").symlink_to(tmp_path, target_is_directory=True)
    outside = {
        "absolute": str(secret),
        "dotdot": "../secret.raw",
        "sneaky": "deeper/../../secret.raw",
        "symlink": "link.raw",
        "symlinked_folder": "dirlink/secret.raw",
    }
    for label, name in outside.items():
        path = folder / f"{label}.nhdr"
        path.write_text(header(extra=f"data file: {name}\n"))
        with pytest.raises(FormatError) as err:
            read_volume(path)
        one_line(err.value, str(path), name, "outside the header's folder", "--allow-outside-data")
        assert np.array_equal(read_volume(path, allow_outside_data=True).data, zyx.T), label
    inside = folder / "inside.nhdr"
    inside.write_text(header(extra=f"data file: {folder / 'deeper' / 'inside.raw'}\n"))
    assert np.array_equal(read_volume(inside).data, zyx.T)
    inside.write_text(header(extra="data file: ./deeper/../deeper/inside.raw\n"))
    assert np.array_equal(read_volume(inside).data, zyx.T)


def test_nrrd_every_detached_form_is_checked(tmp_path, zyx):
    folder = tmp_path / "h"
    folder.mkdir()
    for z in range(4):
        (tmp_path / f"slab{z}.raw").write_bytes(zyx[z].astype("<i2").tobytes())
    forms = {
        "numbered": "data file: ../slab%d.raw 0 3 1\n",
        "list": "data file: LIST\n" + "".join(f"../slab{z}.raw\n" for z in range(4)),
    }
    for label, extra in forms.items():
        path = folder / f"{label}.nhdr"
        path.write_text(header(extra=extra))
        with pytest.raises(FormatError) as err:
            read_volume(path)
        one_line(err.value, str(path), "../slab0.raw", "--allow-outside-data")
        assert np.array_equal(read_volume(path, allow_outside_data=True).data, zyx.T), label


def test_allow_outside_data_is_harmless_where_a_format_has_no_companion_files(tmp_path, zyx):
    """One --allow-outside-data must be usable over a whole batch of mixed formats."""
    from isoconvert.readers import READERS

    assert "allow_outside_data" in READERS.get("nrrd").options
    raw = tmp_path / "v_5x3x4_int16.raw"
    zyx.tofile(raw)
    assert read_volume(raw, allow_outside_data=False).shape == (5, 3, 4)
    assert read_volume(raw, allow_outside_data=True).shape == (5, 3, 4)


# --- NRRD: compressed data bounded by the header --------------------------------------------


@pytest.mark.parametrize("encoding", ["gzip", "bzip2"])
def test_nrrd_compression_bomb_fails_fast_in_little_memory(tmp_path, encoding):
    n = 200 << 20  # 200 MB of zeros, declared as 4x4x4 shorts (128 bytes)
    if encoding == "gzip":
        payload = gzip_bomb(n)
    else:
        packer = bz2.BZ2Compressor(9)
        payload = b"".join(packer.compress(bytes(1 << 20)) for _ in range(n >> 20))
        payload += packer.flush()
    assert len(payload) < 1 << 20
    path = tmp_path / "bomb.nrrd"
    path.write_bytes(header(encoding, sizes="4 4 4", extra="\n").encode() + payload)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(FormatError) as err:
            read_volume(path)
        seconds = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    one_line(err.value, str(path), "holds more than the 128 bytes its header declares")
    assert seconds < 2, seconds
    assert peak < 32 << 20, peak


@pytest.mark.parametrize("encoding", ["gzip", "bzip2"])
def test_nrrd_compressed_data_shorter_than_declared(tmp_path, zyx, encoding):
    path = tmp_path / "short.nrrd"
    body = compress(zyx.astype("<i2").tobytes()[:100], encoding)
    path.write_bytes(header(encoding, extra="\n").encode() + body)
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, str(path), "holds 100 bytes, fewer than the 120 its header declares")
    # a stream cut before its end marker is truncated, even if the samples are all there
    path.write_bytes(header(encoding, extra="\n").encode() + compress(zyx.tobytes(), encoding)[:-4])
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, str(path), "truncated")


def refuse(*args, **kwargs):
    raise AssertionError("pynrrd must not read binary NRRD data")


def test_nrrd_binary_data_never_goes_through_pynrrd(tmp_path, zyx, monkeypatch):
    """raw/gzip/bzip2 data are read here, bounded; pynrrd only parses headers (and ascii)."""

    written = {}
    for encoding in ("raw", "gzip", "bzip2"):
        for detached in (False, True):
            path = tmp_path / f"{encoding}_{detached}.{'nhdr' if detached else 'nrrd'}"
            nrrd.write(
                str(path),
                zyx.T,
                {"encoding": encoding, "spacings": [1.0, 2.0, 3.0]},
                detached_header=detached,
                index_order="F",
            )
            written[path] = nrrd.read(str(path), index_order="F")[0]
    real = [DATASETS / "FLAIR.nrrd", DATASETS / "avf_float_32.nrrd"]
    real = [p for p in real if p.exists()]
    for path in real:
        written[path] = nrrd.read(str(path), index_order="F")[0]
    monkeypatch.setattr(nrrd, "read", refuse)
    monkeypatch.setattr(nrrd, "read_data", refuse)
    monkeypatch.setattr(nrrd.reader, "read_data", refuse)
    for path, expected in written.items():
        vol = read_volume(path)
        assert vol.data.dtype == expected.dtype and np.array_equal(vol.data, expected), path


def memory_mapped(array: np.ndarray) -> bool:
    """True when ``array`` is a view of a memory-mapped file."""
    while array is not None:
        if isinstance(array, np.memmap):
            return True
        array = getattr(array, "base", None)
    return False


@pytest.mark.parametrize("encoding", ["raw", "gzip", "bzip2", "ascii", "hex"])
@pytest.mark.parametrize("endian", ["little", "big"])
@pytest.mark.parametrize("detached", [False, True])
def test_nrrd_skips_endian_and_encodings(tmp_path, zyx, encoding, endian, detached, monkeypatch):
    """line skip and byte skip, both byte orders, attached and detached data.

    Only ascii goes through pynrrd; the others must not.
    """
    if encoding != "ascii":
        monkeypatch.setattr(nrrd.reader, "read_data", refuse)
        monkeypatch.setattr(nrrd, "read_data", refuse)
    monkeypatch.setattr(nrrd, "read", refuse)
    samples = zyx.astype(("<" if endian == "little" else ">") + "i2").tobytes()
    lines = b"P5 # a text header to skip\n5 3\n"
    if encoding == "raw":
        skip, data = 4, lines + b"JUNK" + samples
    elif encoding in ("gzip", "bzip2"):
        # byte skip counts decompressed bytes for gzip/bzip2 (as teem does)
        skip, data = 4, lines + compress(b"JUNK" + samples, encoding)
    elif encoding == "hex":
        text = samples.hex()
        rows = "\n".join(text[i : i + 32] for i in range(0, len(text), 32))
        skip, data = 2, lines + b"ZZ" + rows.encode()
    else:
        skip, data = 0, lines + " ".join(map(str, zyx.ravel())).encode() + b"\n"
    fields = f"line skip: 2\nbyte skip: {skip}\n"
    if detached:
        (tmp_path / "v.data").write_bytes(data)
        path = tmp_path / "v.nhdr"
        path.write_text(header(encoding, endian, fields + "data file: v.data\n"))
    else:
        path = tmp_path / "v.nrrd"
        path.write_bytes(header(encoding, endian, fields + "\n").encode() + data)
    assert np.array_equal(read_volume(path).data, zyx.T)


def test_nrrd_raw_data_is_memory_mapped_when_aligned(tmp_path, zyx):
    for detached in (False, True):
        path = tmp_path / ("v.nhdr" if detached else "v.nrrd")
        nrrd.write(str(path), zyx.T, {"encoding": "raw"}, detached_header=detached, index_order="F")
        vol = read_volume(path)
        assert np.array_equal(vol.data, zyx.T)
        offset = path.stat().st_size - zyx.nbytes if not detached else 0
        assert memory_mapped(vol.data) == (offset % 2 == 0), (detached, offset)
    # a misaligned attached header (odd length) is read into memory instead
    path = tmp_path / "odd.nrrd"
    text = header(extra="# x\n\n")
    text = text if len(text) % 2 else text.replace("# x", "# xy")
    path.write_bytes(text.encode() + zyx.tobytes())
    vol = read_volume(path)
    assert np.array_equal(vol.data, zyx.T) and not memory_mapped(vol.data)


def test_nrrd_raw_byte_skip_minus_one_and_exact_sizes(tmp_path, zyx):
    path = tmp_path / "v.nhdr"
    (tmp_path / "v.raw").write_bytes(b"some header of another format" + zyx.tobytes())
    path.write_text(header(extra="byte skip: -1\ndata file: v.raw\n"))
    assert np.array_equal(read_volume(path).data, zyx.T)
    path.write_text(header("gzip", extra="byte skip: -1\ndata file: v.raw\n"))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, "byte skip -1", "only to raw")
    (tmp_path / "v.raw").write_bytes(zyx.tobytes() + b"extra")
    path.write_text(header(extra="data file: v.raw\n"))
    with pytest.raises(FormatError) as err:
        read_volume(path)
    one_line(err.value, "holds 125 bytes of samples", "need 120")


def test_nrrd_concatenated_gzip_members(tmp_path, zyx):
    raw = zyx.tobytes()
    path = tmp_path / "v.nrrd"
    path.write_bytes(
        header("gzip", extra="\n").encode() + gzip.compress(raw[:50]) + gzip.compress(raw[50:])
    )
    assert np.array_equal(read_volume(path).data, zyx.T)


def test_real_multi_file_headsq_is_checked_and_memory_bounded(tmp_path):
    """The numbered form reads its real files; a copy of the header elsewhere cannot."""
    path = dataset("headsq_vtk/quarter.nhdr")
    vol = read_volume(path)
    raw = np.fromfile(path.parent / "quarter.47", dtype="<i2").reshape(64, 64)
    assert np.array_equal(vol.data[:, :, 46], raw.T)
    copy = tmp_path / "quarter.nhdr"
    text = path.read_text().replace("quarter.%d", f"{path.parent}/quarter.%d")
    copy.write_text(text)
    with pytest.raises(FormatError, match="--allow-outside-data"):
        read_volume(copy)
    assert np.array_equal(read_volume(copy, allow_outside_data=True).data, vol.data)


# --- invalid spacing in metadata is ignored, so --spacing works -----------------------------


@pytest.mark.parametrize("bad", [0.0, float("nan"), -1.0, float("inf")])
def test_ome_tiff_with_bad_physical_size_z(tmp_path, zyx, bad):
    path = tmp_path / "v.ome.tif"
    tifffile.imwrite(
        path,
        zyx,
        ome=True,
        metadata={"axes": "ZYX", "PhysicalSizeX": 0.5, "PhysicalSizeY": 0.25, "PhysicalSizeZ": bad},
    )
    vol = read_volume(path)
    assert vol.spacing.tolist() == [0.5, 0.25, 1.0]
    note = [n for n in vol.notes if n.startswith("PhysicalSizeZ ")]
    assert len(note) == 1
    assert note[0].endswith(" in the OME metadata ignored; using 1; set --spacing"), note
    if bad == 0:
        assert note[0] == "PhysicalSizeZ 0 in the OME metadata ignored; using 1; set --spacing"
    assert read_volume(path, spacing=(1, 1, 2)).spacing.tolist() == [1, 1, 2]


@pytest.mark.parametrize("bad", [0.0, float("nan"), -2.0, float("inf")])
def test_imagej_tiff_with_bad_z_spacing(tmp_path, zyx, bad):
    path = tmp_path / "v.tif"
    tifffile.imwrite(
        path, zyx, imagej=True, resolution=(2.0, 4.0), metadata={"spacing": bad, "axes": "ZYX"}
    )
    vol = read_volume(path)
    assert np.allclose(vol.spacing, [0.5, 0.25, 1.0])
    assert f"spacing {bad:g} in the ImageJ metadata ignored; using 1; set --spacing" in vol.notes
    assert read_volume(path, spacing=(1, 1, 3)).spacing.tolist() == [1, 1, 3]


def test_tiff_with_zero_resolution_tags(tmp_path, zyx):
    path = tmp_path / "v.tif"
    tifffile.imwrite(
        path,
        zyx,
        imagej=True,
        resolution=((0, 1), (0, 1)),
        metadata={"spacing": 2.0, "axes": "ZYX"},
    )
    vol = read_volume(path)
    assert vol.spacing.tolist() == [1, 1, 2]
    assert "XResolution 0/1 in the TIFF tags ignored; using 1; set --spacing" in vol.notes


def test_nrrd_with_bad_spacings_and_directions(tmp_path, zyx):
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), zyx.T, {"spacings": [0.5, np.nan, 0.0]}, index_order="F")
    vol = read_volume(path)
    assert vol.spacing.tolist() == [0.5, 1, 1]
    assert "spacings nan for axis y in the NRRD header ignored; using 1; set --spacing" in vol.notes
    assert "spacings 0 for axis z in the NRRD header ignored; using 1; set --spacing" in vol.notes
    assert read_volume(path, spacing=(1, 2, 3)).spacing.tolist() == [1, 2, 3]
    directions = np.diag([0.5, 0.25, 0.0])
    nrrd.write(
        str(path),
        zyx.T,
        {"space": "left-posterior-superior", "space directions": directions},
        index_order="F",
    )
    vol = read_volume(path)
    assert vol.spacing.tolist() == [1, 1, 1]
    assert any(n.startswith("space directions in the NRRD header ignored") for n in vol.notes)


# --- TIFF pages of different sizes ----------------------------------------------------------


def test_multipage_tiff_with_an_odd_page_is_refused(tmp_path):
    path = tmp_path / "odd.tif"
    with tifffile.TiffWriter(path) as tw:
        for shape in ((4, 5), (6, 7), (4, 5)):
            tw.write(np.ones(shape, np.uint16), photometric="minisblack", metadata=None)
    with pytest.raises(VolumeError) as err:
        read_volume(path)
    one_line(err.value, str(path), "page 2 of 3 is 7x6 uint16", "page 1 is 5x4 uint16")


def test_multi_series_files_tifffile_reads_as_one_still_work(tmp_path):
    hyper = tmp_path / "hyper.tif"
    stack = np.arange(3 * 2 * 4 * 5, dtype=np.uint8).reshape(3, 2, 4, 5)
    tifffile.imwrite(hyper, stack, imagej=True, metadata={"axes": "ZCYX"})
    assert np.array_equal(read_volume(hyper, channel=1).data, stack[:, 1].T)
    ome = tmp_path / "v.ome.tif"
    tifffile.imwrite(ome, stack[:, 0], ome=True, metadata={"axes": "ZYX"})
    assert np.array_equal(read_volume(ome).data, stack[:, 0].T)
    # a thumbnail (reduced-resolution page) does not make the pages "differ"
    thumb = tmp_path / "thumb.tif"
    with tifffile.TiffWriter(thumb) as tw:
        tw.write(stack[:, 0], photometric="minisblack", metadata=None)
        tw.write(np.zeros((2, 3), np.uint8), subfiletype=1, metadata=None)
    vol = read_volume(thumb)
    assert np.array_equal(vol.data, stack[:, 0].T)
    assert any("2 image series; the first (5x4x3) is read" in n for n in vol.notes)
    # and an odd page is refused (the point of this change)
    odd = tmp_path / "odd.tif"
    with tifffile.TiffWriter(odd) as tw:
        tw.write(stack[:, 0], photometric="minisblack", metadata=None)
        tw.write(np.zeros((2, 3), np.uint8), photometric="minisblack", metadata=None)
    with pytest.raises(VolumeError, match="page 4 of 4 is 3x2 uint8"):
        read_volume(odd)


@pytest.mark.parametrize(
    "name", ["mri-stack.tif", "bat-cochlea-volume.tif", "XYZ_organ-of-corti_confocal.tif"]
)
def test_real_tiff_scans_read_as_one_series(name, monkeypatch):
    from isoconvert.readers import tiff

    checked = []
    real_check = tiff._check_series
    monkeypatch.setattr(tiff, "_check_series", lambda t, p: checked.append(p) or real_check(t, p))
    path = dataset(name)
    vol = read_volume(path)
    assert checked == [path]
    assert np.array_equal(vol.data, tifffile.imread(path).T)


# --- byte order of raw files ----------------------------------------------------------------


def real_raw_scans() -> list[Path]:
    if not DATASETS.exists():
        return []
    return sorted(DATASETS.glob("*_*x*x*_*.raw"))


@pytest.mark.skipif(not real_raw_scans(), reason=f"real datasets not found in {DATASETS}")
def test_byte_order_hint_fires_on_swapped_copies_only(tmp_path):
    multibyte = []
    for path in real_raw_scans():
        vol = read_volume(path)
        assert not any("byte-swapped" in n for n in vol.notes), path
        if vol.data.dtype.itemsize > 1:
            multibyte.append(path.name)
    assert "hydrogen_vtk_64x64x64_float32.raw" in multibyte
    hydrogen = dataset("hydrogen_vtk_64x64x64_float32.raw")
    values = np.fromfile(hydrogen, "<f4")
    swapped = tmp_path / "hydrogen_64x64x64_float32.raw"
    values.astype(">f4").tofile(swapped)
    vol = read_volume(swapped)
    assert any("byte-swapped" in n and n.endswith("pass --endian big") for n in vol.notes)
    big = read_volume(swapped, endian="big")
    assert np.array_equal(big.data.T.ravel(), values)
    assert not any("byte-swapped" in n for n in big.notes)
    assert any(
        n.endswith("pass --endian little") for n in read_volume(hydrogen, endian="big").notes
    )
    # headsq: a real int16 CT, as one raw file
    headsq = dataset("headsq_vtk/quarter.nhdr").parent
    ct = np.concatenate(
        [np.fromfile(headsq / f"quarter.{k}", "<i2") for k in range(1, 94)]
    ).reshape(93, 64, 64)
    ct.tofile(tmp_path / "ct_64x64x93_int16.raw")
    ct.astype(">i2").tofile(tmp_path / "ct_swapped_64x64x93_int16.raw")
    assert not any(
        "byte-swapped" in n for n in read_volume(tmp_path / "ct_64x64x93_int16.raw").notes
    )
    notes = read_volume(tmp_path / "ct_swapped_64x64x93_int16.raw").notes
    assert any("byte-swapped" in n and "--endian big" in n for n in notes)


@pytest.mark.parametrize("dtype", ["uint16", "int16", "uint32", "int32", "float32", "float64"])
def test_byte_order_hint_on_a_scaled_real_scan(tmp_path, dtype):
    engine = np.fromfile(dataset("engine_256x256x128_uint8.raw"), np.uint8).astype(np.int64) * 100
    native = tmp_path / f"engine_256x256x128_{dtype}.raw"
    engine.astype(np.dtype(dtype).newbyteorder("<")).tofile(native)
    swapped = tmp_path / f"engine_swapped_256x256x128_{dtype}.raw"
    engine.astype(np.dtype(dtype).newbyteorder(">")).tofile(swapped)
    assert not any("byte-swapped" in n for n in read_volume(native).notes)
    assert not any("byte-swapped" in n for n in read_volume(swapped, endian="big").notes)
    note = [n for n in read_volume(swapped).notes if "byte-swapped" in n]
    assert len(note) == 1 and note[0].endswith("if the file is big-endian, pass --endian big")
    note = [n for n in read_volume(native, endian="big").notes if "byte-swapped" in n]
    assert len(note) == 1 and note[0].endswith("pass --endian little")


def test_byte_order_hint_reads_a_bounded_sample_of_a_big_file(tmp_path):
    path = tmp_path / "big_1024x1024x128_float32.raw"  # 512 MiB, sparse: zeros but one slab
    with open(path, "wb") as fh:
        fh.truncate(1024 * 1024 * 128 * 4)
        fh.write(np.linspace(0.5, 2.0, 1024 * 1024, dtype=">f4").tobytes())
    tracemalloc.start()
    start = time.perf_counter()
    try:
        vol = read_volume(path)
        seconds = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert any("byte-swapped" in n for n in vol.notes)
    assert seconds < 2 and peak < 64 << 20, (seconds, peak)
    assert memory_mapped(vol.data)


# --- formats recognised but not read yet ----------------------------------------------------


def test_formats_not_read_yet_are_named(tmp_path):
    # DICOM is read (the dicom reader): a file with the magic and no header is refused as such
    dicom = bytes(128) + b"DICM" + bytes(16)
    for name in ("slice.dcm", "IM_0001", "1.2.840.113619.2.5"):
        path = tmp_path / name
        path.write_bytes(dicom)
        assert unsupported_format(path) is None, name
        assert detect_format(str(path)) == "dicom", name
        with pytest.raises(FormatError, match="not a readable DICOM image") as err:
            read_volume(path)
        assert str(err.value).startswith(f"{path}: ") and "\n" not in str(err.value)
    for name in ("head.mhd", "head.mha"):  # MetaImage is read since issue 11
        (tmp_path / name).write_bytes(b"NDims = 3\n")
        assert unsupported_format(tmp_path / name) is None
    for name in ("scan.nii.gz", "scan.NII"):  # NIfTI is read since issue 11
        (tmp_path / name).write_bytes(gzip.compress(bytes(352)))
        assert unsupported_format(tmp_path / name) is None
        with pytest.raises(FormatError, match="not a readable NIfTI file"):
            read_volume(tmp_path / name)
    series = tmp_path / "series"
    series.mkdir()
    for k in range(3):
        (series / f"IM{k}").write_bytes(dicom)
    assert unsupported_format(series) is None
    assert detect_format(str(series)) == "dicom"  # not a TIFF stack
    with pytest.raises(FormatError, match="no DICOM image files in"):
        read_volume(series)


def test_other_files_are_not_flagged(tmp_path, zyx):
    paths = [tmp_path / "v_5x3x4_int16.raw", tmp_path / "v.nrrd", tmp_path / "x.xyz"]
    zyx.tofile(paths[0])
    nrrd.write(str(paths[1]), zyx.T, index_order="F")
    paths[2].write_bytes(bytes(200))
    folder = tmp_path / "slices"
    folder.mkdir()
    for z, img in enumerate(zyx):
        tifffile.imwrite(folder / f"s{z}.tif", img)
    (folder / "notes.dcm").write_bytes(b"")  # a stray file beside TIFF slices
    for path in [*paths, folder, tmp_path / "missing.nii"]:
        assert unsupported_format(path) is None, path
    # an explicit reader is obeyed: a .dcm file read as raw
    raw = tmp_path / "pixels.dcm"
    zyx.tofile(raw)
    assert read_volume(raw, format="raw", shape=(5, 3, 4), dtype="int16").shape == (5, 3, 4)
    assert unsupported_format(raw) is None  # DICOM is read (and this file is not DICOM)


def test_real_dicom_and_metaimage_are_named():
    chest = dataset("ct_chest_LIDC-IDRI-0314_dicom")
    assert unsupported_format(chest) is None and detect_format(str(chest)) == "dicom"
    assert read_volume(chest).shape == (512, 512, 64)  # read since DICOM support
    first = sorted(chest.iterdir())[0]
    assert unsupported_format(first) is None
    head = dataset("HeadMRVolume")
    with pytest.raises(FormatError, match="MetaImage header .HeadMRVolume.mhd.: give that file"):
        read_volume(head)
    assert read_volume(head / "HeadMRVolume.mhd").shape == (48, 62, 42)  # read since issue 11
    for name in ("chris_t1.nii.gz", "avg152T1_RL_nifti.nii.gz"):  # read since issue 11
        assert unsupported_format(dataset(name)) is None
        assert read_volume(dataset(name)).ndim == 3


def test_unsupported_format_is_cheap(tmp_path, monkeypatch):
    """Files are judged by name; telling DICOM by its magic reads at most 132 bytes."""
    big = tmp_path / "blob.bin2"
    big.write_bytes(bytes(1 << 20))
    sizes = []
    real_open = open

    def counting_open(file, mode="r", *args, **kwargs):
        handle = real_open(file, mode, *args, **kwargs)
        real_read = handle.read

        def read(n=-1):
            sizes.append(n)
            return real_read(n)

        handle.read = read
        return handle

    import builtins

    raw = tmp_path / "v_64x64x64_uint8.raw"
    raw.write_bytes(bytes(64**3))
    monkeypatch.setattr(builtins, "open", counting_open)
    assert unsupported_format(big) is None
    assert unsupported_format(raw) is None
    assert sizes == []  # DICOM is read now: no file needs its magic looked at
    with pytest.raises(FormatError, match="cannot tell the format"):
        detect_format(str(big))  # no reader claims .bin2: is it DICOM?
    assert detect_format(str(raw)) == "raw"
    monkeypatch.undo()
    assert sizes == [132]
