"""Tasks and what becomes of them: the records the runner's engines share.

See :mod:`isoconvert.runner` for the layering. This module imports nothing of
the package but its errors and, on a Dask worker, its thread count.
"""

from __future__ import annotations

import pickle
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..errors import IsoconvertError

#: What :func:`run_in_order` says of a task whose worker ran out of memory (the
#: callers so far cut their work by ``--block-size``).
MEMORY_HINT = "Give the workers more memory, or lower --block-size"


@dataclass
class Task:
    """One unit of work: ``function(*args)`` on a worker.

    Attributes
    ----------
    function : callable
        Picklable (a module-level function, or a ``functools.partial`` of one).
    args : tuple
        Picklable arguments; ignored when ``load`` is given.
    key : str
        A name unique among the tasks of one run (the Dask key).
    what : str
        Names the task in messages (``"scan.raw: z-layers 0..9"``).
    nbytes : int
        Memory the task holds while it is in flight: its arguments held here
        and sent with it (a slab read here), or its estimated footprint on a
        local worker (a file's conversion). Budgets count it.
    load : callable or None
        Makes the arguments just before the task starts, so that they exist only
        while it is in flight (a slab read here), or prepares its start (a
        batch's output folder). An :class:`~isoconvert.errors.IsoconvertError`
        it raises is the task's failure, the task not started.
    item : object
        The caller's own record of the task (a block job, a file job),
        handed back in :class:`Finished`; never sent.
    kept : bool
        Its value is only an argument of a later task (:class:`Earlier`): on a
        cluster it stays on the workers and goes from one to the other, and the
        run gives None in its place (an error of the task is still raised).
    """

    function: Callable[..., Any]
    args: tuple = ()
    key: str = ""
    what: str = ""
    nbytes: int = 0
    load: Callable[[], tuple] | None = None
    item: Any = None
    kept: bool = False

    def arguments(self) -> tuple:
        """The arguments to send: ``load()`` when given, else ``args``."""
        return self.load() if self.load is not None else self.args


@dataclass(frozen=True)
class Earlier:
    """An argument of a task: the values of the earlier tasks ``keys`` (each
    :attr:`Task.kept`, named once), as a list. A task given the
    :class:`TaskFailure` of one of them returns it (see :func:`failure_among`)."""

    keys: tuple[str, ...]


def failure_among(args: tuple) -> TaskFailure | None:
    """The first :class:`TaskFailure` among the values an :class:`Earlier`
    argument became (lists in ``args``), or None."""
    for arg in args:
        if isinstance(arg, list):
            for value in arg:
                if isinstance(value, TaskFailure):
                    return value
    return None


@dataclass
class Finished:
    """A task that finished, one way or another.

    Attributes
    ----------
    task : Task
    value : object
        What ``task.function`` returned (None unless it returned).
    error : BaseException or None
        The exception the task raised (an :class:`TaskFailure`'s error counts as
        raised), or the engine's one-line ``IsoconvertError`` about it (the
        cluster dropped it, a worker ran out of memory).
    died : bool
        Its worker process died, also when retried (alone, or on other workers).
    started : bool
        False when ``task.load`` failed and the task never started.
    seconds : float
        From its start to its end, as seen here.
    """

    task: Task
    value: Any = None
    error: BaseException | None = None
    died: bool = False
    started: bool = True
    seconds: float = 0.0


@dataclass
class TaskFailure:
    """An :class:`~isoconvert.errors.IsoconvertError` a task met, returned (not
    raised) so that Dask neither retries it nor logs it as a crash.

    Attributes
    ----------
    error : IsoconvertError
        The error itself when it survives pickling, else an ``IsoconvertError``
        with its message.
    """

    error: IsoconvertError

    @classmethod
    def of(cls, error: IsoconvertError) -> TaskFailure:
        try:
            back = pickle.loads(pickle.dumps(error))
            if type(back) is not type(error) or str(back) != str(error):
                raise TypeError
        except Exception:  # a subclass whose constructor takes other arguments
            error = IsoconvertError(str(error))
        return cls(error.with_traceback(None))


def worker_threads() -> int:
    """Kernel threads for one task on this Dask worker: the CPUs shared among
    the worker's task threads (``$ISOCONVERT_THREADS`` there caps it), at least 1.
    Outside a worker: the CPUs available, capped likewise."""
    from ..threads import available_cpus, kernel_threads

    slots = 1
    if "distributed" in sys.modules:  # a Dask worker has imported it; not here otherwise
        try:
            from distributed import get_worker

            slots = get_worker().state.nthreads
        except (ImportError, ValueError, AttributeError):  # not on a worker
            slots = 1
    return max(1, min(kernel_threads(), available_cpus() // max(1, int(slots))))


__all__ = [
    "MEMORY_HINT",
    "Earlier",
    "Finished",
    "Task",
    "TaskFailure",
    "failure_among",
    "worker_threads",
]
