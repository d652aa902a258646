"""How many threads the compiled kernels use (extraction and the mesh report), and the
settings of a process that runs one command (:func:`prepare_process`)."""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from typing import Any

from .errors import IsoconvertError
from .signals import held


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


#: Set while an interrupted caller of :func:`threaded_in_order` waits for the calls
#: running: their long loops (a decimation's collapses) stop at the next step
#: instead of running to the end (a Ctrl-C once waited two minutes for two objects'
#: collapses).
_interrupted = threading.Event()


class Abandoned(Exception):
    """Raised in a worker thread whose run was interrupted; nobody reads it."""


def stop_if_interrupted() -> None:
    """A step of long work in a worker thread: raise :class:`Abandoned` when the run
    that started it was interrupted (the main thread has the signal)."""
    if _interrupted.is_set():
        raise Abandoned()


def threaded_in_order(
    function: Callable[..., Any], arguments: Iterable[tuple], threads: int, window: int = 0
) -> Iterator[Any]:
    """``function(*args)`` for each tuple of ``arguments``, run by ``threads`` threads,
    the results in order.

    For work whose kernels and file writes leave the interpreter free. At most
    ``window`` calls (default: twice the threads) are submitted at once, so an
    ``arguments`` that builds each item when asked for holds only those in flight
    (``Executor.map`` takes every argument first). When the caller stops early (an
    error, an interrupt in the main thread), the calls not started are cancelled and
    those running are waited for: none is left half done; on an interrupt, those that
    call :func:`stop_if_interrupted` stop at their next step. One thread: called here.
    """
    if threads <= 1:
        for args in arguments:
            yield function(*args)
        return
    window = window or 2 * threads
    pending: deque = deque()
    interrupted = False
    try:
        with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="isoconvert") as pool:
            try:
                for args in arguments:
                    with held():  # the future noted before a signal is raised
                        pending.append(pool.submit(function, *args))
                    if len(pending) >= window:
                        yield wait_for(pending.popleft())
                while pending:
                    yield wait_for(pending.popleft())
            except KeyboardInterrupt:
                interrupted = True
                _interrupted.set()  # the calls running stop at their next step
                raise
            finally:
                for future in pending:
                    future.cancel()
    finally:
        if interrupted:
            _interrupted.clear()


def wait_for(future: Future) -> Any:
    """The future's result, waited for in short steps: a wait without a timeout is
    not woken by a signal that lands on another thread (Linux delivers a process's
    SIGINT to any thread), so a Ctrl-C would wait for the call to end."""
    while True:
        try:
            return future.result(timeout=0.2)
        except FuturesTimeout:
            continue


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
