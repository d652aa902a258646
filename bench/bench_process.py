"""Whole commands: isoconvert against a scikit-image + trimesh script and a VTK script (issue 9).

Run ``python bench/bench_process.py`` (``--quick`` for one round, ``--repeat N``). Each
timing is one process from start to exit, as a user's shell sees it (started and waited
for by a small interpreter of its own, :data:`TIMER`, which also reads its peak memory;
interpreter start, imports, reading, extraction, writing), best and median of the rounds:

- ``isoconvert --help``;
- warm conversions to binary PLY of the engine scan (256x256x128 uint8, level 80.5) and of
  a 512^3 float32 gyroid written as a raw file to a temporary folder (level 0.1, about
  5 million triangles): ``isoconvert convert`` against two small scripts written to the
  same temporary folder, ``np.fromfile`` + ``skimage.measure.marching_cubes`` (lewiner) +
  ``trimesh`` binary PLY export (``process=False``: no vertex merging), and ``np.fromfile``
  + ``vtkFlyingEdges3D`` (normals, gradients and scalars off; STDThread backend, 2 threads)
  + ``vtkPLYWriter`` (binary). "Warm": each command runs once untimed first, so the input
  file is in the page cache; then the rounds run the commands in a rotating order. The
  vertex and face counts are read back from the PLY headers and isoconvert's are checked
  against VTK's;
- a cold first run: ``isoconvert convert sample_volumes/sphere.nrrd`` with
  ``XDG_CACHE_HOME`` pointing at a new empty folder each time, as right after
  ``pip install .`` (the kernels are compiled at install, so nothing may be compiled or
  cached here; the operating system's file cache is not emptied, since that needs root
  and disturbs the whole machine), next to the same command warm.

Before timing, the isoconvert package is byte-compiled as ``pip install .`` does: an
editable install run with ``PYTHONDONTWRITEBYTECODE`` set would otherwise compile every
module from source in every process (about 70 ms here), which no installed copy does.
That writes ``__pycache__`` folders (ignored by git) into the package; nothing else is
written inside the repository.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from bench_extract import DATASETS, gyroid

REPO = Path(__file__).resolve().parent.parent
SPHERE = REPO / "sample_volumes" / "sphere.nrrd"
VTK_THREADS = 2

SKIMAGE_SCRIPT = '''\
"""np.fromfile + skimage.measure.marching_cubes + trimesh binary PLY."""
import sys

import numpy as np
import trimesh
from skimage.measure import marching_cubes

path, nx, ny, nz, dtype, level, out = sys.argv[1:]
vol = np.fromfile(path, dtype=dtype).reshape(int(nz), int(ny), int(nx))
verts, faces, _, _ = marching_cubes(vol, float(level))
# (z, y, x) -> (x, y, z); swapping axes mirrors, so reverse the faces to keep orientation
mesh = trimesh.Trimesh(verts[:, ::-1], faces[:, ::-1], process=False)
mesh.export(out, file_type="ply", encoding="binary")
'''

VTK_SCRIPT = '''\
"""np.fromfile + vtkFlyingEdges3D + vtkPLYWriter (binary)."""
import sys

import numpy as np
import vtk
from vtk.util import numpy_support

path, nx, ny, nz, dtype, level, out, backend, threads = sys.argv[1:]
vtk.vtkSMPTools.SetBackend(backend)
vtk.vtkSMPTools.Initialize(int(threads))
vol = np.fromfile(path, dtype=dtype)
image = vtk.vtkImageData()
image.SetDimensions(int(nx), int(ny), int(nz))
image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(vol, deep=False))
fe = vtk.vtkFlyingEdges3D()
fe.SetInputData(image)
fe.SetValue(0, float(level))
fe.ComputeNormalsOff()
fe.ComputeGradientsOff()
fe.ComputeScalarsOff()
writer = vtk.vtkPLYWriter()
writer.SetInputConnection(fe.GetOutputPort())
writer.SetFileTypeToBinary()
writer.SetFileName(out)
if not writer.Write():
    sys.exit("vtkPLYWriter failed")
'''


@dataclass
class Command:
    """One command line to time.

    Attributes
    ----------
    name : str
    argv : list of str
    output : Path or None
        The mesh file it writes (its header gives the counts).
    env : dict or None
        Environment (None: this process's).
    seconds : list of float
    note : str
        Why it was dropped, if it failed.
    """

    name: str
    argv: list[str]
    output: Path | None = None
    env: dict[str, str] | None = None
    seconds: list[float] = field(default_factory=list)
    note: str = ""
    peak_kib: int = 0


#: Starts a command and prints its wall time, peak memory (KiB) and exit code. It
#: runs in a small interpreter of its own: a child's peak includes that of the
#: process it was forked from (Linux keeps the high-water mark across fork and
#: exec), and a benchmark that measured distances in-process holds GBs.
TIMER = (
    "import os, subprocess, sys, time\n"
    "start = time.perf_counter()\n"
    "proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
    "_, status, usage = os.wait4(proc.pid, 0)\n"
    "print(time.perf_counter() - start, usage.ru_maxrss, os.waitstatus_to_exitcode(status))\n"
)


def timed_process(argv: list[str], env: dict[str, str] | None = None, stderr=None):
    """Wall time (s), peak resident memory (KiB, the process's own) and exit code of
    one run of ``argv`` (its output discarded, its error output to ``stderr``)."""
    out = subprocess.run(
        [sys.executable, "-c", TIMER, *argv], stdout=subprocess.PIPE, stderr=stderr,
        env=env, text=True, check=True,
    )  # fmt: skip
    wall, peak_kib, code = out.stdout.split()
    return float(wall), int(peak_kib), int(code)


def run_once(cmd: Command) -> float | None:
    """Run a command to its end; its wall time in seconds, or None (and a note) if it
    failed. Its peak resident memory (:func:`timed_process`) raises ``cmd.peak_kib``."""
    with tempfile.TemporaryFile() as err:
        seconds, peak_kib, code = timed_process(cmd.argv, cmd.env, err)
        cmd.peak_kib = max(cmd.peak_kib, peak_kib)
        if code != 0:
            err.seek(0)
            text = err.read().decode("utf-8", "replace")
            tail = (text.strip().splitlines() or ["no message"])[-1]
            cmd.note = f"exit code {code}: {tail}"
            return None
    return seconds


def time_rounds(commands: list[Command], repeat: int) -> None:
    """One untimed run each (a failure drops the command), then ``repeat`` rotating rounds."""
    live = [c for c in commands if run_once(c) is not None]
    for r in range(repeat if live else 0):
        k = r % len(live)
        for cmd in live[k:] + live[:k]:
            if not cmd.note and (t := run_once(cmd)) is not None:
                cmd.seconds.append(t)


def ply_counts(path: Path) -> tuple[int, int] | None:
    """Vertex and face counts from a PLY header (None if unreadable)."""
    counts = {}
    try:
        with path.open("rb") as f:
            for raw in f:
                line = raw.decode("ascii", "replace").split()
                if line[:1] == ["element"] and len(line) == 3:
                    counts[line[1]] = int(line[2])
                if line[:1] == ["end_header"]:
                    break
    except OSError:
        return None
    if "vertex" not in counts or "face" not in counts:
        return None
    return counts["vertex"], counts["face"]


def print_table(title: str, commands: list[Command], baseline: str | None = None) -> None:
    """Best, median, ratio of medians to ``baseline`` and, for mesh outputs, counts and size."""
    print(f"\n{title}")
    head = (
        f"{'command':<40}{'best s':>8}{'median s':>10}{'ratio':>8}"
        f"{'vertices':>12}{'faces':>12}{'file MB':>9}"
    )
    print(head)
    print("-" * len(head))
    base = next((c for c in commands if c.name == baseline and c.seconds), None)
    for c in commands:
        if not c.seconds:
            print(f"{c.name:<40}  not timed: {c.note or 'no successful run'}")
            continue
        med = statistics.median(c.seconds)
        ratio = f"{med / statistics.median(base.seconds):.2f}" if base else ""
        counts = ply_counts(c.output) if c.output else None
        nv, nf = (f"{counts[0]:,}", f"{counts[1]:,}") if counts else ("", "")
        size = f"{c.output.stat().st_size / 1e6:.1f}" if c.output and c.output.exists() else ""
        line = f"{c.name:<40}{min(c.seconds):>8.3f}{med:>10.3f}{ratio:>8}{nv:>12}{nf:>12}"
        print(f"{line}{size:>9}")
    if base:
        print(f"ratio = median / median of {baseline!r}")
    vtk = [c for c in commands if c.name.startswith("VTK")]
    if vtk:
        ours = ply_counts(base.output) if base and base.output else None
        theirs = ply_counts(vtk[0].output) if vtk[0].seconds else None
        verdict = "unknown" if None in (ours, theirs) else ("yes" if ours == theirs else "no")
        print(f"counts equal VTK: {verdict}")


def conversions(
    raw: Path, shape: tuple[int, int, int], dtype: str, level: float, tmp: Path, backend: str
) -> list[Command]:
    """The three commands converting one raw volume to binary PLY files in ``tmp``."""
    exe = isoconvert_exe()
    dims = [str(n) for n in shape]
    iso = tmp / "isoconvert.ply"
    sk = tmp / "skimage.ply"
    vt = tmp / "vtk.ply"
    common = [str(raw), *dims, dtype, repr(level)]
    return [
        Command(
            "isoconvert convert",
            [exe, "convert", str(raw), "--shape", *dims, "--dtype", dtype, "--level", repr(level)]
            + ["-o", str(iso), "--force", "--quiet"],
            iso,
        ),
        Command(
            "scikit-image + trimesh script",
            [sys.executable, str(tmp / "skimage_trimesh.py"), *common, str(sk)],
            sk,
        ),
        Command(
            f"VTK FE script ({backend}, {VTK_THREADS} threads)",
            [sys.executable, str(tmp / "vtk_fe.py"), *common, str(vt), backend, str(VTK_THREADS)],
            vt,
        ),
    ]


def isoconvert_exe() -> str:
    """The isoconvert command next to this interpreter, else the one on PATH."""
    beside = Path(sys.executable).parent / "isoconvert"
    if beside.exists():
        return str(beside)
    found = shutil.which("isoconvert")
    if found is None:
        sys.exit("isoconvert is not installed (pip install -e .)")
    return found


def cold_runs(tmp: Path, repeat: int) -> list[Command]:
    """The sphere sample converted with a fresh, empty cache folder per run, and warm.

    Parameters
    ----------
    tmp : Path
        Folder for the caches and the output.
    repeat : int
        Cold runs, and timed warm rounds.

    Returns
    -------
    list of Command
        The cold and the warm command, timed.
    """
    exe = isoconvert_exe()
    out = tmp / "sphere.ply"
    argv = [exe, "convert", str(SPHERE), "--level", "127.5", "-o", str(out), "--force"]
    cold = Command("isoconvert convert, empty cache", argv + ["--quiet"], out)
    for i in range(repeat):
        cache = tmp / f"cache{i}"
        cache.mkdir()
        env = dict(os.environ, XDG_CACHE_HOME=str(cache))
        cold.env = env
        if (t := run_once(cold)) is None:
            break
        cold.seconds.append(t)
        shutil.rmtree(cache)
    # what a first run says on stderr (e.g. a notice that kernels compile), once more, cold
    cache = tmp / "cache-notice"
    cache.mkdir()
    cold.env = dict(os.environ, XDG_CACHE_HOME=str(cache))
    proc = subprocess.run(argv, capture_output=True, text=True, env=cold.env)
    notice = " | ".join(proc.stderr.strip().splitlines()) or "(nothing on stderr)"
    files = [f for f in cache.rglob("*") if f.is_file()]
    size = sum(f.stat().st_size for f in files) / 1e6
    print(f"\ncold first run says: {notice}")
    print(f"and leaves {len(files)} file(s), {size:.1f} MB, in its empty cache folder")
    warm = Command("isoconvert convert, warm cache", argv + ["--quiet"], out)
    time_rounds([warm], repeat)
    return [cold, warm]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line (see ``--help``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed rounds (default 5)")
    parser.add_argument("--quick", action="store_true", help="one timed round of everything")
    parser.add_argument(
        "--no-large", action="store_true", help="leave out the 512^3 volume (a 512 MB file)"
    )
    parser.add_argument(
        "--vtk-backend",
        default="STDThread",
        choices=["STDThread", "Sequential"],
        help="vtkSMPTools backend of the VTK script (default STDThread)",
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.repeat = 1
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    return args


def byte_compile_package() -> None:
    """Byte-compile the isoconvert that the commands import, as pip does at install."""
    import compileall
    import importlib.util

    spec = importlib.util.find_spec("isoconvert")
    if spec is None or not spec.submodule_search_locations:
        return
    for folder in spec.submodule_search_locations:
        compileall.compile_dir(folder, quiet=1)


def start(rounds: int) -> str:
    """Byte-compile the package, print the machine's line, and return the isoconvert
    command to time."""
    exe = isoconvert_exe()
    byte_compile_package()
    print(
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; {rounds} timed "
        f"round(s); wall time per process; isoconvert = {exe}"
    )
    return exe


def main(argv: list[str] | None = None) -> None:
    """Run the timings and print their tables."""
    args = parse_args(argv)
    exe = start(args.repeat)
    with tempfile.TemporaryDirectory(prefix="isoconvert-bench-") as name:
        tmp = Path(name)
        (tmp / "skimage_trimesh.py").write_text(SKIMAGE_SCRIPT)
        (tmp / "vtk_fe.py").write_text(VTK_SCRIPT)

        help_cmd = Command("isoconvert --help", [exe, "--help"])
        time_rounds([help_cmd], max(args.repeat, 5))
        print_table("start-up", [help_cmd])

        engine = DATASETS / "engine_256x256x128_uint8.raw"
        if engine.exists():
            cmds = conversions(engine, (256, 256, 128), "uint8", 80.5, tmp, args.vtk_backend)
            time_rounds(cmds, args.repeat)
            print_table(
                "engine 256x256x128 uint8, level 80.5 -> binary PLY, warm",
                cmds,
                "isoconvert convert",
            )
        else:
            print(f"\nengine skipped: {engine} not found (set ISOCONVERT_DATASETS)")

        if not args.no_large:
            raw = tmp / "gyroid_512x512x512_float32.raw"
            gyroid(512)().tofile(raw)
            cmds = conversions(raw, (512, 512, 512), "float32", 0.1, tmp, args.vtk_backend)
            time_rounds(cmds, args.repeat)
            print_table(
                "gyroid 512^3 float32 raw (512 MB), level 0.1 -> binary PLY, warm",
                cmds,
                "isoconvert convert",
            )
            raw.unlink()

        cmds = cold_runs(tmp, min(args.repeat, 3))
        print_table(
            "first run: sample_volumes/sphere.nrrd (40^3 uint8), level 127.5",
            cmds,
            "isoconvert convert, warm cache",
        )
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
