"""Mesh-report speed on a large mesh, against trimesh's own checks.

Run: ``python bench/bench_report.py [--size N]``. Extracts a gyroid (one
surface of high genus, no dataset needed; N = 290 gives about 4.9 million
triangles), then times ``isoconvert.report.check_mesh`` (every check, fans per
vertex, components, examples) against trimesh computing what it has
(is_watertight, is_winding_consistent, euler_number, bodies) on the same arrays
with ``process=False``, each on fresh memory. Prints seconds and the ratio
(> 1: trimesh is slower).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import isoconvert
from isoconvert.report import check_mesh


def gyroid(n: int) -> np.ndarray:
    x = np.linspace(0, 12 * np.pi, n, dtype=np.float32)
    gx, gy, gz = np.meshgrid(x, x, x, indexing="ij")
    return np.sin(gx) * np.cos(gy) + np.sin(gy) * np.cos(gz) + np.sin(gz) * np.cos(gx)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=290, help="grid size N (N^3 samples)")
    args = parser.parse_args()
    mesh = isoconvert.extract(isoconvert.Volume(gyroid(args.size)), 0.0)
    print(f"gyroid {args.size}^3: {mesh.n_vertices:,} vertices, {mesh.n_cells:,} triangles")
    start = time.perf_counter()
    report = check_mesh(mesh)
    ours = time.perf_counter() - start
    import trimesh

    start = time.perf_counter()
    tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    facts = (
        tm.is_watertight,
        tm.is_winding_consistent,
        tm.euler_number,
        len(tm.split(only_watertight=False)),
    )
    theirs = time.perf_counter() - start
    print(f"isoconvert check_mesh  {ours:8.2f} s  (all checks, fans, components, examples)")
    print(f"trimesh                {theirs:8.2f} s  (watertight, winding, Euler, bodies)")
    print(f"ratio trimesh / isoconvert: {theirs / ours:.2f}")
    assert report.checks["watertight"] == facts[0]
    assert report.topology["euler_characteristic"] == facts[2]
    assert report.topology["components"] == facts[3]


if __name__ == "__main__":
    main()
