"""Make a corpus of broken inputs, each with what reading or converting it must say.

Run ``python tests/make_bad_inputs.py FOLDER`` to look at the files; the tests
call :func:`make_bad_inputs` with a temporary folder. Every case must end in one
line on stderr naming the file, a non-zero exit code and no output file.
"""

from __future__ import annotations

import gzip
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class Case:
    """A broken input: the file, extra command-line words, and words the error must hold."""

    path: Path
    args: list[str] = field(default_factory=list)
    says: tuple[str, ...] = ()


def _nrrd_header(sizes="4 4 3", type_="short", encoding="raw", extra="") -> bytes:
    return (
        f"NRRD0004\ndimension: {len(sizes.split())}\ntype: {type_}\nsizes: {sizes}\n"
        f"endian: little\nencoding: {encoding}\n{extra}\n"
    ).encode()


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
    tif = folder / "_good.tif"
    tifffile.imwrite(tif, good.astype(np.uint8), photometric="minisblack")
    put("truncated.tif", tif.read_bytes()[: len(tif.read_bytes()) // 2], says=("not a readable",))
    tif.unlink()
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
