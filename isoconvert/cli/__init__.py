"""Command line: a thin shell over the Python API (the only package using typer/rich).

The top layer: it imports the library, nothing imports it. The help, ``formats``
and ``methods`` need only numpy-free tables; each command imports the rest when
it runs. The options ``convert`` and ``batch`` share are declared once, in
groups (``ReadArgs``, ``ExtractArgs``, ...), and both commands build their
:class:`~isoconvert.convert.ConvertOptions` from them through one function.

Its modules, each importing only those listed before it (so no circle):

- ``coercion``: option values turned into Python values without pydantic;
- ``options``: the option groups and the options several commands take;
- ``display``: progress, the stage clock, notices and batch's table;
- ``reports``: mesh reports printed or written, exit code 4;
- ``convert_cmd``, ``batch_cmd``, ``inspect_cmds``: the commands, plain functions;
- this ``__init__``: the typer application (:func:`typer_app`: every command in the
  order ``--help`` lists them, or, for a run, only the command it names, whose module
  alone is imported), ``main`` with its error handling and exit codes,
  the command-line pre-processing, and ``run`` (the console script).

Exit codes: 0 success, 1 a problem with the input or output (one line on
stderr), 2 a usage error, 3 an internal error (a bug), 4 a check named by
``--require`` failed, 130 interrupted.
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import os
import sys
from contextlib import redirect_stdout
from pathlib import Path
from typing import Annotated

import typer

from .. import __version__
from ..atomic import finished_outputs
from ..errors import IsoconvertError, one_line
from . import display
from .coercion import plain_coercion
from .options import (
    EXIT_CHECK_FAILED,
    ExtractArgs,
    LabelArgs,
    MemoryArgs,
    MeshArgs,
    PostArgs,
    ReadArgs,
    _flag,
    with_method_names,
)

__all__ = [
    "EXIT_CHECK_FAILED",
    "REPORT_SUFFIXES",
    "ExtractArgs",
    "LabelArgs",
    "MemoryArgs",
    "MeshArgs",
    "PostArgs",
    "ReadArgs",
    "app",
    "gather_multi_values",
    "main",
    "run",
]


# What the help, `formats` and `methods` need comes from numpy-free tables
# (methods, checks, and the readers' and writers' registries); each command
# imports the rest (numpy, the kernels, the parsers) when it runs, so that
# `isoconvert --help` starts fast.


class _HelpAsFlag:
    """Show ``--help`` as a flag, as our own flags (typer would show ``-h <bool>``)."""

    def get_help_option(self, ctx):
        option = super().get_help_option(ctx)
        if option is not None:
            option.metavar = ""
            # Absent, typer's help option is None, which typer coerces through
            # pydantic (~50 ms to import); False is a bool, which it passes as
            # is, so `formats` and `methods` need no pydantic.
            option.default = False
        return option


class _Command(_HelpAsFlag, typer.core.TyperCommand):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        plain_coercion(self.params)  # option values without pydantic (0.1 s a run)

    def format_help(self, ctx, formatter) -> None:
        with_method_names(self.params)  # the plugins are looked up for a help only
        super().format_help(ctx, formatter)


class _Group(_HelpAsFlag, typer.core.TyperGroup):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        plain_coercion(self.params)


def _version_and_debug(
    version: Annotated[bool, _flag("--version", help="Show the version.")] = False,
    debug: Annotated[
        bool,
        _flag(
            "--debug",
            help="Show a traceback instead of the one-line error (given anywhere on the "
            "command line).",
        ),
    ] = False,
) -> None:
    if version:
        print(f"isoconvert {__version__}")
        raise typer.Exit()


#: The commands, in the order --help lists them: (module of this package, function, hidden).
_COMMANDS = (
    ("convert_cmd", "convert", False),
    ("inspect_cmds", "check", False),
    ("inspect_cmds", "preview", False),
    ("batch_cmd", "batch", False),
    ("inspect_cmds", "info", False),
    ("inspect_cmds", "warmup", True),
    ("inspect_cmds", "formats", False),
    ("inspect_cmds", "methods", False),
)


def typer_app(only: str | None = None) -> typer.Typer:
    """The typer application: every command, or only the one named ``only``.

    A run needs only its own command: building the others' options (and importing
    batch's module) costs every run some 40 ms, which ``only`` saves; the help and
    an unknown command's message need them all (:data:`app`).
    """
    new = typer.Typer(
        name="isoconvert",
        cls=_Group,
        help="Turn scalar volumes and images (raw, NRRD, TIFF, Zarr, DICOM, NIfTI, MetaImage, "
        "NumPy, PNG, JPEG) into isosurface meshes and contours (PLY, OBJ, OFF, VTP, STL, GLB, "
        "3MF, SVG, GeoJSON), and check and picture meshes.",
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        add_completion=False,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    new.callback(invoke_without_command=True)(_version_and_debug)
    for module, name, hidden in _COMMANDS:
        if only is None or name == only:
            function = getattr(importlib.import_module(f".{module}", __name__), name)
            new.command(cls=_Command, hidden=hidden)(function)
    return new


def __getattr__(name: str):
    if name == "app":  # every command, built when first asked for
        globals()["app"] = built = typer_app()
        return built
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _app_for(args: list[str]) -> typer.Typer:
    """The application for a command line: only its command when it names one (the
    group's own options are flags, so the first other word is the command)."""
    word = next((a for a in args if not a.startswith("-")), None)
    if word in {name for _, name, _ in _COMMANDS}:
        return typer_app(word)
    return typer_app()


#: File names that a bare ``--report`` takes as its value (other names after it are
#: read as inputs; ``--report=NAME`` takes any).
REPORT_SUFFIXES = (".json", ".txt")


# Options that take several numbers; `--shape 256 256 128` is gathered into one
# value before typer sees it (click options have a fixed number of values, and
# --shape takes 2 or 3).
_MULTI_VALUE = ("--shape", "--spacing", "--origin")


def gather_multi_values(argv: list[str]) -> list[str]:
    """Join ``--shape 256 256 128`` into ``--shape 256,256,128`` (also spacing,
    origin), and give convert's bare ``--report`` the value "-" (print) unless a
    ``.json`` or ``.txt`` file name follows it (check's ``--report`` always takes
    the next word)."""
    out: list[str] = []
    command = next((a for a in argv if not a.startswith("-")), None)
    i = 0
    while i < len(argv):
        token = argv[i]
        out.append(token)
        i += 1
        if token == "--report" and command == "convert":
            if i < len(argv) and argv[i].lower().endswith(REPORT_SUFFIXES):
                out.append(argv[i])
                i += 1
            else:
                out.append("-")
            continue
        if token in _MULTI_VALUE:
            values = []
            while i < len(argv) and len(values) < 3 and _is_number(argv[i]):
                values.append(argv[i])
                i += 1
            if values:
                out.append(",".join(values))
    return out


#: options whose value is a file isoconvert writes
_OUTPUT_OPTIONS = ("-o", "--output", "--report", "--plot", "--preview", "--summary")


def _output_streams(args: list[str]) -> set[int]:
    """The file descriptors that output options name (``-o -``, ``-o /dev/stdout``
    give 1, ``/dev/stderr`` 2)."""
    from ..atomic import output_stream

    found: set[int] = set()
    for n, token in enumerate(args):
        name, _, value = token.partition("=")
        if name in _OUTPUT_OPTIONS:
            value = value or (args[n + 1] if n + 1 < len(args) else "")
            if name == "--report" and value == "-":  # convert's bare --report: print it
                continue
            stream = output_stream(value) if value else None
            if isinstance(stream, int):
                found.add(stream)
    return found


@contextlib.contextmanager
def _messages_kept_off(streams: set[int]):
    """A mesh sent to standard output or standard error must not have messages
    mixed into it: those for stdout go to stderr, and with stderr the mesh's,
    the notes are dropped (an error still gets its line, after the run)."""
    with contextlib.ExitStack() as stack:
        if 2 in streams:
            sink = stack.enter_context(open(os.devnull, "w"))  # noqa: SIM115
            stack.enter_context(contextlib.redirect_stderr(sink))
        if 1 in streams:
            stack.enter_context(redirect_stdout(sys.stderr))
        yield


def _is_number(text: str) -> bool:
    try:
        float(text.replace("x", "e") if "x" in text else text)
        return "x" not in text
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``isoconvert`` command; returns the exit code.

    SIGTERM and SIGHUP stop a run as Ctrl-C does (:mod:`isoconvert.signals`):
    partial output is removed, one line says so, and the exit code is 128 +
    the signal number (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP).
    """
    from .. import signals

    finished_outputs(forget=True)  # an earlier command's, in this process
    with signals.handled():
        return _run_command(argv)


def _interrupted() -> int:
    """Say that the run was stopped, in one line; the exit code, 128 + the signal."""
    import contextlib
    import signal

    from .. import signals

    signum = signals.received()
    by = f" ({signals.signal_name(signum)})" if signum and signum != signal.SIGINT else ""
    # outputs finished before the signal stay, whole: say which, since the
    # "wrote" lines come only once every output is written
    kept = ""
    finished = finished_outputs()
    if finished:
        last = f", the last {finished[-1]}" if len(finished) > 1 else f": {finished[0]}"
        some = "1 output" if len(finished) == 1 else f"{len(finished)} outputs"
        kept = f"; {some} finished before it kept{last}"
    with contextlib.suppress(OSError, ValueError):  # SIGHUP: the terminal may be gone
        print(f"isoconvert: interrupted{by}; no partial output was left{kept}", file=sys.stderr)
    return 128 + (signum or signal.SIGINT)


def _run_command(argv: list[str] | None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    display._show_third_party = debug  # numpy warnings and tifffile's log lines are not for users
    args = [a for a in args if a != "--debug"]
    unnamed = _report_names_not_taken(args)
    args = gather_multi_values(args)
    for stream in (sys.stdout, sys.stderr):
        # a file name that is not UTF-8 (Python holds its bytes as surrogates)
        # prints with a replacement character instead of failing the run
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors="replace")
    # a mesh sent to standard output must not have messages mixed into it
    talk = _messages_kept_off(_output_streams(args))
    try:
        with talk:
            result = _app_for(args)(args=args, prog_name="isoconvert", standalone_mode=False)
        code = result if isinstance(result, int) else 0
        if code == 130:  # click turns Ctrl-C into exit code 130
            return _interrupted()
        return code
    except SystemExit as exc:
        code = exc.code
        code = code if isinstance(code, int) else (0 if code is None else 1)
        if code == 130:  # click turns Ctrl-C into exit code 130, and batch Ctrl-C, SIGTERM too
            return _interrupted()
        return code
    except IsoconvertError as exc:
        if debug:
            raise
        print(f"isoconvert: error: {one_line(exc, limit=2000)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C, and SIGTERM or SIGHUP (signals.Interrupted)
        if debug:
            raise
        return _interrupted()
    except MemoryError:
        if debug:
            raise
        print("isoconvert: error: out of memory; try a smaller volume", file=sys.stderr)
        return 1
    except Exception as exc:
        if isinstance(exc, OSError) and exc.errno == errno.ENAMETOOLONG and not debug:
            # a name given on the command line that no file system takes, wherever used
            name = one_line(exc.filename if exc.filename is not None else "a path", limit=120)
            print(
                f"isoconvert: error: {name}: the name is too long for the file system "
                "(255 bytes a name, 4096 a path); choose a shorter one",
                file=sys.stderr,
            )
            return 1
        if _is_usage_error(exc):
            message = exc.format_message()
            if not message:  # `isoconvert` alone: the help was the answer
                return 2
            # one line, as for every other mistake (click draws a box of several)
            ctx = getattr(exc, "ctx", None)
            command = ctx.command_path if ctx is not None else "isoconvert"
            if unnamed and "unexpected extra argument" in message:
                message += (
                    f"; --report takes a file named *.json or *.txt (bare, it prints the "
                    f"report), so {unnamed[0]} was read as another argument"
                )
            print(
                f"isoconvert: error: {one_line(message, limit=500)} (see {command} --help)",
                file=sys.stderr,
            )
            return 2
        if type(exc).__name__ == "Abort":  # click's Ctrl-C (or SIGTERM, SIGHUP)
            return _interrupted()
        # a bug, not a user mistake: say so in one line
        if debug:
            raise
        print(
            f"isoconvert: internal error: {type(exc).__name__}: {exc} "
            "(rerun with --debug and report it)",
            file=sys.stderr,
        )
        return 3
    return 0


def _report_names_not_taken(argv: list[str]) -> list[str]:
    """The words after convert's ``--report`` that look like a file name but not a
    report's (:data:`REPORT_SUFFIXES`): :func:`gather_multi_values` leaves them to
    the command, which may then find an argument too many."""
    command = next((a for a in argv if not a.startswith("-")), None)
    if command != "convert":
        return []
    return [
        word
        for token, word in zip(argv, argv[1:], strict=False)
        if token == "--report"
        and not word.startswith("-")
        and Path(word).suffix
        and not word.lower().endswith(REPORT_SUFFIXES)
    ]


def _is_usage_error(exc: Exception) -> bool:
    """A command line click could not parse (its UsageError, which typer vendors
    under a private name): exit code 2 and a message."""
    return getattr(exc, "exit_code", None) == 2 and hasattr(exc, "format_message")


def run() -> None:
    """Console-script entry point."""
    from ..threads import prepare_process

    prepare_process()
    sys.exit(main())
