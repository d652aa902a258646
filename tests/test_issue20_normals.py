"""Issue 20: ``--normals`` of a volume with rotated axes read from its file.

A file-backed volume is sampled slab by slab; which slab a vertex goes to is
decided in Python from its world position, while the kernel works out the
vertex's grid cell again with its own arithmetic. With a direction matrix the
two can round a vertex lying on a slab's first layer to different sides of
it (64.0 against 63.99999999999999 on FLAIR.nrrd), and the slab then lacked
the layer the gradient's stencil needed: NaN, replaced by the triangles'
normal, up to 125 degrees off. These tests compare every normal (and value)
of the file-backed path with the in-memory path, and with a central-difference
gradient computed here with numpy.
"""

from __future__ import annotations

import dataclasses

import meshio
import nrrd
import numpy as np
import pytest
from conftest import angles_degrees, dataset

from isoconvert import extract, read_volume, vertex_normals, vertex_values
from isoconvert.convert import convert
from isoconvert.extract.blocks import Blocks
from isoconvert.volume import Volume


def in_memory(volume: Volume) -> Volume:
    """The same volume with its samples in memory (sampled in one piece)."""
    copy = dataclasses.replace(volume, data=np.asarray(volume.data))
    assert copy.grid is None
    return copy


def test_flair_file_backed_normals_equal_the_in_memory_ones():
    lazy = read_volume(dataset("FLAIR.nrrd"))
    assert lazy.grid is not None  # read slab by slab
    assert np.count_nonzero(lazy.direction - np.diag(np.diag(lazy.direction))) > 0  # oblique
    memory = in_memory(lazy)
    mesh = extract(lazy, 89.5)
    from_file = vertex_normals(mesh, lazy)
    expected = vertex_normals(mesh, memory)
    assert np.isfinite(from_file).all()
    assert angles_degrees(from_file, expected).max() <= 1e-6
    assert np.array_equal(vertex_values(mesh, lazy), vertex_values(mesh, memory))


def test_flair_convert_writes_the_in_memory_normals(tmp_path):
    """What ``isoconvert convert FLAIR.nrrd -o out.ply --level 89.5 --normals`` writes."""
    source = dataset("FLAIR.nrrd")
    out = tmp_path / "flair.ply"
    convert(source, out, 89.5, normals=True)
    written = meshio.read(out)
    normals = np.column_stack([written.point_data[k] for k in ("nx", "ny", "nz")])
    memory = in_memory(read_volume(source))
    # the written points are the mesh's float32 vertices: pair them with an
    # in-memory extraction's by position, then compare the normals at them
    mesh = extract(memory, 89.5)
    assert len(mesh.vertices) == len(written.points)
    ours = np.lexsort(np.asarray(written.points, dtype=np.float32).T)
    theirs = np.lexsort(mesh.vertices.astype(np.float32).T)
    assert np.array_equal(
        np.asarray(written.points, dtype=np.float32)[ours],
        mesh.vertices.astype(np.float32)[theirs],
    )
    expected = vertex_normals(mesh, memory)
    assert angles_degrees(normals[ours], expected[theirs]).max() <= 1e-6


# The synthetic oblique volume: turned 30 degrees about z, then 25 degrees
# about x, spacing 0.7, 1.1, 1.9. The tilt of the z axis matters: a rotation
# about z alone keeps index z = (world z - origin z) / 1.9, which every way of
# computing it rounds alike, so slab boundaries would never be in doubt.
SHAPE = (36, 32, 44)  # x, y, z samples
SPACING = np.array([0.7, 1.1, 1.9])


