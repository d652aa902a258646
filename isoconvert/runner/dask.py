"""Tasks on a Dask cluster: connect, ship, gather, retry, report progress.

The engine of :mod:`isoconvert.runner` for a scheduler address; it knows
tasks (:class:`~isoconvert.runner.Task`), never what they compute. Block-wise
extraction reaches it only through :func:`isoconvert.runner.run_in_order`
(and :func:`~isoconvert.runner.cluster_size`); a batch calls
:func:`run_as_completed` itself.

Either way a bounded window of tasks is in flight (:func:`window_size`), and
the arguments sent from here (a slab read by the caller) are bounded in bytes
too, so neither this process nor the cluster holds all the work at once.

Failures: a worker process that dies (out of memory, killed) is replaced by
its nanny, and the scheduler runs the tasks it held on another worker, up to
its ``distributed.scheduler.allowed-failures`` times (3 by default); a task
that raised an unexpected exception is run again once (:data:`RETRIES`). An
``IsoconvertError`` inside a task is a user's mistake, not a failure: the task
returns it as a :class:`~isoconvert.runner.TaskFailure`, never retried, and it
is raised (or reported) here with its type and message.

dask and distributed are an optional extra (``pip install isoconvert[dask]``)
and are imported only when a scheduler is used.
"""

from __future__ import annotations

import atexit
import os
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import CancelledError
from typing import TYPE_CHECKING, Any

from ..errors import IsoconvertError, extra_hint, one_line
from .tasks import MEMORY_HINT, Earlier, Finished, Task, TaskFailure, worker_threads

if TYPE_CHECKING:
    from distributed import Client

#: The environment variable naming the scheduler when ``--scheduler`` is not given
#: (the one Dask itself reads).
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"
#: The environment variable giving the seconds to wait for a scheduler to answer.
TIMEOUT_ENV = "ISOCONVERT_DASK_TIMEOUT"
#: Seconds to wait for a scheduler to answer, when :data:`TIMEOUT_ENV` is not set.
DEFAULT_TIMEOUT = 10.0
#: Re-runs of a task that raised an unexpected exception (a worker's death is
#: handled by the scheduler's ``allowed-failures`` instead).
RETRIES = 1
#: Tasks in flight per thread of the cluster: one running, one ready to start.
TASKS_PER_THREAD = 2

_clients: dict[str, Client] = {}
_clients_lock = threading.Lock()


# --- the scheduler -------------------------------------------------------------------------------


def scheduler_address(option: str | None) -> str | None:
    """The Dask scheduler to run on: ``option``, else ``$DASK_SCHEDULER_ADDRESS``,
    else None (run here).

    Parameters
    ----------
    option : str or None
        ``--scheduler`` as given; an empty string counts as not given.

    Returns
    -------
    str or None
    """
    for value in (option, os.environ.get(SCHEDULER_ENV)):
        if value is not None and value.strip():
            return value.strip()
    return None


def connect_timeout() -> float:
    """Seconds to wait for a scheduler: ``$ISOCONVERT_DASK_TIMEOUT``, else 10.

    Raises
    ------
    IsoconvertError
        The variable is set to something other than a positive number.
    """
    given = os.environ.get(TIMEOUT_ENV, "").strip()
    if not given:
        return DEFAULT_TIMEOUT
    try:
        seconds = float(given)
    except ValueError:
        seconds = float("nan")
    if not seconds > 0 or seconds == float("inf"):
        raise IsoconvertError(
            f"{TIMEOUT_ENV} must be a number of seconds greater than 0, got {given!r}; "
            f"unset it to wait {DEFAULT_TIMEOUT:g} s"
        )
    return seconds


