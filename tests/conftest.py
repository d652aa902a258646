"""Shared fixtures: the real scans in ../shared/datasets and small helpers."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
#: The real scans: $ISOCONVERT_DATASETS, else ../shared/datasets beside the repository.
DATASETS = Path(os.environ.get("ISOCONVERT_DATASETS") or ROOT.parent / "shared" / "datasets")
SAMPLES = ROOT / "sample_volumes"


def dataset(name: str) -> Path:
    """Path of a real scan, or skip the test when it is not there."""
    path = DATASETS / name
    if not path.exists():
        pytest.skip(
            f"real dataset {name} not found in {DATASETS}; set "
            "ISOCONVERT_DATASETS=/path/to/datasets (or put shared/datasets beside the repository)"
        )
    return path


def real_scan_names() -> list:
    """Names of the shared datasets' volumes isoconvert reads (for parametrize);
    one skipped case when the datasets are absent."""
    if not DATASETS.is_dir():
        return [pytest.param(None, marks=pytest.mark.skip(reason=f"no datasets at {DATASETS}"))]
    return [
        p.name
        for p in sorted(DATASETS.iterdir())
        if p.suffix in (".raw", ".nrrd", ".tif") or p.name == "headsq_vtk"
    ]


def read_real_scan(name: str):
    """The 3D volume of a shared dataset, or skip (a format not read yet, a 2D image)."""
    from isoconvert import read_volume
    from isoconvert.errors import IsoconvertError

    path = DATASETS / name
    if path.is_dir():
        path = next(path.glob("*.nhdr"))
    try:
        vol = read_volume(path)
    except IsoconvertError as err:
        pytest.skip(f"not read yet: {err}")  # e.g. a raw file that needs its MetaImage header
    if vol.ndim != 3:
        pytest.skip("a 2D image")
    return vol


def load_import_graph():
    """The bench/import_graph.py module (a script, not a package), loaded once."""
    if "import_graph" in sys.modules:
        return sys.modules["import_graph"]
    spec = importlib.util.spec_from_file_location(
        "import_graph", ROOT / "bench" / "import_graph.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def load_samples_module():
    """The sample_volumes/make_samples.py module (not a package)."""
    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def ball(n: int, radius: float, center=None) -> np.ndarray:
    """(n, n, n) float64 field radius - |p - center|: positive inside the ball."""
    c = np.full(3, (n - 1) / 2) if center is None else np.asarray(center, float)
    x, y, z = np.meshgrid(*(np.arange(n, dtype=float),) * 3, indexing="ij")
    return radius - np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2)


def angles_degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rows of ``a (N, 3)`` and ``b (N, 3)``, in degrees, in float64
    (atan2 of the cross and dot products stays accurate near 0, unlike arccos)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    return np.degrees(np.arctan2(cross, np.einsum("ij,ij->i", a, b)))


def edge_key(vertices: np.ndarray, spacing=None) -> tuple[np.ndarray, np.ndarray]:
    """Sort vertices lying strictly inside grid edges by (edge, position).

    Each vertex of a level no sample equals lies strictly inside one grid edge:
    all but one of its index coordinates are integers. Returns the sorted
    integer keys (N, ndim + 1: indices of the edge's lower end, axis) and the
    fractional coordinate of each, so two meshes' vertex sets can be compared
    exactly, edge by edge.
    """
    idx = vertices / (1.0 if spacing is None else np.asarray(spacing))
    frac = np.abs(idx - np.rint(idx))
    axis = np.argmax(frac, axis=1)
    base = np.rint(idx)
    rows = np.arange(len(idx))
    base[rows, axis] = np.floor(idx[rows, axis])
    keys = np.column_stack([base.astype(np.int64), axis])
    order = np.lexsort(keys.T[::-1])
    return keys[order], idx[rows, axis][order]


def edge_use(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges of triangles and how many triangles use each."""
    e = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e, axis=0, return_counts=True)


def directed_edges_consistent(cells: np.ndarray) -> bool:
    """True when every directed edge occurs at most once (consistent orientation)."""
    e = np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]])
    return len(np.unique(e, axis=0)) == len(e)


def euler_characteristic(vertices_used: int, cells: np.ndarray) -> int:
    edges, _ = edge_use(cells)
    return vertices_used - len(edges) + len(cells)


def vtk_flying_edges(zyx: np.ndarray, level: float):
    """Points (N, 3) in index units and triangles (C, 3) of VTK's vtkFlyingEdges3D."""
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.ravel(), deep=True))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, level)
    fe.ComputeNormalsOff()
    fe.ComputeGradientsOff()
    fe.Update()
    out = fe.GetOutput()
    points = numpy_support.vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    cells = numpy_support.vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return points, cells


def cli_peak_mib(*args: str) -> float:
    """The peak resident memory (MiB) of ``isoconvert ARGS`` in a process of its own,
    which must succeed: its own high-water mark, read as it ends (``ru_maxrss`` of a
    child would count the parent's, from before exec)."""
    import subprocess

    code = (
        "import sys\n"
        "from isoconvert.cli import main\n"
        "assert main() == 0\n"
        "peak = [x for x in open('/proc/self/status') if x.startswith('VmHWM')][0]\n"
        "print(int(peak.split()[1]) / 1024, file=sys.stderr)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True
    )
    assert run.returncode == 0, run.stderr
    return float(run.stderr.strip().splitlines()[-1])


@contextlib.contextmanager
def small_tmpfs(folder: Path, size: str):
    """A tmpfs of ``size`` at ``folder`` (needs root), unmounted afterwards."""
    folder.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs to fill: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], capture_output=True)
        if os.path.ismount(folder):
            subprocess.run(["umount", "-l", str(folder)], capture_output=True)
