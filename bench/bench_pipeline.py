"""Whole pipelines as users run them: isoconvert against the script they would write (issue 23).

Run ``python bench/bench_pipeline.py`` (``--rounds N``, ``--quick`` for one round,
``--only NAME ...`` for some pipelines). Every timing is one process from start to exit
(interpreter start, imports, reading, extraction, post-processing, writing), as a user's
shell sees it. Each pipeline's commands run once untimed (warm file cache), then in
``--rounds`` rounds in a rotating order, so the commands of one round see the same
machine; the ratio printed is the median over rounds of each round's ratio (isoconvert /
the peer), beside the best and median times. The pipelines:

- ``engine``: the engine scan (256x256x128 uint8, level 80.5): largest component, 20
  smoothing iterations (windowed sinc, pass band 0.1), 90 % decimation, binary STL;
  against pyvista (Flying Edges, ``connectivity("largest")``, ``smooth_taubin``, which is
  VTK's windowed-sinc filter, and fast-simplification's ``simplify_mesh``). Target 0.5x.
- ``atlas``: a 40-label 256^3 uint8 atlas (bench_labels' synthetic one, saved as .npy),
  one PLY per label: ``isoconvert convert --labels`` (Surface Nets; with 16 relaxation
  iterations, its default, and with ``--smooth 0``) against zmesh (per-label Marching
  Cubes, one thread, ``close=True``, no smoothing; against ``--smooth 0``) and pyvista's
  ``contour_labels(boundary_style="all")`` (vtkSurfaceNets3D, 16 iterations; against
  the default), each label's triangles written by numpy and pyvista. Targets 1.0x zmesh,
  0.5x pyvista.
- ``layer``: the same atlas to a Neuroglancer precomputed layer: ``--format
  precomputed`` with 1 level of detail, 3, and 3 cut into 64-voxel fragments, against
  zmesh + cloud-volume writing the single-resolution format (cloud-volume has no
  multi-resolution writer); and one level with the labels' voxels (``--with-volume``)
  against the same script writing them too (compressed_segmentation, both uncompressed
  on disk). No target: the formats differ.
- ``layer-large``: the atlas at 512^3 as uint32 (a 512 MB file) to a layer of one level
  of detail, within ``--max-memory 256M`` (read in slabs) and whole, against the zmesh +
  cloud-volume script. Peak memory is printed for every command (``wait4``'s maximum
  resident size of the process).
- ``layer-many``: 15,625 small objects (cubes of 6 voxels in a 200^3 uint32 volume) to a
  layer of one level of detail, unsharded, ``--sharded`` and ``--legacy-mesh``, against
  the zmesh + cloud-volume script (which writes the legacy format): the costs per
  object rather than per voxel.
- ``layer-one``: one large object (a bumpy ball in a 448^3 uint8 volume, 1.5 million
  triangles) to a layer of one level cut into 64-voxel fragments, within ``--max-memory
  256M`` and whole, of one level in 128-voxel fragments (``auto``'s for it) and of 3
  levels in 64-voxel ones within that budget, beside the same surface as a
  PLY within it (the bound the other outputs keep) and the zmesh + cloud-volume script
  (one legacy fragment): the peak of cutting and decimating one large object; and the
  defaults (3 levels, ``--fragment-size auto``) against one fragment a level
  (``--fragment-size inf``), in memory and within the budget.
- ``layer-iso``: isosurfaces cut into fragments by default: the same ball's mask at
  ``--level 0.5`` (1.5 million triangles) and the embryo at 60.5 (961,024), as a PLY
  and as layers of one level and of the defaults (3 levels), beside zmesh +
  cloud-volume's legacy layer of the ball's mask, and the embryo's PLY and one-level
  layer within ``--max-memory 128M`` (below its mesh's own peak); level 0's triangles
  (decoded) are printed beside the PLY's, which they equal since the cut planes go
  through the samples.
- ``layer-cluster``: the same object's layer with ``--scheduler``, on a Dask cluster this
  benchmark starts (``dask scheduler`` and ``dask worker --nworkers 2 --nthreads 1`` on
  127.0.0.1), beside the same layer made in memory, with one level cut into 64-voxel
  fragments and with the defaults (3 levels: the workers collapse the slabs and make the
  coarser levels too); the workers' peak resident size is
  printed after (``getrusage`` on each worker), as the client's is by ``wait4``.
- ``normals``: a 384^3 float32 gyroid (raw) to binary PLY with and without ``--normals``.
  Target 1.3x.
- ``ct-bound``: the chest CT (DICOM series, 512x512x64, level 300.5 HU) decimated with
  ``--max-error 1`` (mm) alone; no peer has a distance bound. Printed: time, triangles
  removed, and both one-sided distances between the result and the undecimated surface,
  measured with trimesh's closest-point queries (every original vertex and 200,000
  points sampled on the original to the result, 200,000 points sampled on the result
  to the original). Targets: under 15 s, over 70 %
  removed, both distances at most 1.
- ``ct-print``: the chest CT to a printable STL: largest component, cavities dropped, 10
  smoothing iterations, decimation to a bound of 0.5 mm, capped at the grid's faces
  (``--close``); against pydicom + scikit-image's ``marching_cubes`` + trimesh (largest
  of ``split``, which drops the cavities too; ``filter_taubin``) + fast-simplification
  (90 %: it has no bound) + trimesh's STL export (it has no capping).

Data: the scans come from ``../shared/datasets`` (or ``$ISOCONVERT_DATASETS``); the
pipelines that need a missing one are skipped. The peers (pyvista, fast-simplification,
zmesh, pydicom, scikit-image) must be installed; a pipeline whose peer is missing is
timed without it. The synthetic inputs and all outputs go to a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from bench_extract import DATASETS, gyroid
from bench_labels import synthetic_atlas
from bench_process import Command, ply_counts, run_once, start, time_rounds

ENGINE = DATASETS / "engine_256x256x128_uint8.raw"
CHEST_CT = DATASETS / "ct_chest_LIDC-IDRI-0314_dicom"
CT_LEVEL = 300.5

PYVISTA_ENGINE = '''\
"""np.fromfile + pyvista: flying edges, largest, windowed sinc, fast-simplification, STL."""
import sys

import fast_simplification
import numpy as np
import pyvista as pv

path, nx, ny, nz, dtype, level, iterations, reduction, out = sys.argv[1:]
image = pv.ImageData(dimensions=(int(nx), int(ny), int(nz)))
image.point_data["values"] = np.fromfile(path, dtype=dtype)
surface = image.contour([float(level)], method="flying_edges")
surface = surface.connectivity("largest")
surface = surface.smooth_taubin(n_iter=int(iterations), pass_band=0.1)
surface = fast_simplification.simplify_mesh(surface, target_reduction=float(reduction))
surface.save(out, binary=True)
'''

ZMESH_LABELS = '''\
"""np.load + zmesh (per-label Marching Cubes), one PLY per label."""
import sys
from pathlib import Path

import numpy as np
from zmesh import Mesher

path, out = sys.argv[1:]
mesher = Mesher((1, 1, 1))
mesher.mesh(np.load(path), close=True)
for label in mesher.ids():
    if label:
        mesh = mesher.get(label, normals=False)
        Path(out, f"atlas_label{label}.ply").write_bytes(mesh.to_ply())
'''

PYVISTA_LABELS = '''\
"""np.load + pyvista's contour_labels (vtkSurfaceNets3D), one PLY per label."""
import sys

