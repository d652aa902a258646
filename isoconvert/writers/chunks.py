"""Rows of a mesh array a block at a time, for writers.

A mesh built block-wise may live in file-backed memory maps
(:mod:`isoconvert.extract.blocks`, when it outgrows the memory budget).
Reading such an array keeps each page it touched mapped in the process, so
:func:`row_chunks` gives those pages back after each block: a writer then
streams a mesh of any size through a bounded amount of memory.
"""

from __future__ import annotations

import mmap
from collections.abc import Iterator

import numpy as np

from ..memory import FileMap

#: Rows per block: large enough for numpy to run at full speed, small enough
#: that temporaries stay in cache.
ROWS = 1 << 16


def _file_map(array: np.ndarray) -> FileMap | None:
    """The file-backed memory map ``array`` views, if any."""
    base = array
    while base is not None:
        if isinstance(base, mmap.mmap):
            return base if isinstance(base, FileMap) else None
        base = base.obj if isinstance(base, memoryview) else getattr(base, "base", None)
    return None


def release(array: np.ndarray) -> None:
    """Give back the whole pages of ``array`` when it views a :class:`FileMap`
    (nothing is lost: they are the file's); a no-op for any other array."""
    mapped = _file_map(array) if hasattr(mmap, "MADV_DONTNEED") else None
    if mapped is None or not array.size:
        return
    start = np.frombuffer(mapped, dtype=np.uint8, count=1).ctypes.data
    first = array.ctypes.data - start
    end = first + array.nbytes
    first += -first % mmap.PAGESIZE  # pages wholly inside the array
    end -= end % mmap.PAGESIZE
    if end > first:
        mapped.madvise(mmap.MADV_DONTNEED, first, end - first)


def row_chunks(array: np.ndarray, rows: int = ROWS) -> Iterator[np.ndarray]:
    """Yield ``array[a : a + rows]`` for a = 0, rows, 2 rows, ...; pages of a
    file-backed map are given back once their block has been used."""
    for a in range(0, len(array), rows):
        block = array[a : a + rows]
        yield block
        # with the previous block's tail, so that pages across a cut go too
        release(array[max(0, a - 1) : a + rows])


__all__ = ["ROWS", "release", "row_chunks"]
