"""Label surfaces by Surface Nets (isoconvert.extract.labels)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import dataset, directed_edges_consistent, edge_use

from isoconvert.errors import IsoconvertError, LevelError, VolumeError
from isoconvert.extract.labels import LabelMeshes, SmoothingOptions, label_surfaces
from isoconvert.report import check_mesh
from isoconvert.volume import Volume


def closed_by_index(cells: np.ndarray) -> bool:
    """Every edge in exactly two triangles, used once each way (by vertex index)."""
    _, counts = edge_use(cells)
    return bool(np.all(counts == 2)) and directed_edges_consistent(cells)


def split_and_centred(result: LabelMeshes, label: int, volume: Volume):
    """Which vertices of a label's mesh are copies of a split vertex, and the mesh
    with those copies back at their dual cell's centre (where the unsplit vertices
    are): the voxel faces, exactly."""
    mesh = result[label]
    dual = result.dual_cells[result.vertex_map[label]]
    cells, uses = np.unique(result.dual_cells, return_counts=True)
    split = np.isin(dual, cells[uses > 1])
    cx, cy = volume.shape[0] + 1, volume.shape[1] + 1
    index = np.stack([dual % cx, dual // cx % cy, dual // (cx * cy)], axis=1) - 0.5
    vertices = mesh.vertices.copy()
    vertices[split] = volume.index_to_world(index[split])
    return split, type(mesh)(vertices, mesh.cells, None, mesh.info)


def boundary_faces(mask: np.ndarray) -> int:
    """Faces of the voxels of ``mask`` on the six sides of the grid."""
    return sum(
        int(side.sum())
        for side in (mask[0], mask[-1], mask[:, 0], mask[:, -1], mask[:, :, 0], mask[:, :, -1])
    )


# --- a real binary segmentation ----------------------------------------------------------


@pytest.fixture(scope="module")
def cochlea() -> Volume:
    from isoconvert import read_volume

    return read_volume(dataset("bat-cochlea-volume.tif"))


def test_cochlea_blocky_encloses_exactly_the_voxels(cochlea):
    result = label_surfaces(cochlea, smoothing=0)
    assert result.labels == [255]  # binary 0/255: the object is label 255
    mesh = result[255]
    voxels = int(np.count_nonzero(cochlea.data))
    # split copies start 1/64 of the way towards their own faces (so the surface
    # does not touch itself); at their dual cells' centres the faces enclose exactly
    # the voxels, and the step changes the volume by < 0.05 voxel per copy
    split, centred = split_and_centred(result, 255, cochlea)
    assert centred.signed_volume() == pytest.approx(voxels * np.prod(cochlea.spacing), abs=1e-6)
    voxel = np.prod(cochlea.spacing)
    assert (
        0 < split.sum() and abs(mesh.signed_volume() - voxels * voxel) < 0.05 * voxel * split.sum()
    )
    assert closed_by_index(mesh.cells)
    assert check_mesh(mesh).checks["manifold"]  # the copies differ in position too
    # the other vertices at dual-cell centres: half-integers in index units
    frac = mesh.vertices[~split] / cochlea.spacing - 0.5
    assert np.array_equal(frac, np.round(frac))
    assert mesh.info["label"] == 255 and mesh.info["method"] == "labels"


def test_cochlea_smoothed_is_a_closed_manifold(cochlea):
    result = label_surfaces(cochlea)  # VTK-like defaults: 16 iterations
    mesh = result[255]
    report = check_mesh(mesh)
    for name in ("watertight", "manifold", "oriented", "no-degenerate", "no-duplicates"):
        assert report.checks[name], (name, report.problems)
    voxels = int(np.count_nonzero(cochlea.data))
    volume = mesh.signed_volume()
    assert volume > 0
    assert abs(volume / voxels - 1) < 0.05
    assert result.split_vertices > 0  # the scan has edge contacts (see the module notes)
    # every vertex stays within its dual cell (constraint 0.5 voxel)
    blocky = label_surfaces(cochlea, smoothing=0)[255]
    assert np.abs(mesh.vertices - blocky.vertices).max() <= 0.5 + 1e-9


def test_cochlea_counts_match_vtk(cochlea):
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    zyx = np.ascontiguousarray(cochlea.data.T)
    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(zyx.ravel(), deep=True))
    nets = vtk.vtkSurfaceNets3D()
    nets.SetInputData(image)
    nets.SetLabel(0, 255)
    nets.SmoothingOff()
    nets.Update()
    quads = nets.GetOutput().GetNumberOfCells()
    ours = label_surfaces(cochlea, smoothing=0)
    # VTK leaves the surface open where the object meets the grid's sides; we
    # close it there, one quad per voxel face on the sides
    assert ours.combined.n_cells == 2 * (quads + boundary_faces(cochlea.data > 0))
    points = nets.GetOutput().GetNumberOfPoints()
    assert abs(ours.combined.n_vertices - points) < 0.01 * points


# --- a synthetic atlas -------------------------------------------------------------------


def atlas(direction=None) -> Volume:
    """Three touching boxes and a ball, some on the grid's sides, anisotropic spacing."""
    zyx = np.zeros((14, 16, 18), dtype=np.int16)  # (Z, Y, X)
    zyx[0:8, 0:9, 0:9] = 3  # touches three sides of the grid
    zyx[0:8, 0:9, 9:18] = 7  # touches 3 along x = 9, and the grid's x-high side
    zyx[8:14, 0:16, 0:18] = 5  # a slab on top of both, the whole z-high side
    z, y, x = np.indices(zyx.shape)
    ball = (x - 9) ** 2 + (y - 10) ** 2 + (z - 6) ** 2 < 9
    zyx[ball] = 9  # touches 3, 7, 5 and background
    return Volume.from_zyx(
        zyx, spacing=(0.5, 0.8, 1.7), origin=(10.0, -3.0, 2.5), direction=direction
    )


