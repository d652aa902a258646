"""Signals that stop a run: SIGTERM and SIGHUP handled as SIGINT is.

``timeout``, ``kill``, a CI cancellation and ``docker stop`` send SIGTERM; a
closed terminal sends SIGHUP. Python's default for both is to die on the
spot, which leaves a half-written output file behind. :func:`handled` makes
them (and SIGINT) raise :class:`Interrupted` instead (a KeyboardInterrupt, so every
``except KeyboardInterrupt`` and ``finally`` on the way up runs, and
:func:`isoconvert.atomic.atomic_output` removes its temporary file); the CLI
then says so in one line and exits with 128 + the signal number, as a shell
reports a process killed by it.

Batch worker processes are set up by :func:`worker_init`: they stop when
their parent dies (even of SIGKILL, through Linux's ``PR_SET_PDEATHSIG``, or
a watch on the parent elsewhere), clean up when terminated, and leave SIGINT
to the parent, which stops them (:func:`stop_workers_on_interrupt`). Only
those worker processes ever exit from here; the library never exits the
caller's process.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

#: The signals handled as SIGINT is (those this platform has).
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)

#: A repeated SIGTERM or SIGHUP within this many seconds of the first is
#: ignored, so that it cannot cut short the cleanup the first one started;
#: later ones raise again (the first may have been swallowed, e.g. raised
#: inside a ``__del__``).
REPEAT_GRACE = 5.0

#: Seconds a stopped worker process is given to remove its partial files
#: before it is killed.
WORKER_GRACE = 10.0


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal (SIGINT, SIGTERM, SIGHUP).

    Attributes
    ----------
    signum : int
        The signal number.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal_name(signum))
        self.signum = signum

    @property
    def exit_code(self) -> int:
        """128 + the signal number, as a shell reports a process it killed."""
        return 128 + self.signum


def signal_name(signum: int) -> str:
    """``SIGTERM`` for 15, and so on."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


#: The first stopping signal this process received, and when.
_received: tuple[int, float] | None = None
#: Depth of :func:`defer` in the main thread, and the signal held meanwhile.
_deferring = 0
_pending: int | None = None
#: Whether a batch worker is running a job (see :func:`run_in_worker`).
_busy = False


def received() -> int | None:
    """The number of the first signal :func:`handled` caught (SIGINT, SIGTERM,
    SIGHUP), or None."""
    return _received[0] if _received else None


def _stop(signum: int, frame: Any) -> None:
    global _received, _pending
    now = time.monotonic()
    if signum != signal.SIGINT and _received is not None and now - _received[1] < REPEAT_GRACE:
        return  # already stopping: let the cleanup finish (a Ctrl-C still counts)
    if _received is None:
        _received = (signum, now)
    if _deferring:
        _pending = signum
        return
    raise Interrupted(signum)


@contextlib.contextmanager
def handled() -> Iterator[None]:
    """While inside, SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` (a
    KeyboardInterrupt) in the main thread, except in a :func:`defer` window;
    the handlers before are put back on leaving.

    A signal the process was started ignoring (``nohup`` ignores SIGHUP, a
    shell's background job SIGINT) stays ignored, and so does a SIGINT handler
    someone else installed. Outside the main thread this does nothing (Python
    runs handlers only there).
    """
    global _received, _pending
    _received = _pending = None
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {}
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            before[sig] = signal.signal(sig, _stop)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        before[signal.SIGINT] = signal.signal(signal.SIGINT, _stop)
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


def defer() -> None:
    """Hold a stopping signal until :func:`resume`: for the few steps between
    making a temporary file and entering the block that removes it again (a
    signal there would leave it behind). Pairs nest; other threads than the
    main one are not concerned (no signal is raised in them)."""
    global _deferring
    if threading.current_thread() is threading.main_thread():
        _deferring += 1


def resume() -> None:
    """End a :func:`defer`; raise :class:`Interrupted` now if a signal came meanwhile."""
    global _deferring, _pending
    if threading.current_thread() is not threading.main_thread() or not _deferring:
        return
    _deferring -= 1
    if not _deferring and _pending is not None:
        signum, _pending = _pending, None
        raise Interrupted(signum)


@contextlib.contextmanager
def held() -> Iterator[None]:
    """:func:`defer` for the block, then :func:`resume` (the signal held raised as
    the block ends, what it did done): for a thread pool's ``submit``, which a signal
    can leave with its work queued but the call's future lost, or a thread started
    but not yet noted by the pool, whose shutdown would then not wait for it: it
    would run its call after the run said which files it kept."""
    defer()
    try:
        yield
    finally:
        resume()


# --- batch worker processes -------------------------------------------------------------------

#: prctl(2) option: the signal the calling process gets when its parent dies.
_PR_SET_PDEATHSIG = 1


