"""Issue #9: the report's compiled kernels give the answers of straightforward code.

The kernels (src/report.cpp) merge positions by hash buckets, list corners by
vertex with a counting sort and judge every edge around its lower end. Here a
plain Python reference, written for clarity on small meshes, computes the
whole report (counts, checks, examples in their order, topology, measures)
and the kernels must agree with it on random meshes made to have every kind
of problem. Speed is measured by bench/bench_report.py, not asserted here.
"""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from conftest import ball
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert import Mesh, Volume, extract, write_mesh
from isoconvert import report as report_module
from isoconvert.geometry import flat_bound, flat_triangles, triangle_cross
from isoconvert.graph import edge_table, merge_positions, mix64, row_groups
from isoconvert.meshfile import read_mesh
from isoconvert.report import BOUNDING_BOX_NOTE, NO_FRAME_NOTE, _Frame, check_mesh

# --- the reference ---------------------------------------------------------------------------


def _pos(p) -> list[float]:
    return [float(x) for x in p]


def reference_report(mesh: Mesh, examples: int = 5) -> dict:
    """The report of a triangle mesh by direct enumeration (dicts and loops)."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    n_vertices, n_tris = len(v), len(cells)
    # distinct positions, numbered in the order row_groups puts them in
    u = v + 0.0
    order, new = row_groups(u)
    rank = np.empty(n_vertices, dtype=np.int64)
    rank[order] = np.cumsum(new) - 1
    n_u = int(new.sum())
    first: dict[int, int] = {}
    for i in range(n_vertices):
        first.setdefault(int(rank[i]), i)
    unique = np.array([u[first[r]] for r in range(n_u)]).reshape(-1, 3)
    tris = rank[cells]
    problems: dict = {}

    zero = sorted(
        {
            (min(a, b), max(a, b))
            for c in cells.tolist()
            for a, b in ((c[0], c[1]), (c[1], c[2]), (c[2], c[0]))
            if rank[a] == rank[b]  # one position: two indices, or one index twice
        }
    )
    problems["zero_length_edges"] = {
        "count": len(zero),
        "examples": [{"vertices": [a, b], "position": _pos(v[a])} for a, b in zero[:examples]],
    }

    repeated = [len(set(t)) < 3 for t in tris.tolist()]
    flat = flat_triangles(unique, tris, triangle_cross(unique, tris))
    degenerate = [t for t in range(n_tris) if repeated[t] or flat[t]]
    problems["degenerate_triangles"] = {
        "count": len(degenerate),
        "examples": [
            {
                "triangle": t,
                "reason": "repeated vertex" if repeated[t] else "zero area",
                "position": _pos(unique[tris[t, 0]]),
            }
            for t in degenerate[:examples]
        ],
    }

    kept = [t for t in range(n_tris) if not repeated[t]]
    uses = defaultdict(list)  # (lo, hi) -> [(triangle, start vertex)]
    for t in kept:
        x = tris[t].tolist()
        for j in range(3):
            a, b = x[j], x[(j + 1) % 3]
            uses[(min(a, b), max(a, b))].append((t, a))
    edges = sorted(uses)

    def edge_examples(chosen):
        return [
            {
                "vertices": [first[a], first[b]],
                "position": _pos(0.5 * (unique[a] + unique[b])),
            }
            for a, b in chosen[:examples]
        ]

    frame = _Frame(v, mesh.info.get("grid"), mesh.info, "mesh")
    boundary = [e for e in edges if len(uses[e]) == 1]
    if boundary:
        ends = np.array(boundary)
        on = frame.same_face(unique[ends[:, 0]], unique[ends[:, 1]]).tolist()
    else:
        on = []
    on_domain = [e for e, flag in zip(boundary, on, strict=True) if flag]
    holes = [e for e, flag in zip(boundary, on, strict=True) if not flag]
    nonmanifold = [e for e in edges if len(uses[e]) > 2]
    inconsistent = [e for e in edges if len(uses[e]) == 2 and uses[e][0][1] == uses[e][1][1]]
    problems["boundary_edges_on_domain_boundary"] = {
        "count": len(on_domain),
        "examples": edge_examples(on_domain),
    }
    problems["boundary_edges_inside"] = {"count": len(holes), "examples": edge_examples(holes)}
    problems["non_manifold_edges"] = {
        "count": len(nonmanifold),
        "examples": edge_examples(nonmanifold),
    }
    problems["inconsistently_oriented_edges"] = {
        "count": len(inconsistent),
        "examples": edge_examples(inconsistent),
    }

    same = defaultdict(list)
    for t in kept:
        same[tuple(sorted(tris[t].tolist()))].append(t)
    groups = [(triple, g) for triple, g in same.items() if len(g) > 1]
    if nonmanifold:  # the order of the hash of the sorted merged numbers
        h = {}
        for triple, _ in groups:
            bits = np.array(triple, dtype=np.int64).view(np.uint64)
            x = mix64(bits[:1])
            for b in bits[1:]:
                x = mix64(x ^ b)
            h[triple] = int(x[0])
        groups.sort(key=lambda item: (h[item[0]], item[0]))
    else:
        groups.sort(key=lambda item: item[1][0])
    problems["duplicate_triangles"] = {
        "count": sum(len(g) - 1 for _, g in groups),
        "examples": [
            {"triangles": g, "position": _pos(unique[tris[g[0], 0]])} for _, g in groups[:examples]
        ],
    }

    # fans: around each vertex, triangles joined across edges used exactly twice
    around = defaultdict(list)
    for t in kept:
        for r in set(tris[t].tolist()):
            around[r].append(t)
    fans = {}
    for r, ts in around.items():
        label = {t: t for t in ts}

        def find(t, label=label):
            while label[t] != t:
                t = label[t]
            return t

        for e in edges:
            if r in e and len(uses[e]) == 2:
                a, b = find(uses[e][0][0]), find(uses[e][1][0])
                label[max(a, b)] = min(a, b)
        fans[r] = sum(1 for t in ts if find(t) == t)
    bad = sorted(r for r, n in fans.items() if n > 1)
    problems["non_manifold_vertices"] = {
        "count": len(bad),
        "examples": [
            {"vertex": first[r], "fans": fans[r], "position": _pos(unique[r])}
            for r in bad[:examples]
        ],
    }

    # components of the used vertices, through the kept triangles' edges
    used = sorted(around)
    component = {r: r for r in used}

    def root(r):
        while component[r] != r:
            r = component[r]
        return r

    for a, b in edges:
        ra, rb = root(a), root(b)
        component[max(ra, rb)] = min(ra, rb)
    per: dict = defaultdict(lambda: {"v": 0, "e": 0, "f": 0, "open": False, "bad": False})
    for r in used:
        per[root(r)]["v"] += 1
        per[root(r)]["bad"] |= fans[r] > 1
    for e in edges:
        per[root(e[0])]["e"] += 1
        per[root(e[0])]["open"] |= len(uses[e]) != 2
    for t in kept:
        per[root(int(tris[t, 0]))]["f"] += 1
    components = []
    for smallest in sorted(per, key=lambda c: (-per[c]["f"], c)):
        c = per[smallest]
        chi = c["v"] - c["e"] + c["f"]
        entry = {"triangles": c["f"], "vertices": c["v"], "euler": chi, "closed": not c["open"]}
        if not c["open"] and not c["bad"] and chi % 2 == 0:
            entry["genus"] = (2 - chi) // 2
        components.append(entry)

    watertight = bool(kept) and not boundary and not nonmanifold
    oriented = not inconsistent
    measures = {"area": 0.5 * float(np.linalg.norm(triangle_cross(unique, tris), axis=1).sum())}
    if watertight and oriented:
        c = unique[used].mean(axis=0)
        volume = np.einsum("ij,ij->", unique[tris[:, 0]] - c, triangle_cross(unique, tris)) / 6
        measures["volume"] = float(volume)
    referenced = set(tris.reshape(-1).tolist())
    checks = {
        "watertight": watertight,
        "manifold": not nonmanifold and not bad,
        "oriented": oriented,
        "no-zero-length": not zero,
        "no-degenerate": not degenerate,
        "no-duplicates": not groups,
        "no-holes": not holes,
    }
    non_finite = np.flatnonzero(~np.isfinite(v).all(axis=1)).tolist()
    problems["non_finite_vertices"] = {
        "count": len(non_finite),
        "examples": [{"vertex": i} for i in non_finite[:examples]],
    }
    if non_finite or not components:  # no face: nothing passes (not even vacuously)
        checks = {name: False for name in checks}
    notes = [] if components else [report_module.NO_FACE_NOTE]
    if frame.name != "grid" and frame.used:
        notes.append({"bounding box": BOUNDING_BOX_NOTE, "none": NO_FRAME_NOTE}[frame.name])
    return {
        "schema": "isoconvert-report",
        "schema_version": report_module.SCHEMA_VERSION,
        "source": str(mesh.info.get("source", "")),
        "kind": "triangles",
        "boundary_frame": frame.name,
        "counts": {
            "vertices": n_vertices,
            "merged_vertices": n_vertices - n_u,
            "unreferenced_vertices": n_u - len(referenced),
            "edges": len(edges),
            "triangles": n_tris,
        },
        "checks": checks,
        "problems": problems,
        "topology": {
            "components": len(components),
            "euler_characteristic": len(used) - len(edges) + len(kept),
            "per_component": components,
        },
        "measures": measures,
        "notes": notes,
    }


def assert_same_report(mesh: Mesh, examples: int = 5) -> dict:
    """check_mesh's JSON form equals the reference's (the volume to rounding)."""
    got = json.loads(json.dumps(check_mesh(mesh, examples=examples).to_dict()))
    want = json.loads(json.dumps(reference_report(mesh, examples)))
    # the extraction record echoes mesh.info (tests/test_trilinear_extract.py
    # checks it from files); the reference enumerates geometry only
    made = got.pop("extraction", {})
    assert (made.get("method"), made.get("ambiguity")) == (
        (mesh.info.get("method"), mesh.info.get("ambiguity")) if made else (None, None)
    )
    got_volume = got["measures"].pop("volume", None)
    want_volume = want["measures"].pop("volume", None)
    for key in want:
        assert got[key] == want[key], key
    assert got == want
    assert (got_volume is None) == (want_volume is None)
    if want_volume is not None:
        assert got_volume == pytest.approx(want_volume, rel=1e-12, abs=1e-12)
    return got


# --- random meshes with every kind of problem ------------------------------------------------


def grid_surface(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The closed surface of an n x n x n box of unit cubes, triangulated (with
    each face's diagonal chosen at random), outward normals."""
    pts = {}
    cells = []

    def index(p):
        return pts.setdefault(p, len(pts))

    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for side in (0, n):
            for i in range(n):
                for j in range(n):
                    quad = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        p = [0, 0, 0]
                        p[axis], p[a], p[b] = side, i + di, j + dj
                        quad.append(index(tuple(p)))
                    if side == 0:
                        quad = quad[::-1]
                    q0, q1, q2, q3 = quad
                    if rng.random() < 0.5:
                        cells += [[q0, q1, q2], [q0, q2, q3]]
                    else:
                        cells += [[q0, q1, q3], [q1, q2, q3]]
    vertices = np.array(sorted(pts, key=pts.get), dtype=np.float64)
    return vertices, np.array(cells, dtype=np.int64)


