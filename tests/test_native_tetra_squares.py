"""The compiled Marching Tetrahedra and slice-wise Marching Squares kernels
(src/tetra.cpp, src/squares.cpp) against a small pure-numpy reference: the same
vertices (by edge id, at the same positions) and the same oriented cells (as
edge-id tuples), their documented order, the same output for any number of
threads, blocks that stitch by id, and scikit-image's contours of each slice."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ball
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from isoconvert import Volume, extract
from isoconvert.extract.squares import _square_tables
from isoconvert.extract.tables import (
    CUBE_TETRAHEDRA,
    SQUARE_CORNERS,
    SQUARE_EDGES,
    TETRA_DIRECTIONS,
    TETRA_EDGE_BASE,
    TETRA_EDGE_DIR,
    marching_squares_table,
    marching_tetrahedra_table,
)

RULES = ("separate-positive", "separate-negative", "asymptotic")

# --- the reference: every cell of the grid, one at a time ---------------------------


def _fraction(s0: float, s1: float, level: float) -> float:
    return (level - s0) / (s1 - s0)


def reference_tetra(data: np.ndarray, level: float):
    """Marching Tetrahedra of (X, Y, Z) ``data``, cube by cube.

    Returns
    -------
    verts : dict
        Edge id ``7 * (i + X * (j + Y * k)) + d`` -> (3,) position in index units.
    tris : list of (3,) tuples
        Triangles as edge ids, in table orientation.
    """
    nx, ny, nz = data.shape
    pos = data >= level
    verts = {}
    for d, (dx, dy, dz) in enumerate(TETRA_DIRECTIONS):
        changes = pos[: nx - dx, : ny - dy, : nz - dz] != pos[dx:, dy:, dz:]
        for i, j, k in zip(*np.nonzero(changes), strict=True):
            t = _fraction(float(data[i, j, k]), float(data[i + dx, j + dy, k + dz]), level)
            verts[7 * (i + nx * (j + ny * k)) + d] = (i + t * dx, j + t * dy, k + t * dz)
    counts, table = marching_tetrahedra_table()
    tris = []
    for k in range(nz - 1):
        for j in range(ny - 1):
            for i in range(nx - 1):
                for t, tet in enumerate(CUBE_TETRAHEDRA):
                    corners = [(i + (v & 1), j + ((v >> 1) & 1), k + (v >> 2)) for v in tet]
                    config = sum(int(pos[c]) << q for q, c in enumerate(corners))
                    entry = 16 * t + config
                    for s in range(counts[entry]):
                        tri = []
                        for e in table[entry, s]:
                            bi, bj, bk = np.array([i, j, k]) + TETRA_EDGE_BASE[e]
                            tri.append(7 * (bi + nx * (bj + ny * bk)) + TETRA_EDGE_DIR[e])
                        tris.append(tuple(int(v) for v in tri))
    return verts, tris


def reference_squares(data: np.ndarray, level: float, axis: int, rule: str):
    """Marching Squares of every slice of (X, Y, Z) ``data`` across ``axis``, square
    by square, in the plane of the axes (b, c) that follow it cyclically; or of a
    2D (X, Y) image (``axis`` ignored, ids ``2 * (i + X * j) + axis``).

    Returns
    -------
    verts : dict
        Edge id -> (3,) position in index units (z = 0 for images).
    segs : list of (2,) tuples
        Segments as edge ids, positive side on the left.
    """
    planar = data.ndim == 2
    if planar:
        data, axis = data[:, :, np.newaxis], 2
    dims = data.shape
    a, b, c = axis, (axis + 1) % 3, (axis + 2) % 3
    pos = data >= level
    counts = marching_squares_table("separate-positive")[0]
    tables = [marching_squares_table(r)[1] for r in RULES[:2]]

    def edge_id(p, along):
        lin = p[0] + dims[0] * (p[1] + dims[1] * p[2])
        return 2 * lin + (0 if along == 0 else 1) if planar else 3 * lin + along

    verts, segs = {}, []
    for s in range(dims[a]):
        for v in range(dims[c]):
            for u in range(dims[b]):
                p = np.zeros(3, np.int64)
                p[[a, b, c]] = s, u, v
                for along in (b, c):  # the in-plane edges from grid vertex p
                    q = p.copy()
                    q[along] += 1
                    if q[along] < dims[along] and pos[tuple(p)] != pos[tuple(q)]:
                        t = _fraction(float(data[tuple(p)]), float(data[tuple(q)]), level)
                        x = p.astype(float)
                        x[along] += t
                        verts[edge_id(p, along)] = tuple(x)
                if u + 1 == dims[b] or v + 1 == dims[c]:
                    continue
                corners = []
                for du, dv in SQUARE_CORNERS:
                    q = p.copy()
                    q[b] += du
                    q[c] += dv
                    corners.append(q)
                f = [float(data[tuple(q)]) for q in corners]
                config = sum(int(pos[tuple(q)]) << n for n, q in enumerate(corners))
                r = RULES.index(rule)
                if r == 2:
                    r = 0
                    if config in (6, 9):
                        saddle = (f[0] * f[3] - f[1] * f[2]) / (f[0] + f[3] - f[1] - f[2])
                        r = 1 if saddle >= level else 0
                ends = [
                    edge_id(corners[e0], b if e < 2 else c)
                    for e, (e0, _) in enumerate(SQUARE_EDGES)
                ]
                for n in range(counts[config]):
                    segs.append(tuple(ends[e] for e in tables[r][config, n]))
    return verts, segs


# --- comparing meshes with the reference --------------------------------------------


def rotated(cells: np.ndarray) -> list[tuple]:
    """Cells as sorted tuples, triangles rotated to start at their smallest entry
    (orientation kept; segments are kept as they are)."""
    out = []
    for cell in cells.tolist():
        m = cell.index(min(cell)) if len(cell) == 3 else 0
        out.append(tuple(cell[m:] + cell[:m]))
    return sorted(out)


def assert_matches(mesh, verts: dict, cells: list) -> None:
    ids = mesh.edge_ids
    assert len(np.unique(ids)) == len(ids)
    assert sorted(ids.tolist()) == sorted(verts)
    expected = np.array([verts[i] for i in ids.tolist()]).reshape(-1, 3)
    np.testing.assert_array_equal(mesh.vertices, expected)
    got = rotated(ids[mesh.cells]) if len(mesh.cells) else []
    assert got == rotated(np.array(cells, dtype=np.int64).reshape(-1, mesh.cells.shape[1]))


def tetra_order_key(ids: np.ndarray, shape) -> np.ndarray:
    """Documented vertex order of tetra: row j + Y * k, then direction, then x."""
    nx, ny, _ = shape
    lin, d = ids // 7, ids % 7
    return np.column_stack([lin // nx, d, lin % nx])


def squares_order_key(ids: np.ndarray, shape, planar: bool) -> np.ndarray:
    """Documented vertex order of squares: row j + Y * k, then edge axis, then x."""
    nx = shape[0]
    n = 2 if planar else 3
    lin, axis = ids // n, ids % n
    return np.column_stack([lin // nx, axis, lin % nx])


def assert_increasing(keys: np.ndarray) -> None:
    order = np.lexsort(keys.T[::-1])
    assert np.array_equal(order, np.arange(len(keys)))
    assert len(np.unique(keys, axis=0)) == len(keys)


small3 = st.tuples(st.integers(2, 6), st.integers(2, 6), st.integers(2, 6))
grids3 = st.one_of(
    arrays(np.uint8, small3, elements=st.integers(0, 4)),
    arrays(np.int16, small3, elements=st.integers(-3, 3)),
    arrays(np.float32, small3, elements=st.sampled_from([-1.0, -0.25, 0.0, 0.5, 2.0])),
)
levels = st.sampled_from([-0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0])


@settings(max_examples=120, deadline=None)
@given(data=grids3, level=levels)
def test_tetra_matches_the_reference_and_its_order(data, level):
    """Values equal to the level included (vertices then sit on grid vertices)."""
    assume(data.min() < level <= data.max())
    mesh = extract(Volume(data), level, method="tetra", vertex_offset=0.0)
    assert_matches(mesh, *reference_tetra(data, level))
    assert_increasing(tetra_order_key(mesh.edge_ids, data.shape))


@settings(max_examples=120, deadline=None)
@given(data=grids3, level=levels, axis=st.sampled_from("xyz"), rule=st.sampled_from(RULES))
def test_slices_match_the_reference_and_their_order(data, level, axis, rule):
    assume(data.min() < level <= data.max())
    verts, segs = reference_squares(data, level, "xyz".index(axis), rule)
    assume(segs)  # else "no slice crosses the level"
    mesh = extract(
        Volume(data), level, method="squares", axis=axis, ambiguity=rule, vertex_offset=0.0
    )
    assert_matches(mesh, verts, segs)
    assert_increasing(squares_order_key(mesh.edge_ids, data.shape, planar=False))


@settings(max_examples=120, deadline=None)
@given(
    data=arrays(
        np.uint8, st.tuples(st.integers(2, 9), st.integers(2, 9)), elements=st.integers(0, 4)
    ),
    level=st.sampled_from([0.5, 1.0, 2.0, 2.5, 4.0]),
    rule=st.sampled_from(RULES),
)
def test_images_match_the_reference_and_their_order(data, level, rule):
    assume(data.min() < level <= data.max())
    mesh = extract(Volume(data), level, method="squares", ambiguity=rule, vertex_offset=0.0)
    assert_matches(mesh, *reference_squares(data, level, 2, rule))
    assert_increasing(squares_order_key(mesh.edge_ids, data.shape, planar=True))


@pytest.mark.parametrize("seed", range(6))
def test_seeded_grids_wider_than_a_word_of_signs(seed):
    """Rows of 60-140 samples span several 64-bit words of the row scan's signs."""
    rng = np.random.default_rng(seed)
    shape = (int(rng.integers(60, 140)), int(rng.integers(2, 4)), int(rng.integers(2, 4)))
    data = (rng.random(shape) * 4).astype(np.uint8)  # 0..3: values at the level
    level = float(rng.integers(1, 4))
    mesh = extract(Volume(data), level, method="tetra", vertex_offset=0.0)
    assert_matches(mesh, *reference_tetra(data, level))
    for a, axis in enumerate("xyz"):
        rule = RULES[(seed + a) % 3]
        mesh = extract(
            Volume(data), level, method="squares", axis=axis, ambiguity=rule, vertex_offset=0.0
        )
        assert_matches(mesh, *reference_squares(data, level, a, rule))