def worker_init(initializer: Callable[[], None] | None = None) -> None:
    """Set up a worker process of a batch pool, then run ``initializer``.

    - SIGTERM and SIGHUP: during a job (:func:`run_in_worker`) they raise
      :class:`Interrupted`, so its partial files are removed, and the worker
      then exits; between jobs it exits at once.
    - SIGINT is ignored: a Ctrl-C reaches the whole process group, and the
      parent stops its workers (:func:`stop_workers_on_interrupt`) once it
      has recorded which jobs were interrupted.
    - The worker gets SIGTERM when its parent dies, however it died: Linux's
      ``PR_SET_PDEATHSIG``, else a thread that watches the parent's pid. An
      orphaned worker would otherwise go on writing, and hold the caller's
      stdout and stderr open.
    """
    import multiprocessing

    for sig in STOP_SIGNALS:
        signal.signal(sig, _worker_stop)
    if hasattr(signal, "SIGINT"):
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent_pid = os.getppid()
    if not _die_with_parent():
        threading.Thread(
            target=_watch_parent, args=(parent_pid,), name="isoconvert-parent", daemon=True
        ).start()
    # the process that started this one (spawn: the parent) may have died before
    # the above took hold; a forkserver parent differs from it and is alive
    starter = multiprocessing.parent_process()
    if starter is not None and starter.pid and starter.pid != os.getppid():
        try:
            os.kill(starter.pid, 0)
        except ProcessLookupError:
            os._exit(128 + signal.SIGTERM)
        except OSError:
            pass
    if initializer is not None:
        initializer()


def start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (one process per parent, which
    worker processes report their semaphores to) so that it ignores SIGHUP.

    It ignores SIGINT and SIGTERM itself, but a closed terminal sends SIGHUP to
    the whole process group: the tracker died of it, and the stopping workers
    then printed a traceback each ("resource_tracker: process died
    unexpectedly", ``KeyError: '/mp-...'``). An ignored signal stays ignored
    across the tracker's exec, so it is ignored here while the tracker starts.
    """
    from multiprocessing import resource_tracker

    hangup = getattr(signal, "SIGHUP", None)
    if hangup is None or threading.current_thread() is not threading.main_thread():
        resource_tracker.ensure_running()
        return
    before = signal.signal(hangup, signal.SIG_IGN)
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(hangup, before)


def _die_with_parent() -> bool:
    """Ask Linux to send this process SIGTERM when its parent dies; False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(0.5)
    os.kill(os.getpid(), signal.SIGTERM)


def _worker_stop(signum: int, frame: Any) -> None:
    global _received, _pending
    if _received is not None:
        return  # already stopping
    _received = (signum, time.monotonic())
    if not _busy:
        os._exit(128 + signum)
    if _deferring:
        _pending = signum
        return
    raise Interrupted(signum)


def run_in_worker(function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)`` in a worker set up by :func:`worker_init`. When a
    signal stops it, the files it was writing are removed on the way out
    (atomic outputs), and the worker exits rather than take another job."""
    global _busy
    _busy = True
    try:
        return function(*args)
    except Interrupted as exc:
        os._exit(exc.exit_code)
    finally:
        _busy = False


@contextlib.contextmanager
def stop_workers_on_interrupt(pool: Any, grace: float = WORKER_GRACE) -> Iterator[None]:
    """Around the use of a ``ProcessPoolExecutor``: on KeyboardInterrupt (and
    :class:`Interrupted`), terminate its worker processes before the pool's own
    exit, which would otherwise wait for their jobs to finish.

    Each worker gets SIGTERM (it removes its partial files and exits, see
    :func:`worker_init`) and ``grace`` seconds; one still alive then is killed.
    """
    try:
        yield
    except KeyboardInterrupt:
        stop_workers(pool, grace)
        raise


def stop_workers(pool: Any, grace: float = WORKER_GRACE) -> None:
    """Terminate the worker processes of the ``ProcessPoolExecutor`` ``pool``
    (SIGTERM, then SIGKILL after ``grace`` seconds) and cancel its jobs."""
    # the executor has no public way to reach its processes; _processes (pid ->
    # Process) has been there since Python 3.2
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(Exception):
            process.terminate()
    deadline = time.monotonic() + grace
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(max(0.0, deadline - time.monotonic()))
    for process in processes:
        with contextlib.suppress(Exception):
            if process.is_alive():
                process.kill()
                process.join(1.0)
    with contextlib.suppress(Exception):
        pool.shutdown(wait=False, cancel_futures=True)


__all__ = [
    "STOP_SIGNALS",
    "Interrupted",
    "defer",
    "handled",
    "held",
    "received",
    "resume",
    "run_in_worker",
    "signal_name",
    "start_resource_tracker",
    "quiet_exit",
    "stop_workers",
    "stop_workers_on_interrupt",
    "worker_init",
]


def quiet_exit() -> None:
    """Ignore the signals that stop a run once it has ended, its outputs in place
    or removed: one arriving while the interpreter shuts down would interrupt an
    exit callback (nanobind's, for the kernels) and print a traceback from it,
    and the exit code is already the run's."""
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None:
            signal.signal(sig, signal.SIG_IGN)
