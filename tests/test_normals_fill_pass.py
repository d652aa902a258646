"""Issue 23: normals computed in Marching Cubes' filling pass.

``extract(..., normals=True)`` on a volume in memory takes the gradients at the
two ends of each bipolar edge in the filling pass and mixes them by the
vertex's place on the edge (as VTK's Flying Edges does), instead of a second
pass over the volume. The reference is what ``--normals`` did before, and
still does for block-wise runs: :func:`isoconvert.vertex_normals`, the
trilinear interpolation of the central-difference gradient at each vertex's
world position (``_native.sample_points``). At a vertex on a grid edge the two
are the same number, so every test here asks for the same normals to within
1e-6 degrees, on real scans, with anisotropic spacing and a rotated grid,
with ``flip``, with NaN samples, where the gradient vanishes, for every
ambiguity rule, and on any number of threads; and that they were not sampled
(the second pass never ran) where the filling pass applies.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import angles_degrees, dataset

from isoconvert import _native, extract, read_volume, vertex_normals
from isoconvert.arrays import marching_cubes as array_marching_cubes
from isoconvert.extract.cubes import CubesBlock
from isoconvert.extract.prepare import prepare
from isoconvert.extract.trilinear import inner_base
from isoconvert.methods import CUBE_AMBIGUITY_RULES
from isoconvert.volume import Volume

#: The issue's bound on the angle between the two paths' normals.
TOLERANCE_DEGREES = 1e-6


def rotation(ax: float, ay: float, az: float) -> np.ndarray:
    """A proper rotation (unit axis directions) from three angles in radians."""
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


#: Anisotropic spacing and a rotated, mirrored grid (a left-handed map makes
#: the kernel write triangles reversed; normals must not care).
SPACING = np.array([0.7, 1.3, 2.1])
ORIGIN = np.array([-12.5, 3.25, 40.0])
DIRECTION = rotation(0.3, -0.8, 1.1) @ np.diag([1.0, -1.0, 1.0])


def in_memory(volume: Volume, placed: bool) -> Volume:
    """``volume`` with its samples in memory (the filling pass's case), on the
    placement above when ``placed``."""
    copy = dataclasses.replace(volume, data=np.asarray(volume.data))
    if placed:
        copy = dataclasses.replace(copy, spacing=SPACING, origin=ORIGIN, direction=DIRECTION)
    assert copy.grid is None
    return copy


class SampledTwice(Exception):
    pass


@pytest.fixture
def no_sampling(monkeypatch):
    """Make the second pass (``sample_points``) fail, to show it did not run."""

    def refuse(*args, **kwargs):
        raise SampledTwice("sample_points ran")

    monkeypatch.setattr(_native, "sample_points", refuse)


def compare(volume: Volume, level: float, *, flip=False, nan_as=None, ambiguity=None):
    """The filling pass's mesh and normals against ``vertex_normals`` of the same
    mesh extracted without them; returns the angles (degrees) and the mesh."""
    options = {"flip": flip, "nan_as": nan_as, "ambiguity": ambiguity}
    with_normals = extract(volume, level, normals=True, **options)
    plain = extract(volume, level, **options)
    # the filling pass changes nothing else
    assert plain.normals is None
    assert np.array_equal(with_normals.vertices, plain.vertices)
    assert np.array_equal(with_normals.cells, plain.cells)
    assert np.array_equal(with_normals.edge_ids, plain.edge_ids)
    assert with_normals.normals is not None
    assert with_normals.normals.dtype == np.float32
    assert with_normals.normals.shape == plain.vertices.shape
    expected = vertex_normals(plain, volume, flip=flip, nan_as=nan_as)
    assert np.isfinite(with_normals.normals).all()
    angles = angles_degrees(with_normals.normals, expected)
    return angles, with_normals


@pytest.mark.parametrize("placed", [False, True], ids=["unit-grid", "anisotropic-rotated"])
@pytest.mark.parametrize("flip", [False, True])
def test_engine_normals_from_the_filling_pass_equal_vertex_normals(placed, flip):
    volume = in_memory(read_volume(dataset("engine_256x256x128_uint8.raw")), placed)
    angles, mesh = compare(volume, 80.5, flip=flip)
    assert len(mesh.vertices) > 100_000
    assert angles.max() <= TOLERANCE_DEGREES, angles.max()
    # in fact the same bits: both run sample.hpp's sample_point on the same positions
    reference = vertex_normals(extract(volume, 80.5, flip=flip), volume, flip=flip)
    assert mesh.normals.tobytes() == reference.tobytes()


def test_engine_normals_come_from_the_filling_pass_alone(no_sampling):
    """With fixed ambiguity rules no vertex is sampled again: the second pass
    over the volume is gone (sample_points raises here if it runs)."""
    volume = in_memory(read_volume(dataset("engine_256x256x128_uint8.raw")), True)
    mesh = extract(volume, 80.5, normals=True)
    assert mesh.normals is not None and len(mesh.normals) > 100_000
    with pytest.raises(SampledTwice):
        vertex_normals(mesh, volume)


@pytest.mark.parametrize("flip", [False, True])
def test_float_scan_with_nan_samples(flip):
    """hydrogen (float32) with a block of NaN samples inside the surface, read as
    ``nan_as``, on the anisotropic rotated grid."""
    volume = in_memory(read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw")), True)
    data = np.array(volume.data)
    data[20:30, 25:33, 28:36] = np.nan
    data[0:3, 0:64, 60:64] = np.inf
    volume = dataclasses.replace(volume, data=data)
    level = 0.04
    with pytest.raises(Exception, match="NaN"):
        extract(volume, level, normals=True)
    angles, mesh = compare(volume, level, flip=flip, nan_as=0.5)
    # the NaN block (0.5 there) makes a surface of its own around it
    assert len(mesh.vertices) > 10_000
    assert angles.max() <= TOLERANCE_DEGREES, angles.max()


@pytest.mark.parametrize("blocks", [None, 8], ids=["in-memory", "slabs"])
def test_a_nan_as_float32_cannot_hold_keeps_the_second_pass(blocks):
    """nan_as 0.1 on float32 samples: the extraction reads float32(0.1) where
    the second pass reads 0.1, and near the NaN samples the normals would
    differ by some 1e-6 degrees; such runs keep the second pass, and callers
    (arrays API, convert) get exactly vertex_normals' normals."""
    from isoconvert.extract.blocks import Blocks

    volume = in_memory(read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw")), True)
    data = np.array(volume.data)
    data[20:30, 25:33, 28:36] = np.nan
    volume = dataclasses.replace(volume, data=data)
    given = {} if blocks is None else {"blocks": Blocks(size=blocks)}
    assert extract(volume, 0.04, nan_as=0.1, normals=True, **given).normals is None
    assert extract(volume, 0.04, nan_as=0.5, normals=True, **given).normals is not None
    zyx = np.ascontiguousarray(data.T)
    mesh = array_marching_cubes(zyx, 0.04, normals=True, nan_as=0.1)
    plain = Volume.from_zyx(zyx)
    expected = vertex_normals(extract(plain, 0.04, nan_as=0.1), plain, nan_as=0.1)
    assert mesh.normals.tobytes() == expected.tobytes()


@pytest.mark.parametrize("ambiguity", CUBE_AMBIGUITY_RULES)
def test_every_ambiguity_rule(ambiguity):
    """Fixed rules put every vertex on a grid edge; the trilinear rule adds
    vertices inside cubes, which are sampled as vertex_normals samples them
    (engine at 150.5 has some hundreds of those; at 80.5 none)."""
    volume = in_memory(read_volume(dataset("engine_256x256x128_uint8.raw")), True)
    angles, mesh = compare(volume, 150.5, ambiguity=ambiguity, flip=True)
    assert angles.max() <= TOLERANCE_DEGREES, angles.max()
    inner = np.count_nonzero(mesh.edge_ids >= inner_base(volume.shape))
    assert (inner > 10) if ambiguity == "trilinear" else inner == 0


def test_a_vanishing_gradient_falls_back_to_the_triangles():
    """Samples 0, 1, 0, 1, ... along x: central differences vanish at every inner
    sample, so the filling pass leaves zeros there and the triangles' normals
    stand in, as vertex_normals does."""
    xyz = np.zeros((6, 4, 5))
    xyz[1::2] = 1.0
    xyz[:, :, 4] += 0.25  # a z-gradient on the top layer: not every normal is flat
    volume = Volume(xyz, spacing=np.array([1.0, 2.0, 0.5]))
    prep = prepare(volume, 3, "cubes", 0.5)
    block = CubesBlock.whole(volume, prep.offset, False, prep.threads)
    *_, (raw, count) = block.extract_with_normals(prep.array, prep.scan, -1.0)
    flat = ~raw.any(axis=1)
    assert flat.any() and not flat.all()
    assert count == np.count_nonzero(flat)
    angles, mesh = compare(volume, 0.5)
    assert np.array_equal(mesh.normals[flat], mesh.vertex_normals()[flat].astype(np.float32))
    assert angles.max() <= TOLERANCE_DEGREES, angles.max()


def test_the_same_bits_on_any_number_of_threads(monkeypatch):
    volume = in_memory(read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw")), True)
    runs = []
    for threads in ("1", "2"):
        monkeypatch.setenv("ISOCONVERT_THREADS", threads)
        runs.append(extract(volume, 0.04, normals=True, ambiguity="trilinear").normals)
    assert runs[0].tobytes() == runs[1].tobytes()


def test_the_arrays_api_gives_the_same_normals():
    """``isoconvert.marching_cubes(..., normals=True)`` (scikit-image's call)
    takes the filling pass; its normals are vertex_normals'."""
    zyx = np.fromfile(dataset("hydrogen_vtk_64x64x64_float32.raw"), dtype="<f4").reshape(64, 64, 64)
    spacing = (2.1, 1.3, 0.7)
    mesh = array_marching_cubes(zyx, 0.04, spacing=spacing, normals=True)
    plain = array_marching_cubes(zyx, 0.04, spacing=spacing)
    volume = Volume.from_zyx(zyx, spacing=np.array(spacing[::-1]))
    expected = vertex_normals(plain, volume)
    assert angles_degrees(mesh.normals, expected).max() <= TOLERANCE_DEGREES


def test_other_methods_leave_normals_to_vertex_normals():
    """Tetrahedra put vertices on cube diagonals, along which the gradient is not
    linear; squares make contours. extract gives them no normals (the caller
    samples them, as before)."""
    volume = in_memory(read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw")), False)
    assert extract(volume, 0.04, normals=True, method="tetra").normals is None
    assert extract(volume, 0.04, normals=True, method="squares").normals is None


def test_a_volume_read_from_its_file_as_one_slab(monkeypatch):
    """A raw file is extracted block-wise; when it fits the budget it is one
    slab, the whole grid, and its filling pass gives the normals too (the
    second pass never runs), the same bits as sampling them after."""
    lazy = read_volume(dataset("engine_256x256x128_uint8.raw"))
    assert lazy.grid is not None
    plain = extract(lazy, 80.5, flip=True)
    assert plain.info["blocks"] == 1
    expected = vertex_normals(plain, lazy, flip=True)

    def refuse(*args, **kwargs):
        raise SampledTwice("sample_points ran")

    monkeypatch.setattr(_native, "sample_points", refuse)
    mesh = extract(lazy, 80.5, flip=True, normals=True)
    assert mesh.info["blocks"] == 1
    assert np.array_equal(mesh.vertices, plain.vertices)
    assert np.array_equal(mesh.cells, plain.cells)
    assert mesh.normals.tobytes() == expected.tobytes()


@pytest.mark.parametrize("size", [1, 5, 16])
def test_slabs_read_with_a_halo_give_the_same_normals(size, monkeypatch):
    """Slabs of a volume cut in several: each is read with 2 more layers each
    way, which the stencils reach (a slab's overlap is one sample; a vertex
    rounded into the next cell needs one more), on the rotated grid, with NaN
    samples in another slab's layers; the same bits as sampling after."""
    from isoconvert.extract.blocks import Blocks

    lazy = read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw"))
    assert lazy.grid is not None
    data = np.array(lazy.data)
    data[20:30, 25:33, 30:33] = np.nan  # layers 30-32: halo layers of some slabs
    memory = dataclasses.replace(
        lazy, data=data, spacing=SPACING, origin=ORIGIN, direction=DIRECTION
    )
    plain = extract(memory, 0.04, nan_as=0.5)
    expected = vertex_normals(plain, memory, nan_as=0.5)

    def refuse(*args, **kwargs):
        raise SampledTwice("sample_points ran")

    monkeypatch.setattr(_native, "sample_points", refuse)
    cut = extract(memory, 0.04, nan_as=0.5, normals=True, blocks=Blocks(size=size))
    assert cut.info["blocks"] == -(-64 // size) - (size == 1)  # a lone last layer joins
    assert np.array_equal(cut.vertices, plain.vertices)
    assert cut.normals.tobytes() == expected.tobytes()


def test_other_rules_and_methods_keep_sampling_their_normals():
    """The trilinear rule (its interior vertices need the samples again),
    tetrahedra and squares: extract leaves mesh.normals to vertex_normals."""
    lazy = read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw"))
    assert lazy.grid is not None
    assert extract(lazy, 0.04, normals=True, ambiguity="trilinear").normals is None
    assert extract(lazy, 0.04, normals=True, method="tetra").normals is None
    one = extract(lazy, 0.04, normals=True)
    assert one.info["blocks"] == 1 and one.normals is not None


def test_normals_equal_vtk_flying_edges_compute_normals():
    """Against VTK's vtkFlyingEdges3D with ComputeNormalsOn (central differences
    at the edge's ends, interpolated; normalized in float32) on the engine scan
    with anisotropic spacing (VTK's image data has no direction matrix here)."""
    vtk = pytest.importorskip("vtk")
    from scipy.spatial import cKDTree
    from vtk.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    volume = read_volume(dataset("engine_256x256x128_uint8.raw"))
    zyx = np.ascontiguousarray(np.asarray(volume.data).T)
    spacing = (0.7, 1.3, 2.1)
    volume = Volume.from_zyx(zyx, spacing=np.array(spacing))
    mesh = extract(volume, 80.5, normals=True)
    image = vtk.vtkImageData()
    image.SetDimensions(*zyx.shape[::-1])
    image.SetSpacing(*spacing)
    image.GetPointData().SetScalars(numpy_to_vtk(zyx.ravel(), deep=True))
    fe = vtk.vtkFlyingEdges3D()
    fe.SetInputData(image)
    fe.SetValue(0, 80.5)
    fe.ComputeNormalsOn()
    fe.Update()
    out = fe.GetOutput()
    points = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
    theirs = vtk_to_numpy(out.GetPointData().GetNormals()).astype(np.float64)
    distance, nearest = cKDTree(points).query(mesh.vertices)
    assert distance.max() < 1e-4
    assert len(np.unique(nearest)) == len(points) == len(mesh.vertices)
    angles = angles_degrees(mesh.normals, theirs[nearest])
    # VTK normalizes in float32, and both are ill-defined where the gradient
    # nearly vanishes: nearly all agree to float32 precision
    assert np.mean(angles < 1e-3) > 0.9999
    assert np.median(angles) < 1e-4


def test_convert_of_a_volume_read_into_memory(tmp_path, monkeypatch):
    """``isoconvert convert chris_t1.nii.gz --normals`` (a gzipped NIfTI is read
    whole: the in-memory path) writes the filling pass's normals, which are
    vertex_normals'; the second pass never runs."""
    import meshio

    from isoconvert.convert import convert

    source = dataset("chris_t1.nii.gz")
    volume = read_volume(source)
    assert volume.grid is None
    mesh = extract(volume, 60.5)
    expected = vertex_normals(mesh, volume)

    def refuse(*args, **kwargs):
        raise SampledTwice("sample_points ran")

    monkeypatch.setattr(_native, "sample_points", refuse)
    out = tmp_path / "t1.ply"
    result = convert(source, out, 60.5, normals=True)
    assert result.mesh.info["normals"] == "volume gradient"
    assert result.mesh.normals.tobytes() == expected.tobytes()
    written = meshio.read(out)
    normals = np.column_stack([written.point_data[k] for k in ("nx", "ny", "nz")])
    assert np.array_equal(normals, expected)
