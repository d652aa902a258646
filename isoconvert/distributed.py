"""Dask distributed as the multi-machine engine, behind block-wise extraction and batch.

A z-slab of block-wise extraction (:mod:`isoconvert.extract.blocks`) becomes
one Dask task: :func:`dask_runner` submits the slabs of a volume to a cluster
and hands their results back in z order, so that :func:`stitch_blocks
<isoconvert.extract.blocks.stitch_blocks>` makes the same mesh, bit for bit,
as on one machine. A file of a batch becomes one task too
(:func:`run_on_cluster`).

Where the samples are read:

* a lazy grid that can be read out of order (a raw file, a TIFF stack) is
  pickled with each task (its file's absolute path and layout, never the
  samples) and every worker reads its own slab: the workers need the same
  files at the same paths (a shared file system);
* an in-memory array, or a grid best read in order by one process (a gzip
  stream), is read here, slab by slab in z order, and each slab travels with
  its task.

Either way a bounded window of tasks is in flight (:func:`window_size`), so
neither this process nor the cluster holds the whole volume, and a slab's
samples sent from here are bounded in bytes too.

Failures: a worker process that dies (out of memory, killed) is replaced by
its nanny, and the scheduler runs the tasks it held on another worker, up to
its ``distributed.scheduler.allowed-failures`` times (3 by default); a task
that raised an unexpected exception is run again once (``retries``). When a
slab still fails, the extraction stops with a one-line
:class:`~isoconvert.errors.IsoconvertError` and nothing is written. An
``IsoconvertError`` inside a task (NaN samples without ``nan_as``, a file
shortened meanwhile) is a user's mistake, not a failure: it is returned to
this process as is, never retried, and raised here with its type and message.

dask and distributed are an optional extra (``pip install isoconvert[dask]``)
and are imported only when a scheduler is used.
"""

from __future__ import annotations

import atexit
import copy
import os
import pickle
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import IsoconvertError, one_line

if TYPE_CHECKING:
    import numpy as np
    from distributed import Client

    from .batch import BatchSettings, Job, Outcome
    from .extract.blocks import BlockJob, BlockResult
    from .grid import LazyGrid

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

_INSTALL = "running on a Dask cluster needs dask and distributed: pip install 'isoconvert[dask]'"

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
        raise IsoconvertError(_INSTALL) from None
    from .quiet import silence_distributed

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


