"""isoconvert.post.components: keep the largest, drop small ones, fill cavities."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import SAMPLES, ball, dataset

from isoconvert import extract, read_volume
from isoconvert.errors import IsoconvertError
from isoconvert.post.components import _inside, _labels, drop_small, fill_cavities, keep_largest
from isoconvert.volume import Volume


def parts(mesh) -> list:
    """trimesh's components (independent of isoconvert.graph), largest first."""
    tm = trimesh.Trimesh(mesh.vertices, mesh.cells, process=False)
    found = tm.split(only_watertight=False)
    return sorted(found, key=lambda p: -len(p.faces))


def position_set(vertices: np.ndarray) -> np.ndarray:
    v = np.asarray(vertices)
    return v[np.lexsort(v.T[::-1])]


def two_balls(r1: float, r2: float):
    """Two separate balls of radii r1 (centre x=9) and r2 (centre x=24)."""
    field = np.maximum(ball(34, r1, center=(9, 16, 16)), ball(34, r2, center=(24, 16, 16)))
    return extract(Volume(field), 0.0)


def hollow_ball():
    """A shell: outer radius 13.2, cavity radius 7.3 (positive inside the material)."""
    field = np.minimum(ball(34, 13.2), -ball(34, 7.3))
    return extract(Volume(field), 0.0)


def assert_compact_subset(out, mesh):
    """Vertices are used input vertices, in input order, all referenced."""
    assert out.edge_ids is not None
    index = {int(e): i for i, e in enumerate(mesh.edge_ids)}
    src = np.array([index[int(e)] for e in out.edge_ids])
    assert np.all(np.diff(src) > 0)  # stable order
    assert np.array_equal(out.vertices, mesh.vertices[src])
    assert np.array_equal(np.unique(out.cells), np.arange(out.n_vertices))  # compact
    # each output triangle is an input triangle, same orientation
    tri_in = {tuple(t) for t in mesh.cells.tolist()}
    assert all(tuple(t) in tri_in for t in src[out.cells].tolist())


def test_two_spheres_keep_largest():
    mesh = extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.25)
    pieces = parts(mesh)
    assert len(pieces) == 2
    out = keep_largest(mesh)
    assert len(parts(out)) == 1
    assert out.info["cleanup"][-1]["components_before"] == 2
    # the two spheres are mirror images with equal triangle counts: the tie goes to
    # the component of vertex 0 (the first in the input's order)
    assert len(pieces[0].faces) == len(pieces[1].faces) == out.n_cells
    first = [p for p in pieces if np.any(np.all(p.vertices == mesh.vertices[0], axis=1))][0]
    assert np.array_equal(position_set(out.vertices), position_set(first.vertices))
    assert_compact_subset(out, mesh)


def test_keep_largest_picks_the_larger_ball():
    mesh = two_balls(5.3, 3.4)
    big, small = parts(mesh)
    assert len(big.faces) > len(small.faces)
    out = keep_largest(mesh)
    assert np.array_equal(position_set(out.vertices), position_set(big.vertices))
    assert out.n_cells == len(big.faces)
    both = keep_largest(mesh, k=2)
    assert both.n_cells == mesh.n_cells and len(parts(both)) == 2
    assert_compact_subset(out, mesh)
    with pytest.raises(IsoconvertError):
        keep_largest(mesh, k=0)


def test_drop_small_by_triangles_and_volume():
    mesh = two_balls(5.3, 3.4)
    big, small = parts(mesh)
    cut = (len(big.faces) + len(small.faces)) // 2
    out = drop_small(mesh, min_triangles=cut)
    assert out.n_cells == len(big.faces) and len(parts(out)) == 1
    kept = drop_small(mesh, min_triangles=len(small.faces))  # exactly the minimum stays
    assert kept.n_cells == mesh.n_cells
    # by volume: the small ball encloses about 4/3 pi 3.4^3 = 165, the big one 624
    out = drop_small(mesh, min_volume=300.0)
    assert np.array_equal(position_set(out.vertices), position_set(big.vertices))
    assert abs(small.volume) < 300.0 < abs(big.volume)
    assert drop_small(mesh, min_volume=100.0).n_cells == mesh.n_cells
    assert_compact_subset(out, mesh)


def test_fill_cavities_removes_inner_surface_keeps_outer_exactly():
    mesh = hollow_ball()
    assert len(parts(mesh)) == 2
    outer_only = extract(Volume(ball(34, 13.2)), 0.0)
    out = fill_cavities(mesh)
    assert len(parts(out)) == 1
    assert out.info["cleanup"][-1]["removed"] == 1
    # the outer surface is exactly the ball's: same grid edges, positions, triangles
    assert np.array_equal(np.sort(out.edge_ids), np.sort(outer_only.edge_ids))
    assert np.array_equal(position_set(out.vertices), position_set(outer_only.vertices))
    assert out.n_cells == outer_only.n_cells
    assert out.signed_volume() > 0
    assert_compact_subset(out, mesh)


def test_fill_cavities_leaves_separate_balls_alone():
    mesh = two_balls(5.3, 3.4)
    out = fill_cavities(mesh)
    assert np.array_equal(out.vertices, mesh.vertices)
    assert np.array_equal(out.cells, mesh.cells)
    assert out.info["cleanup"][-1]["removed"] == 0


def test_fill_cavities_island_inside_cavity_also_goes():
    # a shell with a small ball floating in its cavity: both inner surfaces go
    field = np.maximum(np.minimum(ball(34, 13.2), -ball(34, 7.3)), ball(34, 3.1))
    mesh = extract(Volume(field), 0.0)
    assert len(parts(mesh)) == 3
    out = fill_cavities(mesh)
    assert len(parts(out)) == 1
    outer_only = extract(Volume(ball(34, 13.2)), 0.0)
    assert np.array_equal(np.sort(out.edge_ids), np.sort(outer_only.edge_ids))


def test_component_counts_match_trimesh_on_sample():
    mesh = extract(read_volume(SAMPLES / "two_spheres.nrrd"), 0.25)
    assert keep_largest(mesh, k=5).info["cleanup"][-1]["components_before"] == len(parts(mesh))


def test_inside_by_ray_parity_agrees_with_trimesh_on_a_ct_with_many_specks():
    """The compiled ray-parity kernel on the chest CT's bone surface (300.5 HU,
    capped at the grid's faces: one closed surface of 700k triangles, and a
    thousand specks inside its box): for points spread over the box, inside or
    not as trimesh's ``contains`` says (numpy took 200 s on this scan's
    --close --fill-cavities)."""
    from isoconvert.post.cap import close_at_grid

    volume = read_volume(dataset("ct_chest_LIDC-IDRI-0314_dicom"))
    mesh = close_at_grid(extract(volume, 300.5), volume, 300.5)
    tri_comp, sizes, _ = _labels(mesh)
    big = int(np.argmax(sizes))
    outer = trimesh.Trimesh(mesh.vertices, mesh.cells[tri_comp == big], process=False)
    assert outer.is_watertight and outer.volume > 0
    # points 0.4 mm either side of the surface: half inside, half outside
    # (trimesh's contains is slow, about 8 ms a point here)
    samples, faces = trimesh.sample.sample_surface(outer, 300, seed=5)
    normals = outer.face_normals[faces]
    points = np.concatenate([samples - 0.4 * normals, samples + 0.4 * normals])
    ours = _inside(points, np.full(len(points), big), tri_comp, mesh.vertices, mesh.cells)
    theirs = outer.contains(points)
    assert 200 < ours.sum() < len(points) - 200  # both answers occur
    assert (ours != theirs).sum() <= 1  # a ray grazing an edge may tip one vote
