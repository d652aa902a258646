"""threads.threaded_in_order (label files and layer objects written side by side) and
check_output's folder probe, which a run of many files makes once."""

from __future__ import annotations

import tempfile
import threading
import time

import numpy as np
import pytest

from isoconvert.atomic import check_output
from isoconvert.errors import OutputError
from isoconvert.label_convert import convert_labels
from isoconvert.threads import Abandoned, stop_if_interrupted, threaded_in_order


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_results_come_in_order_of_the_arguments(threads):
    def slow_square(n):
        time.sleep(0.002 * ((7 * n) % 5))  # later calls often finish first
        return n * n

    got = list(threaded_in_order(slow_square, ((n,) for n in range(30)), threads))
    assert got == [n * n for n in range(30)]


def test_at_most_the_window_is_taken_from_the_arguments_ahead_of_the_results():
    taken = []

    def arguments():
        for n in range(20):
            taken.append(n)
            yield (n,)

    results = threaded_in_order(lambda n: n, arguments(), threads=2, window=3)
    for n, value in enumerate(results):
        assert value == n
        # the caller has n + 1 results; at most the window more were asked for
        assert len(taken) <= n + 1 + 3


def test_an_error_cancels_the_calls_not_started_and_waits_for_those_running():
    started, finished = set(), set()
    lock = threading.Lock()

    def work(n):
        with lock:
            started.add(n)
        if n == 2:
            raise ValueError("bad item")
        time.sleep(0.01)
        with lock:
            finished.add(n)
        return n

    with pytest.raises(ValueError, match="bad item"):
        list(threaded_in_order(work, ((n,) for n in range(100)), threads=2, window=4))
    # every call that started has ended (nothing runs on after the error) ...
    assert started - {2} == finished
    # ... and most were never started
    assert len(started) < 20


def test_an_interrupt_stops_the_calls_running_at_their_next_step():
    """Ctrl-C while long calls run on the threads: the calls that check
    stop_if_interrupted give up at their next step (a decimation's next collapse),
    so the interrupt is not held up until they finish; a later run is not stopped."""
    import signal

    steps, ends = [], []

    def long_call(n):
        try:
            for step in range(300):  # 30 s when nothing stops it
                stop_if_interrupted()
                steps.append(step)
                time.sleep(0.1)
            ends.append("finished")
        except Abandoned:
            ends.append("abandoned")

    timer = threading.Timer(0.5, signal.raise_signal, (signal.SIGINT,))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            list(threaded_in_order(long_call, ((n,) for n in range(4)), 2))
    finally:
        timer.cancel()
    assert ends == ["abandoned", "abandoned"]  # the two running; the others never started
    assert len(steps) < 2 * 300
    got = list(
        threaded_in_order(lambda n: (stop_if_interrupted(), n)[1], ((n,) for n in range(3)), 2)
    )
    assert got == [0, 1, 2]


def test_a_signal_while_a_thread_starts_leaves_no_call_running_after_the_interrupt(
    monkeypatch,
):
    """SIGINT lands while submit starts the pool's second thread: the pool notes the
    thread only once its start returns, so the interrupt once skipped it in the
    pool's shutdown, and it ran its call after the run had said which files it kept
    (a label file renamed into place after that line). Every call that started has
    ended when the interrupt is raised, and nothing runs on after it."""
    import signal

    from isoconvert import signals

    started, finished = [], []
    starts = []
    real_start = threading.Thread.start

    def start_then_signal(thread):
        real_start(thread)
        starts.append(thread.name)
        if thread.name.startswith("isoconvert") and len(starts) == 2:
            signal.raise_signal(signal.SIGINT)  # handled at the next step of submit

    def work(n):
        started.append(n)
        time.sleep(0.3)
        finished.append(n)

    monkeypatch.setattr(threading.Thread, "start", start_then_signal)
    with signals.handled(), pytest.raises(KeyboardInterrupt):
        list(threaded_in_order(work, ((n,) for n in range(6)), threads=2))
    at_the_interrupt = (list(started), list(finished))
    time.sleep(0.8)
    assert (started, finished) == at_the_interrupt
    assert sorted(started) == sorted(finished)
    # the call submitted while the signal was held was not lost: it ran, or was cancelled
    assert set(started) <= {0, 1}


def test_label_files_written_side_by_side_equal_those_of_one_thread(tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    labels = np.zeros((24, 20, 18), np.uint8)
    for value in range(1, 9):  # eight boxes of labels, some touching
        lo = rng.integers(0, 14, 3)
        hi = lo + rng.integers(3, 8, 3)
        labels[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = value
    np.save(tmp_path / "labels.npy", labels)
    outputs = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        folder = tmp_path / f"t{threads}"
        folder.mkdir()
        results = convert_labels(tmp_path / "labels.npy", folder / "l.ply", label_smoothing=4)
        outputs[threads] = {r.output.name: r.output.read_bytes() for r in results}
    present = sorted(int(v) for v in np.unique(labels) if v)
    assert sorted(outputs["2"]) == sorted(f"l_label{v}.ply" for v in present)
    assert outputs["1"] == outputs["2"]


def test_without_the_probe_nothing_is_made_in_the_folder(tmp_path, monkeypatch):
    made = []
    real = tempfile.mkstemp

    def watch(*args, **kwargs):
        made.append(kwargs.get("prefix"))
        return real(*args, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", watch)
    check_output(tmp_path / "a.ply", probe=False)
    assert made == []
    check_output(tmp_path / "a.ply")
    assert made == [".isoconvert-probe-"]
    assert list(tmp_path.iterdir()) == []
    # the other checks still run without it
    (tmp_path / "b.ply").write_bytes(b"x")
    with pytest.raises(OutputError, match="already exists"):
        check_output(tmp_path / "b.ply", probe=False)