def rotation(axis: int, degrees: float) -> np.ndarray:
    """(3, 3) rotation by ``degrees`` about world axis ``axis`` (0 x, 1 y, 2 z)."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    a, b = [n for n in range(3) if n != axis]
    turn = np.eye(3)
    turn[a, a], turn[a, b], turn[b, a], turn[b, b] = c, -s, s, c
    return turn


DIRECTION = rotation(0, 25.0) @ rotation(2, 30.0)
ORIGIN = np.array([-13.37, 7.21, 3.113])
#: World offset of one step along index axis i: column i (NRRD's ``space
#: directions`` row i).
AFFINE = DIRECTION * SPACING[np.newaxis, :]
LEVEL = 0.5


def oblique_samples() -> np.ndarray:
    """(X, Y, Z) float32: two overlapping blobs and a ripple, so that the
    gradient differs from vertex to vertex and is not a function of the
    distance to one centre."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in SHAPE), indexing="ij")
    blob = np.exp(-(((i - 16.3) / 10.0) ** 2 + ((j - 14.7) / 9.0) ** 2 + ((k - 20.4) / 15.0) ** 2))
    other = 0.6 * np.exp(
        -(((i - 24.1) / 5.5) ** 2 + ((j - 20.2) / 6.0) ** 2 + ((k - 29.9) / 8.0) ** 2)
    )
    ripple = 0.05 * np.cos(0.7 * i + 0.3 * k) * np.sin(0.5 * j)
    return (blob + other + ripple).astype(np.float32)


def write_oblique(path) -> np.ndarray:
    xyz = oblique_samples()
    header = {
        "space": "left-posterior-superior",
        "space directions": AFFINE.T,  # one row per index axis
        "space origin": ORIGIN,
        "encoding": "raw",
    }
    nrrd.write(str(path), xyz, header, index_order="F")
    return xyz


