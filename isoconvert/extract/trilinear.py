"""Marching Cubes with the topology of the trilinear interpolant (``--ambiguity trilinear``).

A fixed rule for ambiguous faces gives a closed surface whose topology is an
accident of the rule. This module derives, in code, the tables and the tests
that make the surface in each cube homeomorphic to the level set of the
trilinear interpolant in that cube (Nielson and Hamann 1991 for the faces;
Chernyaev 1995, Nielson 2003 for the interior). Nothing is typed in: the
triangles come from the face walk of :mod:`.tables` and from the argument
below.

The argument
------------
Let ``g = F - level`` for the trilinear interpolant F of the cube's corner
values. The grid's sign rule (positive: ``value >= level``) extends to the
cube: the positive set is ``g >= 0``, closed; the negative set ``g < 0``.

1. **Faces.** On a face F is bilinear. When its diagonal corners share signs
   (an ambiguous face) the positive corners are joined on the face exactly
   when the saddle value ``(f00 f11 - f10 f01) / (f00 + f11 - f10 - f01)`` is
   ``>= level`` (the asymptotic decider; Marching Squares' ``asymptotic`` rule
   computes the same expression in the same order, so a slice and a cube cut
   every grid face alike, and two cubes sharing a face cut it alike). The face
   decisions fix the contour on the cube's boundary: closed loops of
   bipolar-edge vertices (the face walk, one rule per face).
2. **No closed pieces.** F is harmonic (each term is linear in each
   coordinate), so it has no interior maximum or minimum: every component of
   the positive or the negative set reaches the cube's boundary, and (each
   face being bilinear, each edge linear) contains a corner. The level set has
   no closed component inside the cube.
3. **Interior connectivity.** Which corners the positive set joins through
   the inside is found by sweeping planes ``z = t`` through the cube. On each
   plane F is bilinear, so the plane's positive set joins diagonal corners only
   when the plane's four corners (points on the cube's z-edges, whose signs
   change once, at their edge vertex) have diagonal signs and the plane's
   saddle value is on the positive side: the sign of the quadratic
   ``N(t) = g00(t) g11(t) - g10(t) g01(t)``. Between two edge-vertex heights
   the plane's signs are fixed, so each interval needs only the range of one
   quadratic's sign: at its ends and at its vertex. Its roots inside the cube
   are the body saddles of F at the level. Joins on the side faces come from
   the face decisions (step 1), so the inside never contradicts the boundary.
4. **Surfaces from connectivity.** The positive and negative components
   split the cube into pieces; each component of the level set inside the cube
   is the wall between one positive and one negative piece, and no two walls
   join the same pair (the cube is a ball, so the pieces' adjacency is a tree).
   A boundary loop walls off the pieces of the two corners of its first edge;
   loops that wall off the same pair are one surface: a disk (one loop) or a
   tube (two loops). Disks are the face walk's polygons, triangulated without
   a chord on a face as in :mod:`.tables`; where no such triangulation exists
   (116 of the entries' loops) the disk is a fan from one interior vertex. A
   tube is a strip between its two loops when one exists with no edge on a
   face; otherwise (356 of the 432 loop pairs) it gets a waist of interior
   vertices. Interior vertices sit at the mean of edge vertices the table
   names.

Where it runs: the kernel (src/trilinear.hpp, called by src/cubes.cpp)
repeats these tests on each special cube's values, with the tables
:func:`kernel_table` flattens; :func:`trilinear_cube` is the reference it is
tested against cube by cube (tests/test_trilinear_extract.py).

Ties
----
A sample equal to the level is positive (book Definition 2.1), as in every
rule. A face saddle equal to the level joins the positive corners (``>=``), as
in Marching Squares' ``asymptotic``. Inside, a plane whose saddle is exactly at
the level joins its positive corners (the positive set is closed), so a body
saddle at the level opens a tunnel through the positive side.

Table layout
------------
Entry ``64 * config + faces`` (``faces``: bit f set when face f of
:data:`~.tables.CUBE_FACES` joins its positive corners; only ambiguous faces
may have their bit set) holds the entry's loops; each loop has its two corners,
its disk's triangles and, for each later loop of the entry, the tube to it.
"""