# --- threads, blocks, placement -----------------------------------------------------


def _field() -> np.ndarray:
    """A (Z, Y, X) float32 field with several surfaces, about 2000 rows."""
    rng = np.random.default_rng(7)
    f = ball(48, 15.0, center=(20.3, 24.1, 22.7))[:, :41, :45] + rng.normal(0, 0.7, (48, 41, 45))
    return np.ascontiguousarray(f.T.astype(np.float32))


def _native_tetra(f, level, threads, index_origin=(0, 0, 0), id_dims=None):
    from isoconvert import _native

    counts, triangles = marching_tetrahedra_table()
    tables = (TETRA_DIRECTIONS, CUBE_TETRAHEDRA, counts, triangles, TETRA_EDGE_BASE, TETRA_EDGE_DIR)
    scan = _native.scan_rows(f, level, False, 0.0, threads)
    n = _native.count_tetra(f, scan, *tables, threads)
    out = (
        np.empty((n.vertices, 3)),
        np.empty(n.vertices, np.int64),
        np.empty((n.triangles, 3), np.int64),
    )
    _native.fill_tetra(
        f,
        scan,
        n,
        *tables,
        np.eye(3),
        np.zeros(3),
        np.asarray(index_origin, dtype=np.int64),
        np.asarray(id_dims or (f.shape[2], f.shape[1]), dtype=np.int64),
        0.0,
        False,
        threads,
        *out,
    )
    return out


