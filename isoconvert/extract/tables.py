"""Marching Squares, Marching Cubes and Marching Tetrahedra tables, derived by code.

Nothing here is pasted. Every table comes from one rule, the face walk behind
the book's compatibility argument (Wenger, *Isosurfaces*, sections 2.2-2.3):

1. Each face of a cell (a cube's squares, a tetrahedron's triangles) is
   contoured by the Marching Squares rule: one segment across each pair of
   bipolar edges; on an ambiguous square face (diagonal corners share signs)
   the two segments cut off either the two positive or the two negative
   corners, one fixed choice for all faces.
2. Every bipolar edge of the cell lies on two faces, so the face segments chain
   into closed cycles; each cycle is one polygon of the isosurface patch.
3. Each polygon is triangulated without a diagonal whose ends lie on one face
   of the cell. Such a chord lies in the face, where the neighbouring cell's
   patch may have the same chord: the edge would then belong to four triangles
   (a random grid found this; a fan from a fixed vertex does it for some
   hexagons).

Because the segments on a face depend only on the signs of that face's
corners, two cells that share a face cut it along the same segments: patches
are compatible and closed surfaces come out watertight (the book's Figure 2.17,
never 2.18). The 256 cube entries fall into the book's 22 classes under the 48
symmetries of the cube (:func:`configuration_classes`); the tests check that and
the book's properties on every entry.

Conventions
-----------
Cube vertex ``v`` has offset ``(v & 1, v >> 1 & 1, v >> 2 & 1)`` and is bit ``v``
of the configuration index; the bit is set when the vertex is positive
(value >= isovalue, book Definition 2.1). Square corners likewise, with two bits.
Triangles are ordered so their right-hand normals point from the positive to
the negative side; 2D segments run with the positive side on their left.
"""

from __future__ import annotations

import itertools
from functools import cache
from pathlib import Path

import numpy as np

from ..methods import (  # rules for a face whose diagonal corners share signs, the default
    AMBIGUITY_RULES,
    DEFAULT_AMBIGUITY,
)

#: (8, 3) int: offset of each cube vertex.
CUBE_VERTICES = np.array([(v & 1, (v >> 1) & 1, (v >> 2) & 1) for v in range(8)], dtype=np.int64)


def _axis_edges(n_dims: int) -> np.ndarray:
    # Grouped by axis (edge e = 2**(d-1) * axis + n): the kernels find an edge's
    # grid position from its lower vertex and its axis alone.
    edges = []
    for axis in range(n_dims):
        for v in range(2**n_dims):
            if not (v >> axis) & 1:
                edges.append((v, v | (1 << axis)))
    return np.array(edges, dtype=np.int64)


#: (12, 2) int: the two cube vertices of each edge, lower one first.
CUBE_EDGES = _axis_edges(3)
#: (12,) int: axis (0=x, 1=y, 2=z) along which each edge runs.
EDGE_AXIS = np.repeat(np.arange(3, dtype=np.int64), 4)
#: (12, 3) int: offset of each edge's lower vertex.
EDGE_BASE = CUBE_VERTICES[CUBE_EDGES[:, 0]]


def _faces() -> np.ndarray:
    """(6, 4) cube vertices of each face, counter-clockwise seen from outside."""
    faces = []
    for axis in range(3):
        for side in (0, 1):
            corners = [v for v in range(8) if ((v >> axis) & 1) == side]
            p = CUBE_VERTICES[corners].astype(float) - 0.5
            u, w = [a for a in range(3) if a != axis]
            order = np.argsort(np.arctan2(p[:, w], p[:, u]))
            corners = [corners[o] for o in order]
            outward = np.zeros(3)
            outward[axis] = 1.0 if side else -1.0
            q = CUBE_VERTICES[corners].astype(float)
            if np.dot(np.cross(q[1] - q[0], q[2] - q[1]), outward) < 0:
                corners.reverse()
            faces.append(corners)
    return np.array(faces, dtype=np.int64)


#: (6, 4) int: cube vertices of each face, counter-clockwise seen from outside.
CUBE_FACES = _faces()