from __future__ import annotations

import itertools
import pprint
from functools import cache
from pathlib import Path

import numpy as np

from ..graph import connected_components
from .tables import (
    _CUBE_EDGE_INDEX,
    CUBE_EDGES,
    CUBE_FACES,
    CUBE_VERTICES,
    _share_a_face,
    face_walk,
    triangulate,
)

#: (6, 4) int: each face's corners as (00, 10, 01, 11) in its two in-plane axes,
#: the lower axis first: the order Marching Squares' decider reads them in.
FACE_CORNERS = np.array(
    [
        [
            v
            for w in (0, 1)
            for u in (0, 1)
            for v in range(8)
            if (v >> axis) & 1 == side
            and (v >> [a for a in range(3) if a != axis][0]) & 1 == u
            and (v >> [a for a in range(3) if a != axis][1]) & 1 == w
        ]
        for axis in range(3)
        for side in (0, 1)
    ],
    dtype=np.int64,
)


def ambiguous_faces(config: int) -> int:
    """Bit mask of the faces whose diagonal corners share signs in ``config``."""
    mask = 0
    for f, (c00, c10, c01, c11) in enumerate(FACE_CORNERS):
        s = [(config >> int(c)) & 1 for c in (c00, c10, c01, c11)]
        if s[0] == s[3] and s[1] == s[2] and s[0] != s[1]:
            mask |= 1 << f
    return mask


def _boundary_joins(config: int, faces: int, sign: int) -> list[tuple[int, int]]:
    """Pairs of corners of one sign that the cube's boundary joins: the two ends
    of an edge with both of that sign, and the diagonal of a face that joins
    them (``faces``, as in the table)."""

    def has(v: int) -> bool:
        return (config >> v) & 1 == sign

    pairs = [(int(a), int(b)) for a, b in CUBE_EDGES if has(int(a)) and has(int(b))]
    ambiguous = ambiguous_faces(config)
    for f, (c00, c10, c01, c11) in enumerate(FACE_CORNERS):
        if (ambiguous >> f) & 1 and ((faces >> f) & 1 == 1) == (sign == 1):
            pairs.append((int(c00), int(c11)) if has(int(c00)) else (int(c10), int(c01)))
    return pairs


def _components(pairs: list[tuple[int, int]]) -> np.ndarray:
    """(8,) label of each corner's component under the joins ``pairs``."""
    u, v = np.array(pairs, dtype=np.int64).reshape(-1, 2).T
    return connected_components(8, u, v)


@cache
def needs_interior_test(config: int) -> bool:
    """Whether the trilinear surface of ``config`` can differ from a fixed
    rule's: it has an ambiguous face, or corners of one sign that no edge
    joins (two opposite corners: the book's class of Figure 2.20's tunnel)."""
    if ambiguous_faces(config):
        return True
    for sign in (0, 1):
        labels = _components(_boundary_joins(config, 0, sign))
        roots = {int(labels[v]) for v in range(8) if (config >> v) & 1 == sign}
        if len(roots) > 1:
            return True
    return False


def cube_loops(config: int, faces: int) -> list[list[int]]:
    """The contour on the cube's boundary for one configuration and face decisions.

    Returns
    -------
    list of list of int
        Each loop as the cycle of cube edges its vertices lie on, oriented so
        that a disk spanning it has its right-hand normal towards the negative
        side.
    """
    positive = [(config >> v) & 1 == 1 for v in range(8)]
    rules = []
    for f in range(6):
        # CUBE_FACES and FACE_CORNERS number faces alike (2 * axis + side)
        rules.append("separate-negative" if (faces >> f) & 1 else "separate-positive")
    cycles = face_walk(
        CUBE_VERTICES.astype(float), [[int(c) for c in f] for f in CUBE_FACES], positive, rules
    )
    return [[_CUBE_EDGE_INDEX[e] for e in cycle] for cycle in cycles]


def _midpoint(edge: int) -> np.ndarray:
    return CUBE_VERTICES[CUBE_EDGES[edge]].mean(axis=0)


