"""Output files that appear whole or not at all."""

from __future__ import annotations

import contextlib
import errno
import os
import platform
import re
import shutil
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

from . import signals
from .errors import OutputError


def check_output(
    path: str | Path,
    force: bool = False,
    example: str = "mesh.ply",
    inputs: Iterable[str | Path] = (),
    *,
    probe: bool = True,
) -> Path:
    """Fail early, before any work, when ``path`` cannot be written.

    Parameters
    ----------
    path : str or Path
    force : bool
        An existing file may be replaced.
    example : str
        A file name to suggest when ``path`` is a folder.
    inputs : iterable of str or Path
        The files (and folders) the run reads: ``path`` must be none of them,
        by device and inode, so no symlink or hard link hides one.
    probe : bool
        Make and remove a temporary file in the folder, which permissions alone do
        not prove possible; False where that was done for another file of the same
        folder, or where the file is made next (:func:`atomic_output`).

    Raises
    ------
    OutputError
        The folder is missing or not writable, the path is a folder or a special
        file (a block device, a socket), its name is too long for the folder,
        it is one of ``inputs``, or the file exists and ``force`` is False.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    _check_name_length(path, folder)  # first: stat() of too long a name raises
    refuse_inputs(path, inputs)
    if output_stream(path) is not None:
        return path  # written in place: nothing is replaced (see atomic_output)
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give an output file name such as {path}/{example}")
    if not folder.is_dir():
        raise OutputError(f"{path}: the folder {folder} does not exist; create it first")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(
            f"{path}: cannot write to the folder {folder} (permission denied); "
            "give a path in a folder you can write to"
        )
    if stat.S_ISFIFO(_mode(path)):
        raise OutputError(
            f"{path}: is a named pipe (writing would wait for a reader); name a file, "
            f"or /dev/stdout with the shell's > {path}"
        )
    if os.path.lexists(path) and not path.is_file():
        # A device or socket (or a symlink into /dev, /proc): renaming a file over it
        # would replace it (as root, the device node itself).
        raise OutputError(
            f"{path}: is not a regular file (a device, socket or link to one); "
            "isoconvert writes regular files, pipes and its standard output only; "
            "choose a file name"
        )
    if path.exists() and not force:
        raise OutputError(f"{path}: already exists; pass --force to overwrite it")
    if probe:
        probe_folder(path, folder)
    return path


def probe_folder(path: str | Path, folder: Path) -> None:
    """Fail early when files cannot be made in ``folder``, where ``path`` (a file
    or a layer's folder) is to be written: permissions do not tell everything
    (root, read-only mounts, /proc), so a temporary file is made and removed."""
    signals.defer()  # a signal is held until the probe is gone again
    try:
        try:
            handle, probe = tempfile.mkstemp(dir=folder, prefix=".isoconvert-probe-")
        except OSError as exc:
            raise OutputError(
                f"{path}: cannot create files in the folder {folder} ({exc.strerror}); "
                "give a path in a folder you can write to"
            ) from None
        os.close(handle)
        os.unlink(probe)
    finally:
        signals.resume()


def input_file(input: str | Path) -> list[Path]:
    """The input as a list of the files to protect: itself when it is a file (a
    folder or a glob is resolved by its reader, which names its files)."""
    return [Path(input)] if Path(input).is_file() else []


def refuse_given_outputs(
    input: str | Path, outputs: Iterable[str | Path], folder: str | Path | None = None
) -> None:
    """Before the input's header is read: refuse two outputs (or ``folder``, a
    layer's, and an output) that are one file, and an output that is the input
    file itself."""
    outputs = list(outputs)
    refuse_shared([*([folder] if folder is not None else []), *outputs])
    for path in outputs:
        refuse_inputs(path, input_file(input))


def refuse_inputs(path: str | Path, inputs: Iterable[str | Path]) -> None:
    """Raise OutputError when writing ``path`` would replace a file being read.

    Files are compared by device and inode (through symlinks and hard links).
    A folder in ``inputs`` stands for every file in it (a Zarr store's
    metadata and chunks): an existing file inside it is refused too.

    Parameters
    ----------
    path : str or Path
        The output.
    inputs : iterable of str or Path
        Every file and folder the run reads.
    """
    path = Path(path)
    target = _identity(path)
    if target is None:
        return
    real = Path(os.path.realpath(path))
    for source in inputs:
        source = Path(source)
        if _identity(source) == target:
            same_name = os.path.abspath(source) == os.path.abspath(path)
            what = "the input" if same_name else f"a file the input reads ({source})"
            raise OutputError(
                f"{path}: is {what}; writing it would destroy it: choose another name"
            )
        if source.is_dir() and real.is_relative_to(os.path.realpath(source)) and path.is_file():
            raise OutputError(
                f"{path}: lies inside {source}, which is being read; choose another -o"
            )


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of the file ``path`` names, following symlinks; None when
    there is none."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def _check_name_length(path: Path, folder: Path) -> None:
    """Raise OutputError when the file system cannot hold a file of this name."""
    limit = _name_max(folder)
    size = len(os.fsencode(path.name))
    if size > limit:
        raise OutputError(
            f"{path}: the file name is {size} bytes, longer than the {limit} the folder "
            "allows; choose a shorter name"
        )
    whole = len(os.fsencode(os.path.abspath(path)))
    if whole >= 4096:  # PATH_MAX on Linux, and longer than macOS's and Windows' limits
        raise OutputError(f"{str(path)[:60]}...: the path is {whole} bytes; choose a shorter one")


def _mode(path: Path) -> int:
    """The st_mode of what ``path`` names (following symlinks), 0 when nothing."""
    try:
        return os.stat(path).st_mode
    except (OSError, ValueError):
        return 0


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, the file system of ``folder`` takes."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return 255


#: The outputs this process has renamed into place, in order (what an interrupted
#: run kept: :func:`finished_outputs`).
_FINISHED: list[Path] = []


def finished_outputs(forget: bool = False) -> list[Path]:
    """The files and folders renamed into place so far (since ``forget``), in
    order: a run that is stopped keeps them, whole, and says which
    (``isoconvert.cli``, which forgets them as each command starts)."""
    finished = list(_FINISHED)
    if forget:
        _FINISHED.clear()
    return finished


def note_finished(paths: Iterable[str | Path]) -> None:
    """Add outputs another process renamed into place (a batch's workers) to
    :func:`finished_outputs`."""
    _FINISHED.extend(Path(path) for path in paths)


_FD_PATH = re.compile(r"^/(?:proc/self|dev)/fd/(\d+)$")
_STD_STREAMS = {"/dev/stdout": 1, "/dev/stderr": 2}
#: character devices written in place: the null device and terminals
_WRITABLE_DEVICES = re.compile(r"^/dev/(?:null|tty\w*|pts/\d+)$")


def output_stream(path: str | Path) -> int | str | None:
    """What ``-o PATH`` means when it names a stream rather than a file.

    ``-``, ``/dev/stdout``, ``/dev/stderr`` and ``/dev/fd/N`` (``/proc/self/fd/N``),
    through any symlinks, mean the process's open file descriptor N: returns
    N, and the output goes wherever the shell sent it (a pipe, a terminal, a
    redirected file). ``/dev/null`` or a terminal is written in place: returns
    its path. Anything else (a regular file, a new name, a named pipe, which
    would block with no reader, a block device) returns None.
    """
    if os.fspath(path) == "-":  # the Unix convention: standard output
        return 1
    text = os.path.abspath(os.fspath(path))
    for _ in range(40):  # symlink hops
        if text in _STD_STREAMS:
            return _STD_STREAMS[text]
        found = _FD_PATH.match(text)
        if found:
            return int(found.group(1))
        if not os.path.islink(text):
            break
        text = os.path.normpath(os.path.join(os.path.dirname(text), os.readlink(text)))
    try:
        mode = os.stat(text).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISCHR(mode) and _WRITABLE_DEVICES.match(text):
        return text
    return None


def refuse_shared(outputs: Iterable[str | Path]) -> None:
    """Raise OutputError when two of a run's outputs (meshes, reports, pictures)
    are one file or one stream: the second would replace the first.

    Names are compared as absolute paths, existing files by device and inode,
    streams by what they write to (``-`` and ``/dev/stdout`` are one).
    """
    seen: dict[object, Path] = {}
    for path in map(Path, outputs):
        stream = output_stream(path)
        keys = [("stream", stream)] if stream is not None else [os.path.abspath(path)]
        if stream is None and _identity(path) is not None:
            keys.append(_identity(path))
        for key in keys:
            if key in seen and not (isinstance(stream, str) and stream == "/dev/null"):
                raise OutputError(
                    f"{path}: is named for two outputs ({seen[key]} too), and the second "
                    "would replace the first; give each its own name"
                )
            seen[key] = path


def refuse_stream(path: str | Path, why: str) -> None:
    """Raise OutputError when ``path`` is a stream (:func:`output_stream`) but
    several files would be named after it: ``why`` says which."""
    if output_stream(path) is not None:
        raise OutputError(f"{path}: a stream takes one output, but {why}; give a file name instead")


@contextlib.contextmanager
def atomic_output(
    path: str | Path,
    force: bool = False,
    example: str = "mesh.ply",
    inputs: Iterable[str | Path] = (),
) -> Iterator[BinaryIO]:
    """Open a temporary file beside ``path``; rename it to ``path`` on success.

    On any exception (including KeyboardInterrupt) the temporary file is
    removed, so a failed run leaves no partial output behind. ``example`` and
    ``inputs`` are as for :func:`check_output`.

    A ``path`` naming a stream (:func:`output_stream`: standard output, a
    pipe, ``/dev/null``) is written in place, never replaced: the output is
    written to a temporary file first and copied to the stream once complete,
    so a failed run sends nothing, and writers may seek.
    """
    # no probe: the temporary file made below fails the same way
    path = check_output(path, force, example, inputs, probe=False)
    stream = output_stream(path)
    folder = tempfile.gettempdir() if stream is not None else path.parent
    # the temporary name always fits the folder's limit, however long the user's is
    owner = _owner_tag()
    keep = _name_max(Path(folder)) - len(".") - len(f".{owner}-XXXXXXXX.part") - 8
    stem = os.fsencode(path.name)[: max(keep, 1)].decode("utf-8", "ignore") or "out"
    if stream is None:
        _remove_stale_parts(Path(folder), stem)
    # a signal between making the file and entering the block that removes it
    # would leave it behind: it is held until then (isoconvert.signals)
    signals.defer()
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{stem}.{owner}-", suffix=".part")
    except OSError as exc:
        signals.resume()
        raise OutputError(f"{path}: cannot create a file there ({exc.strerror})") from None
    copying = False  # to the stream: a full disk there is the stream's, not the folder's
    try:
        with os.fdopen(fd, "w+b") as fh:
            signals.resume()
            yield fh
            if stream is not None:
                fh.seek(0)
                copying = True
                _copy_to_stream(fh, stream)
        if stream is None:
            # mkstemp makes the file private (0600); give it the permissions a plain open would
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
            if path.exists() and (not force or not path.is_file()):
                raise OutputError(f"{path}: appeared while writing; choose another name or retry")
            os.replace(tmp, path)
            _FINISHED.append(path)
        else:
            _remove(tmp)
    except OSError as exc:
        written = _size(tmp)
        _remove(tmp)
        if exc.errno in DISK_FULL_ERRNOS:
            # what was written when the disk filled is a lower bound of the need
            if stream is not None and not copying:  # the temporary copy of a stream's output
                why = f"for the output to {path} (set TMPDIR to a folder with room)"
                raise disk_full_error(folder, written, more=True, why=why) from None
            raise disk_full_error(path, written, more=True) from None
        if exc.errno == errno.EPIPE:
            raise OutputError(f"{path}: the reading end of the pipe closed early") from None
        raise OutputError(f"{path}: writing failed ({exc.strerror or exc})") from None
    except BaseException:
        _remove(tmp)
        raise


@contextlib.contextmanager
def atomic_folder(path: str | Path, force: bool = False) -> Iterator[Path]:
    """A temporary folder beside ``path``, renamed to ``path`` on success.

    The folder outputs' :func:`atomic_output` (a Neuroglancer layer): on any
    exception, a signal included, the temporary folder is removed; an existing
    ``path`` is replaced only with ``force``, and only once the new folder is
    complete. A full disk is the one-line :class:`DiskFullError`, any other
    failure to write an :class:`OutputError`.
    """
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    owner = _owner_tag()
    keep = _name_max(parent) - len(".") - len(f".{owner}-XXXXXXXX.part") - 8
    stem = os.fsencode(path.name)[: max(keep, 1)].decode("utf-8", "ignore") or "out"
    _remove_stale_parts(parent, stem)
    signals.defer()  # held until the block that removes the folder is entered
    try:
        tmp = Path(tempfile.mkdtemp(dir=parent, prefix=f".{stem}.{owner}-", suffix=".part"))
    except OSError as exc:
        signals.resume()
        raise OutputError(
            f"{path}: cannot create a folder there ({exc.strerror}); "
            "give a path in a folder you can write to"
        ) from None
    try:
        signals.resume()
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp's 0700 would hide it from a web server
        yield tmp
        _replace_folder(tmp, path, force)
    except OSError as exc:
        written = _tree_size(tmp)
        _remove_tree(tmp)
        if exc.errno in DISK_FULL_ERRNOS:
            raise disk_full_error(path, written, more=True) from None
        raise OutputError(f"{path}: writing failed ({exc.strerror or exc})") from None
    except BaseException:
        _remove_tree(tmp)
        raise


def _remove_tree(folder: Path, tries: int = 5) -> None:
    """Remove a part folder, again if a file appeared in it meanwhile: a cluster's
    task still running when the run failed may write its object there until the
    folder is gone (then its write fails)."""
    for _ in range(tries):
        shutil.rmtree(folder, ignore_errors=True)
        if not os.path.lexists(folder):
            return
        time.sleep(0.05)


def _replace_folder(tmp: Path, path: Path, force: bool) -> None:
    """Rename the finished folder into place, moving an old one away only then
    (an empty folder is renamed over: nothing is in it to keep)."""
    empty = path.is_dir() and not path.is_symlink() and not any(path.iterdir())
    if empty or not (path.exists() or path.is_symlink()):
        os.replace(tmp, path)
        _FINISHED.append(path)
        return
    if not force or not path.is_dir() or path.is_symlink():
        raise OutputError(
            f"{path}: appeared while writing, or is not a folder; choose another name"
        )
    old = Path(tempfile.mkdtemp(dir=tmp.parent, prefix=f".{path.name}.old-"))
    os.replace(path, old / path.name)
    os.replace(tmp, path)
    _FINISHED.append(path)
    shutil.rmtree(old, ignore_errors=True)


def _tree_size(folder: Path) -> int:
    total = 0
    for root, _, files in os.walk(folder):
        for name in files:
            with contextlib.suppress(OSError):
                total += os.stat(os.path.join(root, name)).st_size
    return total


def _owner_tag() -> str:
    """``HOST~PID`` of this process, in its temporary files' names: a file left by
    a process that died without cleaning up (SIGKILL, a power cut) can then be
    told from one still being written, on this host, by another process."""
    host = re.sub(r"[^A-Za-z0-9-]", "", platform.node())[:32] or "host"
    return f"{host}~{os.getpid()}"


_OWNER = re.compile(r"\.(?P<host>[A-Za-z0-9-]+)~(?P<pid>\d+)-[^.]+\.part$")


def _remove_stale_parts(folder: Path, stem: str) -> None:
    """Remove the temporary files of earlier writes of this output whose process,
    on this host, is gone (killed by SIGKILL, or the machine went down)."""
    host = _owner_tag().split("~")[0]
    head = f".{stem}."  # the names atomic_output gives: .STEM.HOST~PID-XXXXXXXX.part
    try:
        with os.scandir(folder) as entries:
            candidates = [
                Path(e.path)
                for e in entries
                if e.name.startswith(head) and e.name.endswith(".part")
            ]
    except OSError:
        return
    for candidate in candidates:
        found = _OWNER.search(candidate.name)
        if found is None or found["host"] != host or _alive(int(found["pid"])):
            continue  # not ours to judge: another host's, or still being written
        if candidate.is_dir() and not candidate.is_symlink():  # an atomic_folder's
            shutil.rmtree(candidate, ignore_errors=True)
            continue
        with contextlib.suppress(OSError):
            candidate.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def _copy_to_stream(source: BinaryIO, stream: int | str) -> None:
    """Copy a finished temporary file to a file descriptor or a stream's path."""
    if isinstance(stream, int):
        with os.fdopen(os.dup(stream), "wb") as out:
            shutil.copyfileobj(source, out, 1 << 20)
    else:
        with open(stream, "wb") as out:
            shutil.copyfileobj(source, out, 1 << 20)


def _remove(tmp: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)


#: errno values that mean "no room": the device is full, or the user's quota is.
DISK_FULL_ERRNOS = frozenset(e for e in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if e)


def free_space(path: str | Path) -> int | None:
    """Bytes an unprivileged user may still write on the file system of
    ``path`` (a file, or its nearest existing folder), or None when unknown."""
    path = Path(os.path.abspath(path))
    for candidate in (path, *path.parents):
        try:
            st = os.statvfs(candidate)
        except OSError:
            continue
        return st.f_bavail * st.f_frsize
    return None


class DiskFullError(OutputError):
    """No room left at :attr:`path` for :attr:`needs` bytes (or more)."""

    def __init__(self, message: str, path: str | Path, needs: int, why: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.needs = needs
        self.why = why  # what was being written (the message's clause)

    def __reduce__(self):  # whole across processes: a cluster's task can meet it
        return type(self), (str(self), self.path, self.needs, self.why)


def disk_full_error(
    path: str | Path, needs: int, more: bool = False, why: str = ""
) -> DiskFullError:
    """The one-line error of a write that found no room at ``path``.

    ``disk full at PATH (needs N MiB, M MiB free)``, ``why`` (what was being
    written) and the fix. ``more`` says that ``needs`` is a lower bound (what
    had been written when the disk filled). The free space is measured now:
    call this once the partial file is gone.
    """
    free = free_space(path)
    parts = [f"needs {'more than ' if more else ''}{_amount(needs)}"] if needs > 0 else []
    parts += [f"{_amount(free)} free"] if free is not None else []
    told = f" ({', '.join(parts)})" if parts else ""
    return DiskFullError(
        f"disk full at {path}{told}{' ' + why if why else ''}; free space there or write elsewhere",
        path,
        needs,
        why,
    )


def _amount(n: int) -> str:
    """Bytes as a reader takes them in: MiB from 1 MiB (to a tenth), else KiB, else bytes
    (a nearly full disk's few KiB are not "0.0 MiB")."""
    if n >= 2**20:
        return f"{n / 2**20:.1f} MiB"
    return f"{n / 2**10:.1f} KiB" if n >= 2**10 else f"{n} bytes"


def _size(tmp: str) -> int:
    """Bytes in the temporary file ``tmp`` (0 when it is gone)."""
    try:
        return os.stat(tmp).st_size
    except OSError:
        return 0
