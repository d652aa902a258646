"""Marching Squares / Marching Cubes lookup tables, derived by code.

Nothing here is pasted. The Marching Cubes table is built by the face rule
behind the book's compatibility argument (Wenger, *Isosurfaces*, section 2.3):

1. On each of the six faces of the cube, the configuration restricted to that
   face is contoured by the Marching Squares rule (one segment across each
   pair of bipolar edges; on an ambiguous face, the two segments cut off either
   the two positive or the two negative corners, one fixed choice for all faces).
2. Every bipolar cube edge lies on two faces, so the face segments chain into
   closed cycles; each cycle is one polygon of the isosurface patch, triangulated
   as a fan.

Because the segments on a face depend only on the signs of that face's four
corners, two cubes that share a face cut it along the same segments: patches are
compatible and closed surfaces come out watertight (the book's Figure 2.17, never
2.18). The 256 entries fall into 22 classes under the 48 symmetries of the cube
(:func:`configuration_classes`); the tests check that and the book's properties
on every entry.

Conventions
-----------
Cube vertex ``v`` has offset ``(v & 1, v >> 1 & 1, v >> 2 & 1)`` and is bit ``v``
of the configuration index; the bit is set when the vertex is positive
(value >= isovalue, book Definition 2.1).
Cube edge ``e`` runs from ``CUBE_EDGES[e, 0]`` to ``CUBE_EDGES[e, 1]`` along axis
``EDGE_AXIS[e]``. Triangles are ordered so their right-hand normals point from
the positive to the negative side.
"""

from __future__ import annotations

import itertools
from functools import cache

import numpy as np

#: Ambiguity rules for a face whose diagonal corners share signs.
AMBIGUITY_RULES = ("separate-positive", "separate-negative")
#: The default rule. It is the one VTK's Marching Cubes / Flying Edges table and
#: scikit-image's ``method="lorensen"`` follow, so triangle counts and
#: connectivity agree with theirs (checked on real scans in the tests).
DEFAULT_AMBIGUITY = "separate-positive"

#: (8, 3) int: offset of each cube vertex.
CUBE_VERTICES = np.array([(v & 1, (v >> 1) & 1, (v >> 2) & 1) for v in range(8)], dtype=np.int64)


def _edges() -> np.ndarray:
    # Grouped by axis so that edge e = 4 * axis + n: the kernels find an edge's
    # grid position from its lower vertex and its axis alone.
    edges = []
    for axis in range(3):
        for v in range(8):
            if not (v >> axis) & 1:
                edges.append((v, v | (1 << axis)))
    return np.array(edges, dtype=np.int64)


#: (12, 2) int: the two cube vertices of each edge, lower one first.
CUBE_EDGES = _edges()
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


def _edge_index(a: int, b: int) -> int:
    lo, hi = min(a, b), max(a, b)
    return int(np.flatnonzero((CUBE_EDGES[:, 0] == lo) & (CUBE_EDGES[:, 1] == hi))[0])


def square_segments(signs: tuple[bool, bool, bool, bool], rule: str) -> list[tuple[int, int]]:
    """Marching Squares on one square, corners given counter-clockwise.

    Parameters
    ----------
    signs : 4 bools
        True where the corner is positive; corner ``c`` and ``c + 1 (mod 4)``
        bound square edge ``c``.
    rule : str
        One of :data:`AMBIGUITY_RULES`, used when diagonal corners share signs.

    Returns
    -------
    list of (int, int)
        Segments as pairs of square-edge indices, unoriented.
    """
    bipolar = [c for c in range(4) if signs[c] != signs[(c + 1) % 4]]
    if len(bipolar) == 2:
        return [tuple(bipolar)]
    if len(bipolar) == 4:
        # Diagonal corners agree: cut off the two corners of the sign to separate.
        cut_positive = rule == "separate-positive"
        corners = [c for c in range(4) if signs[c] == cut_positive]
        # Corner c touches square edges c - 1 and c.
        return [((c - 1) % 4, c) for c in corners]
    return []


def _oriented_face_segments(config: int, rule: str) -> list[tuple[int, int]]:
    """Directed segments (cube edge -> cube edge) on all six faces.

    Each segment is directed so that, seen from outside the cube, the positive
    corners lie on its right; the polygons these chain into then run
    counter-clockwise around the normal that points to the negative side.
    """
    positive = [(config >> v) & 1 == 1 for v in range(8)]
    segments = []
    for f, corners in enumerate(CUBE_FACES):
        axis, side = divmod(f, 2)
        outward = np.zeros(3)
        outward[axis] = 1.0 if side else -1.0
        signs = tuple(positive[c] for c in corners)
        for a, b in square_segments(signs, rule):
            ea = _edge_index(corners[a], corners[(a + 1) % 4])
            eb = _edge_index(corners[b], corners[(b + 1) % 4])
            mid_a = CUBE_VERTICES[CUBE_EDGES[ea]].mean(axis=0)
            mid_b = CUBE_VERTICES[CUBE_EDGES[eb]].mean(axis=0)
            # The positive end of a bipolar edge is always on the positive side of
            # the segment through it.
            pos_end = next(v for v in CUBE_EDGES[ea] if positive[v])
            right = np.cross(mid_b - mid_a, outward)
            if np.dot(right, CUBE_VERTICES[pos_end] - mid_a) > 0:
                segments.append((ea, eb))
            else:
                segments.append((eb, ea))
    return segments


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
    if rule not in AMBIGUITY_RULES:
        raise ValueError(f"unknown ambiguity rule {rule!r}; choose one of {AMBIGUITY_RULES}")
    following = dict(_oriented_face_segments(config, rule))
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


@cache
def marching_cubes_table(rule: str = DEFAULT_AMBIGUITY) -> tuple[np.ndarray, np.ndarray]:
    """The 256-entry Marching Cubes table for one ambiguity rule.

    Returns
    -------
    n_triangles : (256,) int64
        Number of triangles of each configuration.
    triangles : (256, T, 3) int64
        Cube-edge indices of each triangle, padded with -1; T is the largest
        count over all configurations.
    """
    per_config = []
    for config in range(256):
        tris = []
        for poly in cube_polygons(config, rule):
            tris.extend((poly[0], poly[i], poly[i + 1]) for i in range(1, len(poly) - 1))
        per_config.append(tris)
    width = max(len(t) for t in per_config)
    table = np.full((256, width, 3), -1, dtype=np.int64)
    counts = np.zeros(256, dtype=np.int64)
    for config, tris in enumerate(per_config):
        counts[config] = len(tris)
        if tris:
            table[config, : len(tris)] = tris
    table.setflags(write=False)
    counts.setflags(write=False)
    return counts, table


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