def square_segments(signs: tuple[bool, ...], rule: str) -> list[tuple[int, int]]:
    """Marching Squares on one polygon face, corners given in cyclic order.

    Parameters
    ----------
    signs : 3 or 4 bools
        True where the corner is positive; corners ``c`` and ``c + 1 (mod n)``
        bound face edge ``c``.
    rule : str
        One of :data:`AMBIGUITY_RULES`, used when diagonal corners of a square
        share signs (a triangle is never ambiguous).

    Returns
    -------
    list of (int, int)
        Segments as pairs of face-edge indices, unoriented.
    """
    n = len(signs)
    bipolar = [c for c in range(n) if signs[c] != signs[(c + 1) % n]]
    if len(bipolar) == 2:
        return [tuple(bipolar)]
    if len(bipolar) == 4:
        # Diagonal corners agree: cut off the two corners of the sign to separate.
        cut_positive = rule == "separate-positive"
        corners = [c for c in range(n) if signs[c] == cut_positive]
        # Corner c touches face edges c - 1 and c.
        return [((c - 1) % n, c) for c in corners]
    return []


def face_walk(
    corners: np.ndarray,
    faces: list[list[int]],
    positive: list[bool],
    rule: str | list[str],
) -> list[list[tuple[int, int]]]:
    """Isosurface polygons of a convex cell, by walking its faces.

    Parameters
    ----------
    corners : (N, 3) float
        Positions of the cell's corners.
    faces : list of list of int
        Each face's corners, in cyclic order (either direction).
    positive : list of bool
        Sign of each corner.
    rule : str or list of str
        Ambiguous-face rule: one for every face, or one per face (the
        trilinear tables decide each face by its own asymptotic decider).

    Returns
    -------
    list of polygons
        Each polygon is the cycle of cell edges ``(a, b)`` (corner indices,
        ``a < b``) its vertices lie on, ordered so that the right-hand normal
        points to the negative side.
    """
    centre = corners.mean(axis=0)
    following = {}
    rules = [rule] * len(faces) if isinstance(rule, str) else rule
    for face, face_rule in zip(faces, rules, strict=True):
        outward = corners[face].mean(axis=0) - centre
        n = len(face)
        for a, b in square_segments(tuple(positive[c] for c in face), face_rule):
            ea = tuple(sorted((face[a], face[(a + 1) % n])))
            eb = tuple(sorted((face[b], face[(b + 1) % n])))
            mid_a = corners[list(ea)].mean(axis=0)
            mid_b = corners[list(eb)].mean(axis=0)
            # The positive end of a bipolar edge is on the positive side of the
            # segment through it; seen from outside it must lie on the right.
            pos_end = ea[0] if positive[ea[0]] else ea[1]
            right = np.cross(mid_b - mid_a, outward)
            if np.dot(right, corners[pos_end] - mid_a) > 0:
                following[ea] = eb
            else:
                following[eb] = ea
    polygons = []
    while following:
        start = min(following)
        cycle = [start]
        nxt = following.pop(start)
        while nxt != start:
            cycle.append(nxt)
            nxt = following.pop(nxt)
        polygons.append(cycle)
    return polygons


def fan(polygons: list[list[int]]) -> list[tuple[int, int, int]]:
    """Triangulate each polygon as a fan from its first vertex."""
    return [(p[0], p[i], p[i + 1]) for p in polygons for i in range(1, len(p) - 1)]


def _triangulations(poly: list[int]):
    """Every triangulation of a convex polygon, triangles in the polygon's order;
    fans first (from each vertex in turn), then the others."""
    n = len(poly)
    for apex in range(n):
        p = poly[apex:] + poly[:apex]
        yield [(p[0], p[i], p[i + 1]) for i in range(1, n - 1)]

    def split(p):
        if len(p) == 3:
            yield [tuple(p)]
            return
        for k in range(1, len(p) - 1):
            left = [[]] if k == 1 else list(split(p[: k + 1]))
            right = [[]] if k == len(p) - 2 else list(split(p[k:]))
            for a in left:
                for b in right:
                    yield a + b + [(p[0], p[k], p[-1])]

    yield from split(poly)


