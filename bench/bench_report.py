"""Mesh-report speed on large meshes, against trimesh's own checks.

Run: ``python bench/bench_report.py``. Extracts a large surface from the embryo
scan (about 5 million triangles at the default level), then times
``isoconvert.report.check_mesh`` against trimesh computing the checks it has
(is_watertight, is_winding_consistent, euler_number, split into bodies) on the
same arrays with ``process=False``. Prints seconds and the ratio (> 1: trimesh
is slower).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import isoconvert
from isoconvert.report import check_mesh

DATASETS = Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scan", default="embryo_256x256x256_uint8.raw")
    parser.add_argument("--level", type=float, default=30.5)
    parser.add_argument("--method", default="tetra")
    args = parser.parse_args()
    path = DATASETS / args.scan
    if not path.exists():
        print(f"skipped: {path} not found")
        return
    mesh = isoconvert.extract(isoconvert.read_volume(path), args.level, method=args.method)
    print(
        f"{args.scan} level {args.level} {args.method}: {mesh.n_vertices:,} vertices, "
        f"{mesh.n_cells:,} triangles"
    )
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
    print(f"isoconvert check_mesh  {ours:8.2f} s  (all checks, components, fans, examples)")
    print(f"trimesh                {theirs:8.2f} s  (watertight, winding, Euler, split)")
    print(f"ratio trimesh / isoconvert: {theirs / ours:.2f}")
    assert report.checks["watertight"] == facts[0]
    assert report.topology["euler_characteristic"] == facts[2] - int(
        np.sum(np.bincount(mesh.cells.ravel(), minlength=mesh.n_vertices) == 0)
    )


if __name__ == "__main__":
    main()
