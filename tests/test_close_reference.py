"""--close against a slow pure-numpy cap built from its contract (issue 23).

The compiled cap (src/cap.cpp) numbers everything by counting: rows of the
grid's boundary, ranks in bit sets of each face's signs and crossings. The
reference here builds the same closed mesh the direct way, from the contract
that close_at_grid documents (a case per face cell, its positive part fanned
from the walk around the cell, cells by case and then row-major, the cap's
samples by increasing linear index, the surface's vertices looked up by edge
id in a sorted list), and the two must agree byte for byte.
"""

from __future__ import annotations

import nrrd
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert import extract, read_volume
from isoconvert.errors import IsoconvertError
from isoconvert.extract.blocks import Blocks
from isoconvert.mesh import Mesh
from isoconvert.post.cap import close_at_grid
from isoconvert.volume import Volume

RULES = ["separate-positive", "separate-negative", "trilinear"]


def cell_polygons(positive: list[bool], joined: bool) -> list[list[int]]:
    """The positive part of a face cell as polygons of slots (0-3 its corners
    (0, 0), (1, 0), (1, 1), (0, 1) in (p, q); 4 + c the crossing of the edge
    from corner c to c + 1), counter-clockwise. An ambiguous cell's two
    positive corners are cut apart unless ``joined``."""
    bipolar = [positive[c] != positive[(c + 1) % 4] for c in range(4)]
    if all(bipolar) and not joined:
        return [[4 + (c + 3) % 4, c, 4 + c] for c in range(4) if positive[c]]
    polygon = []
    for c in range(4):
        if positive[c]:
            polygon.append(c)
        if bipolar[c]:
            polygon.append(4 + c)
    return [polygon] if any(positive) else []


def reference_close(mesh, volume, level, ambiguity="separate-positive", flip=False, nan_as=None):
    """The closed mesh as close_at_grid documents it, cell by cell.

    Parameters
    ----------
    mesh : Mesh
        The cubes surface of ``volume`` at ``level`` (with its edge ids).
    volume : Volume
        An in-memory volume.
    level, ambiguity, flip, nan_as
        As for :func:`close_at_grid`.

    Returns
    -------
    Mesh or None
        The surface and then the cap; None where the cap has no triangle.

    Raises
    ------
    IsoconvertError
        A crossing of a face has no vertex of the surface.
    """
    f = np.array(volume.data, dtype=np.float64)
    if nan_as is not None:
        f[~np.isfinite(f)] = nan_as
    shape = f.shape
    stride = np.array([1, shape[0], shape[0] * shape[1]])
    mirrored = bool(np.linalg.det(volume.direction * volume.spacing) < 0)
    keys = []  # (T, 3): edge ids >= 0, or -1 - linear index of a sample
    for axis in range(3):
        p_axis, q_axis = [a for a in range(3) if a != axis]
        # +p x +q is +axis for (y, z) and (x, y), -y for (x, z)
        p_cross_q = -1 if axis == 1 else 1
        for side in (0, shape[axis] - 1):
            outward = 1 if side else -1
            reverse = ((p_cross_q != outward) != mirrored) != flip
            image = np.take(f, side, axis=axis)  # (n_p, n_q)
            cells = []  # (order, p, q, triangles of slots)
            for p in range(image.shape[0] - 1):
                for q in range(image.shape[1] - 1):
                    v = [image[p, q], image[p + 1, q], image[p + 1, q + 1], image[p, q + 1]]
                    positive = [x >= level for x in v]
                    case = sum(1 << c for c in range(4) if positive[c])
                    ambiguous = case in (5, 10)
                    joined = ambiguity == "separate-negative"
                    if ambiguity == "trilinear" and ambiguous:
                        f00, f10, f11, f01 = v
                        with np.errstate(divide="ignore", invalid="ignore"):
                            saddle = (f00 * f11 - f10 * f01) / (f00 + f11 - f10 - f01)
                        joined = bool(saddle >= level)
                    # the decider's joined cells come before their case's others
                    order = 2 * case - (ambiguous and ambiguity == "trilinear" and joined)
                    triangles = [
                        (poly[0], poly[i], poly[i + 1])
                        for poly in cell_polygons(positive, joined)
                        for i in range(1, len(poly) - 1)
                    ]
                    if triangles:
                        cells.append((order, p, q, triangles))
            cells.sort(key=lambda cell: cell[0])  # stable: row-major within a case
            for _, p, q, triangles in cells:
                base = side * stride[axis] + p * stride[p_axis] + q * stride[q_axis]
                corners = [(0, 0), (1, 0), (1, 1), (0, 1)]
                edges = [((0, 0), p_axis), ((1, 0), q_axis), ((0, 1), p_axis), ((0, 0), q_axis)]
                slot = [
                    -1 - (base + dp * stride[p_axis] + dq * stride[q_axis]) for dp, dq in corners
                ]
                for (dp, dq), along in edges:
                    slot.append(3 * (base + dp * stride[p_axis] + dq * stride[q_axis]) + along)
                for t in triangles:
                    keys.append([slot[s] for s in (t[::-1] if reverse else t)])
    if not keys:
        return None
    keys = np.array(keys, dtype=np.int64)
    n = mesh.n_vertices
    samples = np.unique(-1 - keys[keys < 0])
    cells = np.empty_like(keys)
    cells[keys < 0] = n + np.searchsorted(samples, -1 - keys[keys < 0])
    for index in zip(*np.nonzero(keys >= 0), strict=True):
        found = np.nonzero(mesh.edge_ids == keys[index])[0]
        if not len(found):
            raise IsoconvertError("missing")
        cells[index] = found[0]  # the first vertex of an id
    ijk = np.column_stack(np.unravel_index(samples, shape, order="F")).astype(np.float64)
    return Mesh(
        np.concatenate([mesh.vertices, volume.index_to_world(ijk)]),
        np.concatenate([mesh.cells, cells]),
        np.concatenate([mesh.edge_ids, -1 - samples]),
    )


