"""Make a corpus of broken inputs, each with what reading or converting it must say.

Run ``python tests/make_bad_inputs.py FOLDER`` to look at the files; the tests
call :func:`make_bad_inputs` with a temporary folder. Every case must end in one
line on stderr naming the file, a non-zero exit code and no output file.
"""

from __future__ import annotations

import gzip
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class Case:
    """A broken input: the file, extra command-line words, and words the error must hold."""

    path: Path
    args: list[str] = field(default_factory=list)
    says: tuple[str, ...] = ()


def _nifti_bytes() -> bytes | None:
    """A small NIfTI-1 image (16^3 int16), or None without nibabel."""
    try:
        import nibabel
    except ImportError:
        return None
    data = np.arange(16**3, dtype=np.int16).reshape(16, 16, 16)
    return nibabel.Nifti1Image(data, np.eye(4)).to_bytes()


def _nrrd_header(sizes="4 4 3", type_="short", encoding="raw", extra="") -> bytes:
    return (
        f"NRRD0004\ndimension: {len(sizes.split())}\ntype: {type_}\nsizes: {sizes}\n"
        f"endian: little\nencoding: {encoding}\n{extra}\n"
    ).encode()


def gzip_bomb(n_bytes: int) -> bytes:
    """gzip data that expands to ``n_bytes`` zeros (about 1/1000 of that compressed)."""
    packer = zlib.compressobj(9, zlib.DEFLATED, zlib.MAX_WBITS | 16)
    chunk = bytes(1 << 20)
    parts = [packer.compress(chunk) for _ in range(n_bytes >> 20)]
    parts.append(packer.compress(bytes(n_bytes & ((1 << 20) - 1))))
    return b"".join(parts) + packer.flush()