def spoiled(rng: np.random.Generator, vertices, cells) -> Mesh:
    """A mesh with some of: holes, flipped and duplicated triangles, triangles
    with a repeated vertex, flat slivers, welded copies of vertices, a second
    touching copy, -0.0 coordinates, a shuffled vertex order."""
    v, c = vertices.copy(), cells.copy()
    n = len(c)
    if rng.random() < 0.5:  # holes
        c = c[rng.random(n) > rng.choice([0.02, 0.2])]
    if rng.random() < 0.4:  # flipped
        flip = rng.random(len(c)) < 0.1
        c[flip] = c[flip][:, ::-1]
    if rng.random() < 0.4:  # duplicated, either way round
        extra = c[rng.integers(0, len(c), int(rng.integers(1, 6)))]
        c = np.vstack([c, extra if rng.random() < 0.5 else extra[:, ::-1]])
    if rng.random() < 0.3:  # a second copy sharing some vertices: non-manifold
        c = np.vstack([c, np.roll(c[: len(c) // 3], 1, axis=1)])
    if rng.random() < 0.3:  # repeated vertex
        t = c[rng.integers(0, len(c), 2)].copy()
        t[:, 1] = t[:, 0]
        c = np.vstack([c, t])
    if rng.random() < 0.3:  # a flat sliver of new vertices
        base = len(v)
        v = np.vstack([v, [[0.25, 0.5, 0.5], [0.5, 0.5, 0.5], [0.75, 0.5, 0.5]]])
        c = np.vstack([c, [[base, base + 1, base + 2]]])
    if rng.random() < 0.4:  # copies of vertices at the same positions (merged)
        pick = rng.integers(0, len(v), int(rng.integers(1, 8)))
        copies = len(v) + np.arange(len(pick))
        v = np.vstack([v, v[pick]])
        for old, new in zip(pick, copies, strict=True):
            rows = np.flatnonzero((c == old).any(axis=1))[:1]
            c[rows] = np.where(c[rows] == old, new, c[rows])
    if rng.random() < 0.2:  # a vertex used by nothing
        v = np.vstack([v, [[9.0, 9.0, 9.0]]])
    if rng.random() < 0.3:
        v[v == 0.0] = -0.0
    if rng.random() < 0.3:  # shuffled vertex order
        perm = rng.permutation(len(v))
        inverse = np.empty_like(perm)
        inverse[perm] = np.arange(len(perm))
        v, c = v[perm], inverse[c]
    if rng.random() < 0.2:  # a triangle soup (as STL stores it)
        v, c = v[c.reshape(-1)], np.arange(3 * len(c)).reshape(-1, 3)
    return Mesh(v, c)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4), examples=st.integers(0, 7))
def test_report_equals_the_reference_on_spoiled_grid_surfaces(seed, n, examples):
    rng = np.random.default_rng(seed)
    mesh = spoiled(rng, *grid_surface(rng, n))
    assert_same_report(mesh, examples)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_vertices=st.integers(1, 12),
    n_cells=st.integers(1, 40),
)
def test_report_equals_the_reference_on_random_triangles(seed, n_vertices, n_cells):
    """Few positions, many triangles: every edge non-manifold, duplicates in groups."""
    rng = np.random.default_rng(seed)
    vertices = rng.integers(0, 2, size=(n_vertices, 3)).astype(np.float64)
    cells = rng.integers(0, n_vertices, size=(n_cells, 3))
    assert_same_report(Mesh(vertices, cells), examples=int(rng.integers(0, 8)))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), pieces=st.integers(2, 8), size=st.integers(1, 4))
