"""The compiled Marching Cubes kernel (src/cubes.cpp, Flying Edges manner).

Checked against a direct numpy evaluation of the same table on every cube, on
grids whose rows straddle the kernel's 64-sample words, in every sample type;
against VTK's vtkFlyingEdges3D on every real scan; and for the properties the
kernel promises: its first pass's statistics, thread-independent output, and
the documented vertex and triangle order.
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import edge_key, read_real_scan, real_scan_names, vtk_flying_edges

from isoconvert import Volume, extract
from isoconvert.errors import IsoconvertError
from isoconvert.extract.tables import EDGE_AXIS, EDGE_BASE, marching_cubes_table


def reference_cubes(zyx: np.ndarray, level: float, rule: str = "separate-positive"):
    """Triangles as sorted-rotation triples of global edge ids, and the ids of
    bipolar edges, by evaluating the table on every cube with numpy (float64)."""
    nz, ny, nx = zyx.shape
    pos = zyx.astype(np.float64) >= level
    config = np.zeros((nz - 1, ny - 1, nx - 1), dtype=np.int64)
    for v in range(8):
        dx, dy, dz = v & 1, (v >> 1) & 1, (v >> 2) & 1
        config |= pos[dz : nz - 1 + dz, dy : ny - 1 + dy, dx : nx - 1 + dx].astype(np.int64) << v
    counts, table = marching_cubes_table(rule)
    k, j, i = np.nonzero(counts[config])
    tris = []
    for t in range(table.shape[1]):
        has = counts[config[k, j, i]] > t
        kk, jj, ii = k[has], j[has], i[has]
        edges = table[config[kk, jj, ii], t]  # (n, 3) cube edges
        ids = np.empty(edges.shape, dtype=np.int64)
        for c in range(3):
            e = edges[:, c]
            base = EDGE_BASE[e]
            gi, gj, gk = ii + base[:, 0], jj + base[:, 1], kk + base[:, 2]
            ids[:, c] = 3 * (gi + nx * (gj + ny * gk)) + EDGE_AXIS[e]
        tris.append(np.column_stack([kk, jj, ii, np.full(len(kk), t), ids]))
    tris = np.concatenate(tris)
    tris = tris[np.lexsort(tris[:, 3::-1].T)][:, 4:]  # cube order, then table order
    bipolar = []
    for axis, (dz, dy, dx) in enumerate([(0, 0, 1), (0, 1, 0), (1, 0, 0)]):
        a = pos[: nz - dz, : ny - dy, : nx - dx]
        b = pos[dz:, dy:, dx:]
        kk, jj, ii = np.nonzero(a != b)
        bipolar.append(3 * (ii + nx * (jj + ny * kk)) + axis)
    return tris, np.sort(np.concatenate(bipolar))


def as_id_triangles(mesh) -> np.ndarray:
    return mesh.edge_ids[mesh.cells]


def values(dtype, shape, rng):
    """Random samples of ``dtype`` spanning the type's sign and range."""
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return (rng.standard_normal(shape) * 3).astype(dtype)
    info = np.iinfo(dtype)
    # a few values near the type's ends and around the signed/unsigned middle
    pool = np.array(
        [info.min, info.min + 1, 0, 1, 2, info.max // 2, info.max // 2 + 1, info.max - 1, info.max],
        dtype=np.int64,
    )
    pool = np.unique(np.clip(pool, info.min, info.max))
    return rng.choice(pool, shape).astype(dtype)


WIDTHS = [2, 3, 63, 64, 65, 129]
DTYPES = ["uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"]


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("nx", WIDTHS)
def test_kernel_equals_table_on_every_cube(dtype, nx):
    rng = np.random.default_rng(nx * 31 + len(dtype))
    zyx = values(dtype, (4, 5, nx), rng)
    levels = sorted(set(np.unique(zyx.astype(np.float64)).tolist()))
    # a level equal to samples, one between two values, and the largest one
    for level in {levels[len(levels) // 2], (levels[0] + levels[1]) / 2, levels[-1]}:
        mesh = extract(Volume(zyx.T), level, vertex_offset=0)
        tris, bipolar = reference_cubes(zyx, level)
        assert np.array_equal(np.sort(mesh.edge_ids), bipolar)
        assert np.array_equal(as_id_triangles(mesh), tris)


@pytest.mark.parametrize("rule", ["separate-positive", "separate-negative"])
def test_both_ambiguity_rules_follow_their_table(rule):
    rng = np.random.default_rng(7)
    zyx = rng.random((6, 7, 70))
    mesh = extract(Volume(zyx.T), 0.5, ambiguity=rule)
    tris, bipolar = reference_cubes(zyx, 0.5, rule)
    assert np.array_equal(as_id_triangles(mesh), tris)


def test_vertex_and_triangle_order_follow_the_grid():
    """Vertices by row (j + Y k), then axis, then x; triangles by cube row and x."""
    rng = np.random.default_rng(3)
    zyx = rng.random((7, 9, 130))
    nz, ny, nx = zyx.shape
    mesh = extract(Volume(zyx.T), 0.5)
    ids = mesh.edge_ids
    axis, cell = ids % 3, ids // 3
    i, row = cell % nx, cell // nx
    key = np.column_stack([row, axis, i])
    assert (np.diff(np.lexsort(key.T[::-1])) == 1).all()
    tris, _ = reference_cubes(zyx, 0.5)
    assert np.array_equal(as_id_triangles(mesh), tris)  # reference is in cube order


def test_output_is_bit_identical_for_any_thread_count(monkeypatch):
    x = np.linspace(0, 4 * np.pi, 90)
    g = (
        np.sin(x)[:, None, None] * np.cos(x)[None, :, None]
        + np.sin(x)[None, :, None] * np.cos(x)[None, None, :]
    )
    vol = Volume(g.astype(np.float32)[:, :, :77])
    meshes = []
    for threads in ("1", "2", "3", "8"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        meshes.append(extract(vol, 0.1))
    # more threads than this machine has CPUs, straight through the kernel
    from isoconvert import _native
    from isoconvert.extract.cubes import CubesBlock

    zyx = np.ascontiguousarray(vol.data.T)
    scan = _native.scan_rows(zyx, 0.1, False, 0.0, 7)
    v, i, t = CubesBlock(vol.affine, vol.origin, vol.shape, threads=7).extract(zyx, scan)
    meshes.append(type(meshes[0])(v, t, i))
    for m in meshes[1:]:
        assert m.vertices.tobytes() == meshes[0].vertices.tobytes()
        assert m.cells.tobytes() == meshes[0].cells.tobytes()
        assert m.edge_ids.tobytes() == meshes[0].edge_ids.tobytes()


@pytest.mark.parametrize("value", ["two", "2.5", "0", "-1"])
def test_bad_thread_count_is_a_clear_error(monkeypatch, value):
    monkeypatch.setenv("ISOCONVERT_THREADS", value)
    with pytest.raises(IsoconvertError, match="ISOCONVERT_THREADS must be a whole number"):
        extract(Volume(np.random.default_rng(0).random((4, 4, 4))), 0.5)


def test_more_threads_than_cpus_are_capped(monkeypatch):
    from isoconvert.threads import available_cpus, kernel_threads

    monkeypatch.setenv("ISOCONVERT_THREADS", "1000")
    assert kernel_threads() == available_cpus()
    monkeypatch.setenv("ISOCONVERT_THREADS", "1")
    assert kernel_threads() == 1


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_first_pass_statistics_equal_numpy(dtype):
    from isoconvert import _native

    rng = np.random.default_rng(11)
    zyx = rng.standard_normal((5, 6, 67)).astype(dtype)
    zyx[1, 2, 3] = np.nan
    zyx[4, 5, 66] = np.inf
    zyx[0, 0, :] = -np.inf
    zyx[2, 3, 10:13] = 0.25
    zyx[3, 1, 63:67] = 0.25  # past the last whole block of 16 samples too
    scan = _native.scan_rows(zyx, 0.25, True, 0.25, 2)
    finite = zyx[np.isfinite(zyx)]
    assert (scan.min, scan.max) == (finite.min(), finite.max())
    assert scan.nonfinite == (~np.isfinite(zyx)).sum()
    assert scan.equal == (zyx == np.float64(0.25)).sum() == 7


def test_all_nonfinite_rows_give_an_empty_range():
    from isoconvert import _native

    scan = _native.scan_rows(np.full((2, 2, 5), np.nan), 0.0, False, 0.0, 1)
    assert scan.nonfinite == 20
    assert scan.min > scan.max


@pytest.mark.parametrize(
    ("dtype", "level"),
    [("float32", 0.1), ("float32", 1e39), ("uint8", 255.5), ("int16", -40000.0)],
)
def test_levels_beyond_what_the_type_holds_are_compared_exactly(dtype, level):
    """The kernel compares in the samples' type; that must agree with float64."""
    rng = np.random.default_rng(5)
    zyx = values(dtype, (3, 4, 66), rng)
    if dtype == "float32":
        zyx[0, 0, :3] = [np.float32(0.1), np.nextafter(np.float32(0.1), np.float32(1)), 0]
    from isoconvert import _native

    scan = _native.scan_rows(zyx, level, False, 0.0, 1)
    counts, table = marching_cubes_table()
    n = _native.count_cubes(zyx, scan, counts, table, None, 1)
    _, bipolar = reference_cubes(zyx, level)
    assert n.vertices == len(bipolar)


@pytest.mark.parametrize("name", real_scan_names())
def test_every_real_scan_matches_vtk_flying_edges(name):
    from isoconvert.stats import histogram, otsu_level

    vol = read_real_scan(name)
    zyx = np.ascontiguousarray(vol.data.T)
    level = otsu_level(histogram(vol.data))
    if np.issubdtype(zyx.dtype, np.integer):
        level = np.floor(level) + 0.5  # half-integer: equal to no sample
    elif (zyx == level).any():
        above = zyx[zyx > level]
        level = (level + float(above.min())) / 2 if above.size else level
    mesh = extract(vol, level)
    points, cells = vtk_flying_edges(zyx, level)
    assert (mesh.n_vertices, mesh.n_cells) == (len(points), len(cells))
    if mesh.n_vertices:
        ours = mesh.vertices - vol.origin
        ours = np.linalg.solve(vol.affine, ours.T).T  # back to index units
        ours_k, _ = edge_key(ours)
        vtk_k, _ = edge_key(points)
        assert np.array_equal(ours_k, vtk_k)


@pytest.mark.parametrize("cuts", [(0, 5, 11, 17), (0, 1, 2, 17), (0, 16, 17)])
def test_blocks_with_global_origin_give_the_whole_mesh_bit_for_bit(cuts):
    """z-slabs sharing one layer, each extracted with its grid offset: every
    vertex equals the whole mesh's vertex of the same edge id, to the bit, and
    the triangles (as id triples) are the whole mesh's, in the same order."""
    from isoconvert import _native
    from isoconvert.extract.cubes import CubesBlock

    rng = np.random.default_rng(2)
    zyx = rng.random((18, 9, 70)).astype(np.float32)
    vol = Volume.from_zyx(zyx, spacing=(0.7, 1.3, 2.1), origin=(5.0, -3.0, 1.5))
    whole = extract(vol, 0.5)
    block = CubesBlock(vol.affine, vol.origin, vol.shape, threads=2)
    ids, verts, tris = [], [], []
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        part = np.ascontiguousarray(zyx[lo : hi + 1])
        scan = _native.scan_rows(part, 0.5, False, 0.0, 2)
        v, i, t = block.extract(part, scan, index_origin=(0, 0, lo))
        ids.append(i)
        verts.append(v)
        tris.append(i[t])
    ids, verts = np.concatenate(ids), np.concatenate(verts)
    first = np.unique(ids, return_index=True)[1]  # a shared layer's vertices come twice
    order = np.argsort(whole.edge_ids)
    assert np.array_equal(ids[first], whole.edge_ids[order])
    assert verts[first].tobytes() == whole.vertices[order].tobytes()
    assert np.array_equal(np.concatenate(tris), whole.edge_ids[whole.cells])


def test_avx2_first_pass_equals_the_baseline_one():
    """float32 volumes take an AVX2 first pass where the CPU has it; the baseline
    (SSE2) pass, forced by ISOCONVERT_SIMD=sse2, must give the same statistics and
    the same mesh, bit for bit, including NaN, +-Inf, samples equal to the level and
    rows of every length around the 64-sample words."""
    script = """
import hashlib, sys
import os
import subprocess
import sys

import numpy as np
from isoconvert import _native, Volume
from isoconvert.extract.cubes import marching_cubes
out = []
rng = np.random.default_rng(5)
for nx in (2, 7, 63, 64, 65, 129, 200):
    zyx = rng.standard_normal((6, 5, nx)).astype(np.float32)
    zyx[zyx > 2.0] = 0.25
    s = _native.scan_rows(zyx, 0.25, True, 0.25, 2)
    out.append((s.min, s.max, s.nonfinite, s.equal))
    m = marching_cubes(Volume.from_zyx(zyx), 0.25)
    out.append(hashlib.sha1(m.vertices.tobytes() + m.cells.tobytes()).hexdigest())
    zyx[1, 2, nx // 2] = np.nan
    zyx[3, 0, nx - 1] = -np.inf
    s = _native.scan_rows(zyx, 0.25, True, 0.25, 1)
    out.append((s.min, s.max, s.nonfinite, s.equal))
print(repr(out))
"""
    runs = []
    for simd in (None, "sse2"):
        env = dict(os.environ)
        env.pop("ISOCONVERT_SIMD", None)
        if simd:
            env["ISOCONVERT_SIMD"] = simd
        proc = subprocess.run(
            [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
        )
        runs.append(proc.stdout)
    assert runs[0] == runs[1]
    # and the statistics are numpy's
    rng = np.random.default_rng(5)
    zyx = rng.standard_normal((6, 5, 65)).astype(np.float32)
    zyx[zyx > 2.0] = 0.25
    zyx[1, 2, 32] = np.nan
    zyx[3, 0, 64] = -np.inf
    from isoconvert import _native

    s = _native.scan_rows(zyx, 0.25, True, 0.25, 2)
    finite = zyx[np.isfinite(zyx)]
    assert (s.min, s.max) == (finite.min(), finite.max())
    assert (s.nonfinite, s.equal) == (2, int((zyx == np.float32(0.25)).sum()))
