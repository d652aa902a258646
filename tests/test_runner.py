"""The task runner's local engine (issue 21), on tasks that are plain library
functions (so spawned workers can import them): every task finishes exactly
once; a worker that dies fails only its own task; a task whose ``load`` fails
never starts; an interrupt met by the caller between two results stops the
workers at once, and so does one that lands on another thread while the caller
waits for a worker or the read-ahead; the read-ahead thread hands back every item
in order.
"""

from __future__ import annotations

import os
import threading
import time

import pytest

from isoconvert.errors import IsoconvertError
from isoconvert.runner import Finished, Task
from isoconvert.runner.local import read_ahead, run_in_processes


def _by_key(finished: list[Finished]) -> dict[str, Finished]:
    keys = [f.task.key for f in finished]
    assert len(keys) == len(set(keys)), keys  # each task finished once
    return {f.task.key: f for f in finished}


def test_a_dead_worker_fails_only_its_own_task():
    tasks = [
        Task(time.sleep, (0.4,), key="slow"),
        Task(os._exit, (3,), key="dies"),  # kills its worker, breaking the pool
        Task(abs, (-7,), key="abs"),
        Task(divmod, (17, 5), key="divmod"),
    ]
    done = _by_key(list(run_in_processes(tasks, 3)))
    assert set(done) == {"slow", "dies", "abs", "divmod"}
    assert done["dies"].died and done["dies"].value is None
    # those beside it were run again (alone) or later: their values, as if alone
    assert [done[k].value for k in ("slow", "abs", "divmod")] == [None, 7, (3, 2)]
    assert not any(done[k].died or done[k].error for k in ("slow", "abs", "divmod"))


def test_a_task_that_raises_or_cannot_start_fails_alone():
    def refuse() -> tuple:
        raise IsoconvertError("out/: cannot make the folder")

    tasks = [
        Task(abs, key="no-start", load=refuse),
        Task(int, ("x",), key="raises"),
        Task(pow, (2, 10), key="pow"),
    ]
    done = _by_key(list(run_in_processes(tasks, 2, budget=1)))  # one at a time
    assert not done["no-start"].started
    assert str(done["no-start"].error) == "out/: cannot make the folder"
    assert isinstance(done["raises"].error, ValueError) and done["raises"].started
    assert done["pow"].value == 1024


def test_tasks_over_budget_run_one_at_a_time():
    """With a budget below every task's estimate, no two tasks overlap: told by
    the tasks' loads, which run here as each task starts."""
    started: list[int] = []
    active = []

    def load(n: int):
        def start() -> tuple:
            started.append(n)
            active.append(n)
            return (0.05,)

        return start

    tasks = [Task(time.sleep, key=str(n), nbytes=10, load=load(n)) for n in range(4)]
    runs = run_in_processes(tasks, 4, budget=5)
    for finished in runs:
        active.remove(int(finished.task.key))
        assert not active  # the next task starts only once this one has finished
    assert started == [0, 1, 2, 3] and not active


def test_an_interrupt_between_results_stops_the_workers_at_once():
    tasks = [Task(abs, (-1,), key="quick"), Task(time.sleep, (60,), key="long")]
    runs = run_in_processes(tasks, 2)
    first = next(runs)
    assert first.task.key == "quick"
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        runs.throw(KeyboardInterrupt())  # what isoconvert.batch does with one it meets
    assert time.monotonic() - start < 20  # not the 60 s of the running task
    assert next(runs, None) is None  # closed


def test_read_ahead_gives_every_item_in_order_reading_the_next_meanwhile():
    readers = []

    def load(n: int) -> int:
        readers.append(threading.current_thread().name)
        return n * n

    got = list(read_ahead(list(range(6)), load, ready=lambda n: n != 3))
    assert got == [(n, n * n) for n in range(6)]
    # the first item, and the one not ready ahead of time, are read here
    assert readers.count(threading.current_thread().name) == 2
    assert list(read_ahead([], load)) == []


def _interrupt_from_another_thread(after: float) -> threading.Timer:
    """SIGINT raised on a thread that is not the main one, as Linux may deliver a
    Ctrl-C: the main thread sees it only when it next runs Python code."""
    import signal

    timer = threading.Timer(after, signal.raise_signal, (signal.SIGINT,))
    timer.start()
    return timer


def test_an_interrupt_while_waiting_for_the_read_ahead_is_seen_before_it_ends():
    release, events = threading.Event(), []

    def load(n: int) -> int:
        if n == 1:  # the item read ahead: a read that takes long
            release.wait(20)
            events.append("read")
        return n

    timer = _interrupt_from_another_thread(0.3)
    try:
        with pytest.raises(KeyboardInterrupt):
            for _item, _loaded in read_ahead([0, 1, 2], load):
                pass
        events.append("interrupted")
    finally:
        timer.cancel()
        release.set()
    # the interrupt came while the read still ran, not once it ended
    assert events[0] == "interrupted"


def test_an_interrupt_while_waiting_for_a_worker_is_seen_before_its_task_ends(tmp_path):
    from pathlib import Path

    ended = tmp_path / "ended"
    tasks = [Task(_sleep_then_touch, (20.0, str(ended)), key="long")]
    runs = run_in_processes(tasks, 1)
    # the worker's start (a spawned interpreter) comes before the wait
    timer = _interrupt_from_another_thread(3.0)
    try:
        with pytest.raises(KeyboardInterrupt):
            next(runs)
    finally:
        timer.cancel()
    assert not Path(ended).exists()  # the task was stopped, not waited for


def _sleep_then_touch(seconds: float, path: str) -> None:
    time.sleep(seconds)
    open(path, "w").close()
