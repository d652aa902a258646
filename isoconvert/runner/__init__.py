"""The task runner: a list of picklable tasks run here (threads, worker processes)
or on a Dask cluster, with nothing known of what the tasks do.

Layering (imports run one way, down; tests/test_layers.py checks it)::

    batch.py (file jobs)        extract/blocks.py (slabs of a volume)
              \\                   /
               isoconvert.runner            engine-neutral: cluster_size, run_in_order
               |- runner.tasks              Task, Finished, TaskFailure (what engines share)
               |- runner.local              threads, processes (retries, memory budget, signals)
               '- runner.dask               connect, ship, gather, retry, progress (Dask)
                      |
               errors, signals, threads, quiet      the model below

* The runner imports nothing above the model: never ``batch``, ``convert``,
  ``cli``, ``extract``, ``volume`` or a reader. A task is a picklable function
  and its arguments; what its value means (a slab's mesh, a file's outcome)
  and what to tidy when it fails (a batch's empty folders) is its caller's.
* Extraction (``extract/``) may import this module and :mod:`.local`, never
  :mod:`.dask` (nor ``dask`` or ``distributed``): a cluster is reached through
  the engine-neutral functions here (:func:`cluster_size`, :func:`run_in_order`),
  which import the Dask code on first use. ``batch.py`` may use any of the three.
* This module imports no numpy and no Dask: ``isoconvert --help`` does not pay
  for them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from .tasks import MEMORY_HINT, Earlier, Finished, Task, TaskFailure, failure_among, worker_threads


def cluster_size(address: str) -> int:
    """Threads of the workers of the Dask cluster at ``address``, together
    (0 when it has none yet); connects first (:func:`isoconvert.runner.dask.connect`).

    Raises
    ------
    IsoconvertError
        As :func:`~isoconvert.runner.dask.connect`.
    """
    from . import dask

    return dask.cluster_threads(dask.connect(address))


def run_in_order(
    address: str,
    tasks: Iterable[Task],
    *,
    budget: int,
    died: Callable[[Task], str],
    tail: str = "",
    memory_hint: str = MEMORY_HINT,
) -> Iterator[Any]:
    """Run ``tasks`` on the Dask cluster at ``address``; their values, in the
    order of ``tasks`` (:func:`isoconvert.runner.dask.run_in_order`).

    Parameters
    ----------
    address : str
    tasks : iterable of Task
        Taken one at a time as room opens: a bounded window in flight, and at
        most ``budget`` bytes of their :attr:`Task.nbytes` (at least two tasks).
        A task's :class:`Earlier` argument becomes the values of the kept tasks
        it names, which run before it and whose values never come here.
    budget : int
    died : callable
        The message of a task whose workers kept dying.
    tail : str
        Ends the message of a cluster without workers.
    memory_hint : str
        Ends the message of a task whose worker ran out of memory.

    Returns
    -------
    iterator
        Closing it (done, failed or abandoned) cancels the tasks in flight.

    Raises
    ------
    IsoconvertError
        From the iterator: the error of a task (its own type and message), or
        one line for a task the cluster dropped or whose workers kept dying.
    """
    from . import dask

    return dask.run_in_order(
        address, tasks, budget=budget, died=died, tail=tail, memory_hint=memory_hint
    )


__all__ = [
    "MEMORY_HINT",
    "Earlier",
    "Finished",
    "Task",
    "TaskFailure",
    "cluster_size",
    "failure_among",
    "run_in_order",
    "worker_threads",
]
