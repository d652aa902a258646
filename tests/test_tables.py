"""The Marching Cubes table: the book's properties checked on all 256 entries."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from isoconvert.extract.tables import (
    AMBIGUITY_RULES,
    CUBE_EDGES,
    CUBE_VERTICES,
    EDGE_AXIS,
    EDGE_BASE,
    configuration_classes,
    cube_polygons,
    cube_symmetries,
    marching_cubes_table,
)


def triangles(config: int, rule: str) -> list[tuple[int, int, int]]:
    counts, table = marching_cubes_table(rule)
    return [tuple(int(e) for e in table[config, t]) for t in range(counts[config])]


def bipolar_edges(config: int) -> set[int]:
    pos = [(config >> v) & 1 for v in range(8)]
    return {e for e, (a, b) in enumerate(CUBE_EDGES) if pos[a] != pos[b]}


def test_48_symmetries_are_distinct_permutations():
    perms = {tuple(p) for p, _ in cube_symmetries()}
    assert len(perms) == 48
    assert sum(reflect for _, reflect in cube_symmetries()) == 24


def test_the_book_s_22_configuration_classes():
    classes = configuration_classes()
    assert len(classes) == 22
    assert sorted(x for c in classes for x in c) == list(range(256))
    # with the sign swap as a symmetry too, 14 classes remain
    assert len(configuration_classes(with_complement=True)) == 14


@pytest.mark.parametrize("rule", AMBIGUITY_RULES)
def test_patch_meets_exactly_the_bipolar_edges_once_per_polygon(rule):
    for config in range(256):
        polys = cube_polygons(config, rule)
        used = [e for p in polys for e in p]
        assert len(used) == len(set(used)), config
        assert set(used) == bipolar_edges(config), config
        tri_edges = {e for t in triangles(config, rule) for e in t}
        assert tri_edges == bipolar_edges(config), config


def _patch_boundary(tris):
    """Directed boundary segments of a patch (edges used by one triangle)."""
    directed = [(t[i], t[(i + 1) % 3]) for t in tris for i in range(3)]
    undirected = [tuple(sorted(d)) for d in directed]
    return {d for d, u in zip(directed, undirected, strict=True) if undirected.count(u) == 1}


@pytest.mark.parametrize("rule", AMBIGUITY_RULES)
def test_patch_is_an_oriented_surface_with_boundary_on_the_faces(rule):
    for config in range(256):
        tris = triangles(config, rule)
        directed = [(t[i], t[(i + 1) % 3]) for t in tris for i in range(3)]
        # each interior edge once in each direction, never twice the same way
        assert len(directed) == len(set(directed)), config
        for a, b in _patch_boundary(tris):
            # a boundary segment joins two cube edges of one face
            va, vb = CUBE_VERTICES[CUBE_EDGES[a]], CUBE_VERTICES[CUBE_EDGES[b]]
            common = [
                (ax, side)
                for ax in range(3)
                for side in (0, 1)
                if (va[:, ax] == side).all() and (vb[:, ax] == side).all()
            ]
            assert len(common) == 1, (config, a, b)


def _face_segments(config, rule, axis, side):
    """Boundary segments of the patch on one face, as directed pairs of grid edges
    (in coordinates of the grid edge: lower vertex offset and axis)."""
    segs = set()
    for a, b in _patch_boundary(triangles(config, rule)):
        ends = []
        for e in (a, b):
            verts = CUBE_VERTICES[CUBE_EDGES[e]]
            if not (verts[:, axis] == side).all():
                break
            ends.append((tuple(EDGE_BASE[e]), int(EDGE_AXIS[e])))
        else:
            segs.add(tuple(ends))
    return segs


@pytest.mark.parametrize("rule", AMBIGUITY_RULES)
def test_neighbouring_patches_agree_on_the_shared_face(rule):
    """Book Figure 2.17: two cubes sharing a face cut it along the same segments,
    traversed in opposite directions (so orientations match across the face)."""
    for axis in range(3):
        low_face = [v for v in range(8) if not (v >> axis) & 1]
        high_face = [v | (1 << axis) for v in low_face]
        others = [v for v in range(8) if v not in low_face]
        for face_signs in itertools.product((0, 1), repeat=4):
            shared = sum(s << v for s, v in zip(face_signs, high_face, strict=True))
            shared_b = sum(s << v for s, v in zip(face_signs, low_face, strict=True))
            for rest_a in range(16):
                # cube A below (its high face is shared), cube B above (its low face)
                a = shared | sum(((rest_a >> n) & 1) << v for n, v in enumerate(low_face))
                seg_a = _face_segments(a, rule, axis, 1)
                # shift A's face coordinates into B's frame: offset along axis 1 -> 0
                seg_a = {
                    tuple(
                        (tuple(o - (1 if k == axis else 0) for k, o in enumerate(off)), ax)
                        for off, ax in seg
                    )
                    for seg in seg_a
                }
                for rest_b in range(16):
                    b = shared_b | sum(((rest_b >> n) & 1) << v for n, v in enumerate(others))
                    seg_b = _face_segments(b, rule, axis, 0)
                    reversed_b = {(q, p) for p, q in seg_b}
                    assert seg_a == reversed_b, (axis, a, b)


def test_orientation_points_from_positive_to_negative():
    """Each polygon's vector area (vertices at edge midpoints; independent of how
    it is triangulated) points from its positive to its negative corners, and
    the table's triangles triangulate those polygons, keeping their direction."""
    for rule in AMBIGUITY_RULES:
        for config in range(1, 255):
            pos = np.array([(config >> v) & 1 for v in range(8)], bool)
            fan = []
            n_tris = 0
            for poly in cube_polygons(config, rule):
                p = np.array([CUBE_VERTICES[CUBE_EDGES[e]].mean(axis=0) for e in poly])
                area = 0.5 * np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
                to_negative = np.zeros(3)
                for e in poly:
                    a, b = CUBE_EDGES[e]
                    step = CUBE_VERTICES[b] - CUBE_VERTICES[a]
                    to_negative += step if pos[a] else -step
                assert np.dot(area, to_negative) > 0, (rule, config, poly)
                fan += [(poly[i], poly[(i + 1) % len(poly)]) for i in range(len(poly))]
                n_tris += len(poly) - 2
            tris = triangles(config, rule)
            assert len(tris) == n_tris
            assert _patch_boundary(tris) == set(fan), (rule, config)