import numpy as np
import pyvista as pv

path, out = sys.argv[1:]
labels = np.load(path)
image = pv.ImageData(dimensions=labels.shape[::-1])
image.point_data["labels"] = labels.reshape(-1)
surface = image.contour_labels(boundary_style="all")
points, faces = surface.points, surface.regular_faces
sides = np.asarray(surface.cell_data["boundary_labels"]).reshape(len(faces), -1)
for label in np.unique(sides):
    if label:
        these = faces[(sides == label).any(axis=1)]
        used, local = np.unique(these, return_inverse=True)
        mesh = pv.PolyData.from_regular_faces(points[used], local.reshape(-1, 3))
        mesh.save(f"{out}/atlas_label{label}.ply")
'''

ZMESH_LAYER = '''\
"""np.load + zmesh + cloud-volume: a Neuroglancer layer of every label's mesh
(cloud-volume writes the single-resolution format; it has no multi-resolution
writer, igneous has), and with "voxels" the labels as compressed_segmentation chunks."""
import shutil
import sys

import numpy as np
from cloudvolume import CloudVolume
from cloudvolume.mesh import Mesh
from zmesh import Mesher

path, out, *voxels = sys.argv[1:]
shutil.rmtree(out, ignore_errors=True)  # a fresh layer each round, as isoconvert's -f
labels = np.load(path).T  # (x, y, z)
mesher = Mesher((1, 1, 1))
mesher.mesh(labels, close=True)
info = CloudVolume.create_new_info(
    num_channels=1, layer_type="segmentation", data_type="uint32" if voxels else "uint8",
    encoding="compressed_segmentation" if voxels else "raw", resolution=[1, 1, 1],
    voxel_offset=[0, 0, 0], mesh="mesh", chunk_size=[64, 64, 64], volume_size=list(labels.shape),
)
vol = CloudVolume(f"file://{out}", info=info, progress=False, compress=False)
vol.commit_info()
if voxels:
    vol[:, :, :] = labels.astype(np.uint32)