@pytest.mark.parametrize("iterations", [0, 16])
@pytest.mark.parametrize("mirror", [False, True])
def test_atlas_labels_closed_and_share_boundaries(iterations, mirror):
    direction = np.diag([-1.0, 1.0, 1.0]) if mirror else None  # left-handed: a mirror
    volume = atlas(direction)
    result = label_surfaces(volume, smoothing=iterations)
    assert isinstance(result, LabelMeshes)
    assert result.labels == [3, 5, 7, 9]
    voxel = float(np.prod(volume.spacing))
    data = volume.data
    total = 0.0
    for label in result.labels:
        mesh = result[label]
        assert mesh.info["label"] == label
        assert closed_by_index(mesh.cells), label
        if iterations:
            report = check_mesh(mesh)
            assert report.checks["watertight"] and report.checks["manifold"], label
            assert report.checks["oriented"], label
        vol = mesh.signed_volume()
        assert vol > 0, label  # normals point out of the label, mirrored or not
        if iterations == 0:
            assert vol == pytest.approx(np.count_nonzero(data == label) * voxel)
        total += vol
        # the per-label mesh is part of the combined one, as documented
        vmap, fmap = result.vertex_map[label], result.face_map[label]
        assert np.array_equal(mesh.vertices, result.combined.vertices[vmap])
        expected = result.combined.cells[fmap].copy()
        out = result.boundary_labels[fmap, 1] == label
        expected[out] = expected[out][:, ::-1]
        assert np.array_equal(vmap[mesh.cells], expected)
    union = label_surfaces(
        Volume((data > 0).astype(np.uint8), volume.spacing, volume.origin, volume.direction),
        smoothing=iterations,
    )[1]
    if iterations == 0:
        assert total == pytest.approx(np.count_nonzero(data) * voxel)
        assert union.signed_volume() == pytest.approx(total)
    # touching labels share their boundary: same vertices, opposite orientation
    for a, b in [(3, 7), (3, 5), (7, 5), (9, 3), (9, 5), (9, 7)]:
        tris_a = {tuple(t) for t in result.vertex_map[a][result[a].cells]}
        tris_b = {tuple(t) for t in result.vertex_map[b][result[b].cells]}
        between = np.flatnonzero(
            np.isin(result.boundary_labels[:, 0], [a, b])
            & np.isin(result.boundary_labels[:, 1], [a, b])
        )
        assert len(between) > 0, (a, b)
        for face in between:
            tri = tuple(result.combined.cells[face])
            rev = tuple(result.combined.cells[face][::-1])
            inside = result.boundary_labels[face, 0]
            mine, theirs = (tris_a, tris_b) if inside == a else (tris_b, tris_a)
            assert tri in mine and rev in theirs and tri not in theirs


def test_atlas_normals_point_out_of_the_label():
    volume = atlas()
    result = label_surfaces(volume, [7], smoothing=0)
    mesh = result[7]
    centers = mesh.vertices[mesh.cells].mean(axis=1)
    step = 0.01 * mesh.triangle_normals()
    inverse = np.linalg.inv(volume.affine)
    ahead = np.rint((centers + step - volume.origin) @ inverse.T).astype(int)
    behind = np.rint((centers - step - volume.origin) @ inverse.T).astype(int)
    data = np.pad(volume.data, 1)  # background around, for the faces on the sides
    assert np.all(data[tuple((behind + 1).T)] == 7)
    assert np.all(data[tuple((ahead + 1).T)] != 7)