def test_report_equals_the_reference_on_separate_pieces(seed, pieces, size):
    """Components of equal size, listed by their first merged position, and
    "pillows" (a triangle and itself reversed: duplicates in a manifold mesh)."""
    rng = np.random.default_rng(seed)
    grid, faces = grid_surface(rng, 3)
    vertices, cells = [], []
    for k in range(pieces):
        if rng.random() < 0.3:
            piece = faces[rng.integers(0, len(faces))]
            piece = np.array([piece, piece[::-1]])
        else:
            start = int(rng.integers(0, len(faces) - size))
            piece = faces[start : start + size]
        used, local = np.unique(piece, return_inverse=True)
        cells.append(local.reshape(-1, 3) + sum(len(p) for p in vertices))
        vertices.append(grid[used] + 10.0 * k)
    v, c = np.vstack(vertices), np.vstack(cells)
    perm = rng.permutation(len(v))
    inverse = np.empty_like(perm)
    inverse[perm] = np.arange(len(perm))
    assert_same_report(Mesh(v[perm], inverse[c]), examples=8)


def test_report_equals_the_reference_on_extracted_meshes():
    for level, offset in ((0.0, 1e-3), (0.5, 0.0)):
        mesh = extract(Volume(ball(12, 4.0)), level, vertex_offset=offset)
        assert_same_report(mesh)
        assert_same_report(mesh.flipped())
    # two balls touching along grid vertices: non-manifold vertices, merged positions
    data = np.maximum(ball(13, 3.0, center=(3, 6, 6)), ball(13, 3.0, center=(9, 6, 6)))
    assert_same_report(extract(Volume(data), 0.0, vertex_offset=0))