#: Interior vertices are numbered after the cube's 12 edges: 12 + slot.
INNER = 12


def _position(vertex: int, inner: list[int]) -> np.ndarray:
    """Derivation-time position of a patch vertex: an edge's midpoint, or the
    mean of the midpoints of the edges in an interior vertex's mask."""
    if vertex < INNER:
        return _midpoint(vertex)
    mask = inner[vertex - INNER]
    return np.mean([_midpoint(e) for e in range(12) if (mask >> e) & 1], axis=0)


def _ladder(a: list[int], b: list[int], rung_ok, inner: list[int]) -> list | None:
    """The strip of triangles between cycles ``a`` and ``b`` (both running the
    same way round the tube) with the shortest rungs, over all alignments of
    ``b``, using only rungs ``rung_ok`` accepts; None when there is none.

    A strip is a walk from rung (a[0], b[0]) once round both cycles, each
    step advancing along one of them; no rung may be walked twice (a vertex
    fanned to a whole cycle would put one rung in three triangles)."""
    m, n = len(a), len(b)
    best, best_cost = None, np.inf
    for shift in range(n):
        bb = b[shift:] + b[:shift]
        for a_steps in itertools.combinations(range(m + n), m):
            i = j = 0
            rungs = [(a[0], bb[0])]
            tris = []
            for step in range(m + n):
                if step in a_steps:
                    tris.append((a[i], a[(i + 1) % m], bb[j % n]))
                    i += 1
                else:
                    tris.append((a[i % m], bb[(j + 1) % n], bb[j]))
                    j += 1
                rungs.append((a[i % m], bb[j % n]))
            inside = rungs[:-1]
            if len(set(inside)) < len(inside) or not all(rung_ok(u, v) for u, v in inside):
                continue
            cost = sum(
                float(np.linalg.norm(_position(u, inner) - _position(v, inner))) for u, v in inside
            )
            if cost < best_cost - 1e-12:
                best, best_cost = tris, cost
    return best


def _off_faces(u: int, v: int) -> bool:
    # an interior vertex lies on no face; two edge vertices may share one
    return u >= INNER or v >= INNER or not _share_a_face(u, v)


#: Interior vertices of a tube that no strip of edge vertices can make.
RING = 3