def triangulate(poly: list[int], share_a_face) -> list[tuple[int, int, int]]:
    """Triangulate a polygon so that no diagonal joins two vertices on one cell face.

    Parameters
    ----------
    poly : list of int
        Cell edges of the polygon's vertices, in cyclic order.
    share_a_face : callable
        ``share_a_face(e1, e2)``: whether cell edges e1 and e2 lie on one face.
    """
    n = len(poly)
    sides = {frozenset((poly[i], poly[(i + 1) % n])) for i in range(n)}
    for tris in _triangulations(poly):
        chords = {frozenset(p) for t in tris for p in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        if not any(share_a_face(*c) for c in chords - sides):
            return tris
    raise ValueError(f"no triangulation of {poly} avoids chords on a face")  # never, by test


def _padded(per_config: list[list[tuple[int, ...]]], arity: int) -> tuple[np.ndarray, np.ndarray]:
    """(n_configs,) counts and (n_configs, width, arity) int64 table padded with -1."""
    width = max(1, max(len(t) for t in per_config))
    table = np.full((len(per_config), width, arity), -1, dtype=np.int64)
    counts = np.zeros(len(per_config), dtype=np.int64)
    for config, items in enumerate(per_config):
        counts[config] = len(items)
        if items:
            table[config, : len(items)] = items
    table.setflags(write=False)
    counts.setflags(write=False)
    return counts, table


def _check_rule(rule: str) -> None:
    if rule not in AMBIGUITY_RULES:
        raise ValueError(f"unknown ambiguity rule {rule!r}; choose one of {AMBIGUITY_RULES}")


# --- Marching Cubes ---------------------------------------------------------------

_CUBE_EDGE_INDEX = {tuple(int(v) for v in e): n for n, e in enumerate(CUBE_EDGES)}


def cube_polygons(config: int, rule: str = DEFAULT_AMBIGUITY) -> list[list[int]]:
    """The isosurface polygons of one cube configuration.

    Parameters
    ----------
    config : int
        Configuration index, 0..255 (bit v set = vertex v positive).
    rule : str
        Ambiguous-face rule, one of :data:`AMBIGUITY_RULES`.

    Returns
    -------
    list of list of int
        Each polygon as the cycle of cube edges its vertices lie on, in the
        order whose right-hand normal points to the negative side.
    """
    _check_rule(rule)
    positive = [(config >> v) & 1 == 1 for v in range(8)]
    faces = [[int(c) for c in f] for f in CUBE_FACES]
    cycles = face_walk(CUBE_VERTICES.astype(float), faces, positive, rule)
    return [[_CUBE_EDGE_INDEX[e] for e in cycle] for cycle in cycles]


@cache
def marching_cubes_table(rule: str = DEFAULT_AMBIGUITY) -> tuple[np.ndarray, np.ndarray]:
    """The 256-entry Marching Cubes table for one ambiguity rule.

    Read from :mod:`isoconvert.extract.cube_tables`, which
    :func:`write_cube_tables` generates from :func:`derive_marching_cubes_table`
    (deriving takes about 0.1 s, a third of a small conversion); the tests
    check that the stored tables equal the derivation.

    Returns
    -------
    n_triangles : (256,) int64
        Number of triangles of each configuration.
    triangles : (256, T, 3) int64
        Cube-edge indices of each triangle, padded with -1; T is the largest
        count over all configurations.
    """
    _check_rule(rule)
    from .cube_tables import TRIANGLES

    return _padded([list(triangles) for triangles in TRIANGLES[rule]], 3)


def derive_marching_cubes_table(rule: str = DEFAULT_AMBIGUITY) -> tuple[np.ndarray, np.ndarray]:
    """:func:`marching_cubes_table`, derived from the face walk."""
    return _padded(
        [
            [t for poly in cube_polygons(config, rule) for t in triangulate(poly, _share_a_face)]
            for config in range(256)
        ],
        3,
    )


def write_cube_tables(path: Path | None = None) -> Path:
    """Write the derived tables of every rule to ``cube_tables.py`` (or ``path``)."""
    path = path or Path(__file__).with_name("cube_tables.py")
    lines = [
        '"""Marching Cubes tables, generated by isoconvert.extract.tables.write_cube_tables().',
        "",
        "Do not edit: :func:`isoconvert.extract.tables.derive_marching_cubes_table` is the",
        "source; tests/test_tables.py checks that these equal it.",
        '"""',
        "",
        "# fmt: off",
        "#: Per rule, per configuration 0..255: triangles as triples of cube edges.",
        "TRIANGLES = {",
    ]
    for rule in AMBIGUITY_RULES:
        counts, table = derive_marching_cubes_table(rule)
        lines.append(f"    {rule!r}: (")
        for config in range(256):
            tris = tuple(tuple(int(e) for e in t) for t in table[config, : counts[config]])
            lines.append(f"        {tris!r},")
        lines.append("    ),")
    lines += ["}", "# fmt: on", ""]
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def _share_a_face(e1: int, e2: int) -> bool:
    """Whether cube edges e1 and e2 lie on one face of the cube."""
    return bool(_EDGE_FACES[e1] & _EDGE_FACES[e2])


#: The faces (axis, side) each cube edge lies on.
_EDGE_FACES = [
    {(a, s) for a in range(3) for s in (0, 1) if (CUBE_VERTICES[CUBE_EDGES[e]][:, a] == s).all()}
    for e in range(12)
]


# --- Marching Squares ---------------------------------------------------------------

#: (4, 2) int: offset of each square corner (bit c of a square configuration).
SQUARE_CORNERS = CUBE_VERTICES[:4, :2]
#: (4, 2) int: the two corners of each square edge, lower first; edges 0, 1 run
#: along x (at y = 0, 1), edges 2, 3 along y (at x = 0, 1).
SQUARE_EDGES = _axis_edges(2)
#: Square configurations whose diagonal corners share signs (book Figure 2.12).
AMBIGUOUS_SQUARES = (0b0110, 0b1001)


@cache
def marching_squares_table(rule: str = DEFAULT_AMBIGUITY) -> tuple[np.ndarray, np.ndarray]:
    """The 16-entry Marching Squares table.

    Returns
    -------
    n_segments : (16,) int64
    segments : (16, 2, 2) int64
        Square-edge indices of each segment's start and end, padded with -1.
        Each segment has the positive corners on its left.
    """
    _check_rule(rule)
    edge_index = {tuple(int(v) for v in e): n for n, e in enumerate(SQUARE_EDGES)}
    cycle = [0, 1, 3, 2]  # corners counter-clockwise
    per_config = []
    for config in range(16):
        positive = [(config >> c) & 1 == 1 for c in range(4)]
        segs = []
        for a, b in square_segments(tuple(positive[c] for c in cycle), rule):
            ea = edge_index[tuple(sorted((cycle[a], cycle[(a + 1) % 4])))]
            eb = edge_index[tuple(sorted((cycle[b], cycle[(b + 1) % 4])))]
            mid_a = SQUARE_CORNERS[SQUARE_EDGES[ea]].mean(axis=0)
            mid_b = SQUARE_CORNERS[SQUARE_EDGES[eb]].mean(axis=0)
            pos_end = next(int(c) for c in SQUARE_EDGES[ea] if positive[c])
            d, w = mid_b - mid_a, SQUARE_CORNERS[pos_end] - mid_a
            segs.append((ea, eb) if d[0] * w[1] - d[1] * w[0] > 0 else (eb, ea))
        per_config.append(segs)
    return _padded(per_config, 2)


# --- Marching Tetrahedra ---------------------------------------------------------------

#: (6, 4) int: the cube split into six tetrahedra around the diagonal from vertex 0
#: to vertex 7 (Kuhn / Freudenthal): tetrahedron (0, a, b, 7) follows the path
#: 0 -> a -> b -> 7 that adds one axis at a time. Every face of the cube is cut by
#: the diagonal through its vertex nearest 0 and 7, on both cubes sharing it, so
#: neighbouring tetrahedra match and the surface has no cracks.
CUBE_TETRAHEDRA = np.array(
    [(0, 1 << p[0], (1 << p[0]) | (1 << p[1]), 7) for p in itertools.permutations(range(3))],
    dtype=np.int64,
)
#: (7, 3) int: the edge directions of the decomposition: the axes x, y, z, the face
#: diagonals xy, xz, yz and the cube diagonal. Every edge of a tetrahedron runs
#: from a grid vertex along one of these (all components >= 0).
TETRA_DIRECTIONS = np.array(
    [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)], dtype=np.int64
)