def connect(address: str, timeout: float | None = None) -> Client:
    """A client of the Dask scheduler at ``address``, one per address and process.

    The client is made on first use and kept for later calls (the slabs of
    one extraction, and of the next); :func:`close_clients`, or the end of
    the interpreter, closes it. It is not made the default client, so Dask
    code of the caller's own is not sent to this cluster.

    Parameters
    ----------
    address : str
        ``tcp://host:8786`` (a bare ``host:port`` means tcp).
    timeout : float or None
        Seconds to wait for the scheduler to answer; None: :func:`connect_timeout`.

    Returns
    -------
    distributed.Client

    Raises
    ------
    IsoconvertError
        dask or distributed is not installed; the address is not one; no
        scheduler answered within ``timeout`` (one line, naming the address).
    """
    try:
        from distributed import Client
    except ImportError:
        raise IsoconvertError(
            f"running on a Dask cluster needs dask and distributed: {extra_hint('dask')}"
        ) from None
    from ..quiet import silence_distributed

    silence_distributed()  # its log lines would reach the user's stderr
    wait = connect_timeout() if timeout is None else float(timeout)
    with _clients_lock:
        client = _clients.get(address)
        if client is not None and client.status in ("running", "connecting"):
            return client
        _clients.pop(address, None)
        _probe(address, wait)
        try:
            client = Client(address, timeout=wait, set_as_default=False)
        except (OSError, TimeoutError):
            raise IsoconvertError(_no_answer(address, wait)) from None
        _clients[address] = client
        return client


def close_clients() -> None:
    """Close the clients :func:`connect` made (it makes new ones when asked again)."""
    with _clients_lock:
        clients = list(_clients.values())
        _clients.clear()
    for client in clients:
        _close_quietly(client)


def _forget(address: str) -> None:
    """Close and forget the client of ``address`` (its scheduler was lost)."""
    with _clients_lock:
        client = _clients.pop(address, None)
    if client is not None:
        _close_quietly(client)


def _close_quietly(client: Client) -> None:
    """Close ``client``; one whose scheduler is gone logs its cancelled attempts
    to reconnect as errors, with a traceback: not for the user's stderr."""
    import logging

    logger = logging.getLogger("distributed")
    disabled = logger.disabled
    logger.disabled = True
    children = [
        (child, child.disabled)
        for name, child in list(logging.Logger.manager.loggerDict.items())
        if name.startswith("distributed.") and isinstance(child, logging.Logger)
    ]
    for child, _ in children:
        child.disabled = True
    try:
        client.close(timeout=2)
    except Exception:  # a scheduler gone already: nothing left to close
        pass
    finally:
        logger.disabled = disabled
        for child, was in children:
            child.disabled = was


atexit.register(close_clients)


def _no_answer(address: str, timeout: float) -> str:
    return (
        f"{address}: no Dask scheduler answered within {timeout:g} s; start one with "
        "`dask scheduler`, or check the address"
    )


def _probe(address: str, timeout: float) -> None:
    """Fail in ``timeout`` seconds unless a Dask scheduler answers at ``address``.

    ``distributed.Client`` waits for ever on a port that accepts connections
    but never answers, and a client that failed to connect warns at exit:
    a plain connection, with a deadline, tells first. It runs on an event
    loop of its own, in a thread of its own (the caller may run a loop, as
    a notebook does).
    """
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect as open_comm
    from distributed.security import Security

    async def knock() -> None:
        args = Security().get_connection_args("client")
        comm = await asyncio.wait_for(open_comm(address, timeout=timeout, **args), timeout)
        await comm.close()

    try:
        with ThreadPoolExecutor(1, thread_name_prefix="isoconvert-dask-probe") as pool:
            pool.submit(asyncio.run, knock()).result()
    except (ValueError, TypeError) as exc:  # no such scheme, no port
        raise IsoconvertError(
            f"{address}: not a Dask scheduler address ({one_line(exc)}); "
            "give one such as tcp://host:8786"
        ) from None
    except (OSError, TimeoutError):
        raise IsoconvertError(_no_answer(address, timeout)) from None
    except MemoryError:  # another service answered first: its banner read as a frame length
        raise IsoconvertError(
            f"{address}: what answers there is not a Dask scheduler; check the address "
            "(a scheduler prints it when it starts: `dask scheduler`)"
        ) from None


def cluster_threads(client: Client) -> int:
    """Threads of the cluster's workers, together (0 when it has none yet)."""
    return int(sum(client.nthreads().values()))


def window_size(threads: int) -> int:
    """Tasks kept in flight on a cluster of ``threads`` threads: two per thread
    (one running, one ready), at least 2."""
    return max(2, TASKS_PER_THREAD * threads)