def make_bad_inputs(folder: Path) -> dict[str, Case]:
    import tifffile
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    good = (np.arange(48, dtype=np.int16) % 7).reshape(3, 4, 4)
    cases: dict[str, Case] = {}

    def put(name: str, data: bytes, args=(), says=()) -> None:
        path = folder / name
        path.write_bytes(data)
        cases[name] = Case(path, list(args), tuple(says))

    put("truncated_8x8x8_uint16.raw", bytes(1000), says=("1000 bytes", "needs 1024"))
    put(
        "zero_dim.raw",
        bytes(16),
        ["--shape", "4", "0", "4", "--dtype", "uint8"],
        says=("positive sizes",),
    )
    put(
        "complex.raw",
        bytes(64),
        ["--shape", "2", "2", "2", "--dtype", "complex64"],
        says=("complex64", "uint8"),
    )
    put("strings.raw", bytes(64), ["--shape", "2", "2", "2", "--dtype", "str"], says=("'str'",))
    nan = np.ones((4, 4, 4), np.float32)
    nan[1, 2, 3] = np.nan
    put("nan_4x4x4_float32.raw", nan.tobytes(), says=("NaN", "--nan-as"))
    put("constant_4x4x4_uint8.raw", bytes(64), says=("constant",))
    put("truncated.nrrd", _nrrd_header() + good.tobytes()[:50], says=("cannot be read",))
    # incompressible samples, so that a cut stream really lacks data
    noise = np.random.default_rng(0).integers(0, 2**15, 48, dtype=np.int16).tobytes()
    put(
        "truncated_gzip.nrrd",
        _nrrd_header(encoding="gzip") + gzip.compress(noise)[:40],
        says=("truncated_gzip.nrrd",),
    )
    put(
        "lies_encoding.nrrd",
        _nrrd_header(encoding="gzip") + good.tobytes(),
        says=("not a readable",),
    )
    put("lies_sizes.nrrd", _nrrd_header(sizes="8 8 8") + good.tobytes(), says=("cannot be read",))
    put("unsupported_encoding.nrrd", _nrrd_header(encoding="zstd") + good.tobytes(), says=("zstd",))
    put("string_type.nrrd", _nrrd_header(type_="string") + good.tobytes(), says=("type",))
    put(
        "huge.nrrd",
        _nrrd_header(sizes="100000 100000 100000", type_="double", encoding="gzip"),
        says=("GiB", "memory available"),
    )
    put("zero_size.nrrd", _nrrd_header(sizes="4 0 3"), says=("sizes", ">= 1"))
    put(
        "missing_data.nhdr",
        _nrrd_header(extra="data file: nowhere.raw"),
        says=("nowhere.raw", "missing"),
    )
    put("not_nrrd.nrrd", b"\x00\xffgarbage\n" * 4, says=("not a readable NRRD",))
    # issue 8: NRRD type block, LIST data, data files outside the header's folder, bombs
    put(
        "block_type.nrrd",
        _nrrd_header(type_="block", extra="block size: 4\n") + bytes(192),
        says=("type 'block'", "not numbers"),
    )
    put(
        "list_missing_part.nhdr",
        _nrrd_header(extra="data file: LIST\nlist_part0.raw\nlist_part1.raw\nlist_part2.raw"),
        says=("list_part0.raw", "missing"),
    )
    put(
        "outside_data.nhdr",
        _nrrd_header(extra="data file: ../outside_secret.raw"),
        says=("outside_secret.raw", "outside the header's folder", "--allow-outside-data"),
    )
    put(
        "outside_absolute.nhdr",
        _nrrd_header(extra="data file: /etc/hostname"),
        says=("/etc/hostname", "--allow-outside-data"),
    )
    put(
        "outside_numbered.nhdr",
        _nrrd_header(extra="data file: ../slab%d.raw 0 2 1"),
        says=("../slab0.raw", "--allow-outside-data"),
    )
    put(
        "gzip_bomb.nrrd",
        _nrrd_header(sizes="4 4 4", encoding="gzip") + gzip_bomb(32 << 20),
        says=("holds more than the 128 bytes its header declares",),
    )
    put(
        "gzip_short.nrrd",
        _nrrd_header(encoding="gzip") + gzip.compress(good.tobytes()[:60]),
        says=("holds 60 bytes, fewer than the 96",),
    )
    # issue 11: NIfTI is read (through nibabel); a header of zeros is not NIfTI
    put("scan.nii.gz", gzip.compress(bytes(352)), says=("not a readable NIfTI file",))
    put("scan.nii", bytes(352), says=("not a readable NIfTI file",))
    # a real NIfTI cut short (a copy stopped midway): the fix is a fresh copy
    nifti = _nifti_bytes()
    if nifti is not None:
        put("cut.nii.gz", gzip.compress(nifti)[:400], says=("not a readable", "cut short"))
    # issue 11: MetaImage is read; a header without its ElementDataFile line is refused
    put("head.mhd", b"ObjectType = Image\nNDims = 3\n", says=("no ElementDataFile line",))
    put("head.mha", b"ObjectType = Image\nNDims = 3\n", says=("no ElementDataFile line",))
    # DICOM is read (through pydicom); the magic alone, with no header, is refused
    dicom = bytes(128) + b"DICM" + bytes(64)
    put("slice.dcm", dicom, says=("not a readable DICOM image",))
    put("IM0001", dicom, says=("not a readable DICOM image",))
    tif = folder / "_good.tif"
    tifffile.imwrite(tif, good.astype(np.uint8), photometric="minisblack")
    put("truncated.tif", tif.read_bytes()[: len(tif.read_bytes()) // 2], says=("not a readable",))
    tif.unlink()
    odd = folder / "odd_page.tif"
    with tifffile.TiffWriter(odd) as tw:  # plain pages, no ImageJ/OME/shape metadata
        for shape in ((4, 5), (4, 5), (6, 7), (4, 5)):
            tw.write(np.zeros(shape, np.uint8), photometric="minisblack", metadata=None)
    cases["odd_page.tif"] = Case(odd, [], ("page 3 of 4 is 7x6 uint8", "page 1 is 5x4 uint8"))
    complex_tif = folder / "complex.tif"
    tifffile.imwrite(complex_tif, np.ones((3, 4, 5), np.complex64), photometric="minisblack")
    cases["complex.tif"] = Case(complex_tif, [], ("complex64", "real"))
    rgb = folder / "rgb.png"
    Image.fromarray(np.zeros((6, 7, 3), np.uint8)).save(rgb)
    cases["rgb.png"] = Case(rgb, ["--method", "cubes"], ("3D volume",))
    rgb_tif = folder / "rgb_stack.tif"
    tifffile.imwrite(rgb_tif, np.zeros((3, 6, 7, 3), np.uint8), photometric="rgb")
    cases["rgb_stack.tif"] = Case(rgb_tif, [], ("channels", "--channel 0..2"))
    put("broken.png", b"\x89PNG\r\n\x1a\n" + b"\x00" * 20, says=("not a readable",))
    put("unknown.xyz", b"1 2 3", says=("known input formats",))
    return cases


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "bad_inputs")
    for case in make_bad_inputs(target).values():
        print(f"{case.path}  {' '.join(case.args)}")
