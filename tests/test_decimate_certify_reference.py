"""Decimation's certificate and triangle lookup against plain Python references
of what they replaced: ``TriangleGrid.certify`` (which keeps each triangle's
midpoint distances for the pieces that share them) against the splitting it
does written out in Python, without that memory, on the same distance grid;
:class:`_InputRows` (the input's triangles hashed once) against
:func:`_rows_in` (sorting both sides). Both must agree exactly, bit for bit:
the decimation's output depends on them."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert.post.decimate import TriangleGrid, _InputRows, _rows_among, _rows_in

# --- the certificate, as distance.cpp computes it, one operation at a time ------------


def _max(a: float, b: float) -> float:
    return b if a < b else a  # std::max


def _min(a: float, b: float) -> float:
    return b if b < a else a  # std::min


def _div(a: float, b: float) -> float:
    """a / b as IEEE doubles (Python raises on division by zero)."""
    return float(np.float64(a) / np.float64(b)) if b == 0.0 else a / b


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _segment_sq(p, a, b) -> float:
    ab, ap = _sub(b, a), _sub(p, a)
    denom = _dot(ab, ab)
    s = _dot(ap, ab) / denom if denom > 0.0 else 0.0
    s = _min(1.0, _max(0.0, s))
    d = (ap[0] - s * ab[0], ap[1] - s * ab[1], ap[2] - s * ab[2])
    return _dot(d, d)


def _triangle_sq(p, a, b, c) -> float:
    ab, ac, ap = _sub(b, a), _sub(c, a), _sub(p, a)
    n = _cross(ab, ac)
    nn = _dot(n, n)
    if nn > 0.0:
        v = _dot(_cross(ap, ac), n) / nn
        w = _dot(_cross(ab, ap), n) / nn
        if v >= 0.0 and w >= 0.0 and v + w <= 1.0:
            h = _dot(ap, n)
            return h * h / nn
    return _min(_min(_segment_sq(p, a, b), _segment_sq(p, b, c)), _segment_sq(p, c, a))


def _cover_radius(p0, p1, p2) -> float:
    side = (_sub(p2, p1), _sub(p0, p2), _sub(p1, p0))
    sq = [_dot(s, s) for s in side]
    if sq[0] >= sq[1]:
        longest = 0 if sq[0] >= sq[2] else 2
    else:
        longest = 1 if sq[1] >= sq[2] else 2
    half_longest = 0.5 * math.sqrt(sq[longest])
    n = _cross(side[1], side[2])
    area2 = math.sqrt(_dot(n, n))
    if not area2 > 0.0:
        return half_longest
    if sq[longest] > sq[(longest + 1) % 3] + sq[(longest + 2) % 3]:
        r = 0.0
        for shift in (1, 2):
            i = (longest + shift) % 3
            j = 3 - longest - i
            s_i = sq[j]
            cos_i = _div(s_i + sq[longest] - sq[i], 2.0 * math.sqrt(s_i * sq[longest]))
            r = _max(r, _div(math.sqrt(s_i), 2.0 * cos_i))
    else:
        r = math.sqrt(sq[0] * sq[1] * sq[2]) / (2.0 * area2)
    return r if math.isfinite(r) else half_longest


def reference_certify(grid, onto_vertices, onto, vertices, triangles, corner, bound, depth):
    """(reach (T,), status (T,)) as ``TriangleGrid.certify`` defines them, every
    midpoint measured afresh by the grid's own nearest-triangle query."""

    def nearest(point):
        distance, which = grid.distances(np.array([point]))
        return float(distance[0]), int(which[0])

    def corner_of(g, k):
        return tuple(float(x) for x in onto_vertices[onto[g, k]])

    reach, status = np.zeros(len(triangles)), np.zeros(len(triangles), dtype=np.uint8)
    for f, tri in enumerate(triangles):
        top = (
            [tuple(float(x) for x in vertices[i]) for i in tri],
            [float(corner[i]) for i in tri],
            [-1, -1, -1],
            0,
        )
        stack, worst, state = [top], 0.0, 0
        while stack and not state:
            p, d, near, level = stack.pop()
            near = list(near)
            far = _max(_max(d[0], d[1]), d[2])
            r = far + _cover_radius(*p)
            if r <= bound:
                worst = _max(worst, r)
                continue
            if level == 0:
                near = [nearest(p[q])[1] for q in range(3)]
            convex = math.inf
            for q in range(3):
                g = near[q]
                if g < 0 or (q > 0 and g == near[0]) or (q > 1 and g == near[1]):
                    continue
                most = 0.0
                for k in range(3):
                    sq = _triangle_sq(p[k], corner_of(g, 0), corner_of(g, 1), corner_of(g, 2))
                    most = _max(most, sq)
                convex = _min(convex, math.sqrt(most))
            if convex <= bound:
                worst = _max(worst, convex)
                continue
            if level == depth:
                state = 2
                worst = _max(worst, far)
                break
            m, dm, nm = [], [], []
            for q in range(3):
                a, b = p[q], p[(q + 1) % 3]
                m.append((0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2])))
                distance, which = nearest(m[q])
                dm.append(distance)
                nm.append(which)
                if distance > bound:
                    state = 1
                    worst = _max(worst, distance)
            if state:
                break
            lv = level + 1
            stack.append(([p[0], m[0], m[2]], [d[0], dm[0], dm[2]], [near[0], nm[0], nm[2]], lv))
            stack.append(([m[0], p[1], m[1]], [dm[0], d[1], dm[1]], [nm[0], near[1], nm[1]], lv))
            stack.append(([m[2], m[1], p[2]], [dm[2], dm[1], d[2]], [nm[2], nm[1], near[2]], lv))
            stack.append(([m[0], m[1], m[2]], [dm[0], dm[1], dm[2]], [nm[0], nm[1], nm[2]], lv))
        reach[f], status[f] = worst, state
    return reach, status


