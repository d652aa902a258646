"""Lazy grids: samples read from their file a slab of z-layers at a time.

A :class:`~isoconvert.volume.Volume` holds either an in-memory array or a
:class:`LazyGrid`. Block-wise extraction (:mod:`isoconvert.extract.blocks`)
asks a lazy grid for one slab at a time, so a volume larger than memory is
never read whole; everything else may call ``numpy.asarray(grid)`` for the
whole (X, Y, Z) array.

A lazy grid holds a file's name and layout, never an open file, so it can be
pickled and sent to a Dask worker, which then reads its own slabs.
"""

from __future__ import annotations

import math
import mmap
from abc import ABC, abstractmethod
from pathlib import Path

import numpy as np


class LazyGrid(ABC):
    """A 3D grid of samples in x, y, z index order, read on demand.

    Attributes
    ----------
    shape : (3,) tuple of int
        (X, Y, Z) samples.
    dtype : numpy dtype
        Of the samples as the file stores them (byte order included).
    sequential : bool
        True when reading in increasing z is much cheaper than reading out of
        order (a compressed stream): slabs are then best read by one process,
        in order.
    path : Path
        The file (or folder) the samples are read from, for messages.
    z_chunk : int
        z-layers the file stores together (a chunk's depth, 1 when layers
        are stored one by one).
    """

    shape: tuple[int, int, int]
    dtype: np.dtype
    sequential: bool = False
    path: Path
    #: z-layers the file stores together (a chunk's depth): reading fewer
    #: decodes them all anyway (see :class:`SlabReader`)
    z_chunk: int = 1
    ndim = 3

    @property
    def size(self) -> int:
        return math.prod(self.shape)  # Python integers: never wraps

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    @abstractmethod
    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        """Layers ``k0 <= k < k1`` as a C-ordered ``(k1 - k0, Y, X)`` array.

        Raises
        ------
        isoconvert.errors.FormatError
            When the file no longer holds what its header promised (truncated,
            a missing chunk), naming the file and the layers.
        """

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """The whole grid as an (X, Y, Z) array (x fastest in memory)."""
        whole = self.read_zyx(0, self.shape[2]).T
        return whole if dtype is None else whole.astype(dtype, copy=False)

    def _check_slab(self, k0: int, k1: int) -> None:
        """For subclasses' :meth:`read_zyx`: check the range (a caller's bug) and, before
        anything is allocated, that the slab fits in the memory available (so that a
        whole-volume read of a grid larger than memory is a one-line error)."""
        from .memory import check_fits

        nx, ny, nz = self.shape
        if not 0 <= k0 <= k1 <= nz:
            raise ValueError(f"z-layers {k0}..{k1 - 1} are not within 0..{nz - 1}")
        nbytes = (k1 - k0) * nx * ny * self.dtype.itemsize
        check_fits(nbytes, f"reading z-layers {k0}..{k1 - 1}", str(self.path))

    def _empty_slab(self, k0: int, k1: int) -> np.ndarray:
        """An uninitialised C-ordered ``(k1 - k0, Y, X)`` array for layers ``k0..k1 - 1``,
        after :meth:`_check_slab`."""
        self._check_slab(k0, k1)
        nx, ny, _ = self.shape
        return np.empty((k1 - k0, ny, nx), dtype=self.dtype)

    def __repr__(self) -> str:
        dims = "x".join(map(str, self.shape))
        return f"{type(self).__name__}({dims} {self.dtype.name})"


