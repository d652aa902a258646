"""The book's Figure 2.4 (Wenger, *Isosurfaces*, section 2.2.4): a 5x5 grid at
isovalue 5 where one sample equals the isovalue.

Every expected number here is worked out from the printed grid by linear
interpolation on bipolar edges (Algorithm 1.1, Definition 2.1), independently
of the kernel and its tables.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from conftest import SAMPLES, load_samples_module

import isoconvert
from isoconvert.report import check_mesh

LEVEL = 5


def printed_grid() -> list[list[int]]:
    return [list(row) for row in load_samples_module().FIGURE_2_4_ROWS]


def value(x: int, y: int) -> int:
    """Sample at grid vertex (x, y): printed row 4 - y, column x (y points up)."""
    return printed_grid()[4 - y][x]


def bipolar_vertices() -> dict[tuple, tuple[Fraction, Fraction]]:
    """Exact isocontour vertex on each bipolar grid edge, keyed by the edge."""
    out = {}
    for x in range(5):
        for y in range(5):
            for dx, dy in ((1, 0), (0, 1)):
                u, v = x + dx, y + dy
                if u > 4 or v > 4:
                    continue
                a, b = value(x, y), value(u, v)
                if (a >= LEVEL) == (b >= LEVEL):
                    continue
                t = Fraction(LEVEL - a, b - a)
                out[((x, y), (u, v))] = (x + t * dx, y + t * dy)
    return out


@pytest.mark.parametrize("name", ["figure_2_4.nrrd", "figure_2_4_5x5_uint8.raw"])
def test_sample_file_holds_the_printed_grid(name):
    volume = isoconvert.read_volume(SAMPLES / name)
    expected = np.array([[value(x, y) for y in range(5)] for x in range(5)])
    np.testing.assert_array_equal(volume.data, expected)


def test_vertices_are_the_linear_interpolations_on_the_bipolar_edges():
    volume = isoconvert.read_volume(SAMPLES / "figure_2_4.nrrd")
    mesh = isoconvert.extract(volume, LEVEL, method="squares", vertex_offset=0.0)
    expected = sorted((float(px), float(py)) for px, py in bipolar_vertices().values())
    got = sorted(map(tuple, mesh.vertices[:, :2].tolist()))
    assert len(got) == len(expected) == 19
    # the exact fractions, up to the rounding of one float64 multiply-add
    np.testing.assert_allclose(got, expected, rtol=0, atol=4 * np.finfo(float).eps * 4)
    assert np.all(mesh.vertices[:, 2] == 0)


def test_the_sample_equal_to_the_isovalue():
    """Its two negative neighbours (along x) make two bipolar edges ending at it,
    so two vertices land on that grid vertex. Its positive neighbours are along
    y, so no square holds both of those edges: the two vertices are never joined
    by a segment (no zero-length segment); the contour touches itself there, a
    vertex of degree 4 once equal positions are merged."""
    where = [(x, y) for x in range(5) for y in range(5) if value(x, y) == LEVEL]
    assert where == [(2, 3)]
    verts = bipolar_vertices()
    at_sample = [e for e, p in verts.items() if p == where[0]]
    assert len(at_sample) == 2
    # a zero-length segment needs a square holding two bipolar edges whose vertices coincide
    squares_with_both = [
        (x, y)
        for x in range(4)
        for y in range(4)
        if all({e[0], e[1]} <= {(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)} for e in at_sample)
    ]
    expected_zero_length = len(squares_with_both)
    assert expected_zero_length == 0

    volume = isoconvert.read_volume(SAMPLES / "figure_2_4.nrrd")
    mesh = isoconvert.extract(volume, LEVEL, method="squares", vertex_offset=0.0)
    report = check_mesh(mesh)
    assert report.problems["zero_length_segments"]["count"] == expected_zero_length
    assert report.counts["merged_vertices"] == len(at_sample) - 1
    branch = report.problems["branch_vertices"]
    assert branch["count"] == 1
    assert branch["examples"][0]["degree"] == 4
    assert branch["examples"][0]["position"][:2] == [2.0, 3.0]


def test_automatic_placement_separates_the_two_vertices():
    """Left to itself, extraction keeps vertices 0.001 of an edge off the sample
    equal to the level: the two vertices there become distinct points, each
    moved 0.001 along its own edge, and nothing else changes."""
    volume = isoconvert.read_volume(SAMPLES / "figure_2_4.nrrd")
    notices = []
    exact = isoconvert.extract(volume, LEVEL, method="squares", vertex_offset=0.0)
    moved = isoconvert.extract(volume, LEVEL, method="squares", on_status=notices.append)
    assert any("equals 1 sample" in n for n in notices)
    assert moved.n_cells == exact.n_cells and moved.n_vertices == exact.n_vertices
    shift = np.linalg.norm(moved.vertices - exact.vertices, axis=1)
    assert np.count_nonzero(shift) == 2
    assert np.allclose(shift[shift > 0], 1e-3)
    report = check_mesh(moved)
    assert report.counts["merged_vertices"] == 0
    assert report.problems["branch_vertices"]["count"] == 0
