"""Output files that appear whole or not at all."""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from .errors import OutputError


def check_output(path: str | Path, force: bool = False, example: str = "mesh.ply") -> Path:
    """Fail early, before any work, when ``path`` cannot be written.

    Parameters
    ----------
    path : str or Path
    force : bool
        An existing file may be replaced.
    example : str
        A file name to suggest when ``path`` is a folder.

    Raises
    ------
    OutputError
        The folder is missing or not writable, the path is a folder or a special
        file (device, FIFO, socket), or the file exists and ``force`` is False.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give an output file name such as {path}/{example}")
    if not folder.is_dir():
        raise OutputError(f"{path}: the folder {folder} does not exist; create it first")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            f"{path}: cannot write to the folder {folder} (permission denied); choose another -o"
        )
    if path.exists() and not path.is_file():
        # A device, FIFO or socket: renaming a file over it would replace it
        # (as root, /dev/null itself); isoconvert writes regular files only.
        raise OutputError(
            f"{path}: is not a regular file (a device, pipe or socket); "
            "isoconvert writes regular files only, choose a file name"
        )
    if path.exists() and not force:
        raise OutputError(f"{path}: already exists; pass --force to overwrite it")
    # permissions do not tell everything (root, read-only mounts, /proc): the
    # temporary file the output is written to must be creatable there
    try:
        handle, probe = tempfile.mkstemp(dir=folder, prefix=".isoconvert-probe-")
    except OSError as exc:
        raise OutputError(
            f"{path}: cannot create files in the folder {folder} ({exc.strerror}); "
            "choose another output"
        ) from None
    os.close(handle)
    os.unlink(probe)
    return path


@contextlib.contextmanager
def atomic_output(
    path: str | Path, force: bool = False, example: str = "mesh.ply"
) -> Iterator[BinaryIO]:
    """Open a temporary file beside ``path``; rename it to ``path`` on success.

    On any exception (including KeyboardInterrupt) the temporary file is
    removed, so a failed run leaves no partial output behind. ``example`` is as
    for :func:`check_output`.
    """
    path = check_output(path, force, example)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    except OSError as exc:
        raise OutputError(f"{path}: cannot create a file there ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
        # mkstemp makes the file private (0600); give it the permissions a plain open would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if path.exists() and (not force or not path.is_file()):
            raise OutputError(f"{path}: appeared while writing; choose another name or retry")
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        if exc.errno == errno.ENOSPC:
            raise OutputError(f"{path}: the disk is full; free space or write elsewhere") from None
        raise OutputError(f"{path}: writing failed ({exc.strerror or exc})") from None
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)