def _tetra_edges() -> np.ndarray:
    """(19, 2) cube vertices of the decomposition's edges: 12 cube edges, 6 face
    diagonals, 1 cube diagonal (each lower vertex first)."""
    edges = set()
    for tet in CUBE_TETRAHEDRA:
        for a, b in itertools.combinations(sorted(int(v) for v in tet), 2):
            edges.add((a, b))
    return np.array(sorted(edges, key=lambda e: (bin(e[1] ^ e[0]).count("1"), e)), dtype=np.int64)


#: (19, 2) int: the edges of the six tetrahedra, as cube-vertex pairs.
TETRA_EDGES = _tetra_edges()
#: (19, 3) int: offset of each edge's lower vertex.
TETRA_EDGE_BASE = CUBE_VERTICES[TETRA_EDGES[:, 0]]
#: (19,) int: direction (index into TETRA_DIRECTIONS) of each edge.
TETRA_EDGE_DIR = np.array(
    [
        int(
            np.flatnonzero((TETRA_DIRECTIONS == CUBE_VERTICES[b] - CUBE_VERTICES[a]).all(axis=1))[0]
        )
        for a, b in TETRA_EDGES
    ],
    dtype=np.int64,
)


@cache
def marching_tetrahedra_table() -> tuple[np.ndarray, np.ndarray]:
    """Triangles of each of the six tetrahedra for each of its 16 configurations.

    Returns
    -------
    n_triangles : (6 * 16,) int64
        Entry ``16 * t + config``: triangles of tetrahedron t in configuration
        ``config`` (bit n set = its n-th corner positive).
    triangles : (6 * 16, 2, 3) int64
        Indices into :data:`TETRA_EDGES`, padded with -1.
    """
    edge_index = {tuple(int(v) for v in e): n for n, e in enumerate(TETRA_EDGES)}
    faces = [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]
    per_entry = []
    for tet in CUBE_TETRAHEDRA:
        corners = CUBE_VERTICES[tet].astype(float)
        for config in range(16):
            positive = [(config >> n) & 1 == 1 for n in range(4)]
            cycles = face_walk(corners, faces, positive, DEFAULT_AMBIGUITY)
            polys = [
                [edge_index[tuple(sorted((int(tet[a]), int(tet[b]))))] for a, b in cycle]
                for cycle in cycles
            ]
            per_entry.append(fan(polys))
    return _padded(per_entry, 3)


