"""How many threads the compiled kernels use (extraction and the mesh report), and the
settings of a process that runs one command (:func:`prepare_process`)."""

from __future__ import annotations

import os

from .errors import IsoconvertError


def available_cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def kernel_threads() -> int:
    """``ISOCONVERT_THREADS`` when set (at most the CPUs available: more only adds
    start-up and switching costs), else the CPUs this process may run on.

    Raises
    ------
    IsoconvertError
        When ``ISOCONVERT_THREADS`` is not a whole number of at least 1.
    """
    cpus = available_cpus()
    given = os.environ.get("ISOCONVERT_THREADS", "").strip()
    if not given:
        return cpus
    try:
        threads = int(given)
    except ValueError:
        threads = 0
    if threads < 1:
        raise IsoconvertError(
            f"ISOCONVERT_THREADS must be a whole number of at least 1, got {given!r}; "
            "unset it to use every CPU"
        )
    return min(threads, cpus)


def prepare_process() -> None:
    """Settings for a process that runs one command and exits, before numpy is imported:

    - freed memory is kept for the next arrays (:func:`isoconvert.memory.keep_freed_memory`);
    - numpy's OpenBLAS gets one thread (unless ``OPENBLAS_NUM_THREADS`` says otherwise):
      isoconvert does no large matrix products, but after any small one (a 3x3
      determinant) OpenBLAS's threads spin for a while, on every core, against the
      kernels' own threads (about 0.1 s of CPU in a labels run on two cores). Processes
      the command starts (batch's workers) inherit it.
    """
    from .memory import keep_freed_memory

    keep_freed_memory()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
