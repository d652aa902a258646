"""Marching Cubes speed against VTK (vtkFlyingEdges3D, vtkMarchingCubes) and scikit-image.

Run: ``python bench/bench_extract.py`` (needs the test extras and ../shared/datasets).
Prints, per scan, the best of N runs for each tool and the ratio to isoconvert
(> 1: the peer is slower). Extraction only: reading and writing are not timed;
numba's compile happens in a warm-up run first.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

import isoconvert
from isoconvert import Volume, extract

DATASETS = Path(
    os.environ.get("ISOCONVERT_DATASETS")
    or Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"
)
SCANS = [
    ("engine_256x256x128_uint8.raw", 80.5),
    # a level equal to samples: the automatic vertex offset (and its count of equal samples)
    ("engine_256x256x128_uint8.raw", 80.0),
    ("embryo_256x256x256_uint8.raw", 60.5),
    ("tooth_103x94x161_uint8.raw", 100.5),
    ("hydrogen_vtk_64x64x64_float32.raw", 0.1001),
    ("headsq_vtk/quarter.nhdr", 1000.5),
]


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def vtk_runner(zyx, level, cls_name):
    import vtk
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.ravel(), deep=True))

    def run():
        f = getattr(vtk, cls_name)()
        f.SetInputData(image)
        f.SetValue(0, level)
        f.ComputeNormalsOff()
        f.ComputeGradientsOff() if hasattr(f, "ComputeGradientsOff") else None
        f.Update()

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    from skimage.measure import marching_cubes

    print(
        f"{'scan':<38} {'isoconvert':>10} {'FlyingEdges':>12} {'vtkMC':>8} {'sk-lorensen':>12} "
        f"{'sk-lewiner':>11}   ratios (peer / isoconvert)"
    )
    for name, level in SCANS:
        path = DATASETS / name
        if not path.exists():
            print(f"{name:<38} skipped: not in {DATASETS} (set ISOCONVERT_DATASETS)")
            continue
        vol = isoconvert.read_volume(path)
        data = np.ascontiguousarray(vol.data.T).T  # in memory, as every peer gets it
        zyx = np.ascontiguousarray(data.T)
        vol = Volume(data)
        extract(vol, level)  # warm-up: compile or load numba's cache
        ours = best_of(lambda v=vol, lv=level: extract(v, lv), args.repeat)
        peers = {
            "FlyingEdges": best_of(vtk_runner(zyx, level, "vtkFlyingEdges3D"), args.repeat),
            "vtkMC": best_of(vtk_runner(zyx, level, "vtkMarchingCubes"), args.repeat),
            "sk-lorensen": best_of(
                lambda z=zyx, lv=level: marching_cubes(z, lv, method="lorensen"), args.repeat
            ),
            "sk-lewiner": best_of(lambda z=zyx, lv=level: marching_cubes(z, lv), args.repeat),
        }
        ratios = "  ".join(f"{k} {v / ours:.2f}" for k, v in peers.items())
        print(
            f"{name:<38} {ours:>10.3f} {peers['FlyingEdges']:>12.3f} {peers['vtkMC']:>8.3f} "
            f"{peers['sk-lorensen']:>12.3f} {peers['sk-lewiner']:>11.3f}   {ratios}"
        )


if __name__ == "__main__":
    main()