def central_difference_normals(xyz: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Unit normals ``(V, 3)`` float64, computed here without isoconvert: the
    index-space gradient by numpy's central differences (one-sided on the
    grid's faces) at the two samples of each vertex's grid edge, mixed by the
    vertex's place on the edge, mapped to world space as a covector (through
    the inverse of the affine) and negated (pointing from high to low values)."""
    grad = np.stack(np.gradient(xyz.astype(np.float64)), axis=-1)  # (X, Y, Z, 3)
    inverse = np.linalg.inv(AFFINE)
    index = (vertices - ORIGIN) @ inverse.T
    whole = np.abs(index - np.round(index)) < 1e-6
    # a vertex on a grid edge has (at least) two whole coordinates
    assert (whole.sum(axis=1) >= 2).all()
    axis = np.argmin(whole, axis=1)  # the fractional one (any when all are whole)
    lower = np.where(whole, np.round(index), np.floor(index)).astype(np.int64)
    lower = np.clip(lower, 0, np.array(SHAPE) - 1)
    rows = np.arange(len(vertices))
    t = index[rows, axis] - lower[rows, axis]
    t[whole[rows, axis]] = 0.0
    upper = lower.copy()
    upper[rows, axis] = np.minimum(upper[rows, axis] + 1, np.array(SHAPE)[axis] - 1)
    at = lambda p: grad[p[:, 0], p[:, 1], p[:, 2]]  # noqa: E731
    g_index = (1.0 - t)[:, None] * at(lower) + t[:, None] * at(upper)
    g_world = g_index @ inverse  # d/d(world)_b = sum_a d/d(index)_a * d(index)_a/d(world)_b
    return -g_world / np.linalg.norm(g_world, axis=1, keepdims=True)


def test_oblique_file_normals_equal_in_memory_and_central_differences(tmp_path, monkeypatch):
    path = tmp_path / "oblique.nrrd"
    xyz = write_oblique(path)
    lazy = read_volume(path)
    assert lazy.grid is not None
    assert np.allclose(lazy.affine, AFFINE) and np.allclose(lazy.origin, ORIGIN)
    memory = in_memory(lazy)
    # slabs of 3 layers for the normals, blocks of 4 for the extraction: many
    # boundaries, every one a chance for the rounding to disagree
    monkeypatch.setattr("isoconvert.attributes.SLAB_LAYERS", 3)
    mesh = extract(lazy, LEVEL, blocks=Blocks(size=4))
    assert mesh.n_vertices > 2000
    from_file = vertex_normals(mesh, lazy)
    expected = vertex_normals(mesh, memory)
    assert np.isfinite(from_file).all()
    assert angles_degrees(from_file, expected).max() <= 1e-6
    # independent of our kernel: numpy's central differences (float32 output,
    # so agreement to float32 rounding, not bits)
    reference = central_difference_normals(xyz, mesh.vertices)
    assert angles_degrees(from_file, reference).max() < 1e-4
    # the vertices on the slab boundaries are among them (the cases that failed)
    layer = ((mesh.vertices - ORIGIN) @ np.linalg.inv(AFFINE).T)[:, 2]
    on_boundary = np.abs(layer - 3 * np.round(layer / 3)) < 1e-9
    assert on_boundary.sum() > 100


def test_oblique_file_values_equal_in_memory_and_linear_interpolation(tmp_path, monkeypatch):
    """--values samples the same slabs; each vertex's value is the linear
    interpolation of its edge's two samples (numpy here), the level itself for
    the volume the mesh came from."""
    path = tmp_path / "oblique.nrrd"
    xyz = write_oblique(path)
    lazy = read_volume(path)
    memory = in_memory(lazy)
    monkeypatch.setattr("isoconvert.attributes.SLAB_LAYERS", 3)
    mesh = extract(lazy, LEVEL, blocks=Blocks(size=4))
    from_file = vertex_values(mesh, lazy)
    assert np.array_equal(from_file, vertex_values(mesh, memory))
    assert np.abs(from_file - LEVEL).max() < 1e-5
    # a second volume on another grid (--values OTHER): a field linear in world
    # position is reproduced by trilinear interpolation, on every slab
    other_path = tmp_path / "linear.nrrd"
    i, j, k = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in SHAPE), indexing="ij")
    world = ORIGIN + np.stack([i, j, k], axis=-1) @ AFFINE.T
    field = (world @ np.array([0.3, -0.2, 0.7]) + 5.0).astype(np.float64)
    nrrd.write(
        str(other_path),
        field,
        {"space": "left-posterior-superior", "space directions": AFFINE.T, "space origin": ORIGIN},
        index_order="F",
    )
    other = read_volume(other_path)
    assert other.grid is not None
    values = vertex_values(mesh, other)
    assert np.array_equal(values, vertex_values(mesh, in_memory(other)))
    truth = mesh.vertices @ np.array([0.3, -0.2, 0.7]) + 5.0
    assert np.abs(values - truth).max() < 1e-4 * np.abs(truth).max()
    del xyz


def test_a_slab_without_the_layers_a_point_needs_is_an_error_not_a_nan():
    """The kernel is told which layers a slab holds; a point whose cell or
    gradient stencil reaches past them is the caller's bug, raised, where it
    used to come back NaN and be replaced by the triangles' normal unseen."""
    from isoconvert import _native

    i, j, k = np.meshgrid(np.arange(4.0), np.arange(4.0), np.arange(10.0), indexing="ij")
    xyz = (0.5 * i + 2.0 * j + 3.0 * k).astype(np.float32)  # gradient (0.5, 2, 3)
    eye = np.eye(3)

    def gradient_at(z: float, k0: int, k1: int) -> np.ndarray:
        out = np.empty((1, 3), dtype=np.float32)
        slab = np.ascontiguousarray(xyz[:, :, k0:k1].T)
        point = np.array([[1.25, 1.5, z]])
        _native.sample_points(
            slab, k0, 10, point, np.zeros(3), eye, eye, 1.0, False, True, False, 0.0, 1e-6, 1, out
        )
        return out[0]

    # cell 3..4 and central differences at layers 3 and 4 read layers 2..5
    assert np.allclose(gradient_at(3.5, 2, 6), [0.5, 2.0, 3.0])
    with pytest.raises(RuntimeError, match="outside the slab"):
        gradient_at(3.5, 2, 5)
    with pytest.raises(RuntimeError, match="outside the slab"):
        gradient_at(3.5, 3, 6)
