"""Validation shared by every extractor: what the kernels may assume.

:func:`prepare` is the one entry point of the built-in extractors: it checks
the volume's shape and type, makes the samples C-ordered (Z, Y, X), and runs
the kernels' first pass (``isoconvert._native.scan_rows``), which reads every
sample once and gives the value range, NaN/Inf and samples equal to the level
on the way; the level and the vertex offset are checked from those, so no
separate sweep over the volume validates it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import LevelError, VolumeError
from ..methods import NO_DEGENERATE_OFFSET
from ..threads import kernel_threads
from ..volume import SUPPORTED_DTYPES, ValueRange, Volume, slabs, value_range


def kernel_samples(
    volume: Volume,
    ndim: int,
    method: str,
    nan_as: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> np.ndarray:
    """Check a volume's shape and type and return its samples as the kernels want them.

    Parameters
    ----------
    volume : Volume
        The input.
    ndim : int
        Dimensions the extractor works in (2 or 3).
    method : str
        Extractor name, for messages.
    nan_as : float or None
        Value that will replace NaN and +-Inf samples (checked here, used by
        :func:`prepare`).
    on_status : callable or None
        Receives a line for each copy made (byte swap, non-contiguous data).

    Returns
    -------
    (Z, Y, X) or (Y, X) array
        C-contiguous, native byte order, one of the kernels' types; a view of
        ``volume.data`` when possible (no copy).
    """
    check_volume(volume, ndim, method, nan_as)
    return kernel_type(volume.data.T, volume.source, on_status)


def check_volume(volume: Volume, ndim: int, method: str, nan_as: float | None = None) -> None:
    """The checks of :func:`kernel_samples` that need no sample (shape, ``nan_as``)."""
    src = volume.source
    shape = volume.shape
    if nan_as is not None and not np.isfinite(nan_as):
        raise VolumeError(
            f"{src}: --nan-as takes a finite number (the value NaN/Inf samples stand for), "
            f"got {nan_as}; e.g. --nan-as 0"
        )
    if len(shape) != ndim:
        hint = (
            "use --method squares for a 2D image"
            if len(shape) == 2
            else "use --method cubes or tetra for a 3D volume"
        )
        raise VolumeError(f"{src}: {method} needs a {ndim}D volume, got shape {shape}; {hint}")
    if any(n < 2 for n in shape):
        raise VolumeError(
            f"{src}: shape {shape} has a dimension below 2; an isosurface needs at least "
            "2 samples along every axis (for a single slice, read it as a 2D image)"
        )


def kernel_type(
    zyx: np.ndarray, src: str, on_status: Callable[[str], None] | None = None
) -> np.ndarray:
    """Samples as the kernels take them: C-contiguous, native byte order, one of
    :data:`SUPPORTED_DTYPES` (booleans as uint8, 64-bit integers as float64 when
    exact); a view when they already are.

    Parameters
    ----------
    zyx : (Z, Y, X) or (Y, X) array
        A volume's samples, or a slab of them.
    src : str
        The volume's source, for messages.
    on_status : callable or None
        Receives a line for each copy made (byte swap, non-contiguous data).
    """
    dtype = zyx.dtype
    if dtype == np.bool_:
        zyx = zyx.view(np.uint8)
    elif dtype.name not in SUPPORTED_DTYPES:  # the name ignores byte order
        if np.issubdtype(dtype, np.integer) and dtype.itemsize == 8:
            zyx = _narrow_int64(zyx, src)
        else:
            raise VolumeError(
                f"{src}: samples of type {dtype} cannot be contoured; supported types: "
                f"{', '.join(SUPPORTED_DTYPES)}"
            )
    if not zyx.dtype.isnative:
        if on_status:
            on_status(f"{src}: converting {zyx.dtype.str} samples to native byte order (a copy)")
        zyx = zyx.astype(zyx.dtype.newbyteorder("="), order="C")
    if not zyx.flags.c_contiguous:
        zyx = np.ascontiguousarray(zyx)
    return zyx


def kernel_array(
    volume: Volume,
    ndim: int,
    method: str,
    nan_as: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, ValueRange]:
    """:func:`kernel_samples` plus the value range (a separate sweep; prefer :func:`prepare`)."""
    arr = kernel_samples(volume, ndim, method, nan_as, on_status)
    stats = value_range(arr.T)
    if stats.nonfinite:
        arr = _replace_nonfinite(arr, stats.nonfinite, nan_as, volume.source)
        lo, hi = min(stats.min, nan_as), max(stats.max, nan_as)
        if stats.nonfinite == arr.size:
            lo = hi = float(nan_as)
        stats = ValueRange(lo, hi, 0)
    return arr, stats


def _replace_nonfinite(arr: np.ndarray, count: int, nan_as: float | None, src: str) -> np.ndarray:
    """A copy of ``arr`` with its ``count`` NaN/Inf samples set to ``nan_as`` (None: refuse)."""
    if nan_as is None:
        raise nonfinite_error(src, count)
    return np.where(np.isfinite(arr), arr, arr.dtype.type(nan_as))


def nonfinite_error(src: str, count: int, where: str = "") -> VolumeError:
    """The error for ``count`` NaN/Inf samples (``where``: of which part of the volume)."""
    samples = "1 sample" if count == 1 else f"{count:,} samples"
    verb = "is" if count == 1 else "are"
    return VolumeError(
        f"{src}: {samples}{where} {verb} NaN or infinite; pass --nan-as VALUE to treat them as "
        "that value"
    )


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


def check_finite_level(level: float, src: str) -> float:
    """``level`` as a float, refused when NaN or infinite (before any sample is read)."""
    level = float(level)
    if not np.isfinite(level):
        raise LevelError(f"{src}: the level must be a finite number, got {level}")
    return level


def check_level(level: float, stats: ValueRange, src: str) -> float:
    """Make sure ``level`` separates some samples from others.

    A grid vertex is positive when its value is >= level (book Definition 2.1),
    so a surface exists exactly when ``min < level <= max``.
    """
    level = check_finite_level(level, src)
    if stats.min == stats.max:
        raise LevelError(
            f"{src}: the volume is constant (every sample is {stats.min:g}); it has no isosurface"
        )
    if not stats.min < level <= stats.max:
        # at the minimum every sample is >= level (positive): nothing lies below it
        where = "at the data's minimum" if level == stats.min else "outside the data range"
        raise LevelError(
            f"{src}: level {level:g} is {where}, so no surface separates samples; choose "
            f"a level with {stats.min:g} < level <= {stats.max:g} (`isoconvert info` "
            "suggests some)"
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

    For extractors that do not use :func:`prepare` (plugins), whose first pass
    counts them on the way.

    Parameters
    ----------
    data : (X, Y, Z) or (X, Y) array
    level : float

    Returns
    -------
    int
        0 at once, without a scan, when no sample of this type can equal
        ``level`` (see :func:`equal_target`).
    """
    target = equal_target(data.dtype, float(level))
    if target is None:
        return 0
    if data.dtype == np.bool_:
        data = data.view(np.uint8)
    value = data.dtype.type(target)
    return sum(int(np.count_nonzero(slab == value)) for slab in slabs(data))