# --- symmetry classes -----------------------------------------------------------------


def cube_symmetries() -> list[tuple[np.ndarray, bool]]:
    """The 48 symmetries of the cube as vertex permutations.

    Returns
    -------
    list of ((8,) int64, bool)
        ``perm[v]`` is the image of vertex v; the flag is True for reflections
        (orientation-reversing symmetries), which reverse triangle orientation.
    """
    result = []
    for axes in itertools.permutations(range(3)):
        for flips in itertools.product((0, 1), repeat=3):
            perm = np.empty(8, dtype=np.int64)
            for v, offset in enumerate(CUBE_VERTICES):
                image = [offset[axes[a]] ^ flips[a] for a in range(3)]
                perm[v] = image[0] + 2 * image[1] + 4 * image[2]
            sign = np.linalg.det(np.eye(3)[list(axes)]) * (-1) ** sum(flips)
            result.append((perm, bool(sign < 0)))
    return result


def configuration_classes(with_complement: bool = False) -> list[list[int]]:
    """Partition the 256 configurations into classes under the cube symmetries.

    Without ``with_complement`` these are the book's 22 classes. With it the sign
    swap counts as a symmetry too, giving 14 classes (Lorensen and Cline's 15
    cases, which use rotations but not reflections, merge into 14).
    """
    perms = [p for p, _ in cube_symmetries()]
    seen: dict[int, int] = {}
    classes: list[list[int]] = []
    for config in range(256):
        if config in seen:
            continue
        members = set()
        for perm in perms:
            image = sum(1 << int(perm[v]) for v in range(8) if (config >> v) & 1)
            members.add(image)
            if with_complement:
                members.add(255 - image)
        for m in members:
            seen[m] = len(classes)
        classes.append(sorted(members))
    return classes