def _native_squares(f, level, axis, rule, threads, index_origin=(0, 0, 0), id_dims=None):
    from isoconvert import _native

    counts, segments = _square_tables()
    scan = _native.scan_rows(f, level, False, 0.0, threads)
    n = _native.count_squares(f, scan, axis, counts, segments, threads)
    out = (
        np.empty((n.vertices, 3)),
        np.empty(n.vertices, np.int64),
        np.empty((n.segments, 2), np.int64),
    )
    _native.fill_squares(
        f,
        scan,
        n,
        axis,
        counts,
        segments,
        rule,
        False,
        np.eye(3),
        np.zeros(3),
        np.asarray(index_origin, dtype=np.int64),
        np.asarray(id_dims or (f.shape[2], f.shape[1]), dtype=np.int64),
        0.0,
        False,
        threads,
        *out,
    )
    return out


def test_same_output_for_any_number_of_threads():
    f = _field()
    runs = [
        lambda th: _native_tetra(f, 0.0, th),
        *(
            lambda th, a=a, r=r: _native_squares(f, 0.0, a, r, th)
            for a in range(3)
            for r in range(3)
        ),
    ]
    for run in runs:
        one = run(1)
        assert len(one[2]) > 1000
        for threads in (2, 3):
            for x, y in zip(one, run(threads), strict=True):
                assert np.array_equal(x, y)


