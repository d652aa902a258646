"""Issue 20, signals and full disks: no partial file is ever left behind.

SIGTERM and SIGHUP (what ``timeout``, ``kill``, CI cancellation and ``docker
stop`` send) are handled as Ctrl-C is: partial output removed, one line, exit
128 + N. A terminated batch takes its worker processes with it. A full disk is
a one-line error, never a SIGBUS from a sparse memory map.

The signal tests run the installed command (``python -m isoconvert``) in a
process of its own and signal it while it holds a file open in the output
folder (found through /proc, so the nameless spill files count too).
"""

from __future__ import annotations

import errno
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import dataset, small_tmpfs

from isoconvert.cli import main
from isoconvert.meshfile import read_mesh

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="uses /proc and tmpfs (Linux)"
)

INTERRUPTED = "no partial output was left"


def gyroid(n: int, period: float = 30.0) -> np.ndarray:
    """An (n, n, n) float32 gyroid: a surface through the whole box, so the mesh
    (and the time to write it) grows with the volume."""
    x = np.arange(n, dtype=np.float32) * np.float32(2 * np.pi / period)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij", sparse=True)
    return (np.sin(X) * np.cos(Y) + np.sin(Y) * np.cos(Z) + np.sin(Z) * np.cos(X)).astype(
        np.float32
    )


@pytest.fixture(scope="module")
def big_volume(tmp_path_factory) -> Path:
    """A 300^3 float32 volume (108 MB) whose level-0.1 mesh has 8.6 M triangles:
    a few seconds to convert, about one to write."""
    path = tmp_path_factory.mktemp("volume") / "gyroid.npy"
    np.save(path, gyroid(300))
    return path


