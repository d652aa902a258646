"""Label surfaces: isoconvert's ``label_surfaces`` against VTK's ``vtkSurfaceNets3D``.

Run ``python bench/bench_labels.py`` (``--rounds N``, ``--iterations 0 16``). Two volumes:

- the bat cochlea scan (``bat-cochlea-volume.tif``, 121x154x114, binary 0/255), from
  ``../shared/datasets`` (or ``$ISOCONVERT_DATASETS``); skipped when missing;
- a synthetic 256^3 atlas of 40 labels (uint8): the Voronoi cells of 40 random seeds
  (fixed seed) in warped coordinates, inside a ball, background outside it. Warping the
  coordinates bends the cell walls, so the labels meet along curved, staircased
  surfaces with edge and corner contacts, as in a real segmentation.

For each volume and number of smoothing iterations, isoconvert (every label present
but the background, as ``isoconvert convert --labels`` does) and VTK (same labels, same
iterations, relaxation 0.5, triangle output; smoothing off for 0 iterations) run in
interleaved rounds, after one untimed warm-up run each, and the best and median times
and their ratio are printed. VTK runs on its STDThread backend with as many threads as
isoconvert's kernels (``ISOCONVERT_THREADS`` or every CPU). Timings include finding the
labels, extraction, smoothing and, for isoconvert, the per-label meshes; not reading.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

DATASETS = Path(os.environ.get("ISOCONVERT_DATASETS") or REPO.parent / "shared" / "datasets")


def synthetic_atlas(n: int = 256, labels: int = 40, seed: int = 7):
    """An (n, n, n) uint8 atlas of ``labels`` Voronoi cells in a ball (see the module notes)."""
    from isoconvert.volume import Volume

    rng = np.random.default_rng(seed)
    seeds = rng.uniform(0.15 * n, 0.85 * n, size=(labels, 3))
    axis = np.arange(n, dtype=np.float32)
    out = np.zeros((n, n, n), dtype=np.uint8)  # (Z, Y, X), as the volume readers give it
    y, z = np.meshgrid(axis, axis, indexing="ij")
    for i in range(n):  # one z slab at a time: bounded memory
        x = np.full_like(y, i)  # the slab's coordinate, the same formula along each axis
        # warped coordinates: the walls between cells become curved surfaces
        wx = x + 6 * np.sin(y / 17.0)
        wy = y + 6 * np.sin(z / 23.0)
        wz = z + 6 * np.sin(x / 19.0)
        best = np.full(y.shape, np.inf, dtype=np.float32)
        slab = np.zeros(y.shape, dtype=np.uint8)
        for label, (sx, sy, sz) in enumerate(seeds, start=1):
            d = (wx - sx) ** 2 + (wy - sy) ** 2 + (wz - sz) ** 2
            closer = d < best
            best[closer] = d[closer]
            slab[closer] = label
        inside = (x - n / 2) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2 < (0.45 * n) ** 2
        out[i] = np.where(inside, slab, 0)
    # from_zyx: a view, as the readers make (an (X, Y, Z) C-ordered array would first be
    # copied to the kernels' (Z, Y, X) layout, about 0.1 s at this size)
    return Volume.from_zyx(out, spacing=(1.0, 1.0, 1.0))


def vtk_runner(volume, labels, iterations: int, threads: int):
    """A function that runs ``vtkSurfaceNets3D`` once, returning (seconds, triangles)."""
    import vtk
    from vtk.util import numpy_support

    zyx = np.ascontiguousarray(volume.data.T)
    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.SetSpacing(*volume.spacing)
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.reshape(-1), deep=False))
    smp = vtk.vtkSMPTools
    smp.SetBackend("STDThread")

    def run() -> tuple[float, int]:
        smp.Initialize(threads)
        start = time.perf_counter()
        nets = vtk.vtkSurfaceNets3D()
        nets.SetInputData(image)
        for i, value in enumerate(labels):
            nets.SetLabel(i, float(value))
        nets.SetOutputMeshTypeToTriangles()
        if iterations:
            nets.SmoothingOn()
            nets.SetNumberOfIterations(iterations)
            nets.SetRelaxationFactor(0.5)
        else:
            nets.SmoothingOff()
        nets.Update()
        seconds = time.perf_counter() - start
        return seconds, nets.GetOutput().GetNumberOfCells()

    run.keep = (image, zyx)  # the image views zyx
    return run


def ours_runner(volume, iterations: int):
    from isoconvert.extract.labels import label_surfaces

    def run() -> tuple[float, int]:
        start = time.perf_counter()
        result = label_surfaces(volume, smoothing=iterations)
        # the combined mesh and every label's are built on first access: timed too
        cells = result.combined.n_cells
        for label in result.labels:
            result[label]
        seconds = time.perf_counter() - start
        return seconds, cells

    return run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--iterations", type=int, nargs="+", default=[0, 16])
    args = parser.parse_args(argv)

    from isoconvert.threads import kernel_threads

    threads = kernel_threads()
    volumes = []
    cochlea = DATASETS / "bat-cochlea-volume.tif"
    if cochlea.exists():
        from isoconvert import read_volume

        volumes.append(("cochlea 121x154x114", read_volume(cochlea)))
    else:
        print(f"skipping the cochlea: {cochlea} not found")
    volumes.append(("atlas 256^3, 40 labels", synthetic_atlas()))

    print(f"{threads} threads; best / median of {args.rounds} interleaved rounds, seconds")
    print(
        f"{'volume':24} {'iter':>4} {'isoconvert':>17} {'VTK':>17} {'ratio':>6} {'triangles':>20}"
    )
    for name, volume in volumes:
        values = np.unique(volume.data)
        labels = [int(v) for v in values if v != 0]
        for iterations in args.iterations:
            runners = {
                "ours": ours_runner(volume, iterations),
                "vtk": vtk_runner(volume, labels, iterations, threads),
            }
            times: dict[str, list[float]] = {key: [] for key in runners}
            cells = {key: run()[1] for key, run in runners.items()}  # warm-up
            for r in range(args.rounds):
                # alternate which goes first, so neither always runs on a warmer cache
                for key in list(runners)[:: 1 if r % 2 == 0 else -1]:
                    times[key].append(runners[key]()[0])
            best = {key: min(t) for key, t in times.items()}
            median = {key: statistics.median(t) for key, t in times.items()}
            print(
                f"{name:24} {iterations:>4} "
                f"{best['ours']:8.3f} {median['ours']:8.3f} "
                f"{best['vtk']:8.3f} {median['vtk']:8.3f} "
                f"{best['ours'] / best['vtk']:6.2f} "
                f"{cells['ours']:>10} {cells['vtk']:>9}"
            )
    print("ratio: isoconvert's best time / VTK's; triangles: isoconvert (closed on the grid's")
    print("sides, non-manifold vertices split) and VTK")
    return 0


if __name__ == "__main__":
    sys.exit(main())