def test_slabs_stitch_exactly_by_edge_id():
    """Two z-slabs sharing one layer, placed by index_origin in the whole grid's ids,
    give the whole volume's vertices (same ids, same positions) and cells."""
    f = _field()
    nz, ny, nx = f.shape
    k0 = nz // 2
    whole = _native_tetra(f, 0.0, 2)
    lower = _native_tetra(np.ascontiguousarray(f[: k0 + 1]), 0.0, 2, id_dims=(nx, ny))
    upper = _native_tetra(np.ascontiguousarray(f[k0:]), 0.0, 2, (0, 0, k0), (nx, ny))
    for parts, full in [((lower, upper), whole)] + [
        (
            (
                _native_squares(np.ascontiguousarray(f[: k0 + 1]), 0.0, a, 2, 2, id_dims=(nx, ny)),
                _native_squares(np.ascontiguousarray(f[k0:]), 0.0, a, 2, 2, (0, 0, k0), (nx, ny)),
            ),
            _native_squares(f, 0.0, a, 2, 2),
        )
        for a in range(3)
    ]:
        by_id = {}
        for verts, ids, _ in (full, *parts):
            for i, v in zip(ids.tolist(), verts.tolist(), strict=True):
                assert by_id.setdefault(i, v) == v  # one position per id everywhere
        assert set(full[1].tolist()) == set(parts[0][1].tolist()) | set(parts[1][1].tolist())
        cells = [rotated(ids[c]) for _, ids, c in parts]
        # slices across z at the shared layer are contoured in both slabs
        assert sorted(set(cells[0]) | set(cells[1])) == sorted(set(rotated(full[1][full[2]])))
        assert len(cells[0]) + len(cells[1]) >= len(full[2])


@pytest.mark.parametrize("method", ["tetra", "squares-x", "squares-y", "squares-z"])
def test_world_placement_and_mirrored_orientation(method):
    """Vertices come out in world units (origin + A index) and a left-handed map
    reverses the cells, so the positive side stays where it was."""
    name, _, axis = method.partition("-")
    kw = {"axis": axis} if axis else {}
    data = ball(14, 4.5, center=(6.2, 6.9, 5.6))
    plain = extract(Volume(data), 0.0, method=name, vertex_offset=0.0, **kw)
    direction = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # det -1
    spacing, origin = np.array([0.5, 2.0, 1.5]), np.array([3.0, -1.0, 7.0])
    vol = Volume(data, spacing=spacing, origin=origin, direction=direction)
    placed = extract(vol, 0.0, method=name, vertex_offset=0.0, **kw)
    assert np.array_equal(placed.edge_ids, plain.edge_ids)
    np.testing.assert_allclose(placed.vertices, origin + plain.vertices @ vol.affine.T, atol=1e-12)
    assert np.array_equal(placed.cells, plain.cells[:, ::-1])
    flipped = extract(vol, 0.0, method=name, vertex_offset=0.0, flip=True, **kw)
    assert np.array_equal(flipped.cells, plain.cells)


def test_image_vertices_lie_in_the_plane_z_0_in_world_units():
    image = ball(20, 6.0)[:, :, 9]
    vol = Volume(image, spacing=(0.5, 2.0), origin=(1.0, -3.0))
    mesh = extract(vol, 0.0, method="squares", vertex_offset=0.0)
    plain = extract(Volume(image), 0.0, method="squares", vertex_offset=0.0)
    assert np.all(mesh.vertices[:, 2] == 0)
    np.testing.assert_array_equal(
        mesh.vertices[:, :2], plain.vertices[:, :2] * (0.5, 2.0) + (1, -3)
    )


# --- against scikit-image ------------------------------------------------------------


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_slices_agree_with_find_contours(axis):
    """Each slice's segments are those of scikit-image's find_contours of that slice
    (separate-positive is its fully_connected="low")."""
    measure = pytest.importorskip("skimage.measure")
    data = (
        ball(30, 11.0, center=(14.2, 15.1, 13.6)) + 3 * np.sin(np.arange(30) / 3.0)[:, None, None]
    )
    level = 0.1
    assert not (data == level).any()
    a = "xyz".index(axis)
    b, c = (a + 1) % 3, (a + 2) % 3
    mesh = extract(Volume(data), level, method="squares", axis=axis, vertex_offset=0.0)
    ours = {frozenset(map(tuple, np.round(mesh.vertices[s], 7).tolist())) for s in mesh.cells}
    theirs = set()
    for s in range(data.shape[a]):
        plane = np.moveaxis(data, a, 0)[s]  # (remaining axes in increasing order)
        image = plane if b < c else plane.T  # image[u, v] with u along b, v along c
        for line in measure.find_contours(image.T, level, fully_connected="low"):
            pts = np.zeros((len(line), 3))
            pts[:, a] = s
            pts[:, b], pts[:, c] = line[:, 1], line[:, 0]  # (row, col) = (v, u)
            pts = np.round(pts, 7)
            theirs |= {
                frozenset(map(tuple, seg))
                for seg in zip(pts[:-1].tolist(), pts[1:].tolist(), strict=True)
            }
    assert len(ours) == len(mesh.cells) > 100
    assert ours == theirs
