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
    """

    shape: tuple[int, int, int]
    dtype: np.dtype
    sequential: bool = False
    ndim = 3

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

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

    def __repr__(self) -> str:
        dims = "x".join(map(str, self.shape))
        return f"{type(self).__name__}({dims} {self.dtype.name})"


class RawGrid(LazyGrid):
    """Samples stored uncompressed in one file, x fastest, from a byte offset.

    Slabs are read with plain reads, not a memory map, so that memory stays
    bounded by the slab: pages of a map stay in the process once touched.
    ``numpy.asarray`` of the whole grid is a copy-on-write memory map (nothing
    read up front, the file never changed), as the in-memory path always had.

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

        nx, ny, _ = self.shape
        layer = nx * ny
        count = (k1 - k0) * layer
        with open(self.path, "rb") as fh:
            fh.seek(self.offset + k0 * layer * self.dtype.itemsize)
            out = np.fromfile(fh, dtype=self.dtype, count=count)
        if out.size != count:
            raise FormatError(
                f"{self.path}: the file ends inside z-layers {k0}..{k1 - 1} "
                f"(it was shortened after it was opened?)"
            )
        return out.reshape(k1 - k0, ny, nx)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        mapped = np.memmap(
            self.path, dtype=self.dtype, mode="c", offset=self.offset, shape=self.shape[::-1]
        )
        whole = np.asarray(mapped).T
        return whole if dtype is None else whole.astype(dtype, copy=False)


def grid_slab_zyx(data: np.ndarray | LazyGrid, k0: int, k1: int) -> np.ndarray:
    """Layers ``k0 <= k < k1`` of an (X, Y, Z) array or lazy grid, as (k1 - k0, Y, X).

    A view for in-memory arrays; a fresh array for lazy grids.
    """
    if isinstance(data, LazyGrid):
        return data.read_zyx(k0, k1)
    return data[:, :, k0:k1].T


__all__ = ["LazyGrid", "RawGrid", "grid_slab_zyx"]