meshes = []
for label in mesher.ids():
    if label:
        m = mesher.get(label, normals=False)
        meshes.append(Mesh(m.vertices, m.faces, segid=label))
vol.mesh.put(meshes)
'''

SKIMAGE_CT_PRINT = '''\
"""pydicom + scikit-image + trimesh + fast-simplification: a CT to a printable STL."""
import sys
from pathlib import Path

import fast_simplification
import numpy as np
import pydicom
import trimesh
from skimage.measure import marching_cubes

folder, level, iterations, reduction, out = sys.argv[1:]
slices = [pydicom.dcmread(p) for p in sorted(Path(folder).glob("*.dcm"))]
slices.sort(key=lambda s: float(s.ImagePositionPatient[2]))
hu = np.stack([s.pixel_array * float(s.RescaleSlope) + float(s.RescaleIntercept) for s in slices])
dz = abs(float(slices[1].ImagePositionPatient[2]) - float(slices[0].ImagePositionPatient[2]))
dy, dx = (float(v) for v in slices[0].PixelSpacing)
verts, faces, _, _ = marching_cubes(hu, float(level), spacing=(dz, dy, dx))
mesh = trimesh.Trimesh(verts[:, ::-1], faces[:, ::-1])
mesh = max(mesh.split(only_watertight=False), key=lambda m: len(m.faces))
trimesh.smoothing.filter_taubin(mesh, iterations=int(iterations))
points, triangles = fast_simplification.simplify(mesh.vertices, mesh.faces, float(reduction))
trimesh.Trimesh(points, triangles).export(out, file_type="stl")
'''


def round_ratios(num: Command, den: Command) -> list[float]:
    """Per-round ratios num / den (the rounds where both ran)."""
    return [a / b for a, b in zip(num.seconds, den.seconds, strict=False)]


def print_pipeline(title: str, commands: list[Command], pairs: list[tuple[str, str, float | None]]):
    """Times of each command; for each (ours, theirs, target or None) the median
    per-round ratio."""
    print(f"\n{title}")
    head = f"{'command':<46}{'best s':>8}{'median s':>10}{'peak MB':>9}{'faces':>12}"
    print(head)
    print("-" * len(head))
    for c in commands:
        if not c.seconds:
            print(f"{c.name:<46}  not timed: {c.note or 'no successful run'}")
            continue
        counts = ply_counts(c.output) if c.output and c.output.suffix == ".ply" else None
        faces = f"{counts[1]:,}" if counts else ""
        med = statistics.median(c.seconds)
        peak = c.peak_kib * 1024 / 1e6
        print(f"{c.name:<46}{min(c.seconds):>8.3f}{med:>10.3f}{peak:>9.0f}{faces:>12}")
    by_name = {c.name: c for c in commands}
    for ours, theirs, target in pairs:
        r = round_ratios(by_name[ours], by_name[theirs])
        if not r:
            print(f"{ours} / {theirs}: not measured")
            continue
        med = statistics.median(r)
        line = f"{ours} / {theirs}: {med:.2f} (rounds {min(r):.2f}-{max(r):.2f})"
        if target is not None:
            line += f"; target {target}: {'met' if med <= target else 'NOT met'}"
        print(line)


def engine_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    dims = ["256", "256", "128"]
    (tmp / "pv_engine.py").write_text(PYVISTA_ENGINE)
    ours = tmp / "engine_iso.stl"
    argv = [exe, "convert", str(ENGINE), "--shape", *dims, "--dtype", "uint8", "--level", "80.5"]
    argv += ["--largest", "--smooth", "20", "--decimate", "0.9", "-o", str(ours), "-f", "-q"]
    peer = [sys.executable, str(tmp / "pv_engine.py"), str(ENGINE), *dims, "uint8", "80.5"]
    peer += ["20", "0.9", str(tmp / "engine_pv.stl")]
    commands = [
        Command("isoconvert convert", argv, ours),
        Command("pyvista + fast-simplification script", peer, tmp / "engine_pv.stl"),
    ]
    return commands, [("isoconvert convert", "pyvista + fast-simplification script", 0.5)]


def atlas_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    atlas = tmp / "atlas.npy"
    np.save(atlas, np.ascontiguousarray(synthetic_atlas().data.T))
    (tmp / "zmesh_labels.py").write_text(ZMESH_LABELS)
    (tmp / "pv_labels.py").write_text(PYVISTA_LABELS)
    folders = {}
    for name in ("iso16", "iso0", "zmesh", "pyvista"):
        folders[name] = tmp / f"atlas_{name}"
        folders[name].mkdir()
    base = [exe, "convert", str(atlas), "--labels", "--spacing", "1", "1", "1", "-f", "-q"]
    commands = [
        Command("isoconvert --labels", base + ["-o", str(folders["iso16"] / "atlas.ply")]),
        Command(
            "isoconvert --labels --smooth 0",
            base + ["--smooth", "0", "-o", str(folders["iso0"] / "atlas.ply")],
        ),
        Command(
            "zmesh script",
            [sys.executable, str(tmp / "zmesh_labels.py"), str(atlas), str(folders["zmesh"])],
        ),
        Command(
            "pyvista contour_labels script",
            [sys.executable, str(tmp / "pv_labels.py"), str(atlas), str(folders["pyvista"])],
        ),
    ]
    pairs = [
        ("isoconvert --labels --smooth 0", "zmesh script", 1.0),
        ("isoconvert --labels", "pyvista contour_labels script", 0.5),
    ]
    return commands, pairs


def layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    atlas = tmp / "atlas.npy"
    if not atlas.exists():
        np.save(atlas, np.ascontiguousarray(synthetic_atlas().data.T))
    (tmp / "zmesh_layer.py").write_text(ZMESH_LAYER)
    base = [exe, "convert", str(atlas), "--labels", "--format", "precomputed", "-f", "-q"]
    commands = [
        Command("isoconvert precomputed, 1 level", base + ["--lods", "1", "-o", str(tmp / "l1")]),
        Command("isoconvert precomputed, 3 levels", base + ["--lods", "3", "-o", str(tmp / "l3")]),
        Command(
            "isoconvert precomputed, 3 levels, fragments 64",
            base + ["--lods", "3", "--fragment-size", "64", "-o", str(tmp / "l3f")],
        ),
        Command(
            "zmesh + cloud-volume script (1 level)",
            [sys.executable, str(tmp / "zmesh_layer.py"), str(atlas), str(tmp / "zl")],
        ),
        Command(
            "isoconvert 1 level --with-volume",
            base + ["--lods", "1", "--with-volume", "-o", str(tmp / "l1v")],
        ),
        Command(
            "zmesh + cloud-volume script, voxels too",
            [sys.executable, str(tmp / "zmesh_layer.py"), str(atlas), str(tmp / "zlv"), "voxels"],
        ),
    ]
    return commands, [
        ("isoconvert precomputed, 1 level", "zmesh + cloud-volume script (1 level)", None),
        ("isoconvert 1 level --with-volume", "zmesh + cloud-volume script, voxels too", None),
    ]


def large_layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    """A 512 MB label volume (the atlas at 512^3, uint32) to a layer, once within a
    --max-memory of half its size (read in slabs) and once whole, against zmesh +
    cloud-volume, which hold it whole."""
    atlas = tmp / "atlas512_uint32.npy"
    if not atlas.exists():
        np.save(atlas, np.ascontiguousarray(synthetic_atlas(512).data.T).astype(np.uint32))
    (tmp / "zmesh_layer.py").write_text(ZMESH_LAYER)
    base = [exe, "convert", str(atlas), "--labels", "--format", "precomputed", "--lods", "1"]
    base += ["-f", "-q"]
    commands = [
        Command(
            f"isoconvert 1 level --max-memory {LARGE_BUDGET}",
            base + ["--max-memory", LARGE_BUDGET, "-o", str(tmp / "big_slabs")],
        ),
        Command("isoconvert 1 level, in memory", base + ["-o", str(tmp / "big_whole")]),
        Command(
            "zmesh + cloud-volume script (1 level)",
            [sys.executable, str(tmp / "zmesh_layer.py"), str(atlas), str(tmp / "big_zl")],
        ),
    ]
    return commands, [
        (commands[0].name, "zmesh + cloud-volume script (1 level)", None),
        (commands[1].name, "zmesh + cloud-volume script (1 level)", None),
    ]


def many_objects_volume(n: int = 200, block: int = 8) -> np.ndarray:
    """(X, Y, Z) uint32 labels: a grid of ``(n // block)^3`` cubes of ``block - 2``
    voxels a side, each its own label, background between them (a connectomics
    layer's many small objects: 15,625 at the defaults)."""
    index = np.arange(n) // block
    side = n // block
    labels = index[:, None, None] * side * side + index[None, :, None] * side + index[None, None, :]
    inside = np.arange(n) % block < block - 2
    cubes = inside[:, None, None] & inside[None, :, None] & inside[None, None, :]
    return np.where(cubes, labels + 1, 0).astype(np.uint32)


def many_layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    """A layer of 15,625 small objects: the per-object costs (encoding, manifests,
    shards) rather than the extraction's."""
    volume = tmp / "many_objects.npy"
    if not volume.exists():
        np.save(volume, np.ascontiguousarray(many_objects_volume().T))
    (tmp / "zmesh_layer.py").write_text(ZMESH_LAYER)
    base = [exe, "convert", str(volume), "--labels", "--format", "precomputed", "-f", "-q"]
    one = [*base, "--lods", "1"]
    commands = [
        Command("isoconvert 1 level", one + ["-o", str(tmp / "many_l1")]),
        Command("isoconvert 1 level --sharded", one + ["--sharded", "-o", str(tmp / "many_sh")]),
        Command("isoconvert --legacy-mesh", base + ["--legacy-mesh", "-o", str(tmp / "many_lg")]),
        Command(
            "zmesh + cloud-volume script (legacy)",
            [sys.executable, str(tmp / "zmesh_layer.py"), str(volume), str(tmp / "many_zl")],
        ),
    ]
    peer = "zmesh + cloud-volume script (legacy)"
    return commands, [(c.name, peer, None) for c in commands[:3]]


def one_object_volume(n: int = 448) -> np.ndarray:
    """(X, Y, Z) uint8: one label, a ball of radius about 190 voxels with five bumps
    around z (1.5 million triangles as a label surface)."""
    x, y, z = np.ogrid[:n, :n, :n]
    radius = np.sqrt((x - n / 2) ** 2 + (y - n / 2) ** 2 + (z - n / 2) ** 2)
    bumps = 12 * np.sin(5 * np.arctan2(y - n / 2, x - n / 2))
    return (radius < 190 + bumps).astype(np.uint8)


def one_object_layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    """One object of 1.5 million triangles cut into fragments, within a budget and
    whole: what cutting a large object holds."""
    volume = tmp / "one_object.npy"
    if not volume.exists():
        np.save(volume, np.ascontiguousarray(one_object_volume().T))
    (tmp / "zmesh_layer.py").write_text(ZMESH_LAYER)
    base = [exe, "convert", str(volume), "--labels", "-f", "-q"]
    layer = [*base, "--format", "precomputed", "--lods", "1", "--fragment-size", "64"]
    budget = ["--max-memory", LARGE_BUDGET]
    commands = [
        Command(
            f"isoconvert fragments 64 --max-memory {LARGE_BUDGET}",
            layer + budget + ["-o", str(tmp / "one_b")],
        ),  # fmt: skip
        Command("isoconvert fragments 64, in memory", layer + ["-o", str(tmp / "one_m")]),
        Command(
            f"isoconvert fragments 128 --max-memory {LARGE_BUDGET}",
            [*layer[:-1], "128", *budget, "-o", str(tmp / "one_128")],
        ),  # --fragment-size auto's for this object
        Command(
            f"isoconvert 3 levels, fragments 64 --max-memory {LARGE_BUDGET}",
            [*layer[:-3], "3", *layer[-2:], *budget, "-o", str(tmp / "one_3")],
        ),
        Command(
            f"isoconvert PLY --max-memory {LARGE_BUDGET}",
            base + budget + ["-o", str(tmp / "one.ply")],
        ),  # fmt: skip
        Command(
            "zmesh + cloud-volume script (legacy)",
            [sys.executable, str(tmp / "zmesh_layer.py"), str(volume), str(tmp / "one_zl")],
        ),
    ]
    # the defaults (3 levels, --fragment-size auto: 128-voxel nodes for an object
    # this large) against one fragment a level (inf), in memory and within the budget
    defaults = [*base, "--format", "precomputed"]
    for name, extra in [("in memory", []), (f"--max-memory {LARGE_BUDGET}", budget)]:
        commands += [
            Command(f"isoconvert defaults, {name}", defaults + extra + ["-o", str(tmp / "one_d")]),
            Command(
                f"isoconvert defaults --fragment-size inf, {name}",
                [*defaults, "--fragment-size", "inf", *extra, "-o", str(tmp / "one_i")],
            ),
        ]
    peer = "zmesh + cloud-volume script (legacy)"
    ply = commands[4].name
    return commands, [(commands[0].name, ply, None), (commands[2].name, ply, None),
                      (commands[3].name, ply, None), (commands[1].name, peer, None),
                      (commands[6].name, commands[7].name, None),
                      (commands[8].name, commands[9].name, None)]  # fmt: skip


def layer_level0_faces(folder: Path) -> int | None:
    """Level 0's triangles in a multi-resolution layer, over all its objects and
    fragments (decoded with DracoPy); None if it is not one."""
    import struct

    import DracoPy

    total = 0
    for index in sorted((folder / "mesh").glob("*.index")):
        raw = index.read_bytes()
        (n,) = struct.unpack_from("<I", raw, 24)
        at = 28 + 16 * n
        (count,) = struct.unpack_from("<I", raw, at)
        sizes = np.frombuffer(raw, "<u4", count, at + 4 * n + 12 * count)
        data, start = (folder / "mesh" / index.stem).read_bytes(), 0
        for size in sizes:
            if size:
                total += len(DracoPy.decode(data[start : start + int(size)]).faces)
            start += int(size)
    return total if total else None


def iso_layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    """Isosurfaces large enough to be cut into fragments by default (the binary-mask
    ball at 0.5 and the embryo at 60.5) to layers of one level and of the default
    three, beside the same surface as a PLY and zmesh + cloud-volume's legacy layer
    of the ball's mask: level 0's triangles are printed after."""
    volume = tmp / "one_object.npy"
    if not volume.exists():
        np.save(volume, np.ascontiguousarray(one_object_volume().T))
    (tmp / "zmesh_layer.py").write_text(ZMESH_LAYER)
    embryo = DATASETS / "embryo_256x256x256_uint8.raw"
    inputs = [("ball", [str(volume), "--level", "0.5"])]
    if embryo.exists():
        inputs.append(("embryo", [str(embryo), "--level", "60.5"]))
    commands, pairs, layers = [], [], []
    for name, given in inputs:
        base = [exe, "convert", *given, "-f", "-q"]
        layer = [*base, "--format", "precomputed"]
        out = tmp / f"{name}.ply"
        ply = Command(f"isoconvert {name} PLY", [*base, "-o", str(out)], out)
        one = Command(
            f"isoconvert {name} layer, 1 level", [*layer, "--lods", "1", "-o", f"{out}_1"]
        )
        three = Command(f"isoconvert {name} layer, defaults (3 levels)", [*layer, "-o", f"{out}_3"])
        commands += [ply, one, three]
        pairs.append((one.name, ply.name, None))
        if name == "embryo":  # within a budget below its mesh's own peak
            small = ["--max-memory", "128M"]
            ply_in = Command(f"{ply.name} within 128M", [*ply.argv, *small], out)
            one_in = Command(f"{one.name} within 128M", [*one.argv, *small])
            commands += [ply_in, one_in]
            pairs.append((one_in.name, ply_in.name, None))
        layers.append((name, ply, [Path(f"{out}_1"), Path(f"{out}_3")]))
    peer = Command(
        "zmesh + cloud-volume script, ball (legacy)",
        [sys.executable, str(tmp / "zmesh_layer.py"), str(volume), str(tmp / "ball_zl")],
    )
    commands.append(peer)
    pairs.append(("isoconvert ball layer, 1 level", peer.name, None))

    def level0() -> None:
        for name, ply, folders in layers:
            counts = ply_counts(ply.output)
            faces = [layer_level0_faces(f) for f in folders]
            print(f"{name}: level 0 of the layers {faces[0]:,} and {faces[1]:,} triangles, "
                  f"the PLY {counts[1]:,}")  # fmt: skip

    return commands, pairs, level0


def cluster_layer_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list, object]:
    """The one object's layer made by a local Dask cluster's two workers."""
    volume = tmp / "one_object.npy"
    if not volume.exists():
        np.save(volume, np.ascontiguousarray(one_object_volume().T))
    address = start_cluster(tmp)
    layer = [exe, "convert", str(volume), "--labels", "-f", "-q", "--format", "precomputed"]
    layer += ["--lods", "1", "--fragment-size", "64"]
    commands = [
        Command(
            "isoconvert fragments 64, --scheduler (2 workers)",
            layer + ["--scheduler", address, "-o", str(tmp / "one_c")],
        ),  # fmt: skip
        Command("isoconvert fragments 64, in memory", layer + ["-o", str(tmp / "one_m")]),
    ]
    # the defaults (3 levels, 128-voxel fragments for this object): the workers also
    # collapse its slabs and make its coarser levels from them
    defaults = [exe, "convert", str(volume), "--labels", "-f", "-q", "--format", "precomputed"]
    commands += [
        Command(
            "isoconvert defaults, --scheduler (2 workers)",
            defaults + ["--scheduler", address, "-o", str(tmp / "one_cd")],
        ),  # fmt: skip
        Command("isoconvert defaults, in memory", defaults + ["-o", str(tmp / "one_md")]),
    ]

    def workers_peak() -> None:
        from distributed import Client

        with Client(address, timeout=30) as client:
            peaks = client.run(_peak_kib)
        text = ", ".join(f"{kib / 1024:.0f} MB" for kib in peaks.values())
        print(f"the workers' peak resident sizes: {text}")

    pairs = [(commands[0].name, commands[1].name, None), (commands[2].name, commands[3].name, None)]
    return commands, pairs, workers_peak


def _peak_kib() -> int:
    """This process's peak resident size (KiB): run on each worker."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def start_cluster(tmp: Path) -> str:
    """A scheduler and two one-thread workers on 127.0.0.1, stopped at exit."""
    import atexit
    import socket
    import subprocess

    from distributed import Client

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask"]
    quiet = {"cwd": tmp, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    processes = [
        subprocess.Popen(
            [*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            **quiet,
        ),
        subprocess.Popen(
            [*dask, "worker", address, "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
            **quiet,
        ),
    ]

    def stop() -> None:
        for process in reversed(processes):
            process.terminate()
            process.wait(30)

    atexit.register(stop)
    with Client(address, timeout=60) as client:
        client.wait_for_workers(2, timeout=60)
    return address


#: --max-memory of the large layer: half the 512 MB volume.
LARGE_BUDGET = "256M"


def normals_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    raw = tmp / "gyroid_384.raw"
    gyroid(384)().tofile(raw)
    argv = [exe, "convert", str(raw), "--shape", "384", "384", "384", "--dtype", "float32"]
    argv += ["--level", "0.1", "-f", "-q"]
    commands = [
        Command(
            "isoconvert --normals", argv + ["--normals", "-o", str(tmp / "n.ply")], tmp / "n.ply"
        ),
        Command("isoconvert", argv + ["-o", str(tmp / "p.ply")], tmp / "p.ply"),
    ]
    return commands, [("isoconvert --normals", "isoconvert", 1.3)]


def ct_print_pipeline(tmp: Path, exe: str) -> tuple[list[Command], list]:
    (tmp / "sk_ct_print.py").write_text(SKIMAGE_CT_PRINT)
    ours = tmp / "ct_iso.stl"
    argv = [exe, "convert", str(CHEST_CT), "--level", str(CT_LEVEL), "--largest"]
    argv += ["--fill-cavities", "--smooth", "10", "--max-error", "0.5", "--close"]
    argv += ["-o", str(ours), "-f", "-q"]
    peer = [sys.executable, str(tmp / "sk_ct_print.py"), str(CHEST_CT), str(CT_LEVEL), "10"]
    peer += ["0.9", str(tmp / "ct_sk.stl")]
    commands = [
        Command("isoconvert convert", argv, ours),
        Command("scikit-image + trimesh + fast-simplification", peer, tmp / "ct_sk.stl"),
    ]
    # no target: the peer neither bounds its decimation nor caps the surface
    return commands, [("isoconvert convert", "scikit-image + trimesh + fast-simplification", None)]


def ct_bound(tmp: Path, exe: str, rounds: int) -> None:
    """``--max-error 1`` on the chest CT: time, triangles removed, both distances."""
    import trimesh

    full, decimated = tmp / "ct_full.ply", tmp / "ct_bound.ply"
    base = [exe, "convert", str(CHEST_CT), "--level", str(CT_LEVEL), "-f", "-q"]
    undecimated = Command("undecimated", base + ["-o", str(full)])
    if run_once(undecimated) is None:
        print(f"\nct-bound: the undecimated surface failed: {undecimated.note}")
        return
    cmd = Command("isoconvert --max-error 1", base + ["--max-error", "1", "-o", str(decimated)])
    time_rounds([cmd], rounds)
    print("\nct-bound: chest CT 512x512x64, level 300.5 HU, --max-error 1 (mm)")
    if not cmd.seconds:
        print(f"not timed: {cmd.note}")
        return
    before = trimesh.load(full, process=False)
    after = trimesh.load(decimated, process=False)
    removed = 1 - len(after.faces) / len(before.faces)
    # original -> result: every vertex of the undecimated surface, and points
    # spread over its triangles
    spread, _ = trimesh.sample.sample_surface(before, 200_000, seed=2)
    points = np.concatenate([before.vertices, spread])
    _, forward, _ = trimesh.proximity.closest_point(after, points)
    # result -> original: points spread over the result's triangles
    samples, _ = trimesh.sample.sample_surface(after, 200_000, seed=1)
    _, backward, _ = trimesh.proximity.closest_point(before, samples)
    med = statistics.median(cmd.seconds)
    print(
        f"median {med:.1f} s (best {min(cmd.seconds):.1f} s; target under 15 s: "
        f"{'met' if med < 15 else 'NOT met'}); {len(before.faces):,} -> {len(after.faces):,} "
        f"triangles, {100 * removed:.1f} % removed (target over 70 %: "
        f"{'met' if removed > 0.7 else 'NOT met'})"
    )
    print(
        f"original within {forward.max():.3f} of the result (its vertices and 200,000 "
        f"points on it); result within {backward.max():.3f} of the original (200,000 "
        f"points); bound 1 both ways: "
        f"{'met' if max(forward.max(), backward.max()) <= 1 else 'NOT met'}"
    )


PIPELINES = {
    "engine": ("engine 256x256x128: largest, smooth 20, decimate 0.9, STL", engine_pipeline),
    "atlas": ("40-label 256^3 atlas: one PLY per label", atlas_pipeline),
    "layer": ("40-label 256^3 atlas: a Neuroglancer precomputed layer", layer_pipeline),
    "layer-large": (
        "40-label 512^3 uint32 atlas (512 MB): a layer, within --max-memory and whole",
        large_layer_pipeline,
    ),
    "layer-many": ("15,625 small objects (200^3 uint32): a layer", many_layer_pipeline),
    "layer-one": ("one object, 1.5 M triangles (448^3 uint8): a layer", one_object_layer_pipeline),
    "layer-iso": ("isosurfaces of 1-1.5 M triangles: layers, level 0 cut", iso_layer_pipeline),
    "layer-cluster": ("the same object's layer on a local Dask cluster", cluster_layer_pipeline),
    "normals": ("gyroid 384^3 float32 -> PLY, with and without --normals", normals_pipeline),
    "ct-print": ("chest CT -> printable STL", ct_print_pipeline),
}
NEEDS = {"engine": ENGINE, "ct-print": CHEST_CT, "ct-bound": CHEST_CT}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="one timed round")
    names = [*PIPELINES, "ct-bound"]
    parser.add_argument("--only", nargs="+", choices=names, default=names)
    args = parser.parse_args(argv)
    rounds = 1 if args.quick else args.rounds
    exe = start(rounds)
    with tempfile.TemporaryDirectory(prefix="isoconvert-pipeline-") as name:
        tmp = Path(name)
        for key in args.only:
            if key in NEEDS and not NEEDS[key].exists():
                print(f"\n{key} skipped: {NEEDS[key]} not found (set ISOCONVERT_DATASETS)")
                continue
            if key == "ct-bound":
                ct_bound(tmp, exe, rounds)
                continue
            title, build = PIPELINES[key]
            commands, pairs, *after = build(tmp, exe)
            time_rounds(commands, rounds)
            print_pipeline(title, commands, pairs)
            for report in after:  # what the commands' own peaks leave out
                report()
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
