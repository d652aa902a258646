"""Tasks run on this machine: a thread reading ahead, or a pool of worker processes.

The local engine of :mod:`isoconvert.runner`. It knows tasks
(:class:`~isoconvert.runner.Task`), never what they compute: block-wise
extraction reads its next slab with :func:`read_ahead`, a batch converts its
files with :func:`run_in_processes`.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from typing import Any, TypeVar

from ..errors import IsoconvertError
from ..signals import (
    run_in_worker,
    start_resource_tracker,
    stop_workers_on_interrupt,
    worker_init,
)
from ..threads import wait_for
from .tasks import Finished, Task

T = TypeVar("T")
L = TypeVar("L")


def read_ahead(
    items: Sequence[T],
    load: Callable[[T], L],
    ready: Callable[[T], bool] | None = None,
) -> Iterator[tuple[T, L]]:
    """Each item with what ``load`` makes of it, in order; the next item is
    loaded in a thread of its own while the caller works on this one.

    Parameters
    ----------
    items : sequence
    load : callable
        ``load(item)``, run in the reading thread (it should release the GIL:
        file reads, decompression).
    ready : callable or None
        ``ready(item)``: whether the next item may be loaded ahead now (False:
        it is loaded when its turn comes, e.g. when loading it early would
        need memory still in use); None: always.

    Yields
    ------
    (item, loaded)
        The caller should drop ``loaded`` before asking for the next one.
    """
    if not items:
        return
    reader = _Reader(load)
    try:
        ahead = None
        for i, item in enumerate(items):
            loaded = wait_for(ahead) if ahead is not None else load(item)
            following = items[i + 1] if i + 1 < len(items) else None
            go = following is not None and (ready is None or ready(following))
            ahead = reader.submit(following) if go else None
            yield item, loaded
            del loaded
    finally:
        reader.close()


class _Reader:
    """``load(item)`` for each item submitted, in one daemon thread: a Ctrl-C while
    it reads ends the run at once (a pool's thread would be waited for, at the pool's
    exit and again at the interpreter's). One thread for every item: a thread per
    item spreads the slabs over malloc's arenas (a 512 MiB volume's run within 128M
    peaked 30 MB higher)."""

    def __init__(self, load: Callable[[T], L]) -> None:
        self._load = load
        self._requests: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._run, name="isoconvert-read", daemon=True).start()

    def submit(self, item: T) -> Future:
        future: Future = Future()
        self._requests.put((item, future))
        return future

    def close(self) -> None:
        """Stop after the read in progress (not waited for)."""
        self._requests.put(None)

    def _run(self) -> None:
        while (request := self._requests.get()) is not None:
            item, future = request
            future.set_running_or_notify_cancel()
            try:
                future.set_result(self._load(item))
            except BaseException as exc:  # handed to the caller, who re-raises it
                future.set_exception(exc)
            del item, future, request  # the result is the caller's alone


def run_in_processes(
    tasks: Iterable[Task],
    workers: int,
    *,
    budget: int | None = None,
    initializer: Callable[[], None] | None = None,
) -> Iterator[Finished]:
    """Run ``tasks`` in ``workers`` worker processes; each as it finishes.

    Tasks start in order while fewer than ``workers`` run and the
    :attr:`~isoconvert.runner.Task.nbytes` of those running stay within
    ``budget`` (a task whose own estimate exceeds it runs with nothing beside
    it). A task whose :attr:`~isoconvert.runner.Task.load` raises an
    ``IsoconvertError`` is not started and finishes at once (``started`` False).

    A worker that dies (killed, out of memory) breaks the pool, and with it the
    tasks beside it: each task that was running is then run again alone, which
    fails (``died``) only the one that kills its worker; a new pool takes the
    rest. Worker processes are spawned (no fork of a threaded parent), run
    :func:`isoconvert.signals.worker_init` with ``initializer``, and stop with
    this process: on KeyboardInterrupt or SIGTERM/SIGHUP here they are
    terminated (:func:`isoconvert.signals.stop_workers_on_interrupt`), which
    propagates out of this iterator.

    Parameters
    ----------
    tasks : iterable of Task
        Their functions and arguments are pickled to the workers.
    workers : int
    budget : int or None
        Bytes; None: no limit.
    initializer : callable or None
        Run first in each worker process (picklable).

    Yields
    ------
    Finished
        ``value`` what the function returned; ``error`` an exception it
        raised (or the pool's, other than a dead worker).
    """
    import multiprocessing
    from concurrent.futures.process import BrokenProcessPool  # here: read_ahead needs none

    limit = budget or (1 << 62)
    pending = list(tasks)
    context = multiprocessing.get_context("spawn")  # no fork of a threaded parent
    start_resource_tracker()  # before the workers: one that a hangup cannot kill
    while pending:
        running: dict = {}  # future: (task, start, its arguments)
        used = 0
        try:
            with (
                _pool(workers, context, initializer) as pool,
                stop_workers_on_interrupt(pool),  # not wait for their tasks to finish
            ):
                while pending or running:
                    while pending and len(running) < workers:
                        task = pending[0]
                        if running and used + task.nbytes > limit:
                            break
                        pending.pop(0)
                        try:
                            args = task.arguments()
                        except IsoconvertError as exc:
                            yield Finished(task, error=exc, started=False)
                            continue
                        future = pool.submit(run_in_worker, task.function, *args)
                        running[future] = (task, time.perf_counter(), args)
                        used += task.nbytes
                    if not running:
                        continue
                    # in short steps, as wait_for: a Ctrl-C is not held until a task ends
                    finished, _ = wait(running, timeout=0.2, return_when=FIRST_COMPLETED)
                    for future in finished:
                        task, start, _ = running[future]  # stays there if the pool broke
                        try:
                            result = Finished(task, value=future.result())
                        except BrokenProcessPool:
                            raise
                        except Exception as exc:
                            result = Finished(task, error=exc)
                        result.seconds = time.perf_counter() - start
                        del running[future]
                        used -= task.nbytes
                        yield result
        except BrokenProcessPool:
            # A dead worker breaks the whole pool, and with it the tasks beside it.
            # Run each of those alone: only the one that kills its worker fails.
            for task, _, args in running.values():
                yield _run_alone(task, args, context, initializer)


def _pool(workers: int, context: Any, initializer: Callable[[], None] | None):
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=context,
        initializer=worker_init,
        initargs=(initializer,),
    )


def _run_alone(
    task: Task, args: tuple, context: Any, initializer: Callable[[], None] | None
) -> Finished:
    """Run one task in a worker of its own; a worker that dies fails only this task.
    ``args`` are those made when it first started (``load`` is not run again)."""
    from concurrent.futures.process import BrokenProcessPool

    start = time.perf_counter()
    try:
        with _pool(1, context, initializer) as pool, stop_workers_on_interrupt(pool):
            future = pool.submit(run_in_worker, task.function, *args)
            result = Finished(task, value=wait_for(future))
    except BrokenProcessPool:
        result = Finished(task, died=True)
    result.seconds = time.perf_counter() - start
    return result


__all__ = ["read_ahead", "run_in_processes"]