class _Watch:
    """Waits on tasks, and gives up when the cluster has had no worker for
    ``patience`` seconds (a scheduler nobody started workers for; the nannies
    of dead workers start new ones within seconds).

    Futures are tracked (:meth:`track`) once, when submitted: each says when it is
    done by its key (never by itself, which would keep its result alive on the
    cluster until read from the queue).
    """

    def __init__(self, client: Client, address: str, patience: float, tail: str = "") -> None:
        import queue

        self.client = client
        self.address = address
        self.patience = patience
        self.tail = tail  # the end of the message
        self._idle_since: float | None = time.monotonic()  # until workers are seen
        self._done: queue.SimpleQueue = queue.SimpleQueue()

    def track(self, future):
        """``future``, which will say when it is done."""
        done = self._done
        future.add_done_callback(lambda f: done.put(f.key))
        return future

    def next_key(self) -> Any:
        """The key of a tracked future that is done, waiting for one as needed.

        Raises
        ------
        IsoconvertError
            No worker for ``patience`` seconds.
        """
        import queue

        while True:
            try:
                return self._done.get(timeout=1.0)
            except queue.Empty:
                self._check()

    def until_done(self, future) -> None:
        """Wait for the tracked ``future`` (keys of others done meanwhile are dropped)."""
        while not future.done():
            self.next_key()

    def _check(self) -> None:
        try:
            threads = cluster_threads(self.client)
        except Exception:  # the connection is being re-made: the futures will say
            return
        if threads:
            self._idle_since = None
        elif self._idle_since is None:
            self._idle_since = time.monotonic()
        elif time.monotonic() - self._idle_since > self.patience:
            raise IsoconvertError(
                f"{self.address}: the Dask scheduler has had no worker for "
                f"{self.patience:g} s; start some with `dask worker {self.address}` "
                f"(or raise {TIMEOUT_ENV}){self.tail}"
            )


# --- tasks in flight -----------------------------------------------------------------------------


def _submit(client: Client, task: Task, args: tuple):
    """Submit one task; arguments sent from here (a slab) are no "large graph"
    to warn about."""
    import dask

    with dask.config.set({"distributed.admin.large-graph-warning-threshold": "1 PiB"}):
        return client.submit(task.function, *args, key=task.key, retries=RETRIES, pure=False)


_DIED = object()


def _task_result(future, address: str, what: str, memory_hint: str = MEMORY_HINT) -> Any:
    """``future``'s value; :data:`_DIED` when its workers kept dying.

    Raises
    ------
    IsoconvertError
        The task was cancelled (scheduler restarted or connection lost), or
        raised an ``IsoconvertError`` (re-raised as is) or ran out of memory.
    """
    from distributed.comm.core import CommClosedError
    from distributed.scheduler import KilledWorker

    try:
        return future.result()
    except KilledWorker:
        return _DIED
    except IsoconvertError as exc:
        raise exc.with_traceback(None) from None
    except MemoryError:
        raise IsoconvertError(
            f"{what}: a Dask worker ran out of memory; nothing was written. {memory_hint}"
        ) from None
    except (CancelledError, CommClosedError, OSError):
        if future.client.status not in ("running", "closing", "closed"):
            _forget(address)  # reconnecting, or given up: the next call starts afresh
        raise IsoconvertError(
            f"{what}: the Dask scheduler at {address} dropped the task (restarted, or the "
            "connection to it was lost); nothing was written"
        ) from None


def _cancel(client: Client, futures: list) -> None:
    """Cancel tasks still in flight (a worker cannot stop one already running;
    its result is dropped)."""
    if not futures:
        return
    try:
        client.cancel(futures)
    except Exception:  # the scheduler is gone: nothing to cancel there
        pass


def run_in_order(
    address: str,
    tasks: Iterable[Task],
    *,
    budget: int,
    died: Callable[[Task], str],
    tail: str = "",
    memory_hint: str = MEMORY_HINT,
) -> Iterator[Any]:
    """The values of ``tasks`` run on the cluster at ``address``, in order
    (see :func:`isoconvert.runner.run_in_order` for the parameters).

    Connects now (an unreachable scheduler fails before any work). At most
    :func:`window_size` tasks are in flight, and at most ``budget`` bytes of
    their :attr:`~isoconvert.runner.Task.nbytes` (two tasks always may be).
    """
    client = connect(address)
    watch = _Watch(client, address, connect_timeout(), tail)
    return _in_order(client, watch, address, iter(tasks), budget, died, memory_hint)


