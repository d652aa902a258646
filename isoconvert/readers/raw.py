"""Raw sample files: no header, x varies fastest (Open SciVis layout)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import VolumeError
from ..volume import SUPPORTED_DTYPES, Volume
from .options import ReadOptions

# Common spellings from other tools (NRRD, VTK, MetaImage) mapped to numpy names.
_DTYPE_ALIASES = {
    "uchar": "uint8",
    "char": "int8",
    "ushort": "uint16",
    "short": "int16",
    "uint": "uint32",
    "int": "int32",
    "float": "float32",
    "double": "float64",
}

# name_XxYxZ_dtype.raw, the Open SciVis naming (also name_XxY_dtype.raw for 2D)
_NAME_PATTERN = re.compile(r"_(\d+)x(\d+)(?:x(\d+))?_([a-z]+\d*)$", re.IGNORECASE)


def dtype_from_name(name: str, source: str = "") -> np.dtype:
    """The numpy dtype for a sample-type name; the error lists the accepted names."""
    key = _DTYPE_ALIASES.get(name.lower(), name.lower())
    if key not in SUPPORTED_DTYPES:
        where = f"{source}: " if source else ""
        raise VolumeError(
            f"{where}unknown sample type {name!r} for --dtype; "
            f"choose one of: {', '.join(SUPPORTED_DTYPES)}"
        )
    return np.dtype(key)


def layout_from_filename(path: Path) -> tuple[tuple[int, ...], str] | None:
    """Shape (x, y[, z]) and dtype name from a ``name_XxYxZ_dtype.raw`` file name."""
    match = _NAME_PATTERN.search(path.stem)
    if not match:
        return None
    shape = tuple(int(g) for g in match.groups()[:3] if g is not None)
    return shape, match.group(4)


def read_raw(path: Path, options: ReadOptions) -> Volume:
    """Memory-map a raw file as a Volume (copy-on-write: nothing is read up front).

    Parameters
    ----------
    path : Path
        The file.
    options : ReadOptions
        ``shape`` (x, y[, z]) and ``dtype`` (else taken from a
        ``name_XxYxZ_dtype.raw`` file name), ``endian``, ``header_bytes``.
    """
    notes = []
    shape, dtype_name = options.shape, options.dtype
    if shape is None or dtype_name is None:
        from_name = layout_from_filename(path)
        if from_name is None:
            missing = " and ".join(
                n for n, v in (("--shape X Y Z", shape), ("--dtype TYPE", dtype_name)) if v is None
            )
            raise VolumeError(
                f"{path}: a raw file needs {missing} (or a name like name_256x256x128_uint8.raw)"
            )
        taken = []
        if shape is None:
            shape = from_name[0]
            taken.append(f"shape {'x'.join(map(str, shape))}")
        if dtype_name is None:
            dtype_name = from_name[1]
            taken.append(f"sample type {dtype_name}")
        notes.append(f"{' and '.join(taken)} taken from the file name")
    if len(shape) not in (2, 3) or any(int(n) <= 0 for n in shape):
        raise VolumeError(
            f"{path}: --shape needs 2 or 3 positive sizes (x y [z]), "
            f"got {' '.join(map(str, shape))}"
        )
    if options.endian not in ("little", "big"):
        raise VolumeError(f"{path}: --endian must be 'little' or 'big', got {options.endian!r}")
    if options.header_bytes < 0:
        raise VolumeError(f"{path}: --header-bytes must be >= 0, got {options.header_bytes}")
    dtype = dtype_from_name(dtype_name, str(path)).newbyteorder(
        "<" if options.endian == "little" else ">"
    )
    expected = options.header_bytes + int(np.prod(shape)) * dtype.itemsize
    actual = path.stat().st_size
    if actual != expected:
        dims = "x".join(map(str, shape))
        raise VolumeError(
            f"{path}: file has {actual} bytes but shape {dims} of {dtype.name} "
            f"with {options.header_bytes} header bytes needs {expected}; "
            "check --shape, --dtype and --header-bytes"
        )
    # Mode "c" (copy-on-write) maps the file without reading it and gives a writeable
    # array, which keeps numba to one specialization per dtype; the file is never changed.
    data = np.memmap(path, dtype=dtype, mode="c", offset=options.header_bytes, shape=shape[::-1])
    return Volume.from_zyx(np.asarray(data), source=str(path), notes=notes)