def test_selected_labels_and_the_grid_side():
    volume = atlas()
    result = label_surfaces(volume, labels=[5], smoothing=SmoothingOptions(iterations=4))
    assert result.labels == [5]
    # faces between two labels not asked for are left out; 5 still closed, on the grid's sides too
    assert set(np.unique(result.boundary_labels[:, 0])) == {5}
    mesh = result[5]
    assert closed_by_index(mesh.cells)
    assert check_mesh(mesh).checks["watertight"]
    top = volume.origin[2] + volume.spacing[2] * (volume.shape[2] - 0.5)
    assert np.isclose(mesh.vertices[:, 2].max(), top)  # closed half a voxel beyond the grid


def test_edge_and_corner_contacts_stay_manifold():
    data = np.zeros((6, 6, 6), dtype=np.uint8)
    data[1, 1, 1:4] = data[2, 2, 1:4] = 1  # two rods touching along an edge
    data[4, 4, 4] = data[3, 3, 3] = 1  # two voxels touching at a corner
    result = label_surfaces(Volume(data), smoothing=0)
    assert result.split_vertices > 0
    assert closed_by_index(result[1].cells)
    smoothed = label_surfaces(Volume(data))
    assert check_mesh(smoothed[1]).checks["manifold"]


# --- the compiled kernels: layouts, types, threads ----------------------------------------


def random_labels(shape=(13, 11, 9), values=4, seed=1) -> np.ndarray:
    """Random labels: every kind of edge and corner contact, and junctions."""
    return np.random.default_rng(seed).integers(0, values, size=shape).astype(np.uint8)


def as_arrays(result: LabelMeshes) -> dict:
    out = {
        "v": result.combined.vertices,
        "c": result.combined.cells,
        "b": result.boundary_labels,
        "d": result.dual_cells,
    }
    for label in result.labels:
        out[f"{label}c"] = result[label].cells
        out[f"{label}vm"] = result.vertex_map[label]
        out[f"{label}fm"] = result.face_map[label]
    return out