# --- slabs as tasks ------------------------------------------------------------------------------


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
    the worker's task threads (``$ISOCONVERT_THREADS`` there caps it), at least 1."""
    from .threads import available_cpus, kernel_threads

    try:
        from distributed import get_worker

        slots = get_worker().state.nthreads
    except (ImportError, ValueError, AttributeError):  # not on a worker
        slots = 1
    return max(1, min(kernel_threads(), available_cpus() // max(1, int(slots))))


def extract_slab(job: BlockJob, samples: np.ndarray | LazyGrid) -> BlockResult | TaskFailure:
    """One slab, as a Dask task: read it (unless sent), extract it.

    Parameters
    ----------
    job : BlockJob
        Its ``threads`` is replaced by :func:`worker_threads` (the mesh is the
        same for any number).
    samples : LazyGrid or (layers, Y, X) array
        The grid to read the slab from (on the worker), or the slab itself
        (:func:`~isoconvert.extract.blocks.read_block` of ``job``, read by the
        client).

    Returns
    -------
    BlockResult or TaskFailure
        The result with its arrays; a failure for an ``IsoconvertError``.
    """
    from .extract.blocks import read_block, run_block
    from .grid import LazyGrid

    try:
        job = replace(job, threads=worker_threads())
        if isinstance(samples, LazyGrid):
            try:
                zyx = read_block(samples, job)
            except OSError as exc:
                raise IsoconvertError(_unreadable(samples, job, exc)) from None
        else:
            zyx = samples
        return run_block(job, zyx)
    except IsoconvertError as exc:
        return TaskFailure.of(exc)


def _unreadable(grid: LazyGrid, job: BlockJob, exc: OSError) -> str:
    import socket

    lo, hi = job.read_range
    reason = exc.strerror or one_line(exc)
    return (
        f"{getattr(grid, 'path', job.source)}: a Dask worker on {socket.gethostname()} cannot "
        f"read z-layers {lo}..{hi - 1} ({reason}); the workers need the same files at the "
        "same paths (a shared file system)"
    )


def _worker_side(source: np.ndarray | LazyGrid) -> LazyGrid | None:
    """``source`` as workers should receive it when they can read their own
    slabs (a grid read out of order, paths made absolute), else None."""
    from .grid import LazyGrid

    if not isinstance(source, LazyGrid) or source.sequential:
        return None
    grid = _absolute(source)
    try:
        pickle.dumps(grid)
    except Exception:  # holds something a worker cannot receive: read here instead
        return None
    return grid


def _absolute(grid: LazyGrid) -> LazyGrid:
    """A copy of ``grid`` whose paths (attributes holding a Path, or a list or
    tuple of them) are absolute: a worker's working folder is not ours."""
    state = getattr(grid, "__dict__", {})
    if not any(_relative_paths(v) for v in state.values()):
        return grid
    out = copy.copy(grid)
    for name, value in state.items():
        if isinstance(value, Path):
            setattr(out, name, value.absolute())
        elif isinstance(value, list | tuple) and any(isinstance(v, Path) for v in value):
            fixed = [v.absolute() if isinstance(v, Path) else v for v in value]
            setattr(out, name, type(value)(fixed) if isinstance(value, tuple) else fixed)
    return out


def _relative_paths(value: Any) -> bool:
    if isinstance(value, Path):
        return not value.is_absolute()
    if isinstance(value, list | tuple):
        return any(isinstance(v, Path) and not v.is_absolute() for v in value)
    return False


Task = Callable[["BlockJob", Any], Any]


def dask_runner(
    address: str,
    source: np.ndarray | LazyGrid,
    name: str,
    task: Task | None = None,
    *,
    max_bytes: int | None = None,
) -> Callable[[list[BlockJob]], Iterator[BlockResult]]:
    """A runner of slab jobs on the Dask cluster at ``address``, for
    :func:`~isoconvert.extract.blocks.extract_blocks`.

    Connects now (so an unreachable scheduler fails before any work); the
    runner may then be called more than once (an extraction restarted with
    another vertex offset).

    Parameters
    ----------
    address : str
        The scheduler.
    source : (X, Y, Z) array or LazyGrid
        The volume's samples (``Volume.samples``).
    name : str
        The volume's name, for messages.
    task : callable or None
        ``task(job, samples)`` run on a worker for each slab, ``samples`` being
        the grid to read from or the slab itself; None is :func:`extract_slab`.
        It must be picklable. For tests, which wrap it.
    max_bytes : int or None
        Bytes of slabs read here and sent with their tasks that may be in
        flight at once (at least two slabs are); None is
        :data:`~isoconvert.extract.blocks.DEFAULT_MAX_MEMORY`.

    Returns
    -------
    callable
        ``runner(jobs)``: a generator of the jobs' :class:`BlockResult`, in
        the order of ``jobs``. Closing it (done, failed or abandoned) cancels
        the tasks still in flight.

    Raises
    ------
    IsoconvertError
        As :func:`connect`; and, from the generator, a slab whose workers kept
        dying, the connection to the scheduler lost, or an ``IsoconvertError``
        of a task (its own type and message).
    """
    from .extract.blocks import DEFAULT_MAX_MEMORY, read_block

    client = connect(address)
    watch = _Watch(client, address, connect_timeout(), "; nothing was written")
    grid = _worker_side(source)
    run = task or extract_slab
    budget = max_bytes or DEFAULT_MAX_MEMORY

    def runner(jobs: list[BlockJob]) -> Iterator[BlockResult]:
        window = window_size(cluster_threads(client))
        token = uuid.uuid4().hex[:12]
        in_flight: deque = deque()  # (future, job, bytes sent)
        sent = 0
        upcoming = iter(jobs)
        following = next(upcoming, None)
        try:
            while following is not None or in_flight:
                while following is not None and len(in_flight) < window:
                    size = 0 if grid is not None else _slab_bytes(source, following)
                    if len(in_flight) >= 2 and sent + size > budget:
                        break
                    samples = grid if grid is not None else read_block(source, following)
                    future = watch.track(_submit(client, run, following, samples, token))
                    del samples
                    in_flight.append((future, following, size))
                    sent += size
                    following = next(upcoming, None)
                future, job, size = in_flight[0]
                watch.until_done(future)
                in_flight.popleft()
                result = _block_result(future, job, address, name)
                sent -= size
                del future
                yield result
        finally:
            _cancel(client, [f for f, _, _ in in_flight])

    return runner


def _slab_bytes(source: np.ndarray | LazyGrid, job: BlockJob) -> int:
    import numpy as np

    lo, hi = job.read_range
    nx, ny, _ = source.shape
    return (hi - lo) * nx * ny * np.dtype(source.dtype).itemsize


def _submit(client: Client, run: Task, job: BlockJob, samples: Any, token: str):
    """Submit one slab; a slab sent from here is no "large graph" to warn about."""
    import dask

    with dask.config.set({"distributed.admin.large-graph-warning-threshold": "1 PiB"}):
        return client.submit(
            run,
            job,
            samples,
            key=f"isoconvert-slab-{token}-{job.k0}",
            retries=RETRIES,
            pure=False,
        )


def _block_result(future, job: BlockJob, address: str, name: str) -> BlockResult:
    """The slab's result, or its failure as one line."""
    result = _task_result(future, address, f"{name}: z-layers {job.k0}..{job.k1 - 1}")
    if result is _DIED:
        raise IsoconvertError(
            f"{name}: a Dask worker died while extracting z-layers {job.k0}..{job.k1 - 1} "
            "(out of memory?), also when retried on other workers; nothing was written. "
            "Give the workers more memory, or lower --block-size"
        )
    if isinstance(result, TaskFailure):
        raise result.error
    return result


_DIED = object()


def _task_result(future, address: str, what: str) -> Any:
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
            f"{what}: a Dask worker ran out of memory; nothing was written. "
            "Give the workers more memory, or lower --block-size"
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


# --- batch ---------------------------------------------------------------------------------------


def run_on_cluster(
    address: str,
    jobs: list[Job],
    settings: BatchSettings,
    on_done: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Convert the files of a batch on the Dask cluster at ``address``, one task each.

    The cluster's workers run :func:`isoconvert.batch.run_one`; they must see
    the input files and the output folder at the same paths (which are made
    absolute here; outcomes name them as given). Output folders are made here
    before the tasks are submitted, and those left empty by failed files are
    removed, as :func:`isoconvert.batch.run_jobs` does.

    Parameters
    ----------
    address : str
    jobs : list of Job
    settings : BatchSettings
        Sent to each task, without its scheduler (a file's blocks run on the
        worker that converts it).
    on_done : callable or None
        Called with each outcome as its file finishes.

    Returns
    -------
    list of Outcome
        In the order the files finished. A file whose workers kept dying
        fails alone, with a one-line message.

    Raises
    ------
    IsoconvertError
        As :func:`connect`.
    KeyboardInterrupt
        After reporting the files not finished as ``interrupted`` and
        cancelling their tasks (one already running on a worker finishes,
        its output written whole or not at all).
    """
    from . import batch

    client = connect(address)
    watch = _Watch(client, address, connect_timeout())
    options = settings.options
    if options.blocks.scheduler is not None:
        options = replace(options, blocks=replace(options.blocks, scheduler=None))
    remote = replace(settings, options=options, scheduler=None)
    token = uuid.uuid4().hex[:12]
    outcomes: list[Outcome] = []
    made: list[Path] = []
    running: dict = {}  # key: (future, job as given, job as sent, start)

    def done(outcome: Outcome) -> None:
        outcomes.append(outcome)
        if on_done:
            on_done(outcome)

    def tidy() -> None:
        writing = [Path(sent.output).parent for _, _, sent, _ in running.values()]
        batch.remove_empty_folders(
            [f for f in made if not any(w == f or w.is_relative_to(f) for w in writing)]
        )
        made[:] = [f for f in made if f.is_dir()]

    waiting = list(jobs)  # not submitted yet
    try:
        try:
            for n, job in enumerate(jobs):
                waiting.pop(0)
                sent = replace(
                    job,
                    input=os.path.abspath(job.input),
                    output=os.path.abspath(job.output),
                    # the header records the input as given, as a local run does
                    options={**job.options, "source_name": job.input},
                )
                try:
                    made.extend(batch.make_folders(Path(sent.output).parent))
                except IsoconvertError as exc:
                    done(batch.Outcome(job.name, job.output, "failed", message=str(exc)))
                    continue
                future = client.submit(
                    batch.run_one,
                    sent,
                    remote,
                    key=f"isoconvert-file-{token}-{n}",
                    retries=RETRIES,
                    pure=False,
                )
                running[future.key] = (future, job, sent, time.perf_counter())
                watch.track(future)
            while running:
                try:
                    key = watch.next_key()
                except IsoconvertError as exc:  # no worker to run them
                    for _, job, _, _ in running.values():
                        done(batch.Outcome(job.name, job.output, "failed", message=str(exc)))
                    break
                if key not in running:
                    continue
                future, job, sent, start = running.pop(key)
                outcome = _file_outcome(future, job, sent, start, address)
                del future
                if outcome.status == "failed":
                    tidy()
                done(outcome)
        except KeyboardInterrupt:
            _cancel(client, [future for future, *_ in running.values()])
            for job in [*(job for _, job, _, _ in running.values()), *waiting]:
                done(batch.Outcome(job.name, job.output, "interrupted", message="interrupted"))
            running.clear()
            raise
    finally:
        _cancel(client, [future for future, *_ in running.values()])
        running.clear()
        tidy()
    return outcomes


def _file_outcome(future, job: Job, sent: Job, start: float, address: str) -> Outcome:
    """The outcome of one file's task, naming the file as the user gave it."""
    from .batch import Outcome

    def failed(message: str) -> Outcome:
        return Outcome(
            job.name, job.output, "failed", seconds=time.perf_counter() - start, message=message
        )

    try:
        result = _task_result(future, address, job.input)
    except IsoconvertError as exc:
        return failed(str(exc))
    except Exception as exc:  # a bug: report it for this file, keep the others going
        return failed(f"{job.name}: internal error {type(exc).__name__}: {one_line(exc)}")
    if result is _DIED:
        return failed(
            f"{job.name}: the Dask worker converting it died (out of memory?), also when "
            "retried on other workers; give the workers more memory or convert it alone"
        )
    result.message = result.message.replace(sent.input, job.input).replace(sent.output, job.output)
    result.input, result.output = job.name, job.output
    return result


__all__ = [
    "DEFAULT_TIMEOUT",
    "SCHEDULER_ENV",
    "TIMEOUT_ENV",
    "TaskFailure",
    "close_clients",
    "cluster_threads",
    "connect",
    "connect_timeout",
    "dask_runner",
    "extract_slab",
    "run_on_cluster",
    "scheduler_address",
    "window_size",
    "worker_threads",
]