def test_area_is_numpys_sum_to_the_bit_on_large_meshes():
    """The kernel sums |cross| in numpy's pairwise order (subtrees of 2**15 triangles)."""
    rng = np.random.default_rng(5)
    for n in (1, 7, 8, 129, 40_000, 100_003):
        vertices = rng.normal(size=(n + 2, 3)) * 10.0 ** rng.uniform(-3, 3, size=(n + 2, 1))
        cells = np.column_stack([np.arange(n), np.arange(n) + 1, np.arange(n) + 2])
        expected = 0.5 * float(np.linalg.norm(triangle_cross(vertices, cells), axis=1).sum())
        assert check_mesh(Mesh(vertices, cells)).measures["area"] == expected, n


# --- the pieces ------------------------------------------------------------------------------


def numpy_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges of the triangles without a repeated vertex, by np.unique."""
    t = triangles[
        (triangles[:, 0] != triangles[:, 1])
        & (triangles[:, 1] != triangles[:, 2])
        & (triangles[:, 0] != triangles[:, 2])
    ]
    pairs = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0, return_counts=True)


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_vertices=st.integers(1, 300),
    n_cells=st.integers(0, 400),
    dtype=st.sampled_from([np.int32, np.int64]),
)
def test_edge_table_has_the_multiplicities_of_np_unique(seed, n_vertices, n_cells, dtype):
    rng = np.random.default_rng(seed)
    triangles = rng.integers(0, n_vertices, size=(n_cells, 3))
    if n_cells and rng.random() < 0.5:  # duplicates, either way round
        extra = triangles[rng.integers(0, n_cells, n_cells // 2)]
        triangles = np.vstack([triangles, extra[:, ::-1] if rng.random() < 0.5 else extra])
    edges, counts = edge_table(triangles.astype(dtype), n_vertices)
    want_edges, want_counts = numpy_edges(triangles)
    assert np.array_equal(edges, want_edges.reshape(-1, 2))
    assert np.array_equal(counts, want_counts)


def test_edge_table_of_a_closed_surface_uses_every_edge_twice():
    rng = np.random.default_rng(1)
    vertices, cells = grid_surface(rng, 5)
    edges, counts = edge_table(cells, len(vertices))
    assert (counts == 2).all()
    assert len(vertices) - len(edges) + len(cells) == 2


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 200))
def test_merged_positions_are_those_of_row_groups(seed, n):
    """Keys order the positions as row_groups numbers them; rep is each position's
    smallest index; -0.0 and 0.0 are one position."""
    rng = np.random.default_rng(seed)
    vertices = rng.integers(-1, 2, size=(n, 3)).astype(np.float64)
    vertices[rng.random((n, 3)) < 0.2] *= -0.0
    if n and rng.random() < 0.3:
        vertices[rng.integers(0, n)] = np.nan
    if n and rng.random() < 0.3:
        vertices[rng.integers(0, n), rng.integers(0, 3)] = -np.inf
    vertices *= 10.0 ** rng.integers(-3, 4)
    merged = merge_positions(vertices)
    assert flat_bound(vertices, merged.magnitude) == flat_bound(vertices)
    order, new = row_groups(vertices + 0.0)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.cumsum(new) - 1
    assert merged.unique == int(new.sum())
    first = np.full(merged.unique, n)
    np.minimum.at(first, rank, np.arange(n))
    assert np.array_equal(merged.rep, first[rank])
    assert np.array_equal(merged.ranks(np.arange(n)), rank)
    # keys sort the positions as ranks do
    assert np.array_equal(np.argsort(merged.key, kind="stable"), np.argsort(rank, kind="stable"))


def test_report_does_not_depend_on_threads_or_index_width(monkeypatch):
    rng = np.random.default_rng(3)
    mesh = spoiled(rng, *grid_surface(rng, 6))
    mesh = Mesh(np.vstack([mesh.vertices] * 2), np.vstack([mesh.cells, mesh.cells[::-1]]))
    first = check_mesh(mesh).to_dict()
    monkeypatch.setenv("ISOCONVERT_THREADS", "1")
    assert check_mesh(mesh).to_dict() == first
    monkeypatch.delenv("ISOCONVERT_THREADS")
    # int64 indices inside the kernels, as for meshes beyond 2**31 corners
    monkeypatch.setattr(report_module, "index_dtype", lambda *counts: np.dtype(np.int64))
    assert check_mesh(mesh).to_dict() == first
    # int32 cells are read as they are
    assert check_mesh(Mesh(mesh.vertices, mesh.cells.astype(np.int32))).to_dict() == first


def test_binary_ply_reads_back_exactly(tmp_path):
    mesh = extract(Volume(ball(16, 5.0)), 0.0)
    path = write_mesh(mesh, tmp_path / "ball.ply")
    back = read_mesh(path)
    assert back.cells.dtype == np.int64 and back.cells.flags.c_contiguous
    assert np.array_equal(back.cells, mesh.cells)
    stored = back.info["stored_precision"]
    assert np.array_equal(back.vertices, mesh.vertices.astype(stored).astype(np.float64))
    assert check_mesh(back).to_dict()["counts"] == check_mesh(mesh).to_dict()["counts"]