def tube(a: list[int], b: list[int]) -> tuple[list[tuple[int, int, int]], list[int]]:
    """Triangles joining loops ``a`` and ``b`` into a tube, and its interior vertices.

    Both loops are oriented as disks' boundaries (:func:`cube_loops`); walking
    ``a`` forward and ``b`` backward keeps the tube's normals on the disks'
    side. A strip straight from ``a`` to ``b`` is used when one has no edge on
    a face of the cube (where it could meet the neighbouring cube's patch).
    Otherwise the tube gets a waist of :data:`RING` interior vertices, each the
    mean of an arc of ``a`` and the facing arc of ``b``, and two strips.

    Returns
    -------
    triangles : list of (int, int, int)
        Cube edges 0..11 and interior vertices ``INNER + slot``.
    inner : list of int
        Per interior slot, the mask of cube edges whose vertices it averages.
    """
    back = b[::-1]
    strip = _ladder(a, back, _off_faces, [])
    if strip is not None:
        return strip, []
    # the alignment of b that a strip would use (faces allowed) fixes the arcs
    rough = _ladder(a, back, lambda u, v: True, [])
    first_b = next(t[2] for t in rough if t[:2] == (a[0], a[1]))
    shift = back.index(first_b)
    back = back[shift:] + back[:shift]
    inner = []
    for s in range(RING):
        arc_a = a[s * len(a) // RING : (s + 1) * len(a) // RING]
        arc_b = back[s * len(back) // RING : (s + 1) * len(back) // RING]
        inner.append(sum(1 << e for e in arc_a + arc_b))
    ring = [INNER + s for s in range(RING)]
    low = _ladder(a, ring, _off_faces, inner)
    high = _ladder(ring, back, _off_faces, inner)
    return low + high, inner


def disk(loop: list[int]) -> tuple[list[tuple[int, int, int]], list[int]]:
    """Triangles spanning one loop, and its interior vertices: the face walk's
    triangulation when one has no chord on a face, else a fan from one
    interior vertex at the mean of the loop's vertices."""
    try:
        return triangulate(loop, _share_a_face), []
    except ValueError:
        centre = INNER
        n = len(loop)
        return [(centre, loop[i], loop[(i + 1) % n]) for i in range(n)], [sum(1 << e for e in loop)]


@cache
def entry(config: int, faces: int) -> tuple:
    """One table entry: ``(loops, corners, disks, tubes)``.

    corners[i] is (positive corner, negative corner) of loop i's first edge;
    disks[i] is (triangles, inner) spanning loop i (:func:`disk`);
    tubes[(i, j)] the tube from loop i to loop j (:func:`tube`).
    """
    loops = cube_loops(config, faces)
    corners = []
    for loop in loops:
        u, v = (int(c) for c in CUBE_EDGES[loop[0]])
        corners.append((u, v) if (config >> u) & 1 else (v, u))
    disks = [disk(loop) for loop in loops]
    tubes = {
        (i, j): tube(loops[i], loops[j])
        for i in range(len(loops))
        for j in range(i + 1, len(loops))
    }
    return loops, corners, disks, tubes


def reachable_entries() -> list[tuple[int, int]]:
    """Every (config, faces) a cube can take: the configurations that need the
    interior test, each with every subset of its ambiguous faces joined."""
    keys = []
    for config in range(256):
        if not needs_interior_test(config):
            continue
        amb = ambiguous_faces(config)
        keys += [(config, faces) for faces in range(64) if faces & ~amb == 0]
    return keys


def derive_trilinear_entries() -> dict[tuple[int, int], tuple]:
    """Every reachable entry as ``(corners, disks, tubes)`` (:func:`entry`
    without its loops), plain tuples of ints; about 45 s."""
    out = {}
    for key in reachable_entries():
        _, corners, disks, tubes = entry(*key)
        out[key] = (
            tuple(tuple(c) for c in corners),
            tuple((tuple(map(tuple, t)), tuple(m)) for t, m in disks),
            {pair: (tuple(map(tuple, t)), tuple(m)) for pair, (t, m) in tubes.items()},
        )
    return out


def write_trilinear_tables(path: Path | None = None, entries: dict | None = None) -> Path:
    """Write ``entries`` (by default :func:`derive_trilinear_entries`) to
    ``trilinear_tables.py`` (or ``path``)."""
    path = path or Path(__file__).with_name("trilinear_tables.py")
    entries = derive_trilinear_entries() if entries is None else entries
    body = pprint.pformat(entries, width=99, sort_dicts=False, compact=True)
    lines = [
        '"""Trilinear-topology cube entries, generated by',
        "isoconvert.extract.trilinear.write_trilinear_tables().",
        "",
        "Do not edit: :func:`isoconvert.extract.trilinear.derive_trilinear_entries` is",
        "the source; tests/test_trilinear.py checks that these equal it.",
        '"""',
        "",
        "# fmt: off",
        "#: (config, faces) -> (corners, disks, tubes); see isoconvert.extract.trilinear.",
        f"ENTRIES = {body}",
        "# fmt: on",
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


@cache
def stored_entries() -> dict[tuple[int, int], tuple]:
    """The entries of ``trilinear_tables.py`` (:func:`derive_trilinear_entries`)."""
    from .trilinear_tables import ENTRIES

    return ENTRIES


#: Tube pieces of an entry are stored by loop pair, in this order.
LOOP_PAIRS = tuple(itertools.combinations(range(4), 2))


@cache
def kernel_table() -> dict[str, np.ndarray]:
    """The stored entries flattened for the kernel (``_native.TrilinearTable``).

    Returns
    -------
    dict of str to array
        ``special (256,) uint8`` configurations that take the interior test;
        ``entry (256 * 64,) int32`` row of ``64 * config + faces`` in the
        per-entry arrays, -1 when unreachable; per entry ``loops (E,) int32``,
        ``corners (E, 4, 2) int32`` (positive, negative corner of each loop),
        ``disk (E, 4) int32`` and ``tube (E, 6) int32`` (piece of each loop,
        of each pair in :data:`LOOP_PAIRS`; -1 none); per piece
        ``piece_tris (P + 1,) int32`` and ``piece_inner (P + 1,) int32``
        starts into ``tris (T, 3) int32`` (cube edges, ``INNER + slot``) and
        ``inner (I,) int32`` (edge masks of interior vertices).
    """
    entries = stored_entries()
    n = len(entries)
    special = np.array([needs_interior_test(c) for c in range(256)], dtype=np.uint8)
    row = np.full(256 * 64, -1, dtype=np.int32)
    loops = np.zeros(n, dtype=np.int32)
    corners = np.full((n, 4, 2), -1, dtype=np.int32)
    disk = np.full((n, 4), -1, dtype=np.int32)
    tube = np.full((n, 6), -1, dtype=np.int32)
    tris: list[tuple[int, int, int]] = []
    inner: list[int] = []
    piece_tris, piece_inner = [0], [0]

    def piece(triangles: tuple, masks: tuple) -> int:
        tris.extend(triangles)
        inner.extend(masks)
        piece_tris.append(len(tris))
        piece_inner.append(len(inner))
        return len(piece_tris) - 2

    for e, ((config, faces), (cs, disks, tubes)) in enumerate(entries.items()):
        row[64 * config + faces] = e
        loops[e] = len(cs)
        corners[e, : len(cs)] = cs
        for i, (t, m) in enumerate(disks):
            disk[e, i] = piece(t, m)
        for pair, (t, m) in tubes.items():
            tube[e, LOOP_PAIRS.index(pair)] = piece(t, m)
    table = {
        "special": special,
        "entry": row,
        "loops": loops,
        "corners": corners,
        "disk": disk,
        "tube": tube,
        "piece_tris": np.array(piece_tris, dtype=np.int32),
        "piece_inner": np.array(piece_inner, dtype=np.int32),
        "tris": np.array(tris, dtype=np.int32).reshape(-1, 3),
        "inner": np.array(inner, dtype=np.int32),
    }
    for a in table.values():
        a.setflags(write=False)
    return table


def inner_base(grid_shape: tuple[int, int, int]) -> int:
    """First id of the vertices inside cubes, past every edge id of a grid of
    ``grid_shape`` (X, Y, Z): the vertex in slot s of the cube with lowest
    corner (i, j, k) has id ``inner_base + 16 * (i + X * (j + Y * k)) + s``."""
    x, y, z = (int(n) for n in grid_shape)
    return 3 * x * y * z


def interior_layer(ids: np.ndarray, grid_shape: tuple[int, int, int]) -> np.ndarray:
    """(V,) int64: the grid layer k of each vertex id, edge or interior
    (:func:`inner_base`)."""
    x, y = int(grid_shape[0]), int(grid_shape[1])
    base = inner_base(grid_shape)
    return np.where(ids < base, ids // (3 * x * y), (ids - base) // (16 * x * y))


@cache
def native_trilinear_table():
    """:func:`kernel_table` as the kernel's ``_native.TrilinearTable``, built once."""
    from .. import _native

    k = kernel_table()

    def int32(a) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.int32)

    return _native.TrilinearTable.from_arrays(
        *(int32(k[name]) for name in ("special", "entry", "loops", "corners", "disk", "tube")),
        *(int32(k[name]) for name in ("piece_tris", "piece_inner", "tris", "inner")),
        int32(CUBE_EDGES),
        int32(FACE_CORNERS),
    )


# --- the tests, in Python: the reference the C++ kernel is checked against ----------


def asymptotic_joins_positive(f00, f10, f01, f11, level: float):
    """The asymptotic decider on squares whose diagonal corners share signs
    (corners 00, 10, 01, 11, the lower in-plane axis first; floats or arrays):
    whether the bilinear saddle value is >= level. The same expression, in the
    same order, as ``iso::asymptotic_joins_positive`` (src/common.hpp), so the
    cap of ``--close`` and this reference decide faces as the kernels do."""
    return (f00 * f11 - f10 * f01) / (f00 + f11 - f10 - f01) >= level


def face_decisions(values: np.ndarray, level: float, config: int) -> int:
    """Face bits of one cube: the asymptotic decider on each ambiguous face.

    values : (8,) float64, corner values by cube vertex.
    """
    faces = 0
    amb = ambiguous_faces(config)
    for f, (c00, c10, c01, c11) in enumerate(FACE_CORNERS):
        if (amb >> f) & 1:
            corners = (float(values[c]) for c in (c00, c10, c01, c11))
            if asymptotic_joins_positive(*corners, level):
                faces |= 1 << f
    return faces


def interior_joins(values: np.ndarray, level: float) -> list[tuple[int, int, int]]:
    """Corner pairs the inside of the cube joins, by sweeping planes z = t.

    Returns
    -------
    list of (sign, corner, corner)
        sign 1: the positive set joins the two corners; 0: the negative set.
    """
    g = np.asarray(values, dtype=np.float64) - level
    bottom, top = g[:4], g[4:]
    cross = []
    for q in range(4):
        if (bottom[q] >= 0) != (top[q] >= 0):
            cross.append(bottom[q] / (bottom[q] - top[q]))
    ts = sorted({0.0, 1.0, *(t for t in cross if 0.0 < t < 1.0)})
    joins = []
    slope = top - bottom
    for lo, hi in zip(ts[:-1], ts[1:], strict=True):
        mid = 0.5 * (lo + hi)
        pos = bottom + mid * slope >= 0
        if not (pos[0] == pos[3] and pos[1] == pos[2] and pos[0] != pos[1]):
            continue
        sigma = 1.0 if pos[0] else -1.0
        a, b = bottom, slope
        qa = a[0] * a[3] - a[1] * a[2]
        qb = a[0] * b[3] + a[3] * b[0] - a[1] * b[2] - a[2] * b[1]
        qc = b[0] * b[3] - b[1] * b[2]
        samples = [lo, hi]
        if qc != 0.0:
            vertex = -qb / (2.0 * qc)
            if lo < vertex < hi:
                samples.append(vertex)
        vals = [sigma * (qa + t * (qb + t * qc)) for t in samples]
        diag_pos, diag_neg = ((0, 3), (1, 2)) if pos[0] else ((1, 2), (0, 3))

        def corner(q: int, sign: int) -> int:
            # a z-edge holds one end of each sign it takes
            return q if (bottom[q] >= 0) == (sign == 1) else q + 4

        if max(vals) >= 0:
            joins.append((1, corner(diag_pos[0], 1), corner(diag_pos[1], 1)))
        if min(vals) < 0:
            joins.append((0, corner(diag_neg[0], 0), corner(diag_neg[1], 0)))
    return joins


def trilinear_cube(values: np.ndarray, level: float) -> list[tuple[list, list[int]]]:
    """The pieces of surface in one cube under ``trilinear``.

    values : (8,) float64, corner values by cube vertex.

    Returns
    -------
    list of (triangles, inner)
        Each disk or tube: triangles over cube edges and ``INNER + slot``, and
        its interior vertices as masks of the edges they average.
    """
    values = np.asarray(values, dtype=np.float64)
    config = sum(1 << v for v in range(8) if values[v] >= level)
    faces = face_decisions(values, level, config)
    corners, disks, tubes = (
        stored_entries()[config, faces]
        if needs_interior_test(config)
        else (entry(config, faces)[1:])
    )
    joins = {sign: _boundary_joins(config, faces, sign) for sign in (0, 1)}
    for sign, u, v in interior_joins(values, level):
        joins[sign].append((u, v))
    labels = {sign: _components(pairs) for sign, pairs in joins.items()}
    groups: dict[tuple[int, int], list[int]] = {}
    for i, (p, n) in enumerate(corners):
        groups.setdefault((int(labels[1][p]), int(labels[0][n])), []).append(i)
    pieces = []
    for members in groups.values():
        if len(members) == 2:
            pieces.append(tubes[tuple(members)])
        else:
            # one loop; more than two would be a surface trilinear level sets
            # do not have (the tests look for one): keep the disks
            pieces += [disks[i] for i in members]
    return pieces
