"""Memory: how much there is (declared sizes are refused before allocating), file-backed
maps that hand their pages back, and arrays walked a block of rows at a time.

A mesh built block-wise may live in file-backed memory maps
(:mod:`isoconvert.extract.blocks`, when it outgrows the memory budget).
Reading such an array keeps each page it touched mapped in the process, so
:func:`row_chunks` gives those pages back after each block: a writer (or
:mod:`isoconvert.attributes`) then streams a mesh of any size through a
bounded amount of memory. This module is part of the model layer: extraction
and the writers both use it, and neither imports the other for it.
"""

from __future__ import annotations

import contextlib
import errno
import mmap
import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from .errors import OutputError, VolumeError

if TYPE_CHECKING:
    import numpy as np

#: Rows per block of :func:`row_chunks`: large enough for numpy to run at full
#: speed, small enough that temporaries stay in cache.
ROWS = 1 << 16


#: glibc's mallopt parameters (malloc.h) and the values :func:`keep_freed_memory` sets:
#: blocks up to 32 MiB (the largest threshold glibc takes) from the heap, not from
#: their own maps, and freed memory kept by the process up to 2 GiB.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8
_MMAP_THRESHOLD, _TRIM_THRESHOLD = 32 << 20, 2**31 - 1


def keep_freed_memory() -> bool:
    """Let the C allocator keep freed memory for the process's next allocations
    (glibc only; elsewhere nothing happens): for a short-lived process such as
    one ``isoconvert`` command.

    By default glibc gives every freed block of more than 128 KiB (up to 32 MiB
    as it adapts) back to the system at once, and the next array of that size
    starts on fresh pages: a fault per 4 kB page, and on a virtual machine that
    hands freed memory back to its host (this project's), first writes several
    times slower than writes to memory in use. A label volume's run frees about
    150 MB of the surface net's working arrays, then allocates the label meshes
    and the writers' blocks; kept, these reuse those pages (a third fewer page
    faults for the 40-label atlas of bench_pipeline). Every thread allocates from
    the one heap, so that what one thread frees the others reuse. The process's memory then
    stays at its peak until it exits, which a command's does at once.

    Returns
    -------
    bool
        Whether the allocator took the setting.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # glibc's; musl has none
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # the trim threshold first: setting either stops glibc adapting both
    trims = mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD)
    maps = mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)
    # one heap for every thread: memory freed by one (a kernel's worker, a label
    # written on another thread) is reused by the others, not kept in its arena
    return bool(mallopt(_M_ARENA_MAX, 1) and maps and trims)


def release_freed_memory() -> bool:
    """Give the memory the process has freed back to the system now (glibc's
    ``malloc_trim``; elsewhere nothing happens).

    :func:`keep_freed_memory` keeps it for the next arrays, which a run within
    ``--max-memory`` cannot afford between its phases: the arrays of more than
    32 MiB that the next phase makes come from maps of their own, not from what
    the last phase freed. Returns whether anything was given back.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return bool(trim(0))


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux MemAvailable), or None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_fits(n_bytes: int, what: str, source: str) -> None:
    """Refuse, before allocating, data that would not fit in available memory."""
    available = available_memory()
    if available is not None and n_bytes > available:
        raise VolumeError(
            f"{source}: {what} needs {n_bytes / 2**30:.1f} GiB, more than the "
            f"{available / 2**30:.1f} GiB of memory available; check the header, or use a "
            "machine with more memory"
        )


class FileMap(mmap.mmap):
    """A shared memory map of a temporary file (a mesh that outgrew memory).

    Its pages are the file's: giving them back (``madvise(MADV_DONTNEED)``, see
    :func:`row_chunks`) loses nothing, whereas on an
    anonymous map it would erase them. Only maps of this type are released.

    Make one with :meth:`create` and grow it with :meth:`grow`: both give the
    file its disk blocks first (:func:`reserve_disk`), so that no write through
    the map can meet a full disk (which the kernel answers with SIGBUS).
    """

    @classmethod
    def create(cls, fd: int, size: int, folder: str | Path, why: str = "") -> FileMap:
        """Map the first ``size`` bytes of the empty file ``fd`` (in ``folder``),
        once they are on disk; ``why`` is for :func:`reserve_disk`'s message."""
        reserve_disk(fd, size, folder, why)
        mapped = cls(fd, size)
        mapped.fd, mapped.folder, mapped.why = fd, folder, why
        return mapped

    def grow(self, size: int) -> None:
        """Make the map (and its file) ``size`` bytes long, disk blocks first."""
        reserve_disk(self.fd, size, self.folder, self.why)
        self.resize(size)


