"""Isosurface extraction: isoconvert against VTK, scikit-image and PyMCubes (issue 9).

Run ``python bench/bench_extract.py`` (``--quick`` for a short smoke run, ``--cases`` and
``--tools`` for subsets, ``--repeat N`` for the number of timed rounds). It needs the test
extras (VTK, scikit-image), optionally PyMCubes (``pip install pymcubes``), and the real
scans in ``../shared/datasets`` (or ``$ISOCONVERT_DATASETS``); a missing peer or scan is
skipped with a printed note.

What is timed: one extraction call on an array already in memory, as each tool is called
from Python (isoconvert ``extract`` on ``Volume.from_zyx``, which does not copy;
vtkFlyingEdges3D and vtkMarchingCubes from filter creation to ``Update()`` on a
vtkImageData wrapping the same array, with normals, gradients and scalars off so they
produce what isoconvert does; scikit-image ``marching_cubes``, which also returns normals
and values; ``mcubes.marching_cubes``). Reading and writing files are not timed (see
``bench_process.py`` for whole commands).

How: a warm-up round (compiling or loading kernels, first touches of the code), then
``--repeat`` rounds; in each round every case runs every tool once, in an order rotated by
one tool per round, so slow drifts of the machine (other jobs, heat) hit all tools alike.
Per tool and case it prints the median and the min-max of the rounds and the per-round
ratio to the best VTK Flying Edges of that same round (the faster of the Sequential and
the STDThread backend). isoconvert's tetra and squares methods are also given as per-round
ratios to isoconvert's cubes (target: at most 3).

Peak extra memory: each tool and case runs once more in a fresh Python process, which
loads the volume, warms the tool up on every 8th sample of it, releases freed heap memory
(``malloc_trim``), resets the peak resident set size (writing 5 to
``/proc/self/clear_refs``) and runs the extraction. The figure is the peak RSS during the
call minus the RSS before it, minus the bytes of what the call returns (isoconvert's
vertex and cell arrays, VTK's output ``GetActualMemorySize``, the arrays scikit-image and
PyMCubes return): the scratch memory and copies a tool needs beyond its input and its
output. glibc's ``MALLOC_MMAP_THRESHOLD_`` is fixed at 128 KiB in those processes so large
blocks freed earlier cannot hide new ones. Memory that a tool allocates but never touches
is not resident and not counted.

Memory regime of the timed rounds (``--memory``). With glibc's defaults (``default``),
a block of 32 MiB or more is mapped afresh for every call and unmapped when freed, so
its pages are new to the process each time, while smaller blocks are recycled from the
heap: which outputs and scratch arrays pay for new pages depends on their size, not on
the tool. ``recycled`` re-runs the benchmark with glibc told to serve every block from
its heap and keep what is freed (``GLIBC_TUNABLES`` mmap_max=0, a 64 GiB trim
threshold), so that every tool reuses warm pages alike. The header gives this
machine's cost of a first touch: on virtual machines that hand freed memory back to
the host, new pages can cost twenty times more than recycled ones.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

DATASETS = Path(
    os.environ.get("ISOCONVERT_DATASETS")
    or Path(__file__).resolve().parent.parent.parent / "shared" / "datasets"
)
MB = 1e6
#: Threads for VTK's STDThread backend.
VTK_THREADS = 2


# --------------------------------------------------------------------------- cases


@dataclass(frozen=True)
class Case:
    """One volume and level.

    Attributes
    ----------
    name : str
        Short name for ``--cases``.
    title : str
        What the volume is, printed above its table.
    level : float
        The isovalue.
    load : callable
        Returns the samples as a C-ordered (z, y, x) array.
    large : bool
        Left out of ``--quick`` runs unless named with ``--cases``.
    """

    name: str
    title: str
    level: float
    load: Callable[[], np.ndarray]
    large: bool = False


def raw_scan(name: str, shape_zyx: tuple[int, int, int], dtype: str) -> Callable[[], np.ndarray]:
    """Loader of a raw scan in the datasets folder (x fastest)."""

    def load() -> np.ndarray:
        path = DATASETS / name
        if not path.exists():
            raise FileNotFoundError(f"{path} not found (set ISOCONVERT_DATASETS)")
        return np.fromfile(path, dtype=dtype).reshape(shape_zyx)

    return load


def gyroid(n: int) -> Callable[[], np.ndarray]:
    """Loader of sin x cos y + sin y cos z + sin z cos x on n^3 samples over two periods."""

    def load() -> np.ndarray:
        t = np.linspace(0, 4 * np.pi, n, dtype=np.float32)
        s, c = np.sin(t), np.cos(t)
        out = np.empty((n, n, n), dtype=np.float32)  # axes (z, y, x)
        np.multiply(s[None, None, :], c[None, :, None], out=out)  # sin x cos y
        out += s[None, :, None] * c[:, None, None]  # sin y cos z
        out += s[:, None, None] * c[None, None, :]  # sin z cos x
        return out

    return load


def sphere(n: int, radius: float) -> Callable[[], np.ndarray]:
    """Loader of the signed distance to a sphere centred in an n^3 grid (negative inside)."""

    def load() -> np.ndarray:
        r = np.arange(n, dtype=np.float32) - np.float32((n - 1) / 2)
        d = r[:, None, None] ** 2 + r[None, :, None] ** 2
        d = d + r[None, None, :] ** 2
        np.sqrt(d, out=d)
        d -= np.float32(radius)
        return d

    return load


def dicom_series_uint16(folder: str) -> Callable[[], np.ndarray]:
    """Loader of an uncompressed DICOM series of unsigned 16-bit slices, sorted by z.

    Reads just what it needs (rows, columns, bits, sign, ImagePositionPatient, pixel data)
    from files in Implicit VR Little Endian, the transfer syntax of the series in the
    datasets folder, and refuses anything else.
    """

    def load() -> np.ndarray:
        path = DATASETS / folder
        files = sorted(path.glob("*.dcm"))
        if not files:
            raise FileNotFoundError(f"{path} has no .dcm files (set ISOCONVERT_DATASETS)")
        slices = sorted(_dicom_slice(f) for f in files)
        return np.stack([pixels for _, pixels in slices])

    return load


def _dicom_slice(path: Path) -> tuple[float, np.ndarray]:
    data = path.read_bytes()
    if data[128:132] != b"DICM":
        raise ValueError(f"{path}: no DICM prefix")
    pos = 132
    meta_end = None
    syntax = None
    while pos < len(data):  # group 0002, explicit VR little endian
        group, elem = struct.unpack_from("<HH", data, pos)
        if group != 2:
            break
        vr = data[pos + 4 : pos + 6]
        if vr in (b"OB", b"OW", b"SQ", b"UN", b"UT"):
            length = struct.unpack_from("<I", data, pos + 8)[0]
            start = pos + 12
        else:
            length = struct.unpack_from("<H", data, pos + 6)[0]
            start = pos + 8
        if elem == 0x0010:
            syntax = data[start : start + length].rstrip(b"\0 ").decode()
        pos = meta_end = start + length
    if syntax != "1.2.840.10008.1.2":
        raise ValueError(f"{path}: transfer syntax {syntax}, only Implicit VR Little Endian here")
    fields: dict[tuple[int, int], bytes] = {}
    pos = meta_end
    while pos + 8 <= len(data):  # the data set, implicit VR little endian
        group, elem, length = struct.unpack_from("<HHI", data, pos)
        if length == 0xFFFFFFFF:
            raise ValueError(f"{path}: undefined-length element ({group:04x},{elem:04x})")
        fields[(group, elem)] = data[pos + 8 : pos + 8 + length]
        pos += 8 + length
    rows, cols, bits, signed = (
        struct.unpack("<H", fields[(0x0028, e)])[0] for e in (0x0010, 0x0011, 0x0100, 0x0103)
    )
    if bits != 16 or signed:
        raise ValueError(f"{path}: {bits}-bit {'signed' if signed else 'unsigned'} samples")
    z = float(fields[(0x0020, 0x0032)].decode().split("\\")[2])
    pixels = np.frombuffer(fields[(0x7FE0, 0x0010)], dtype="<u2").reshape(rows, cols)
    return z, pixels


CASES = {
    c.name: c
    for c in [
        Case(
            "engine",
            "engine 256x256x128 uint8 (industrial CT), level 80.5",
            80.5,
            raw_scan("engine_256x256x128_uint8.raw", (128, 256, 256), "uint8"),
        ),
        Case(
            "embryo",
            "embryo 256x256x256 uint8, level 60.5",
            60.5,
            raw_scan("embryo_256x256x256_uint8.raw", (256, 256, 256), "uint8"),
        ),
        Case(
            "ct-uint16",
            "chest CT LIDC-IDRI-0314 512x512x64 uint16 (stored values, HU + 1000; DICOM), "
            "level 600.5 (-399.5 HU: skin and lungs)",
            600.5,
            dicom_series_uint16("ct_chest_LIDC-IDRI-0314_dicom"),
        ),
        Case("gyroid256", "gyroid 256^3 float32 (two periods), level 0.1", 0.1, gyroid(256)),
        Case(
            "gyroid512",
            "gyroid 512^3 float32 (two periods), level 0.1",
            0.1,
            gyroid(512),
            large=True,
        ),
        Case(
            "sphere512",
            "sphere distance field 512^3 float32 (radius 102.4), level 0",
            0.0,
            sphere(512, 512 / 5),
            large=True,
        ),
    ]
}


# --------------------------------------------------------------------------- tools


@dataclass(frozen=True)
class Result:
    """What one extraction call gave.

    Attributes
    ----------
    seconds : float
    vertices, cells : int
        Vertex and cell (triangle or segment) counts.
    output_bytes : int
        Size of what the call returned.
    """

    seconds: float
    vertices: int
    cells: int
    output_bytes: int


#: A tool's factory takes (zyx, level) and returns a function that runs one extraction.
Factory = Callable[[np.ndarray, float], Callable[[], Result]]


@dataclass(frozen=True)
class Tool:
    """One extraction method of one library.

    Attributes
    ----------
    name : str
        Name for ``--tools`` and the tables.
    make : Factory
        Raises ImportError (with a hint) when the library is missing.
    relative_to_cubes : bool
        Also report the per-round ratio to isoconvert cubes.
    cubes_limit : float
        The target for that ratio (its median must not exceed it).
    """

    name: str
    make: Factory
    relative_to_cubes: bool = False
    cubes_limit: float = 3.0


def _isoconvert(method: str, **options) -> Factory:
    def make(zyx: np.ndarray, level: float) -> Callable[[], Result]:
        from isoconvert import Volume, extract

        volume = Volume.from_zyx(zyx)

        def run() -> Result:
            start = time.perf_counter()
            mesh = extract(volume, level, method=method, **options)
            seconds = time.perf_counter() - start
            out = mesh.vertices.nbytes + mesh.cells.nbytes
            return Result(seconds, mesh.n_vertices, mesh.n_cells, out)

        return run

    return make


def _vtk_image(zyx: np.ndarray):
    import vtk
    from vtk.util import numpy_support

    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    # a view of the array (no copy); numpy_to_vtk keeps a reference to it
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.reshape(-1), deep=False))
    return image


def _vtk(cls_name: str, backend: str = "Sequential", threads: int = 1) -> Factory:
    def make(zyx: np.ndarray, level: float) -> Callable[[], Result]:
        try:
            import vtk
        except ImportError as exc:
            raise ImportError("VTK is not installed (pip install vtk)") from exc
        smp = vtk.vtkSMPTools
        if not smp.SetBackend(backend):
            raise ImportError(f"this VTK build has no SMP backend {backend!r}")
        image = _vtk_image(zyx)

        def run() -> Result:
            smp.SetBackend(backend)
            smp.Initialize(threads)
            start = time.perf_counter()
            f = getattr(vtk, cls_name)()
            f.SetInputData(image)
            f.SetValue(0, level)
            f.ComputeNormalsOff()
            f.ComputeGradientsOff()
            f.ComputeScalarsOff()
            f.Update()
            seconds = time.perf_counter() - start
            out = f.GetOutput()
            return Result(
                seconds,
                out.GetNumberOfPoints(),
                out.GetNumberOfCells(),
                out.GetActualMemorySize() * 1024,
            )

        return run

    return make


def _skimage(method: str) -> Factory:
    def make(zyx: np.ndarray, level: float) -> Callable[[], Result]:
        try:
            from skimage.measure import marching_cubes
        except ImportError as exc:
            raise ImportError("scikit-image is not installed (pip install scikit-image)") from exc

        def run() -> Result:
            start = time.perf_counter()
            arrays = marching_cubes(zyx, level, method=method)  # verts, faces, normals, values
            seconds = time.perf_counter() - start
            out = sum(a.nbytes for a in arrays)
            return Result(seconds, len(arrays[0]), len(arrays[1]), out)

        return run

    return make


def _pymcubes(zyx: np.ndarray, level: float) -> Callable[[], Result]:
    try:
        import mcubes
    except ImportError as exc:
        raise ImportError("PyMCubes is not installed (pip install pymcubes)") from exc

    def run() -> Result:
        start = time.perf_counter()
        verts, tris = mcubes.marching_cubes(zyx, level)
        seconds = time.perf_counter() - start
        return Result(seconds, len(verts), len(tris), verts.nbytes + tris.nbytes)

    return run


FE_SEQ = "vtk FE Sequential"
FE_THREAD = f"vtk FE STDThread x{VTK_THREADS}"
CUBES = "isoconvert cubes"
TOOLS = {
    t.name: t
    for t in [
        Tool(CUBES, _isoconvert("cubes")),
        # issue 22: the trilinear topology at most 1.5x the default rule's time
        Tool(
            "isoconvert trilinear",
            _isoconvert("cubes", ambiguity="trilinear"),
            relative_to_cubes=True,
            cubes_limit=1.5,
        ),
        Tool(FE_SEQ, _vtk("vtkFlyingEdges3D", "Sequential", 1)),
        Tool(FE_THREAD, _vtk("vtkFlyingEdges3D", "STDThread", VTK_THREADS)),
        Tool("vtkMarchingCubes", _vtk("vtkMarchingCubes")),
        Tool("skimage lewiner", _skimage("lewiner")),
        Tool("skimage lorensen", _skimage("lorensen")),
        Tool("PyMCubes", _pymcubes),
        Tool("isoconvert tetra", _isoconvert("tetra"), relative_to_cubes=True),
        Tool("isoconvert squares", _isoconvert("squares"), relative_to_cubes=True),
    ]
}


# --------------------------------------------------------------------------- timing


@dataclass
class CaseRun:
    """Everything measured for one case.

    Attributes
    ----------
    case : Case
    zyx : ndarray
        The samples.
    runs : dict
        Tool name -> function running one extraction.
    first : dict
        Tool name -> Result of the warm-up call (counts come from it).
    seconds : dict
        Tool name -> seconds per timed round (None where the call failed).
    notes : list of str
        Skipped tools and failures.
    memory : dict
        Tool name -> (peak extra bytes, output bytes), or a note string.
    """

    case: Case
    zyx: np.ndarray
    runs: dict[str, Callable[[], Result]] = field(default_factory=dict)
    first: dict[str, Result] = field(default_factory=dict)
    seconds: dict[str, list[float | None]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    memory: dict[str, tuple[int, int] | str] = field(default_factory=dict)


def _call(cr: CaseRun, name: str) -> Result | None:
    """Run one tool on one case; a failure or a change of counts becomes a note."""
    try:
        res = cr.runs[name]()
    except Exception as exc:  # a tool that fails is reported, not fatal
        cr.notes.append(f"{name} failed: {type(exc).__name__}: {exc}")
        del cr.runs[name]
        return None
    first = cr.first.get(name)
    if first and (res.vertices, res.cells) != (first.vertices, first.cells):
        cr.notes.append(
            f"{name} counts changed between runs: {first.vertices:,}/{first.cells:,} "
            f"then {res.vertices:,}/{res.cells:,}"
        )
    return res


def time_cases(case_runs: list[CaseRun], tools: list[str], repeat: int) -> None:
    """Warm up, then time ``repeat`` interleaved rounds (results go into ``case_runs``)."""
    for cr in case_runs:
        for name in tools:
            if name in cr.runs and (res := _call(cr, name)) is not None:
                cr.first[name] = res
                cr.seconds[name] = []
    for r in range(repeat):
        order = tools[r % len(tools) :] + tools[: r % len(tools)]
        for cr in case_runs:
            for name in order:
                if name in cr.seconds:
                    res = _call(cr, name) if name in cr.runs else None
                    cr.seconds[name].append(None if res is None else res.seconds)
        print(f"  round {r + 1}/{repeat} done", file=sys.stderr, flush=True)


def best_fe(cr: CaseRun) -> list[float] | None:
    """Per round, the faster of the two VTK Flying Edges backends (None if neither ran)."""
    series = [cr.seconds[n] for n in (FE_SEQ, FE_THREAD) if n in cr.seconds]
    if not series:
        return None
    best = []
    for times in zip(*series, strict=True):
        ok = [t for t in times if t is not None]
        best.append(min(ok) if ok else float("nan"))
    return best


def ratios(num: list[float | None], den: list[float] | None) -> list[float]:
    """Per-round ratios, leaving out failed rounds."""
    if den is None:
        return []
    return [a / b for a, b in zip(num, den, strict=True) if a is not None and not math.isnan(b)]


# --------------------------------------------------------------------------- memory


def _rss_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"no {key} in /proc/self/status")


def probe(tool: str, npy: str, level: float) -> dict:
    """Measure one call's peak extra memory in this (fresh) process; see the module docstring.

    Parameters
    ----------
    tool : str
        Name in :data:`TOOLS`.
    npy : str
        The case's samples, saved with ``np.save``.
    level : float

    Returns
    -------
    dict
        ``extra`` and ``output`` in bytes.
    """
    zyx = np.load(npy)
    make = TOOLS[tool].make
    warm = np.ascontiguousarray(zyx[::8, ::8, ::8])  # a small copy that has the surface too
    make(warm, level)()  # load kernels, libraries and code pages first
    del warm
    run = make(zyx, level)
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except OSError:
        pass
    before = _rss_kib("VmRSS")
    Path("/proc/self/clear_refs").write_text("5")  # peak RSS := current RSS
    res = run()
    peak = _rss_kib("VmHWM")
    return {"extra": (peak - before) * 1024 - res.output_bytes, "output": res.output_bytes}


def measure_memory(cr: CaseRun, tools: list[str], workdir: Path) -> None:
    """Run :func:`probe` in a fresh process for each tool that ran on this case."""
    npy = workdir / f"{cr.case.name}.npy"
    np.save(npy, cr.zyx)
    env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="131072")
    env.pop("GLIBC_TUNABLES", None)  # --memory recycled would keep freed blocks
    for name in tools:
        if name not in cr.first:
            continue
        cmd = [sys.executable, __file__, "--probe", name, str(npy), repr(cr.case.level)]
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
        try:
            out = json.loads(proc.stdout.strip().splitlines()[-1])
            cr.memory[name] = (out["extra"], out["output"])
        except (IndexError, ValueError, KeyError):
            tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            cr.memory[name] = f"probe failed: {tail}"
    npy.unlink()


# --------------------------------------------------------------------------- report


def _span(values: list[float], fmt: str) -> str:
    if not values:
        return "n/a"
    return f"{statistics.median(values):{fmt}} ({min(values):{fmt}}-{max(values):{fmt}})"


def counts_equal_vtk(cr: CaseRun) -> str:
    """'yes', 'no (...)' or 'unknown (...)': isoconvert cubes' counts against VTK FE's."""
    fe = [cr.first[n] for n in (FE_SEQ, FE_THREAD) if n in cr.first]
    if CUBES not in cr.first or not fe:
        return "unknown (isoconvert cubes or VTK FE did not run)"
    ours = cr.first[CUBES]
    bad = [
        f"VTK {r.vertices:,} vertices {r.cells:,} triangles"
        for r in fe
        if (r.vertices, r.cells) != (ours.vertices, ours.cells)
    ]
    if bad:
        return f"no (isoconvert {ours.vertices:,} / {ours.cells:,}; {'; '.join(bad)})"
    return "yes"


def print_case(cr: CaseRun) -> None:
    """Print one case's table."""
    print(f"\n{cr.case.title}")
    print(f"counts equal VTK: {counts_equal_vtk(cr)}")
    head = (
        f"{'tool':<24}{'vertices':>11}{'cells':>11}  {'median s':>9} {'min-max s':>15}  "
        f"{'/ best VTK FE':>20}  {'extra MB':>9} {'out MB':>7}  {'/ cubes':>26}"
    )
    print(head)
    print("-" * len(head))
    fe = best_fe(cr)
    for name, first in cr.first.items():
        times = [t for t in cr.seconds[name] if t is not None]
        span = f"{min(times):.3f}-{max(times):.3f}" if times else "n/a"
        med = f"{statistics.median(times):.3f}" if times else "n/a"
        mem = cr.memory.get(name, "")
        if isinstance(mem, tuple):
            extra, out = f"{mem[0] / MB:.1f}", f"{mem[1] / MB:.1f}"
        else:
            extra, out = "n/a", "n/a"
        vs_cubes = ""
        if TOOLS[name].relative_to_cubes and CUBES in cr.seconds:
            rel = ratios(cr.seconds[name], cr.seconds[CUBES])
            if rel:
                limit = TOOLS[name].cubes_limit
                verdict = f"<= {limit:g} ok" if statistics.median(rel) <= limit else "OVER"
                vs_cubes = f"{_span(rel, '.2f')} {verdict}"
        print(
            f"{name:<24}{first.vertices:>11,}{first.cells:>11,}  {med:>9} {span:>15}  "
            f"{_span(ratios(cr.seconds[name], fe), '.2f'):>20}  {extra:>9} {out:>7}  "
            f"{vs_cubes:>26}"
        )
    for name, mem in cr.memory.items():
        if isinstance(mem, str):
            cr.notes.append(f"{name} memory: {mem}")
    for note in cr.notes:
        print(f"  note: {note}")


