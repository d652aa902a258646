"""What the commands show on the terminal while they work, and their tables.

The stage spinner or ``--verbose`` clock of ``convert``, batch's progress bar
and table, notices on stderr, and third-party warnings kept off stderr unless
``--debug``. Progress displays only on a terminal (rich is imported then).
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from pathlib import Path

#: Set by :func:`main`: with --debug, third-party warnings and log lines stay visible.
_show_third_party = False


def _quiet_third_party() -> None:
    """Keep numpy's warnings and tifffile's log lines off stderr, unless --debug.

    Called by the commands that read or compute, not by ``main``: it imports
    numpy, which the help, ``formats`` and ``methods`` do without.
    """
    if not _show_third_party:
        from ..quiet import silence_third_party

        silence_third_party()


def _interactive() -> bool:
    """Progress displays only on a terminal, never in pipes, logs or CI."""
    return sys.stderr.isatty()


@contextmanager
def _stage_display(quiet: bool, verbose: bool = False):
    """Yield ``(on_progress, on_status)`` for :func:`isoconvert.convert`.

    On a terminal a spinner names the stage (reading, extracting, writing);
    notices print above it. With
    ``verbose``, a timed line per stage instead (also when not a terminal).
    Otherwise notices are plain lines on stderr.
    """
    if quiet:
        yield None, None
        return
    if verbose or not _interactive():
        clock = _StageClock() if verbose else None
        yield (clock.start if clock else None), _status(quiet)
        if clock:
            clock.finish()
        return
    from rich.console import Console

    console = Console(stderr=True)
    with console.status("starting") as status:

        def on_status(message: str) -> None:
            console.print(message, markup=False, highlight=False)

        yield (lambda stage: status.update(f"{stage}...")), on_status


class _StageClock:
    """--verbose: one line per stage with the time it took, as it ends, then the
    total, so that the lines add up to the run."""

    def __init__(self) -> None:
        self.began = self.since = time.perf_counter()
        self.stage: str | None = None

    def start(self, stage: str) -> None:
        now = time.perf_counter()
        if self.stage is not None:
            print(f"{now - self.since:7.2f} s  {self.stage}", file=sys.stderr)
        self.stage, self.since = stage, now

    def finish(self) -> None:
        self.start("")  # the line of the last stage
        print(f"{time.perf_counter() - self.began:7.2f} s  in all", file=sys.stderr)


def _status(quiet: bool):
    """Notices as plain lines on stderr (None when quiet)."""
    if quiet:
        return None

    def say(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    return say


@contextmanager
def _batch_display(quiet: bool, total: int, verbose: bool = False):
    """Files done of total with ETA on a terminal; failures as lines on stderr
    (with ``verbose``, every file as it finishes)."""
    count = [0]

    def report_failure(outcome, console=None):
        count[0] += 1
        line = None
        if outcome.status in ("failed", "check-failed"):  # errors, even with --quiet
            line = f"isoconvert: {outcome.message}"
        elif outcome.status == "ok" and outcome.message and not quiet and not verbose:
            line = f"note: {outcome.message}"  # e.g. a thumbnail left out, and why
        elif verbose and not quiet:
            line = (
                f"[{count[0]}/{total}] {outcome.status} {outcome.input} -> {outcome.output} "
                f"({outcome.cells or 0:,} cells, {outcome.seconds:.2f} s)"
            )
        if line:
            if console is not None:
                console.print(line, markup=False, highlight=False)
            else:
                print(line, file=sys.stderr)

    if quiet or verbose or not _interactive() or total == 0:
        yield report_failure
        return
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    console = Console(stderr=True)
    columns = [
        TextColumn("converting"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.description}"),
    ]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task("", total=total)

        def on_done(outcome):
            report_failure(outcome, progress.console)
            progress.update(task, advance=1, description=Path(outcome.input).name)

        yield on_done


def _collapse_skipped(outcomes, limit: int = 3):
    """Skipped files of one folder, suffix and reason as one row when there are many."""
    groups: dict = {}
    for o in outcomes:
        if o.status == "skipped" and not o.output:
            p = Path(o.input)
            groups.setdefault((str(p.parent), p.suffix, o.message), []).append(o)
    shown, done = [], set()
    for o in outcomes:
        p = Path(o.input)
        key = (str(p.parent), p.suffix, o.message)
        group = groups.get(key) if o.status == "skipped" and not o.output else None
        if group is None or len(group) <= limit:
            shown.append(o)
        elif key not in done:
            done.add(key)
            name = f"{p.parent / ('*' + p.suffix)} ({len(group)} files)"
            shown.append(type(o)(name, "", "skipped", message=o.message))
    return shown


def _print_batch_table(outcomes) -> None:
    rows = [("file", "level", "vertices", "cells", "seconds", "checks", "status")]
    for o in _collapse_skipped(outcomes):
        checks = (
            ""
            if o.checks is None
            else ",".join(f"{k}{'' if v else '!'}" for k, v in o.checks.items())
        )
        rows.append(
            (
                o.input,
                "" if o.level is None else f"{o.level:g}",
                "" if o.vertices is None else f"{o.vertices:,}",
                "" if o.cells is None else f"{o.cells:,}",
                f"{o.seconds:.2f}" if o.status not in ("skipped",) else "",
                checks,
                o.status if not o.message or o.status == "ok" else f"{o.status}: {o.message}"[:80],
            )
        )
    widths = [max(len(r[c]) for r in rows) for c in range(6)]
    for r in rows:
        print(
            "  ".join(r[c].ljust(widths[c]) if c == 0 else r[c].rjust(widths[c]) for c in range(6))
            + "  "
            + r[6]
        )
    totals = {}
    for o in outcomes:
        totals[o.status] = totals.get(o.status, 0) + 1
    print(", ".join(f"{n} {s}" for s, n in totals.items()))