def _bumpy_sheet(n: int, amplitude: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A height field over an (n + 1)^2 grid of unit cells, random heights:
    (vertices (V, 3), triangles (T, 3)), two triangles a cell, one diagonal
    direction at random per cell."""
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    z = amplitude * rng.standard_normal(i.shape)
    vertices = np.column_stack([i.ravel(), j.ravel(), z.ravel()]).astype(np.float64)
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    flip = rng.random(len(a)) < 0.5
    first = np.where(flip[:, None], np.column_stack([a, b, d]), np.column_stack([a, b, c]))
    second = np.where(flip[:, None], np.column_stack([b, c, d]), np.column_stack([a, c, d]))
    return vertices, np.concatenate([first, second]).astype(np.int64)


def _coarse(n: int, step: int) -> np.ndarray:
    """Triangles over every ``step``-th vertex of :func:`_bumpy_sheet`'s grid
    (the kind of large triangle a collapse leaves)."""
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)[::step, ::step]
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]).astype(np.int64)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    amplitude=st.floats(0.02, 0.6),
    step=st.sampled_from([2, 3, 4]),
    bound=st.floats(0.1, 1.5),
    depth=st.integers(0, 4),
    lift=st.floats(0.0, 0.3),
)
def test_certify_equals_the_reference_bit_for_bit(seed, amplitude, step, bound, depth, lift):
    """The large triangles over a bumpy sheet, lifted off it (so their corners
    are not on it), certified onto the sheet: the same reach and status as the
    reference, to the last bit, whether a triangle is certified, fails at a
    point or runs out of halvings (bounds and depths are drawn to give all three)."""
    n = 4 * step
    vertices, fine = _bumpy_sheet(n, amplitude, seed)
    coarse = _coarse(n, step)
    lifted = vertices + [0.0, 0.0, lift]
    both = np.concatenate([vertices, lifted])
    grid = TriangleGrid(both, fine, bound)
    corner, _ = grid.distances(both)
    triangles = coarse + len(vertices)
    reach, status = grid.certify(both, triangles, corner, bound, depth)
    expected_reach, expected_status = reference_certify(
        grid, both, fine, both, triangles, corner, bound, depth
    )
    assert status.tolist() == expected_status.tolist()
    assert reach.tobytes() == expected_reach.tobytes()


def test_certify_deeper_than_the_midpoint_memory_equals_the_reference():
    """Nine halvings: more points than the kernel keeps per triangle (2^16
    slots), so the deepest are measured again; still the reference's answers."""
    vertices, fine = _bumpy_sheet(8, 0.05, 3)
    coarse = _coarse(8, 8)[:1]
    grid = TriangleGrid(vertices, fine, 0.5)
    corner = np.zeros(len(vertices))
    # tight enough that the pieces go deep, loose enough that they get certified
    bound = 0.02 + float(np.abs(vertices[:, 2]).max())
    reach, status = grid.certify(vertices, coarse, corner, bound, 9)
    expected = reference_certify(grid, vertices, fine, vertices, coarse, corner, bound, 9)
    assert status.tolist() == expected[1].tolist()
    assert reach.tobytes() == expected[0].tobytes()


# --- the input's triangles, hashed once ----------------------------------------------


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n_vertices=st.integers(3, 12),
    n_input=st.integers(0, 40),
    n_out=st.integers(0, 40),
)
def test_input_rows_find_what_sorting_both_sides_finds(seed, n_vertices, n_input, n_out):
    """Few vertices, so that rows repeat (fins), recur in both meshes in any
    vertex order, and also differ: :meth:`_InputRows.shared` both ways equals
    :func:`_rows_in` both ways."""
    rng = np.random.default_rng(seed)
    cells = rng.integers(0, n_vertices, (n_input, 3))
    out = rng.integers(0, n_vertices, (n_out, 3))
    if n_input and n_out:  # some of the input's triangles again, rotated or reversed
        picked = cells[rng.integers(0, n_input, n_out)]
        rolled = np.roll(picked, rng.integers(0, 3), axis=1)[:, :: rng.choice([1, -1])]
        out = np.where(rng.random((n_out, 1)) < 0.5, rolled, out)
    kept, still = _InputRows(cells).shared(out)
    assert kept.tolist() == _rows_in(out, cells).tolist() == _rows_among(out, cells).tolist()
    assert still.tolist() == _rows_in(cells, out).tolist() == _rows_among(cells, out).tolist()


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_input=st.integers(0, 40), n_out=st.integers(0, 40))
def test_input_rows_settle_rows_that_share_a_hash_exactly(seed, n_input, n_out):
    """Different rows that share a hash (forced here: a hash of 3 values) are told
    apart, as repeated rows are: :meth:`_InputRows.shared` both ways still equals
    :func:`_rows_in` both ways."""
    from unittest import mock

    import isoconvert.post.decimate as decimate

    rng = np.random.default_rng(seed)
    cells = rng.integers(0, 9, (n_input, 3))
    out = rng.integers(0, 9, (n_out, 3))
    if n_input and n_out:
        out[: n_out // 2] = cells[rng.integers(0, n_input, n_out // 2)][:, ::-1]
    weak = lambda rows: (np.asarray(rows).sum(axis=1) % 3).astype(np.uint64)  # noqa: E731
    with mock.patch.object(decimate, "row_hashes", weak):
        kept, still = _InputRows(cells).shared(out)
        among = _rows_among(out, cells), _rows_among(cells, out)
    assert kept.tolist() == _rows_in(out, cells).tolist() == among[0].tolist()
    assert still.tolist() == _rows_in(cells, out).tolist() == among[1].tolist()