def assert_same(closed, expected, mesh):
    if expected is None:
        assert closed is mesh
        return
    for a, b in (
        (closed.vertices, expected.vertices),
        (closed.cells, expected.cells),
        (closed.edge_ids, expected.edge_ids),
    ):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    cap = closed.info["closed"]
    assert cap["cap_triangles"] == expected.n_cells - mesh.n_cells
    assert cap["cap_vertices"] == expected.n_vertices - mesh.n_vertices


DIRECTIONS = {
    "axes": np.eye(3),
    "mirrored": np.diag([1.0, -1.0, 1.0]),
    "oblique": np.array([[0.8, -0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]]),
}


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shape=st.tuples(st.integers(2, 9), st.integers(2, 9), st.integers(2, 9)),
    rule=st.sampled_from(RULES),
    flip=st.booleans(),
    integers=st.booleans(),
    direction=st.sampled_from(sorted(DIRECTIONS)),
)
def test_cap_equals_the_reference(seed, shape, rule, flip, integers, direction):
    """Random fields, some with samples equal to the level (positive), under
    every ambiguity rule, with flip and on mirrored and oblique grids."""
    rng = np.random.default_rng(seed)
    f = rng.integers(0, 4, size=shape).astype(np.float64) if integers else rng.random(shape)
    level = 2.0 if integers else 0.5
    if (f >= level).all() or (f < level).all():
        return  # no surface to close
    volume = Volume(
        f, spacing=(0.5, 1.25, 2.0), origin=(1.0, -2.0, 3.5), direction=DIRECTIONS[direction]
    )
    mesh = extract(volume, level, ambiguity=rule, flip=flip)
    closed = close_at_grid(mesh, volume, level, ambiguity=rule, flip=flip)
    assert_same(closed, reference_close(mesh, volume, level, rule, flip), mesh)


@pytest.mark.parametrize("nan_as", [0.0, 1.0])
def test_cap_with_nan_samples_equals_the_reference(nan_as):
    rng = np.random.default_rng(8)
    f = rng.random((9, 7, 8))
    f[rng.random(f.shape) < 0.2] = np.nan
    f[0, 2, 3], f[8, 0, 0] = np.inf, -np.inf
    volume = Volume(f)
    mesh = extract(volume, 0.5, nan_as=nan_as)
    closed = close_at_grid(mesh, volume, 0.5, nan_as=nan_as)
    assert_same(closed, reference_close(mesh, volume, 0.5, nan_as=nan_as), mesh)


@pytest.mark.parametrize("rule", RULES)
def test_cap_of_large_faces_equals_the_reference_on_any_thread_count(rule, monkeypatch):
    """Faces of more cells than one task of the kernel takes, on 1 and 2 threads."""
    t = np.linspace(0, 3 * np.pi, 150)
    x, y, z = np.meshgrid(t, t[:140], t[:131], indexing="ij")
    f = np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x)
    volume = Volume(f, spacing=(1.0, 0.5, 0.25))
    mesh = extract(volume, 0.2, ambiguity=rule)
    expected = reference_close(mesh, volume, 0.2, rule)
    for threads in ("1", "2"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        assert_same(close_at_grid(mesh, volume, 0.2, ambiguity=rule), expected, mesh)


def test_cap_of_a_volume_read_block_wise_equals_the_reference(tmp_path):
    x, y, z = np.meshgrid(*(np.arange(30, dtype=float),) * 3, indexing="ij")
    f = (12 - np.sqrt((x - 3) ** 2 + (y - 15) ** 2 + (z - 27) ** 2)).astype(np.float32)
    path = tmp_path / "ball.nrrd"
    nrrd.write(str(path), f, {"spacings": [0.5, 0.5, 1.0]}, index_order="F")
    lazy = read_volume(path)
    assert lazy.grid is not None
    mesh = extract(lazy, 0.0, blocks=Blocks(size=4))
    expected = reference_close(mesh, Volume(f, spacing=(0.5, 0.5, 1.0)), 0.0)
    assert_same(close_at_grid(mesh, lazy, 0.0), expected, mesh)


def test_cap_takes_the_first_vertex_of_an_id_and_refuses_a_missing_one():
    f = np.random.default_rng(4).random((6, 5, 7))
    volume = Volume(f)
    m = extract(volume, 0.5)
    # the surface twice over, the second copy's vertices first
    n = m.n_vertices
    twice = Mesh(
        np.concatenate([m.vertices[::-1], m.vertices]),
        np.concatenate([m.cells, m.cells + n]),
        np.concatenate([m.edge_ids[::-1], m.edge_ids]),
    )
    assert_same(close_at_grid(twice, volume, 0.5), reference_close(twice, volume, 0.5), twice)
    # a vertex on an edge in a face of the grid gone from the surface
    ijk = np.column_stack(np.unravel_index(m.edge_ids // 3, f.shape, order="F"))
    across = (ijk == 0) | (ijk == np.array(f.shape) - 1)
    across[np.arange(n), m.edge_ids % 3] = False  # the edge's own axis
    keep = np.ones(n, dtype=bool)
    keep[np.nonzero(across.any(axis=1))[0][0]] = False
    holed = Mesh(m.vertices[keep], m.cells[:1], m.edge_ids[keep])
    with pytest.raises(IsoconvertError, match="does not cross the grid's faces"):
        close_at_grid(holed, volume, 0.5)