@dataclass(frozen=True)
class Prepared:
    """What a kernel may assume about its input.

    Attributes
    ----------
    array : (Z, Y, X) or (Y, X) array
        The samples, C-contiguous, native byte order, a supported type.
    scan : isoconvert._native.RowScan
        The first pass over ``array`` (viewed as (Z, Y, X); (1, Y, X) for 2D).
    level : float
        The isovalue, inside the data range.
    offset : float
        The vertex offset to use (0 <= offset < 0.5).
    threads : int
    """

    array: np.ndarray
    scan: object
    level: float
    offset: float
    threads: int

    @property
    def volume3(self) -> np.ndarray:
        """``array`` as (Z, Y, X): 2D images as one slice."""
        return self.array if self.array.ndim == 3 else self.array[np.newaxis]


def prepare(
    volume: Volume,
    ndim: int,
    method: str,
    level: float,
    *,
    nan_as: float | None = None,
    vertex_offset: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> Prepared:
    """Check a volume and a level for a kernel, and run the kernels' first pass.

    Parameters
    ----------
    volume : Volume
    ndim : int
        Dimensions the extractor works in (2 or 3).
    method : str
        Extractor name, for messages.
    level : float
    nan_as : float or None
        Value that replaces NaN and +-Inf samples; None makes them an error.
    vertex_offset : float or None
        See :func:`resolve_vertex_offset`; None chooses.
    on_status : callable or None
        Receives notices: copies made, and where vertices are placed.

    Returns
    -------
    Prepared
    """
    from .. import _native

    src = volume.source
    level = check_finite_level(level, src)
    arr = kernel_samples(volume, ndim, method, nan_as, on_status)
    threads = kernel_threads()
    equal_to = equal_target(arr.dtype, level)

    def scan(samples: np.ndarray):
        vol3 = samples if samples.ndim == 3 else samples[np.newaxis]
        return _native.scan_rows(vol3, level, equal_to is not None, equal_to or 0.0, threads)

    rows = scan(arr)
    if rows.nonfinite:
        arr = _replace_nonfinite(arr, rows.nonfinite, nan_as, src)
        rows = scan(arr)
    check_level(level, ValueRange(rows.min, rows.max, 0), src)
    offset, note = resolve_vertex_offset(arr.dtype, level, vertex_offset, rows.equal)
    if note and on_status:
        on_status(note)
    return Prepared(arr, rows, level, offset, threads)


def resolve_vertex_offset(
    dtype: np.dtype, level: float, given: float | None, equal: int
) -> tuple[float, str | None]:
    """The vertex offset to use, and a notice for the user (or None).

    ``given`` is used as it is (after :func:`check_vertex_offset`), except None
    (automatic): then :data:`NO_DEGENERATE_OFFSET` when some sample equals the
    level, else 0. With the sign rule (positive when value >= level) the
    connectivity at a level equal to sample values is that of a level a hair
    below, so keeping vertices a thousandth of their edge away from those
    samples changes no count (vertices and triangles stay equal to VTK's) and
    removes every zero-length edge and collapsed triangle.

    Parameters
    ----------
    dtype : numpy dtype
        Of the samples (for the level suggested instead).
    level : float
    given : float or None
    equal : int
        Samples equal to ``level``.
    """
    if given is not None and given != 0:
        return check_vertex_offset(given), None
    if not equal:
        return 0.0, None
    samples = f"{equal:,} sample{'s' if equal > 1 else ''}"
    if given is None:
        return NO_DEGENERATE_OFFSET, (
            f"level {level:g} equals {samples}: the vertices there are kept "
            f"{NO_DEGENERATE_OFFSET:g} of an edge away from them, so the mesh has no "
            "zero-length edges (--exact-placement puts them on the samples)"
        )
    return 0.0, (
        f"level {level:g} equals {samples}: expect zero-length edges and degenerate cells "
        f"there; use --level {_level_below(dtype, level):g}, or drop --exact-placement"
    )


def _level_below(dtype: np.dtype, level: float) -> float:
    """A level just below ``level`` that no sample of this type can equal."""
    if np.issubdtype(dtype, np.integer) or dtype == np.bool_:
        return level - 0.5
    return float(np.nextafter(level, -np.inf))


def equal_target(dtype: np.dtype, level: float) -> float | None:
    """``level`` when a sample of this type can equal it, else None (nothing to count).

    A level that is not a whole number cannot equal integer samples, nor can a
    float64 level with no float32 twin (0.1) equal float32 samples.
    """
    if dtype == np.bool_:
        dtype = np.dtype(np.uint8)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        if level.is_integer() and info.min <= level <= info.max:
            return level
        return None
    if np.issubdtype(dtype, np.floating) and float(dtype.type(level)) == level:
        return level
    return None