def start(args: list[str]) -> subprocess.Popen:
    """``python -m isoconvert ARGS`` in a session of its own (its process group
    is its pid), with pipes for stdout and stderr."""
    return subprocess.Popen(
        [sys.executable, "-m", "isoconvert", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def open_in(pid: int, folder: Path) -> list[str]:
    """Files of ``folder`` the process ``pid`` has open (a nameless temporary
    file shows as ``folder/#inode (deleted)``)."""
    found = []
    fds = Path(f"/proc/{pid}/fd")
    try:
        links = list(fds.iterdir())
    except OSError:
        return found
    for link in links:
        try:
            target = os.readlink(link)
        except OSError:
            continue
        if target.startswith(f"{folder}/"):
            found.append(target)
    return found


def wait_until(proc: subprocess.Popen, ready, what: str, timeout: float = 90.0) -> None:
    """Poll ``ready()`` every 10 ms until it is true; fail if the process ends first."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if ready():
            return
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the command ended ({proc.returncode}) before {what}: {err.decode()}")
        time.sleep(0.01)
    proc.kill()
    pytest.fail(f"no {what} within {timeout} s")


def part_files(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.endswith(".part")]


def interrupted_line(signum: int) -> str:
    by = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
    return f"isoconvert: interrupted{by}; {INTERRUPTED}"


def assert_names_kept(line: str, signum: int, kept: list[Path]) -> None:
    """``line`` is the interrupted line, naming how many outputs were kept (those
    finished before the signal) and the last of them, one of ``kept``."""
    if not kept:
        assert line == interrupted_line(signum)
        return
    head = interrupted_line(signum)
    if len(kept) == 1:
        assert line == f"{head}; 1 output finished before it kept: {kept[0]}"
        return
    head += f"; {len(kept)} outputs finished before it kept, the last "
    assert line.startswith(head) and Path(line.removeprefix(head)) in kept, line


def group_members(pgid: int) -> list[tuple[int, str]]:
    """(pid, state) of the processes of process group ``pgid``, zombies left out
    (a zombie is dead: it runs nothing and holds no file open)."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()  # state, ppid, pgrp, ...
        if int(fields[2]) == pgid and fields[0] not in "ZX":
            members.append((int(entry), fields[0]))
    return members


def kill_group(pgid: int) -> None:
    """SIGKILL what is left of process group ``pgid`` (a test that failed)."""
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


# --- convert: SIGTERM, SIGHUP, SIGINT -----------------------------------------------------------

CASES = {
    # a file-backed volume: block-wise, one slab, the mesh in memory
    "one-slab": ["--level", "0.1"],
    # a mesh past a quarter of --max-memory moves to a nameless file in the output folder
    "spilled": ["--level", "0.1", "--max-memory", "64M"],
    # two levels: the volume is read into memory once, the in-memory path
    "in-memory": ["--level", "0.1", "--level", "0.3"],
}


@pytest.mark.parametrize(
    "case, signum",
    [
        ("one-slab", signal.SIGTERM),
        ("one-slab", signal.SIGHUP),
        ("one-slab", signal.SIGINT),
        ("spilled", signal.SIGTERM),
        ("spilled", signal.SIGHUP),
        ("in-memory", signal.SIGTERM),
    ],
)
def test_signal_while_writing_leaves_nothing(tmp_path, big_volume, case, signum):
    out = tmp_path / "out"
    out.mkdir()
    proc = start(["convert", str(big_volume), "-o", str(out / "g.ply"), "-q", *CASES[case]])
    wait_until(proc, lambda: part_files(out), "a .part file in the output folder")
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signum, err.decode()
    assert err.decode().strip().splitlines() == [interrupted_line(signum)]
    assert list(out.iterdir()) == []


def test_an_interrupted_run_names_the_outputs_it_finished_and_kept(tmp_path, capsys, monkeypatch):
    """Ctrl-C while the third of five labels' files is written: those written
    whole stay, the third leaves nothing, and the one line says how many outputs
    were kept and names the last (the "wrote" lines come only at the end of a
    run). Without any finished, the line is as before."""
    import isoconvert.label_convert as label_convert

    volume = np.zeros((5, 12, 12), np.uint8)
    for n in range(5):
        volume[n, 2:6, 2 * n + 1 : 2 * n + 2] = n + 1
    np.save(tmp_path / "labels.npy", volume)
    real, calls = label_convert.write_mesh, []

    def write_mesh(mesh, path, **kwargs):
        calls.append(path)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(mesh, path, **kwargs)

    monkeypatch.setattr(label_convert, "write_mesh", write_mesh)
    args = ["convert", str(tmp_path / "labels.npy"), "--labels", "-o", str(tmp_path / "m.ply")]
    assert main([*args, "-q"]) == 130
    # the labels are written on threads: those already started may finish
    kept = sorted(p for p in tmp_path.iterdir() if p.suffix == ".ply")
    assert Path(calls[2]) not in kept and 2 <= len(kept) <= 4
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert_names_kept(line, signal.SIGINT, kept)

    def interrupted(mesh, path, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(label_convert, "write_mesh", interrupted)  # nothing finishes
    assert main([*args, "-f", "-q"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [interrupted_line(signal.SIGINT)]


def test_sigterm_while_the_mesh_spills_leaves_nothing(tmp_path, big_volume):
    """Signalled during extraction, while the mesh lives in its spill files
    (before any output file exists): nothing is left in the folder."""
    out = tmp_path / "out"
    out.mkdir()
    proc = start(["convert", str(big_volume), "-o", str(out / "g.ply"), "-q", *CASES["spilled"]])
    wait_until(proc, lambda: open_in(proc.pid, out), "a spill file open in the output folder")
    assert not part_files(out)  # still extracting: the file open is a spill file
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err.decode()
    assert err.decode().strip().splitlines() == [interrupted_line(signal.SIGTERM)]
    assert list(out.iterdir()) == []


# --- batch: terminated with its workers ---------------------------------------------------------


@pytest.mark.parametrize("group", [False, True], ids=["parent", "process group"])
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL, signal.SIGHUP])
def test_terminated_batch_takes_its_workers_with_it(tmp_path, big_volume, signum, group):
    if group and signum == signal.SIGKILL:
        pytest.skip("SIGKILL to every process leaves nobody to remove the partial files")
    """SIGTERM to a 2-worker batch mid-run: within a few seconds no process of
    its group is left, stdout reaches EOF, no .part file remains and no mesh
    appears afterwards. SIGKILL (no handler runs in the parent): the workers
    stop by themselves once their parent is gone, removing their partial files."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    for n in range(4):  # hard links: four files to discover, one copy on disk
        os.link(big_volume, inputs / f"g{n}.npy")
    out = tmp_path / "out"
    proc = start(["batch", str(inputs), "-o", str(out), "--level", "0.1", "--jobs", "2", "-q"])
    wait_until(proc, lambda: out.is_dir() and part_files(out), "a .part file from a worker")
    finished = {p.name for p in out.iterdir() if not p.name.endswith(".part")}
    workers = [pid for pid, _ in group_members(proc.pid) if pid != proc.pid]
    assert workers  # the worker processes (and multiprocessing's resource tracker)
    if group:  # a closed terminal signals every process of the group at once
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    start_wait = time.monotonic()
    try:
        _, err = proc.communicate(timeout=15)  # EOF: nobody holds the pipes any more
    except subprocess.TimeoutExpired:
        kill_group(proc.pid)
        pytest.fail("the batch's pipes stayed open 15 s after it was signalled (orphaned workers)")
    assert time.monotonic() - start_wait < 12
    lines = err.decode().strip().splitlines()
    if signum != signal.SIGKILL:  # one line, no worker's or tracker's traceback
        assert proc.returncode == 128 + signum, err.decode()
        assert len(lines) == 1 and lines[0].startswith(interrupted_line(signum)), lines
    else:
        assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 5
    while group_members(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = group_members(proc.pid)
    kill_group(proc.pid)  # so that a failing run leaves no orphan behind either
    assert alive == []
    time.sleep(1.0)  # a worker left alive would write its mesh now
    left = {p.name for p in out.iterdir()} if out.is_dir() else set()
    assert not [name for name in left if name.endswith(".part")]
    assert left <= finished
    if signum != signal.SIGKILL:  # what the line says was kept is there, whole
        assert_names_kept_at_most(lines[0], signum, [out / name for name in left])


def assert_names_kept_at_most(line: str, signum: int, whole: list[Path]) -> None:
    """``line`` is the interrupted line of a batch whose workers finished ``whole``:
    it names as kept no more of them than there are (a worker stopped between its
    rename and its report is not counted) and, naming any, the last is one of them."""
    head = interrupted_line(signum)
    if line == head:
        return
    found = re.fullmatch(
        re.escape(head) + r"; (\d+) outputs? finished before it kept(?:: |, the last )(.+)", line
    )
    assert found, line
    assert 1 <= int(found[1]) <= len(whole) and Path(found[2]) in whole, line


def test_an_interrupted_batch_names_the_files_its_workers_finished(tmp_path):
    """Ctrl-C to a 2-worker batch once some files are written: the one line names
    how many its workers had finished and the last (the workers report the files
    they renamed into place; before, the line said nothing of them), each of them
    whole on disk, and no partial file."""
    inputs = tmp_path / "in"
    inputs.mkdir()
    for n in range(12):
        np.save(inputs / f"g{n:02d}.npy", gyroid(96 + 8 * n))
    out = tmp_path / "out"
    proc = start(["batch", str(inputs), "-o", str(out), "--level", "0.1", "--jobs", "2", "-q"])

    def written() -> list[Path]:
        return [p for p in out.iterdir() if p.suffix == ".ply"] if out.is_dir() else []

    wait_until(proc, lambda: len(written()) >= 2, "two finished files")
    time.sleep(0.3)  # their workers' reports reach the batch
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    lines = err.decode().strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1, err.decode()
    whole = written()
    assert lines[0] != interrupted_line(signal.SIGINT), lines[0]
    assert_names_kept_at_most(lines[0], signal.SIGINT, whole)
    assert not part_files(out)
    for path in whole:
        assert read_mesh(path).n_cells > 0


# --- full disks ---------------------------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path):
    """A 12 MiB tmpfs at tmp_path/full (needs root); unmounted afterwards."""
    with small_tmpfs(tmp_path / "full", "12m") as folder:
        yield folder


DISK_FULL = re.compile(
    r"^isoconvert: error: disk full at (?P<path>\S+) \(needs more than (?P<needs>[\d.]+) MiB, "
    r"(?P<free>[\d.]+) MiB free\)"
)


def disk_full_line(err: str, path: Path) -> re.Match:
    """The one error line, ``disk full at PATH (needs more than N MiB, M MiB free)``,
    with M what the (now empty) file system has free and N at least that."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    found = DISK_FULL.match(lines[0])
    assert found, lines[0]
    assert found["path"] == str(path)
    stat = os.statvfs(path if path.is_dir() else path.parent)
    assert float(found["free"]) == pytest.approx(stat.f_bavail * stat.f_frsize / 2**20, abs=0.06)
    # what the disk held when it filled (the temporary file) is what it has free again
    assert float(found["needs"]) >= float(found["free"])
    return found


@pytest.mark.parametrize(
    "make, args",
    [
        # the case: spilled at 2 MiB, the file fails to grow past 12 MiB
        ("engine", ["--level", "60", "--max-memory", "8M"]),
        # a 34 MiB mesh at once: the spill file cannot be made
        ("gyroid", ["--level", "0.1", "--max-memory", "64M"]),
    ],
)
def test_full_disk_while_the_mesh_spills_is_one_line(tmp_path, small_disk, big_volume, make, args):
    """Was SIGBUS (exit 135, no message): the spill file was a sparse memory map."""
    source = dataset("engine_256x256x128_uint8.raw") if make == "engine" else big_volume
    done = subprocess.run(
        [sys.executable, "-m", "isoconvert", "convert", str(source)]
        + ["-o", str(small_disk / "m.ply"), "-q", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 1, (done.returncode, done.stderr)
    disk_full_line(done.stderr, small_disk)
    assert "the mesh being built" in done.stderr and "--max-memory" in done.stderr
    assert list(small_disk.iterdir()) == []


@pytest.mark.parametrize(
    "size, budget, what",
    [
        ("12m", "4M", "for the label slabs"),
        ("12m", "16M", "for the label slabs"),
        # room for the slabs' files, not for them and the merged net's beside them
        ("40m", "16M", "for the label surfaces' net"),
    ],
)
def test_full_disk_while_label_slabs_and_their_net_wait_on_disk(tmp_path, size, budget, what):
    """A label layer whose slabs and merged net (38 MB) wait beside the output on a
    small disk: one line naming the disk and what filled it, exit 1, nothing left."""
    labels = np.random.default_rng(4).integers(0, 4, (64, 64, 64)).astype(np.uint8)
    np.save(tmp_path / "noise.npy", labels)
    with small_tmpfs(tmp_path / "disk", size) as disk:
        done = subprocess.run(
            [sys.executable, "-m", "isoconvert", "convert", str(tmp_path / "noise.npy")]
            + ["--label", "1,2,3", "--format", "precomputed", "--smooth", "2"]
            + ["--block-size", "8", "--max-memory", budget, "-o", str(disk / "layer"), "-q"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 1, (done.returncode, done.stderr)
        disk_full_line(done.stderr, disk)
        assert what in done.stderr and "--max-memory" in done.stderr
        assert list(disk.iterdir()) == []


WRITERS = ["ply", "stl", "obj", "off", "vtp", "glb", "3mf"]


@pytest.fixture(scope="module")
def mid_volume(tmp_path_factory) -> Path:
    """A 160^3 gyroid of period 15: a mesh of 2.6 M triangles, a file of 22 MB (3MF)
    to 130 MB in every format, never spilled (below a quarter of the default budget)."""
    path = tmp_path_factory.mktemp("mid") / "gyroid.npy"
    np.save(path, gyroid(160, 15.0))
    return path


@pytest.mark.parametrize("suffix", WRITERS)
def test_full_disk_at_the_final_write_is_one_line(small_disk, mid_volume, capsys, suffix):
    """Every writer, writing into a full disk: exit 1, one line naming the file,
    and the temporary file removed."""
    target = small_disk / f"g.{suffix}"
    code = main(["convert", str(mid_volume), "-o", str(target), "--level", "0.1", "-q"])
    err = capsys.readouterr().err
    assert code == 1, err
    disk_full_line(err, target)
    assert list(small_disk.iterdir()) == []


@pytest.mark.parametrize("suffix", ["ply", "3mf"])
def test_full_disk_while_streaming_a_spilled_mesh(tmp_path, small_disk, big_volume, suffix):
    """A mesh spilled to files elsewhere, streamed by the writer into a full disk:
    the error, and neither the output's folder nor the spill folder keeps a file."""
    from isoconvert import convert
    from isoconvert.convert import ConvertOptions
    from isoconvert.errors import OutputError
    from isoconvert.extract.blocks import Blocks

    spill = tmp_path / "spill"
    spill.mkdir()
    options = ConvertOptions(blocks=Blocks(max_memory=64 << 20, spill_dir=spill))
    target = small_disk / f"g.{suffix}"
    with pytest.raises(OutputError) as caught:
        convert(big_volume, target, 0.1, options)
    disk_full_line(f"isoconvert: error: {caught.value}", target)
    assert list(small_disk.iterdir()) == []
    assert list(spill.iterdir()) == []


def test_reserve_disk_falls_back_to_writing_zeros(small_disk, monkeypatch):
    """Where posix_fallocate is not supported, the blocks are written: the file
    then owns them (st_blocks), and a request past the free space is refused
    with the file as it was."""
    from isoconvert.atomic import DiskFullError
    from isoconvert.memory import reserve_disk

    def unsupported(fd, offset, length):
        raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    monkeypatch.setattr(os, "posix_fallocate", unsupported)
    with open(small_disk / "f", "wb+") as fh:
        reserve_disk(fh.fileno(), 3 << 20, small_disk)
        st = os.fstat(fh.fileno())
        assert st.st_size == 3 << 20 and st.st_blocks * 512 >= 3 << 20  # not sparse
        with pytest.raises(DiskFullError, match=f"disk full at {small_disk} "):
            reserve_disk(fh.fileno(), 20 << 20, small_disk)
        assert os.fstat(fh.fileno()).st_size == 3 << 20


def test_reserve_disk_makes_a_map_safe(small_disk):
    """The blocks are reserved before the map is used: writing every page of a
    FileMap that filled the disk works (a sparse map would SIGBUS), and one
    more than fits is refused before mapping."""
    from isoconvert.atomic import DiskFullError
    from isoconvert.memory import FileMap

    with open(small_disk / "f", "wb+") as fh:
        mapped = FileMap.create(fh.fileno(), 8 << 20, small_disk)
        mapped[:] = b"\x01" * len(mapped)
        with pytest.raises(DiskFullError):
            mapped.grow(16 << 20)
        assert len(mapped) == 8 << 20
        mapped.close()


def test_a_signal_just_after_the_temporary_file_is_made_leaves_nothing(tmp_path, monkeypatch):
    """SIGTERM arriving between mkstemp and the block that removes the file on
    failure (the window a test polling for the .part file hits) is held until
    that block is entered: the file goes, and the run stops."""
    import tempfile

    from isoconvert import signals
    from isoconvert.atomic import atomic_output

    real_mkstemp = tempfile.mkstemp

    def mkstemp_then_signal(*args, **kwargs):
        made = real_mkstemp(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGTERM)  # handled here, before mkstemp returns
        return made

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp_then_signal)
    with signals.handled(), pytest.raises(signals.Interrupted) as caught:
        with atomic_output(tmp_path / "m.ply") as fh:
            fh.write(b"never")
    assert caught.value.signum == signal.SIGTERM and caught.value.exit_code == 143
    assert list(tmp_path.iterdir()) == []


def test_handlers_keep_nohup_and_hold_a_repeated_signal_during_cleanup():
    """A SIGHUP ignored at start (``nohup``) stays ignored; a second SIGTERM
    while the first one's cleanup runs does not cut that cleanup short; the
    handlers before are put back afterwards."""
    from isoconvert import signals

    before_hup = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    before_term = signal.getsignal(signal.SIGTERM)
    cleaned = False
    try:
        with signals.handled():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGHUP)  # ignored: nothing raised
            with pytest.raises(signals.Interrupted):
                try:
                    os.kill(os.getpid(), signal.SIGTERM)
                    time.sleep(1)  # the handler raises here
                finally:
                    os.kill(os.getpid(), signal.SIGTERM)  # held: the cleanup goes on
                    time.sleep(0.05)
                    cleaned = True
            assert signals.received() == signal.SIGTERM
        assert signal.getsignal(signal.SIGTERM) is before_term
    finally:
        signal.signal(signal.SIGHUP, before_hup)
    assert cleaned


def test_full_temporary_folder_of_a_stream_output_names_that_folder(
    small_disk, mid_volume, capsys, monkeypatch
):
    """-o /dev/null is made in the temporary folder first: when that fills, the
    one line names the folder (and TMPDIR), not the stream, and leaves nothing."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(small_disk))
    code = main(["convert", str(mid_volume), "-o", "/dev/null", "--format", "ply", "-l", "0.1"])
    err = capsys.readouterr().err
    assert code == 1, err
    found = disk_full_line(err, small_disk)
    assert "TMPDIR" in err and "/dev/null" in err, found
    assert list(small_disk.iterdir()) == []


@pytest.mark.parametrize("name", ["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_while_the_command_starts_is_one_line(name):
    """While typer and the commands are imported (a fifth of a second), a signal
    stopped the command with a traceback (SIGINT) or without a word (TERM, HUP)."""
    code = (
        "import os, signal, sys, time\n"
        "import isoconvert.entry as entry\n"
        "assert 'typer' not in sys.modules  # the entry point starts light\n"
        "entry._quiet_start()\n"
        f"os.kill(os.getpid(), signal.{name})\n"
        "time.sleep(10)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    signum = getattr(signal, name)
    assert done.returncode == 128 + signum, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert lines[0] == f"isoconvert: interrupted ({name}) while starting; nothing was written"


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_while_label_files_are_written_side_by_side(tmp_path, signum):
    """Label files are written by two threads at once: a signal to the main thread
    cancels the ones not started, waits for those being written, and leaves only
    whole files, each the bytes of an uninterrupted run."""
    i = np.arange(96) // 12
    # 512 labels, 12-voxel cubes: hundreds of files to write
    labels = (1 + i[:, None, None] * 64 + i[None, :, None] * 8 + i[None, None, :]).astype(np.uint16)
    np.save(tmp_path / "labels.npy", labels)
    reference = tmp_path / "reference"
    reference.mkdir()
    assert main(["convert", str(tmp_path / "labels.npy"), "--labels", "--smooth", "0", "-q",
                 "-o", str(reference / "l.ply")]) == 0  # fmt: skip
    out = tmp_path / "out"
    out.mkdir()
    proc = start(["convert", str(tmp_path / "labels.npy"), "--labels", "--smooth", "0", "-q",
                  "-o", str(out / "l.ply")])  # fmt: skip
    wait_until(proc, lambda: part_files(out), "a .part file in the output folder")
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signum, err.decode()
    written = list(out.iterdir())
    (line,) = err.decode().strip().splitlines()
    assert_names_kept(line, signum, written)
    assert part_files(out) == []
    assert len(written) < len(list(reference.iterdir()))  # it was stopped part of the way
    for path in written:
        assert path.read_bytes() == (reference / path.name).read_bytes(), path.name


@pytest.mark.parametrize(
    "needs, free, told",
    [
        (3 * 2**20 + 2**19, 12 * 2**20, "(needs more than 3.5 MiB, 12.0 MiB free)"),
        (900_000, 8192, "(needs more than 878.9 KiB, 8.0 KiB free)"),
        (2**20, 512, "(needs more than 1.0 MiB, 512 bytes free)"),
    ],
)
def test_a_full_disk_names_small_amounts_in_kib_or_bytes(tmp_path, monkeypatch, needs, free, told):
    """Below 1 MiB the line gives KiB (or bytes), not "0.0 MiB"."""
    from isoconvert import atomic

    monkeypatch.setattr(atomic, "free_space", lambda path: free)
    error = atomic.disk_full_error(tmp_path / "m.ply", needs, more=True)
    assert (
        str(error)
        == f"disk full at {tmp_path / 'm.ply'} {told}; free space there or write elsewhere"
    )


def test_a_signal_while_the_interpreter_shuts_down_after_a_run_prints_no_traceback(tmp_path):
    """A Ctrl-C that comes once the run has ended (its outputs in place), while the
    exit callbacks run (nanobind registers one for the kernels), is ignored: no
    "Exception ignored in atexit callback" traceback, and the run's exit code."""
    script = tmp_path / "late.py"
    script.write_text(
        "import atexit, os, signal, sys, time\n"
        "import isoconvert.cli\n"
        "from isoconvert import entry\n"
        "def late():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(0.3)\n"
        "isoconvert.cli.main = lambda: atexit.register(late) and 0\n"
        "sys.argv = ['isoconvert']\n"
        "entry.run()\n"
    )
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True)
    assert (run.returncode, run.stderr) == (0, "")