def reserve_disk(fd: int, size: int, folder: str | Path, why: str = "") -> None:
    """Give the file ``fd`` real disk blocks for its first ``size`` bytes.

    A file extended by ``truncate`` is sparse: its blocks are found only when
    a page is written, and a write through a memory map that finds none kills
    the process with SIGBUS (no exception, no message, whatever the handlers).
    Reserving them first turns a full disk into an error here, before any map
    uses them. Uses ``posix_fallocate``; where the file system does not do it,
    writes zeros.

    Parameters
    ----------
    fd : int
        An open, writable regular file, at most ``size`` bytes long.
    size : int
        Bytes it must hold.
    folder : str or Path
        Where it is (it may have no name), for the message.
    why : str
        What it holds, for the message.

    Raises
    ------
    DiskFullError
        No room for it (``disk full at FOLDER (needs N MiB, M MiB free)``).
    OutputError
        Another write error.
    """
    from .atomic import DISK_FULL_ERRNOS, disk_full_error

    have = os.fstat(fd).st_size
    if size <= have:
        return
    try:
        try:
            os.posix_fallocate(fd, have, size - have)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                raise
            _write_zeros(fd, have, size)
    except OSError as exc:
        with contextlib.suppress(OSError):  # give back what was reserved: the caller stops
            os.ftruncate(fd, have)
        if exc.errno in DISK_FULL_ERRNOS:
            raise disk_full_error(folder, size - have, why=why) from None
        raise OutputError(f"{folder}: writing a temporary file failed ({exc.strerror})") from None


def _write_zeros(fd: int, start: int, stop: int) -> None:
    """Write zeros into bytes ``start .. stop - 1`` of the file ``fd``."""
    step = 1 << 20
    zeros = bytes(step)
    for at in range(start, stop, step):
        n = min(step, stop - at)
        done = 0
        while done < n:
            done += os.pwrite(fd, zeros[: n - done], at + done)


def file_array(shape: tuple[int, ...], dtype, folder: str | Path, why: str = "") -> np.ndarray:
    """A zeroed array whose memory is a nameless temporary file in ``folder``.

    For an array too large for the memory budget that is filled and read a part at
    a time: :func:`release` gives back the pages touched so far, and the file keeps
    what they held. The file has no name (nothing is left however the process
    ends) and its disk blocks are reserved first (:meth:`FileMap.create`).

    Parameters
    ----------
    shape : tuple of int
    dtype : numpy dtype
    folder : str or Path
        Where the file is made (beside the output: the disk a run writes to).
    why : str
        What it holds, for a full disk's message.

    Raises
    ------
    DiskFullError, OutputError
        No room for it in ``folder``, or no file can be made there.
    """
    import tempfile

    import numpy as np

    dtype = np.dtype(dtype)
    size = dtype.itemsize * int(np.prod(shape, dtype=np.int64))
    if size == 0:
        return np.zeros(shape, dtype)
    try:
        fh = tempfile.TemporaryFile(dir=folder, prefix=".isoconvert-array-")
    except OSError as exc:
        raise OutputError(
            f"{folder}: cannot make a temporary file there ({exc.strerror}); set "
            "--max-memory higher or write elsewhere"
        ) from None
    with fh:  # the map keeps the file (a duplicate of its descriptor)
        mapped = FileMap.create(fh.fileno(), size, folder, why)
    mapped.fd = -1  # closed: never grown (a reused descriptor must not be written)
    return np.frombuffer(mapped, dtype=dtype).reshape(shape)


# --- arrays a block of rows at a time ----------------------------------------------------------


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
    import numpy as np  # here: the rest of this module serves callers without numpy

    start = np.frombuffer(mapped, dtype=np.uint8, count=1).ctypes.data
    first = array.ctypes.data - start
    end = first + array.nbytes
    first += -first % mmap.PAGESIZE  # pages wholly inside the array
    end -= end % mmap.PAGESIZE
    if end > first:
        mapped.madvise(mmap.MADV_DONTNEED, first, end - first)


def row_chunks(array: np.ndarray, rows: int = ROWS) -> Iterator[np.ndarray]:
    """Yield ``array[a : a + rows]`` for a = 0, rows, 2 rows, ...; pages of a
    file-backed map are given back once their block has been used.

    Parameters
    ----------
    array : (N, ...) array
    rows : int

    Yields
    ------
    (<= rows, ...) array
        Views of ``array``, in order.
    """
    for a in range(0, len(array), rows):
        block = array[a : a + rows]
        yield block
        # with the previous block's tail, so that pages across a cut go too
        release(array[max(0, a - 1) : a + rows])