class RawGrid(LazyGrid):
    """Samples stored uncompressed in one file, x fastest, from a byte offset.

    Each slab is a memory map of its own bytes (a plain read when the offset
    is not a multiple of the sample size), so memory stays bounded by the
    slabs alive: a map of the whole file would keep every page it touched.
    ``numpy.asarray`` of the whole grid is a copy-on-write memory map (nothing
    read up front, the file never changed), as the in-memory path always had;
    when the offset is not a multiple of the sample size it is an aligned
    copy instead, since unaligned samples slow down (or, on some machines,
    break) the compiled kernels.

    Parameters
    ----------
    path : Path
    dtype : numpy dtype
        With its byte order.
    shape : (3,) tuple of int
        (X, Y, Z).
    offset : int
        Bytes before the first sample.
    """

    def __init__(self, path: Path, dtype: np.dtype, shape: tuple[int, int, int], offset: int = 0):
        self.path = Path(path)
        self.dtype = np.dtype(dtype)
        self.shape = tuple(int(n) for n in shape)
        self.offset = int(offset)

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        from .errors import FormatError

        nx, ny, nz = self.shape
        start = self.offset + k0 * nx * ny * self.dtype.itemsize
        if self.offset % self.dtype.itemsize == 0 and 0 <= k0 < k1 <= nz:
            # A map of the slab's own bytes, unmapped with the slab: the kernels
            # read the cached file with no copy and no fresh memory to fault in,
            # and what stays resident is bounded by the slabs alive.
            try:
                slab = np.memmap(
                    self.path, dtype=self.dtype, mode="c", offset=start, shape=(k1 - k0, ny, nx)
                )
            except (ValueError, OSError):
                pass  # shortened since it was opened: the read below says so
            else:
                if hasattr(mmap, "MADV_WILLNEED"):
                    slab._mmap.madvise(mmap.MADV_WILLNEED)  # read ahead from now on
                return slab
        out = self._empty_slab(k0, k1)
        with open(self.path, "rb", buffering=0) as fh:
            fh.seek(start)
            got = read_exactly(fh, out)
        if got != out.nbytes:
            raise FormatError(
                f"{self.path}: the file ends inside z-layers {k0}..{k1 - 1} "
                f"(it was shortened after it was opened?)"
            )
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        if self.offset % self.dtype.itemsize:
            return super().__array__(dtype, copy)
        mapped = np.memmap(
            self.path, dtype=self.dtype, mode="c", offset=self.offset, shape=self.shape[::-1]
        )
        whole = np.asarray(mapped).T
        return whole if dtype is None else whole.astype(dtype, copy=False)


def read_exactly(fh, out: np.ndarray) -> int:
    """Fill the contiguous array ``out`` with bytes from the open binary file ``fh``.

    Returns the number of bytes read, short only when the file ends: one
    ``readinto`` may return less than asked (at most about 2 GiB on Linux).
    """
    view = memoryview(out.reshape(-1).view(np.uint8))
    got = 0
    while got < len(view):
        n = fh.readinto(view[got:])
        if not n:
            break
        got += n
    return got


class SlabReader:
    """Reads z-ranges of an array or lazy grid in increasing z, decoding each
    stored chunk row once.

    A chunked store (Zarr) decodes whole chunks: a slab thinner than a chunk
    is deep would decode every chunk of its row again for each slab. The
    reader keeps the row (:attr:`LazyGrid.z_chunk` layers) that the current
    range lies in and cuts ranges out of it; a range across two rows is
    copied out of the first, which is dropped before the next is decoded,
    so that two rows are never held at once.

    Parameters
    ----------
    source : (X, Y, Z) array or LazyGrid
    """

    def __init__(self, source: np.ndarray | LazyGrid) -> None:
        self.source = source
        self.unit = source.z_chunk if isinstance(source, LazyGrid) else 1
        self._rows: dict[int, np.ndarray] = {}

    def ready(self, k0: int, k1: int) -> bool:
        """Whether reading ``k0 .. k1 - 1`` decodes no new row (so it may run
        beside other work without holding two rows)."""
        if self.unit <= 1:
            return True
        return all(r in self._rows for r in range(k0 // self.unit, (k1 - 1) // self.unit + 1))

    def read(self, k0: int, k1: int) -> np.ndarray:
        """Layers ``k0 <= k < k1`` as a C-ordered ``(k1 - k0, Y, X)`` array
        (a view where possible)."""
        if self.unit <= 1:
            return grid_slab_zyx(self.source, k0, k1)
        unit = self.unit
        first, last = k0 // unit, (k1 - 1) // unit
        for r in [r for r in self._rows if r < first]:
            del self._rows[r]
        if first == last:
            return self._row(first)[k0 - first * unit : k1 - first * unit]
        nx, ny, _ = self.source.shape
        out = np.empty((k1 - k0, ny, nx), dtype=self.source.dtype)
        for r in range(first, last + 1):
            lo, hi = max(k0, r * unit), min(k1, (r + 1) * unit)
            out[lo - k0 : hi - k0] = self._row(r)[lo - r * unit : hi - r * unit]
            if r < last:
                del self._rows[r]
        return out

    def _row(self, r: int) -> np.ndarray:
        if r not in self._rows:
            k = r * self.unit
            self._rows[r] = self.source.read_zyx(k, min(k + self.unit, self.source.shape[2]))
        return self._rows[r]


def grid_slab_zyx(data: np.ndarray | LazyGrid, k0: int, k1: int) -> np.ndarray:
    """Layers ``k0 <= k < k1`` of an (X, Y, Z) array or lazy grid, as (k1 - k0, Y, X).

    A view for in-memory arrays; a fresh array for lazy grids.
    """
    if isinstance(data, LazyGrid):
        return data.read_zyx(k0, k1)
    return data[:, :, k0:k1].T


__all__ = ["LazyGrid", "RawGrid", "SlabReader", "grid_slab_zyx", "read_exactly"]