# --------------------------------------------------------------------------- memory

#: glibc malloc settings of ``--memory recycled``: no block is mapped on its own, and
#: freed memory stays with the process (below 64 GiB), so later blocks reuse it.
RECYCLE_TUNABLES = "glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736"
MEMORY_REGIMES = {
    "default": "glibc's defaults: blocks of 32 MiB or more are mapped afresh at every call",
    "recycled": f"GLIBC_TUNABLES={RECYCLE_TUNABLES}: every block reuses freed pages",
}


def first_touch_costs(megabytes: int = 256) -> str:
    """A line giving what a first write to new pages costs on this machine.

    Touches one byte per 4 KiB of a new numpy array of ``megabytes`` (numpy asks for
    huge pages, as it does for the tools' outputs), frees it, does the same with a
    second new array (which, with ``--memory recycled``, reuses the first one's pages),
    and then writes the second whole (pages already there: the speed of memory itself).
    """
    size = megabytes << 20

    def touch(step: int, array: np.ndarray | None = None) -> tuple[float, np.ndarray]:
        array = np.empty(size, dtype=np.uint8) if array is None else array
        start = time.perf_counter()
        array[::step] = 1
        return time.perf_counter() - start, array

    t_new, first = touch(4096)
    del first
    t_again, second = touch(4096)
    t_warm, _ = touch(1, second)
    del second
    gbps = [size / t / 1e9 for t in (t_new, t_again, t_warm)]
    return (
        f"first touch of a new {megabytes} MiB array: {gbps[0]:.1f} GB/s, of a second one "
        f"right after freeing it: {gbps[1]:.1f} GB/s; writing an array already there: "
        f"{gbps[2]:.1f} GB/s"
    )


