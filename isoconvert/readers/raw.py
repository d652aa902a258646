"""Raw sample files: no header, x varies fastest (Open SciVis layout)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from ..errors import VolumeError
from ..grid import RawGrid
from ..volume import SUPPORTED_DTYPES, Volume
from .options import ReadOptions, absolute_files

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
    # Python integers: sizes whose product overflows 64 bits give the true, huge count
    expected = options.header_bytes + math.prod(int(n) for n in shape) * dtype.itemsize
    actual = path.stat().st_size
    if actual != expected:
        dims = "x".join(map(str, shape))
        raise VolumeError(
            f"{path}: file has {actual} bytes but shape {dims} of {dtype.name} "
            f"with {options.header_bytes} header bytes needs {expected}; "
            "check --shape, --dtype and --header-bytes"
        )
    # Mode "c" (copy-on-write) maps the file without reading it; the file is never changed.
    data = np.asarray(
        np.memmap(path, dtype=dtype, mode="c", offset=options.header_bytes, shape=shape[::-1])
    )
    hint = byte_order_note(data, options.endian)
    if hint:
        notes.append(hint)
    if len(shape) == 3:
        # read slab by slab when extracted block-wise; whole, it is the same map
        grid = RawGrid(path, dtype, tuple(shape), options.header_bytes)
        return Volume(grid, source=str(path), notes=notes, files=absolute_files([path]))
    return Volume.from_zyx(data, source=str(path), notes=notes, files=absolute_files([path]))


# Samples looked at to judge the byte order: a few slabs, never the whole file.
_SAMPLE_LIMIT = 1 << 20
_SAMPLE_PIECES = 8
# Floats: magnitudes beyond these (or NaN/inf) are implausible for measured data.
_FLOAT_HUGE, _FLOAT_TINY = 1e30, 1e-30


def _sample_rows(data: np.ndarray) -> np.ndarray:
    """Up to ``_SAMPLE_LIMIT`` samples as rows along x, from slabs spread over the volume."""
    width = data.shape[-1]
    rows = data.reshape(-1, width)  # a view: C order, x last
    cols = min(width, _SAMPLE_LIMIT)
    wanted = max(1, _SAMPLE_LIMIT // cols)
    if wanted >= len(rows):
        return np.array(rows[:, :cols])
    run = max(1, wanted // _SAMPLE_PIECES)
    starts = np.linspace(0, len(rows) - run, _SAMPLE_PIECES).astype(np.int64)
    return np.concatenate([rows[s : s + run, :cols] for s in starts])


def _implausible_floats(values: np.ndarray) -> tuple[float, int]:
    """Share of the non-zero samples that are NaN, inf, or beyond 1e+-30 in magnitude."""
    nonzero = values[values != 0]
    if nonzero.size == 0:
        return 0.0, 0
    with np.errstate(all="ignore"):
        mag = np.abs(nonzero.astype(np.float64))
        odd = ~np.isfinite(mag) | (mag > _FLOAT_HUGE) | (mag < _FLOAT_TINY)
    return float(odd.mean()), nonzero.size


def _roughness(values: np.ndarray) -> float:
    """Mean absolute difference of neighbouring samples along x."""
    return float(np.abs(np.diff(values.astype(np.float64), axis=-1)).mean())


def byte_order_note(data: np.ndarray, endian: str) -> str | None:
    """A note suggesting the other byte order when the samples look byte-swapped.

    Looks at a bounded sample (at most about a million samples from slabs
    spread over the volume), so a memory-mapped file is barely read. Floats
    look swapped when many non-zero samples are NaN, infinite or beyond
    1e+-30 in magnitude while the swapped values are ordinary; 16- and 32-bit
    integers when the swapped values are far smoother along x (mean absolute
    difference of neighbours). 1-byte samples have no byte order.

    Parameters
    ----------
    data : ndarray
        The samples in C (z, y, x) order, as read with ``endian``.
    endian : str
        The byte order they were read with, "little" or "big".

    Returns
    -------
    str or None
        The note, or None when the values look plausible.
    """
    if data.dtype.itemsize == 1 or data.dtype.kind not in "iuf" or data.size < 2:
        return None
    other = "big" if endian == "little" else "little"
    sample = _sample_rows(data)
    swapped = sample.view(sample.dtype.newbyteorder())  # the same bytes, the other order
    name = data.dtype.name
    if data.dtype.kind == "f":
        odd, count = _implausible_floats(sample)
        odd_swapped, _ = _implausible_floats(swapped)
        if count < 16 or odd < 0.05 or odd_swapped > min(0.01, odd / 10):
            return None
        return (
            f"the samples look byte-swapped: {odd:.0%} of the non-zero {name} values are NaN, "
            f"infinite or beyond 1e+-30 as {endian}-endian, {odd_swapped:.0%} as {other}-endian; "
            f"if the file is {other}-endian, pass --endian {other}"
        )
    if sample.shape[-1] < 2:
        return None
    rough, rough_swapped = _roughness(sample), _roughness(swapped)
    if not rough > 4 * rough_swapped:
        return None
    return (
        f"the samples look byte-swapped: neighbouring {name} values differ by {rough:.3g} on "
        f"average as {endian}-endian, by {rough_swapped:.3g} as {other}-endian; if the file is "
        f"{other}-endian, pass --endian {other}"
    )
