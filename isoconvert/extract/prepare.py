"""Validation shared by every extractor: what the kernels may assume."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import LevelError, VolumeError
from ..volume import SUPPORTED_DTYPES, ValueRange, Volume, slabs, value_range


def kernel_array(
    volume: Volume,
    ndim: int,
    method: str,
    nan_as: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, ValueRange]:
    """Check a volume and return its samples as the kernels want them.

    Parameters
    ----------
    volume : Volume
        The input.
    ndim : int
        Dimensions the extractor works in (2 or 3).
    method : str
        Extractor name, for messages.
    nan_as : float or None
        Value that replaces NaN and +-Inf samples; None makes them an error.
    on_status : callable or None
        Receives a line for each copy made (byte swap, non-contiguous data).

    Returns
    -------
    array : (Z, Y, X) or (Y, X) C-contiguous, native byte order
        A view of ``volume.data`` when possible (no copy).
    ValueRange
        Range of the (finite) samples.
    """
    src = volume.source
    data = volume.data
    if nan_as is not None and not np.isfinite(nan_as):
        raise VolumeError(
            f"{src}: --nan-as takes a finite number (the value NaN/Inf samples stand for), "
            f"got {nan_as}; e.g. --nan-as 0"
        )
    if data.ndim != ndim:
        hint = (
            "use --method squares for a 2D image"
            if data.ndim == 2
            else "use --method cubes or tetra for a 3D volume"
        )
        raise VolumeError(f"{src}: {method} needs a {ndim}D volume, got shape {data.shape}; {hint}")
    if any(n < 2 for n in data.shape):
        raise VolumeError(
            f"{src}: shape {data.shape} has a dimension below 2; an isosurface needs at least "
            "2 samples along every axis (for a single slice, read it as a 2D image)"
        )
    dtype = data.dtype
    if dtype == np.bool_:
        data = data.view(np.uint8)
    elif dtype.name not in SUPPORTED_DTYPES:  # the name ignores byte order
        if np.issubdtype(dtype, np.integer) and dtype.itemsize == 8:
            data = _narrow_int64(data, src)
        else:
            raise VolumeError(
                f"{src}: samples of type {dtype} cannot be contoured; supported types: "
                f"{', '.join(SUPPORTED_DTYPES)}"
            )
    arr = data.T
    if not arr.dtype.isnative:
        if on_status:
            on_status(f"{src}: converting {arr.dtype.str} samples to native byte order (a copy)")
        arr = arr.astype(arr.dtype.newbyteorder("="), order="C")
    if not arr.flags.c_contiguous:
        arr = np.ascontiguousarray(arr)
    stats = value_range(arr.T)
    if stats.nonfinite:
        if nan_as is None:
            raise VolumeError(
                f"{src}: {stats.nonfinite} samples are NaN or infinite; pass --nan-as VALUE "
                "(nan_as=) to treat them as that value"
            )
        arr = np.where(np.isfinite(arr), arr, arr.dtype.type(nan_as))
        lo, hi = min(stats.min, nan_as), max(stats.max, nan_as)
        if stats.nonfinite == arr.size:
            lo = hi = float(nan_as)
        stats = ValueRange(lo, hi, 0)
    return arr, stats


def _narrow_int64(data: np.ndarray, src: str) -> np.ndarray:
    """64-bit integers are contoured as float64 when that is exact."""
    limit = 2**53
    for slab in slabs(data):
        if slab.size and (slab.min() < -limit or slab.max() > limit):
            raise VolumeError(
                f"{src}: 64-bit integer samples beyond +-2**53 cannot be contoured exactly; "
                "rescale the data first"
            )
    return data.astype(np.float64)


def check_level(level: float, stats: ValueRange, src: str) -> float:
    """Make sure ``level`` separates some samples from others.

    A grid vertex is positive when its value is >= level (book Definition 2.1),
    so a surface exists exactly when ``min < level <= max``.
    """
    level = float(level)
    if not np.isfinite(level):
        raise LevelError(f"{src}: the level must be a finite number, got {level}")
    if stats.min == stats.max:
        raise LevelError(
            f"{src}: the volume is constant (every sample is {stats.min:g}); it has no isosurface"
        )
    if not stats.min < level <= stats.max:
        raise LevelError(
            f"{src}: level {level:g} is outside the data range; choose a level with "
            f"{stats.min:g} < level <= {stats.max:g} (`isoconvert info` suggests some)"
        )
    return level


def check_vertex_offset(offset: float) -> float:
    """Validate the fraction of an edge that vertices keep from its ends.

    With the sign rule (positive when value >= level) the configurations at a
    level equal to grid values are those of a level a hair below it, so the
    mesh is combinatorially what a generic level gives: a closed 2-manifold for
    closed surfaces. Only the geometry degenerates: a vertex whose edge starts
    at a grid vertex with exactly the level sits on that grid vertex (t = 0), and
    vertices of several edges coincide there (zero-length edges, book sections
    2.2.4 and 2.3.4). Clamping t to [f, 1 - f] moves each such vertex a fraction f
    along its own edge; vertices on different grid edges are then distinct
    points, so no edge has length zero, and the connectivity is unchanged.
    """
    offset = float(offset)
    if not 0.0 <= offset < 0.5:
        raise VolumeError(f"the vertex offset must be in [0, 0.5), got {offset:g}")
    return offset


def count_equal(data: np.ndarray, level: float) -> int:
    """How many samples equal ``level`` exactly (slab by slab, no full-size temporary).

    Parameters
    ----------
    data : (X, Y, Z) or (X, Y) array
    level : float

    Returns
    -------
    int
        0 at once, without a scan, when no sample of this type can equal
        ``level`` (a level that is not a whole number for integer samples, or
        not representable in the samples' floating-point type).
    """
    level = float(level)
    if data.dtype == np.bool_:
        data = data.view(np.uint8)
    if np.issubdtype(data.dtype, np.integer):
        info = np.iinfo(data.dtype)
        if not level.is_integer() or not info.min <= level <= info.max:
            return 0
        target = data.dtype.type(int(level))
    elif np.issubdtype(data.dtype, np.floating):
        if float(data.dtype.type(level)) != level:  # e.g. 0.1 against float32 samples
            return 0
        target = level
    else:
        return 0
    return sum(int(np.count_nonzero(slab == target)) for slab in slabs(data))
