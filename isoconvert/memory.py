"""How much memory there is, so that declared sizes can be refused before allocating."""

from __future__ import annotations

import mmap
import os

from .errors import VolumeError


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
    :func:`isoconvert.writers.chunks.row_chunks`) loses nothing, whereas on an
    anonymous map it would erase them. Only maps of this type are released.
    """