def test_output_does_not_depend_on_threads(monkeypatch):
    volume = Volume(random_labels((24, 20, 18)), spacing=(1.0, 2.0, 0.5))
    results = []
    for threads in ("1", "2"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        results.append(as_arrays(label_surfaces(volume, smoothing=5)))
    assert results[0].keys() == results[1].keys()
    for name in results[0]:
        assert np.array_equal(results[0][name], results[1][name]), name


@pytest.mark.parametrize("dtype", [np.uint8, np.int8, np.uint16, np.int32, np.float32, np.int64])
def test_sample_types_and_layouts_agree(dtype):
    data = random_labels((9, 8, 7))
    expected = as_arrays(label_surfaces(Volume(data), smoothing=3))
    for layout in (data.astype(dtype), np.asfortranarray(data.astype(dtype))):
        got = as_arrays(label_surfaces(Volume(layout), smoothing=3))
        for name in expected:
            assert np.array_equal(expected[name], got[name]), (dtype, name)


def test_single_sample_thick_axes_are_closed_outward():
    # the two sides of an axis of one sample are different faces (the numpy
    # version took both for low sides, turning the high side's quads inwards)
    for shape in [(1, 1, 4), (3, 1, 5), (1, 4, 1)]:
        data = random_labels(shape, values=2, seed=4)
        data[0, 0, 0] = 2  # a second label next to the first
        result = label_surfaces(Volume(data), smoothing=0)
        for label in result.labels:
            mesh = result[label]
            assert closed_by_index(mesh.cells), (shape, label)
            centred = split_and_centred(result, label, Volume(data))[1]
            assert centred.signed_volume() == pytest.approx(np.count_nonzero(data == label))


def test_wide_label_values_and_a_background_outside_the_type():
    data = np.zeros((6, 5, 4), dtype=np.int32)
    data[1:3, 1:4, 1:3] = 2**30  # labels spread wider than a lookup table
    data[3:5, 1:4, 1:3] = -7
    result = label_surfaces(Volume(data), smoothing=0)
    assert result.labels == [-7, 2**30]
    for label in result.labels:
        assert result[label].signed_volume() == pytest.approx(np.count_nonzero(data == label))
    # background -1 for uint8 samples: every value present is a label, 0 included
    small = random_labels((5, 4, 3), values=2)
    result = label_surfaces(Volume(small), background=-1, smoothing=0)
    assert result.labels == [0, 1]
    assert result[0].signed_volume() + result[1].signed_volume() == pytest.approx(small.size)


# --- errors --------------------------------------------------------------------------------


def test_errors():
    volume = atlas()
    with pytest.raises(VolumeError, match="not in the volume"):
        label_surfaces(volume, labels=[4])
    with pytest.raises(VolumeError, match="background"):
        label_surfaces(volume, labels=[0, 3])
    with pytest.raises(VolumeError, match="whole numbers"):
        label_surfaces(Volume(np.full((3, 3, 3), 1.5)))
    with pytest.raises(VolumeError, match="3D"):
        label_surfaces(Volume(np.ones((4, 4), dtype=np.uint8)))
    with pytest.raises(LevelError, match="background"):
        label_surfaces(Volume(np.zeros((3, 3, 3), dtype=np.uint8)))
    with pytest.raises(VolumeError, match="iterations"):
        label_surfaces(volume, smoothing=-1)
    # whole-number floats are labels
    floats = Volume(volume.data.astype(np.float32), volume.spacing, volume.origin)
    assert label_surfaces(floats, smoothing=0).labels == [3, 5, 7, 9]
    for err in (VolumeError, LevelError):
        assert issubclass(err, IsoconvertError)


# --- built on first access ------------------------------------------------------------------


def test_per_label_mappings_are_built_once_on_access():
    from collections.abc import Mapping

    result = label_surfaces(atlas(), smoothing=2)
    for mapping in (result.meshes, result.vertex_map, result.face_map):
        assert isinstance(mapping, Mapping)
        assert list(mapping) == result.labels == [3, 5, 7, 9] and len(mapping) == 4
        assert 5 in mapping and np.int64(5) in mapping
        assert 4 not in mapping and "5" not in mapping and 5.0 not in mapping
        for missing in (4, 0, -1, "5", 5.5, True):
            with pytest.raises(KeyError):
                mapping[missing]
    assert not result._meshes and not result._maps  # nothing built until asked for
    mesh = result.meshes[np.int64(7)]
    assert mesh is result[7] is result.meshes[7] and list(result._meshes) == [7]
    assert not result._maps  # the maps only when asked for
    assert result.vertex_map[7] is result.vertex_map[7] and list(result._maps) == [7]
    assert result[7] is mesh  # the same mesh, while it is held
    face_map = result.face_map[5]
    assert result.face_map[5] is face_map and list(result._maps) == [7, 5]
    assert list(result._meshes) == [7]  # label 5's mesh (built for its maps) is held by no one
    # let go, a mesh is built again, the same: a run over many labels holds the few in use
    vertices, cells, info = mesh.vertices.copy(), mesh.cells.copy(), mesh.info
    assert result.summary(7).n_vertices == len(vertices) and result.summary(7).info == info
    del mesh
    assert not result._meshes
    again = result[7]
    assert np.array_equal(again.vertices, vertices) and np.array_equal(again.cells, cells)
    assert again.info == info and result.summary(7).n_cells == len(cells)
    assert set(dict(result.meshes)) == {3, 5, 7, 9}
    assert [m.info["label"] for m in result.meshes.values()] == [3, 5, 7, 9]
    # each label's info is its own (no dict shared between labels)
    result[3].info["grid"]["shape"] = None
    assert result[5].info["grid"]["shape"] is not None
    assert result.combined is result.combined


def test_label_mesh_kernel_with_either_index_type_and_its_checks():
    from isoconvert import _native

    result = label_surfaces(Volume(random_labels()), smoothing=0)
    net = result._net
    for n, label in enumerate(result.labels):
        quads = net.quads[net.offsets[n] : net.offsets[n + 1]]
        assert quads.dtype == np.int32  # every quad index fits
        args = (net.corners, net.cut, net.vertices)
        small = _native.label_mesh(*args, quads, int(net.inside[n]))
        large = _native.label_mesh(*args, quads.astype(np.int64), int(net.inside[n]))
        for a, b in zip(small, large, strict=True):
            assert np.array_equal(a, b)
        faces, used, local, verts = small
        assert np.array_equal(faces, result.face_map[label])
        assert np.array_equal(used, result.vertex_map[label])
        assert np.array_equal(local, result[label].cells)
    args = (net.corners, net.cut, net.vertices)
    with pytest.raises(ValueError, match="quad index"):
        _native.label_mesh(*args, np.array([len(net.corners)], dtype=np.int32), 0)
    with pytest.raises(ValueError, match="inside"):
        _native.label_mesh(*args, np.array([0], dtype=np.int32), 2)
    with pytest.raises(ValueError, match="side is not a label"):
        _native.label_quads(net.corners, net.vertices, np.full((len(net.corners), 2), 9,
                            dtype=np.int32), 4, 1)  # fmt: skip
    # a corner past the vertices, in the last quad: found by the threads' checks too
    corners = net.corners.copy()
    corners[-1, 2] = len(net.vertices)
    with pytest.raises(ValueError, match="corner is not a vertex"):
        _native.label_mesh(corners, net.cut, net.vertices, np.array([len(corners) - 1]), 0)
    for threads in (1, 2):
        sides = np.zeros((len(corners), 2), dtype=np.int32)
        with pytest.raises(ValueError, match="corner is not a vertex"):
            _native.label_quads(corners, net.vertices, sides, 4, threads)
