"""Post-processing and attributes against VTK: smoothing, decimation, normals, closing.

Run ``python bench/bench_post.py`` (``--rounds N``, ``--size N``, ``--only close`` for
one pair; the load average is printed before and after). One surface: the
gyroid ``sin x cos y + sin y cos z + sin z cos x`` at level 0.1 on an N^3 float32 grid
(two periods, N = 256 by default: 1.26 million triangles), extracted once by isoconvert
(VTK's Flying Edges gives the same vertices and triangles). Each pair below runs in
interleaved rounds after an untimed warm-up, and the best and median times and their
ratio (isoconvert / VTK) are printed:

- smoothing: ``isoconvert.post.smooth.smooth(mesh, 50, "sinc")`` against
  ``vtkWindowedSincPolyDataFilter`` (50 iterations, pass band 0.1, normalized
  coordinates, Nuttall window where VTK has it);
- decimation by 90 %: ``isoconvert.post.decimate.decimate(mesh, 0.9)`` (meshoptimizer,
  the ``simplify`` extra) against ``vtkQuadricDecimation`` (target reduction 0.9);
- normals: ``extract(..., normals=True)`` (normals in the filling pass, issue 23)
  against ``vtkFlyingEdges3D`` with ``ComputeNormalsOn``, each minus its extraction
  without normals (the cost of the normals alone), VTK on its STDThread backend with
  as many threads as isoconvert; and, for comparison, the second pass over the volume
  that block-wise runs still take (``extract`` + ``vertex_normals``);
- closing: ``close_at_grid`` on the gyroid (which meets every face of the grid), alone
  (VTK has no counterpart; printed against isoconvert's own extraction time).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))


def gyroid(n: int) -> np.ndarray:
    """(n, n, n) float32 gyroid, two periods along each axis, (Z, Y, X)."""
    t = np.linspace(0, 4 * np.pi, n, dtype=np.float32)
    z, y, x = np.meshgrid(t, t, t, indexing="ij")
    return (np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)).astype(
        np.float32
    )


def vtk_polydata(mesh):
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData

    points = vtkPoints()
    points.SetData(numpy_support.numpy_to_vtk(np.ascontiguousarray(mesh.vertices), deep=True))
    offsets = np.arange(0, 3 * len(mesh.cells) + 1, 3, dtype=np.int64)
    cells = vtkCellArray()
    cells.SetData(
        numpy_support.numpy_to_vtkIdTypeArray(offsets, deep=True),
        numpy_support.numpy_to_vtkIdTypeArray(mesh.cells.ravel().astype(np.int64), deep=True),
    )
    data = vtkPolyData()
    data.SetPoints(points)
    data.SetPolys(cells)
    return data


def vtk_image(zyx: np.ndarray):
    from vtkmodules.util import numpy_support
    from vtkmodules.vtkCommonDataModel import vtkImageData

    image = vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.ravel(), deep=True))
    return image


def interleaved(pairs: dict[str, Callable[[], object]], rounds: int) -> dict[str, list[float]]:
    """Seconds per round of each function, the functions taking turns."""
    for run in pairs.values():
        run()  # warm-up
    times: dict[str, list[float]] = {name: [] for name in pairs}
    for _ in range(rounds):
        for name, run in pairs.items():
            start = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - start)
    return times


def report(title: str, ours: list[float], theirs: list[float] | None, peer: str) -> None:
    best, median = min(ours), statistics.median(ours)
    line = f"{title:<34} isoconvert {best:7.3f} {median:7.3f}"
    if theirs is not None:
        ratios = [a / b for a, b in zip(ours, theirs, strict=True)]
        line += (
            f"   {peer} {min(theirs):7.3f} {statistics.median(theirs):7.3f}"
            f"   ratio {statistics.median(ratios):5.2f} ({min(ratios):.2f}-{max(ratios):.2f})"
        )
    print(line, flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument(
        "--only",
        choices=["smooth", "decimate", "normals", "close"],
        action="append",
        help="run only these pairs (repeatable); all by default",
    )
    args = parser.parse_args(argv)
    chosen = set(args.only or ["smooth", "decimate", "normals", "close"])

    from vtkmodules.vtkCommonCore import vtkSMPTools
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D, vtkWindowedSincPolyDataFilter

    from isoconvert import extract, vertex_normals
    from isoconvert.post.cap import close_at_grid
    from isoconvert.post.smooth import smooth
    from isoconvert.threads import kernel_threads
    from isoconvert.volume import Volume

    vtkSMPTools.SetBackend("STDThread")
    vtkSMPTools.Initialize(kernel_threads())
    zyx = gyroid(args.size)
    volume = Volume.from_zyx(zyx)
    mesh = extract(volume, 0.1)
    polydata = vtk_polydata(mesh)
    image = vtk_image(zyx)
    print(
        f"gyroid {args.size}^3 at 0.1: {mesh.n_vertices:,} vertices, {mesh.n_cells:,} "
        f"triangles; seconds best, median; {args.rounds} rounds; {kernel_threads()} threads; "
        f"load average {load_average()}"
    )

    def vtk_sinc():
        f = vtkWindowedSincPolyDataFilter()
        f.SetInputData(polydata)
        f.SetNumberOfIterations(50)
        f.SetPassBand(0.1)
        f.NormalizeCoordinatesOn()
        if hasattr(f, "SetWindowFunctionToNuttall"):
            f.SetWindowFunctionToNuttall()
        f.Update()

    if "smooth" in chosen:
        t = interleaved({"ours": lambda: smooth(mesh, 50, "sinc"), "vtk": vtk_sinc}, args.rounds)
        report("smooth, sinc, 50 iterations", t["ours"], t["vtk"], "VTK")

    if "decimate" in chosen:
        run_decimate(mesh, polydata, args.rounds)

    def vtk_contour(normals: bool):
        f = vtkFlyingEdges3D()
        f.SetInputData(image)
        f.SetValue(0, 0.1)
        f.SetComputeNormals(normals)
        f.Update()

    if "normals" in chosen:
        t = interleaved(
            {
                "ours": lambda: extract(volume, 0.1, normals=True),
                "ours second pass": lambda: vertex_normals(extract(volume, 0.1), volume),
                "ours plain": lambda: extract(volume, 0.1),
                "vtk": lambda: vtk_contour(True),
                "vtk plain": lambda: vtk_contour(False),
            },
            args.rounds,
        )
        ours = [a - b for a, b in zip(t["ours"], t["ours plain"], strict=True)]
        theirs = [a - b for a, b in zip(t["vtk"], t["vtk plain"], strict=True)]
        report("normals (with minus without)", ours, [max(x, 1e-6) for x in theirs], "VTK")
        second = [a - b for a, b in zip(t["ours second pass"], t["ours plain"], strict=True)]
        report("normals, second pass instead", second, [max(x, 1e-6) for x in theirs], "VTK")

    if "close" in chosen:
        pairs = {
            "close": lambda: close_at_grid(mesh, volume, 0.1),
            "extract": lambda: extract(volume, 0.1),
        }
        t = interleaved(pairs, args.rounds)
        report("close at the grid's faces", t["close"], t["extract"], "extract")
    print(f"load average {load_average()}")


def run_decimate(mesh, polydata, rounds: int) -> None:
    """isoconvert's decimation against vtkQuadricDecimation, when the simplify extra is there."""
    from vtkmodules.vtkFiltersCore import vtkQuadricDecimation

    try:
        from isoconvert.post.decimate import decimate

        decimate(mesh, 0.9)
    except Exception as exc:  # the simplify extra is missing
        print(f"decimate: skipped ({exc})")
        return

    def vtk_decimate():
        f = vtkQuadricDecimation()
        f.SetInputData(polydata)
        f.SetTargetReduction(0.9)
        f.Update()

    t = interleaved({"ours": lambda: decimate(mesh, 0.9), "vtk": vtk_decimate}, rounds)
    report("decimate 90%", t["ours"], t["vtk"], "VTK")


def load_average() -> str:
    """The 1, 5 and 15 minute load averages (other work on the machine skews timings)."""
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # not on this system
        return "unknown"


if __name__ == "__main__":
    main()