# --------------------------------------------------------------------------- main


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line (see ``--help``)."""
    epilog = "cases: " + "; ".join(f"{c.name} = {c.title}" for c in CASES.values())
    epilog += ". tools: " + ", ".join(TOOLS)
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog=epilog,
    )
    parser.add_argument("--repeat", type=int, default=5, help="timed rounds (default 5)")
    parser.add_argument("--cases", help="comma-separated case names (default: all)")
    parser.add_argument("--tools", help="comma-separated tool names (default: all)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: one timed round, and no 512^3 cases unless named with --cases",
    )
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-memory probes")
    parser.add_argument(
        "--memory",
        choices=MEMORY_REGIMES,
        default="default",
        help="glibc malloc regime of the timed rounds: default (blocks of 32 MiB or more get "
        "new pages at every call) or recycled (every block reuses freed pages); see the top "
        "of this file",
    )
    # internal: one memory probe, run by measure_memory in a fresh process
    parser.add_argument(
        "--probe", nargs=3, metavar=("TOOL", "NPY", "LEVEL"), help=argparse.SUPPRESS
    )
    args = parser.parse_args(argv)
    for attr, table in (("cases", CASES), ("tools", TOOLS)):
        names = getattr(args, attr)
        if names:
            picked = [n.strip() for n in names.split(",")]
            unknown = [n for n in picked if n not in table]
            if unknown:
                parser.error(f"unknown {attr}: {', '.join(unknown)}; known: {', '.join(table)}")
            setattr(args, attr, picked)
    if args.quick:
        args.repeat = 1
        if not args.cases:
            args.cases = [n for n, c in CASES.items() if not c.large]
    args.cases = args.cases or list(CASES)
    args.tools = args.tools or list(TOOLS)
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    return args


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print its tables."""
    args = parse_args(argv)
    if args.probe:
        tool, npy, level = args.probe
        print(json.dumps(probe(tool, npy, float(level))))
        return
    if args.memory == "recycled" and os.environ.get("GLIBC_TUNABLES") != RECYCLE_TUNABLES:
        # glibc reads its tunables at start-up only: run again with them set
        argv = sys.argv[1:] if argv is None else argv
        env = dict(os.environ, GLIBC_TUNABLES=RECYCLE_TUNABLES)
        sys.stdout.flush()
        os.execve(sys.executable, [sys.executable, __file__, *argv], env)
    print(
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; "
        f"{args.repeat} timed round(s) after a warm-up round; VTK STDThread with "
        f"{VTK_THREADS} threads; isoconvert with its default threads"
    )
    print(f"memory regime: {args.memory} ({MEMORY_REGIMES[args.memory]})")
    print(first_touch_costs())
    case_runs = []
    skipped = []
    for name in args.cases:
        case = CASES[name]
        try:
            zyx = case.load()
        except (OSError, ValueError, KeyError) as exc:
            skipped.append(f"{name} skipped: {exc}")
            continue
        cr = CaseRun(case, zyx)
        for tool in args.tools:
            try:
                cr.runs[tool] = TOOLS[tool].make(zyx, case.level)
            except ImportError as exc:
                cr.notes.append(f"{tool} skipped: {exc}")
        case_runs.append(cr)
    for note in skipped:
        print(f"note: {note}")
    time_cases(case_runs, args.tools, args.repeat)
    if not args.no_memory:
        with tempfile.TemporaryDirectory(prefix="isoconvert-bench-") as tmp:
            for cr in case_runs:
                print(f"  memory probes: {cr.case.name}", file=sys.stderr, flush=True)
                measure_memory(cr, args.tools, Path(tmp))
    for cr in case_runs:
        print_case(cr)
    verdicts = [counts_equal_vtk(cr) for cr in case_runs]
    overall = "yes" if verdicts and all(v == "yes" for v in verdicts) else "no"
    print(f"\ncounts equal VTK in every case: {overall}")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    print(
        "cells = triangles (segments for squares); seconds and ratios: median (min-max) of "
        "the rounds; / best VTK FE: per round, time / the faster VTK Flying Edges backend; "
        "/ cubes: per round, time / isoconvert cubes (ok when the median is within the "
        "target printed beside it)"
    )
    if args.no_memory:
        print("peak extra memory not measured (--no-memory)")
    else:
        print(
            "extra MB = peak RSS during the call - RSS before it - returned arrays (out MB), "
            "in a fresh process after a warm-up on every 8th sample"
        )


if __name__ == "__main__":
    main()
