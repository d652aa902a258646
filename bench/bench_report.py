"""Mesh-report speed and memory on a large mesh, against extraction and trimesh (issue 9).

Run: ``python bench/bench_report.py [--size N] [--level L] [--repeat R]``. Extracts the
gyroid of bench_extract.py (sin x cos y + sin y cos z + sin z cos x over two periods;
N = 512 and level 0.1 give 2,535,582 vertices and 5,052,860 triangles), then, in one run:

- extraction (``isoconvert.extract``) and ``isoconvert.report.check_mesh`` (every check,
  fans per vertex, components, examples) in this process, best of R, and the first
  check on its own, which pays for fresh memory as a command does;
- trimesh on the same arrays (``process=False``, a new object each round, so nothing is
  cached): ``is_watertight``, ``is_winding_consistent`` and ``euler_number``, best of R;
- ``isoconvert check FILE`` on the mesh written as binary PLY to a temporary folder, as
  a process (interpreter start, imports, reading, checking, printing), best of R, with
  its peak resident memory, taken apart as the interpreter with its imports (a process
  that imports and stops), the mesh's arrays, and the rest; next to it a process that
  only reads the file (``read_mesh``).

The targets of issue 9: the check at most twice the extraction, the command's peak
under 1.5 GB. Nothing is written inside the repository.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_extract import gyroid
from bench_process import timed_process

import isoconvert
from isoconvert.report import check_mesh

#: The interpreter with what ``check`` imports, and no mesh.
IMPORTS_ONLY = "import numpy, isoconvert.meshfile, isoconvert.report, isoconvert._native\n"
READ_ONLY = (
    "import sys\n"
    "from isoconvert.meshfile import read_mesh\n"
    "mesh = read_mesh(sys.argv[1])\n"
    "print(mesh.n_cells)\n"
)


def best(fn, repeat: int) -> tuple[float, object]:
    """Smallest wall time of ``repeat`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return min(times), result


def run_process(args: list[str]) -> tuple[float, int]:
    """Wall time (s) and peak resident memory (bytes) of one process."""
    wall, peak_kib, code = timed_process(args, stderr=subprocess.PIPE)
    if code != 0:
        raise RuntimeError(f"{' '.join(args)} exited with {code}")
    return wall, peak_kib * 1024  # ru_maxrss is in KiB on Linux


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=512, help="grid size N (N^3 samples)")
    parser.add_argument("--level", type=float, default=0.1)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    volume = isoconvert.Volume(gyroid(args.size)().T)  # (z, y, x) C order -> x fastest
    t_extract, mesh = best(lambda: isoconvert.extract(volume, args.level), args.repeat)
    mesh_mb = (mesh.vertices.nbytes + mesh.cells.nbytes) / 2**20
    print(
        f"gyroid {args.size}^3, level {args.level}: {mesh.n_vertices:,} vertices, "
        f"{mesh.n_cells:,} triangles ({mesh_mb:.0f} MiB as float64 and int64)"
    )

    start = time.perf_counter()
    report = check_mesh(mesh)
    t_first = time.perf_counter() - start
    t_check, _ = best(lambda: check_mesh(mesh), args.repeat)

    import trimesh

    def trimesh_checks():
        tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
        return tm.is_watertight, tm.is_winding_consistent, tm.euler_number

    t_trimesh, facts = best(trimesh_checks, args.repeat)
    assert report.checks["watertight"] == facts[0], (report.checks, facts)
    assert report.topology["euler_characteristic"] == facts[2], (report.topology, facts)

    folder = Path(tempfile.mkdtemp(prefix="bench_report_"))
    try:
        path = isoconvert.write_mesh(mesh, folder / "gyroid.ply")
        command = shutil.which("isoconvert") or "isoconvert"
        runs = [run_process([command, "check", str(path)]) for _ in range(args.repeat)]
        reads = [run_process([sys.executable, "-c", READ_ONLY, str(path)]) for _ in range(2)]
        base = max(run_process([sys.executable, "-c", IMPORTS_ONLY])[1] for _ in range(2))
        file_mb = path.stat().st_size / 2**20
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    t_cli = min(w for w, _ in runs)
    peak = max(m for _, m in runs) / 2**20
    read_peak = max(m for _, m in reads) / 2**20

    ratio = t_check / t_extract
    print(f"{'extract (in process)':34s} {t_extract:7.3f} s")
    print(
        f"{'check_mesh (in process)':34s} {t_check:7.3f} s   first call {t_first:.3f} s   "
        f"{ratio:.2f} x extraction ({'ok' if ratio <= 2 else 'OVER'} <= 2)"
    )
    print(
        f"{'trimesh watertight/winding/Euler':34s} {t_trimesh:7.3f} s   "
        f"({t_trimesh / t_check:.1f} x check_mesh)"
    )
    print(
        f"{'isoconvert check FILE (process)':34s} {t_cli:7.3f} s   binary PLY {file_mb:.0f} MiB, "
        f"a process that only reads it {min(w for w, _ in reads):.3f} s"
    )
    base_mb = base / 2**20
    print(
        f"{'peak memory of the command':34s} {peak:7.0f} MiB ({'ok' if peak < 1536 else 'OVER'}"
        f" < 1536): {base_mb:.0f} MiB interpreter and imports, {mesh_mb:.0f} MiB mesh, "
        f"{peak - base_mb - mesh_mb:.0f} MiB more; a process that only reads the file peaks "
        f"at {read_peak:.0f} MiB (the file is mapped while read)"
    )


if __name__ == "__main__":
    main()