def _in_order(client, watch, address, upcoming, budget, died, memory_hint) -> Iterator[Any]:
    window = window_size(cluster_threads(client))
    in_flight: deque = deque()  # (future, task, bytes held)
    kept: dict[str, Any] = {}  # kept tasks' futures, until a later task takes them
    sent = 0
    following = next(upcoming, None)
    try:
        while following is not None or in_flight:
            while following is not None and len(in_flight) < window:
                size = following.nbytes
                if len(in_flight) >= 2 and sent + size > budget:
                    break
                # an Earlier argument: the futures themselves, which the scheduler
                # resolves on the worker (their values never come here)
                args = tuple(
                    [kept.pop(key) for key in a.keys] if isinstance(a, Earlier) else a
                    for a in following.arguments()
                )
                future = watch.track(_submit(client, following, args))
                del args
                if following.kept:
                    kept[following.key] = future
                in_flight.append((future, following, size))
                sent += size
                following = next(upcoming, None)
            future, task, size = in_flight[0]
            watch.until_done(future)
            in_flight.popleft()
            if task.kept and future.status == "finished":  # its value stays there
                sent -= size
                del future
                yield None
                continue
            result = _task_result(future, address, task.what, memory_hint)
            if result is _DIED:
                raise IsoconvertError(died(task))
            if isinstance(result, TaskFailure):
                raise result.error
            sent -= size
            del future
            yield result
    finally:
        _cancel(client, [f for f, _, _ in in_flight] + list(kept.values()))


def run_as_completed(
    address: str, tasks: Iterable[Task], *, memory_hint: str = MEMORY_HINT
) -> Iterator[Finished]:
    """Submit all ``tasks`` to the cluster at ``address``; each as it finishes.

    A task whose :attr:`~isoconvert.runner.Task.load` raises an
    ``IsoconvertError`` is not submitted and finishes at once (``started``
    False). When the cluster has had no worker for :func:`connect_timeout`
    seconds, every task still running finishes with that one-line error.
    Closing the iterator (done, failed, interrupted) cancels the tasks still
    running (one already running on a worker finishes there, its value dropped).

    Raises
    ------
    IsoconvertError
        As :func:`connect` (when the iteration starts).
    """
    client = connect(address)
    watch = _Watch(client, address, connect_timeout())
    running: dict = {}  # key: (future, task, start)
    try:
        for task in tasks:
            try:
                args = task.arguments()
            except IsoconvertError as exc:
                yield Finished(task, error=exc, started=False)
                continue
            future = _submit(client, task, args)
            running[future.key] = (future, task, time.perf_counter())
            watch.track(future)
        while running:
            try:
                key = watch.next_key()
            except IsoconvertError as exc:  # no worker to run them
                for _, task, _ in list(running.values()):
                    yield Finished(task, error=exc)
                break
            if key not in running:
                continue
            future, task, start = running.pop(key)
            finished = _finished(future, task, start, address, memory_hint)
            del future
            yield finished
    finally:
        _cancel(client, [future for future, *_ in running.values()])
        running.clear()


def _finished(future, task: Task, start: float, address: str, memory_hint: str) -> Finished:
    try:
        value = _task_result(future, address, task.what, memory_hint)
    except Exception as exc:  # the engine's one line, or the task's own exception
        return Finished(task, error=exc, seconds=time.perf_counter() - start)
    if value is _DIED:
        return Finished(task, died=True, seconds=time.perf_counter() - start)
    if isinstance(value, TaskFailure):
        return Finished(task, error=value.error, seconds=time.perf_counter() - start)
    return Finished(task, value=value, seconds=time.perf_counter() - start)


def new_token() -> str:
    """A fresh prefix for the keys of one run's tasks."""
    return uuid.uuid4().hex[:12]


__all__ = [
    "DEFAULT_TIMEOUT",
    "RETRIES",
    "SCHEDULER_ENV",
    "TIMEOUT_ENV",
    "TaskFailure",
    "close_clients",
    "cluster_threads",
    "connect",
    "connect_timeout",
    "new_token",
    "run_as_completed",
    "run_in_order",
    "scheduler_address",
    "window_size",
    "worker_threads",
]
