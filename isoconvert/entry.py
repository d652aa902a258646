"""The ``isoconvert`` command's entry point, light enough to start at once.

Importing the command line (typer, rich, the commands) takes a fifth of a
second; a Ctrl-C, SIGTERM or SIGHUP in that time would print a traceback or
kill the process without a word. This module installs handlers first that
stop quietly, in one line with exit code 128 + N (nothing has been written
yet), then imports the command line, whose :func:`isoconvert.cli.main`
handles signals itself from then on.
"""

from __future__ import annotations

import signal
import sys


def _stop_while_starting(signum: int, frame: object) -> None:
    try:
        name = signal.Signals(signum).name
    except ValueError:
        name = f"signal {signum}"
    print(f"isoconvert: interrupted ({name}) while starting; nothing was written", file=sys.stderr)
    raise SystemExit(128 + signum)


def _quiet_start() -> dict:
    """Handlers for the signals that stop a run, where the process does not ignore
    them; returns the handlers they replace."""
    before = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            before[sig] = signal.signal(sig, _stop_while_starting)
    return before


def run() -> None:
    """Console-script entry point: ``isoconvert ARGS``."""
    before = _quiet_start()
    from .cli import main
    from .threads import prepare_process

    prepare_process()

    # the command line's own handling takes over from here (isoconvert.signals
    # installs it only over Python's defaults)
    for sig, handler in before.items():
        signal.signal(sig, handler)
    code = main()
    from .signals import quiet_exit

    quiet_exit()
    sys.exit(code)


if __name__ == "__main__":
    run()