def test_rules_differ_only_on_configurations_with_an_ambiguous_face():
    def has_ambiguous_face(config):
        for axis in range(3):
            for side in (0, 1):
                face = [v for v in range(8) if ((v >> axis) & 1) == side]
                s = [(config >> v) & 1 for v in face]
                # face corners in index order: 0-3 and 1-2 are the diagonals
                if s[0] == s[3] and s[1] == s[2] and s[0] != s[1]:
                    return True
        return False

    c1, t1 = marching_cubes_table("separate-positive")
    c2, t2 = marching_cubes_table("separate-negative")
    for config in range(256):
        same = c1[config] == c2[config] and np.array_equal(t1[config], t2[config])
        if not has_ambiguous_face(config):
            assert same, config

    # Swapping signs swaps the rules and reverses orientation: configuration k
    # under one rule has the polygons of 255 - k under the other, reversed.
    def cycles(polys):
        return {tuple(np.roll(p, -int(np.argmin(p)))) for p in polys}

    for config in range(256):
        a = cycles(cube_polygons(config, "separate-positive"))
        b = cycles(p[::-1] for p in cube_polygons(255 - config, "separate-negative"))
        assert a == b, config


@pytest.mark.parametrize("rule", AMBIGUITY_RULES)
def test_no_diagonal_lies_in_a_cube_face(rule):
    """A triangle edge that is not a side of its polygon must not join two cube
    edges of one face: the neighbouring cube's patch could use the same chord,
    making an edge of four triangles (found by a random grid with a fan rule)."""

    def faces(e):
        v = CUBE_VERTICES[CUBE_EDGES[e]]
        return {(a, s) for a in range(3) for s in (0, 1) if (v[:, a] == s).all()}

    for config in range(256):
        sides = {
            frozenset((p[i], p[(i + 1) % len(p)]))
            for p in cube_polygons(config, rule)
            for i in range(len(p))
        }
        for t in triangles(config, rule):
            for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])):
                if frozenset((a, b)) not in sides:
                    assert not faces(a) & faces(b), (config, t)


@pytest.mark.parametrize("rule", ["separate-positive", "separate-negative"])
def test_stored_cube_tables_equal_the_derivation(rule):
    """cube_tables.py is generated; it must stay what the face walk derives."""
    from isoconvert.extract.tables import derive_marching_cubes_table

    stored_counts, stored = marching_cubes_table(rule)
    counts, derived = derive_marching_cubes_table(rule)
    assert np.array_equal(stored_counts, counts)
    assert np.array_equal(stored, derived)
