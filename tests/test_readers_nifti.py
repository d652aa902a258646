"""NIfTI-1 / NIfTI-2 reading (issue 11): placement, scaling, 4D, laziness, real brains."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest
from conftest import dataset, edge_key, vtk_flying_edges

from isoconvert import extract, read_volume
from isoconvert.errors import FormatError, IsoconvertError, VolumeError, extra_hint
from isoconvert.extract.blocks import Blocks
from isoconvert.grid import RawGrid
from isoconvert.readers import detect_format, format_suffix, unsupported_format
from isoconvert.readers.nifti import nifti_ndim

nib = pytest.importorskip("nibabel")


@pytest.fixture
def xyz() -> np.ndarray:
    """A (x, y, z) = (7, 5, 6) float32 field with a closed surface at 0.5, all axes distinct."""
    x, y, z = np.meshgrid(np.arange(7.0), np.arange(5.0), np.arange(6.0), indexing="ij")
    return (2.2 - np.sqrt((x - 3.1) ** 2 + (y - 2.2) ** 2 + (z - 2.6) ** 2)).astype(np.float32)


def same_mesh(a, b) -> None:
    assert (a.n_vertices, a.n_cells) == (b.n_vertices, b.n_cells)
    ka, ta = edge_key(a.vertices)
    kb, tb = edge_key(b.vertices)
    assert np.array_equal(ka, kb) and np.allclose(ta, tb)


def save(path, data, affine=None, cls=None, sform=True, qform=True, **header):
    cls = cls or nib.Nifti1Image
    img = cls(data, np.eye(4) if affine is None else affine)
    if not sform:
        img.set_sform(None, code=0)
    if not qform:
        img.set_qform(None, code=0)
    for key, value in header.items():
        img.header[key] = value
    nib.save(img, str(path))
    return path


def world(vol, ijk) -> np.ndarray:
    return vol.index_to_world(np.asarray(ijk, dtype=np.float64).reshape(1, -1))[0]


def one_line_error(path, kind, *says, **options):
    with pytest.raises(kind) as err:
        read_volume(path, **options)
    msg = str(err.value)
    assert "\n" not in msg, msg
    for part in says:
        assert part in msg, msg
    return msg


# --- files nibabel writes -------------------------------------------------------------------


@pytest.mark.parametrize("cls", ["Nifti1Image", "Nifti2Image"])
@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.float32])
def test_nifti1_and_2_dtypes_are_lazy_and_exact(tmp_path, xyz, cls, dtype):
    data = (xyz * 50).astype(dtype) if dtype != np.float32 else xyz
    affine = np.diag([0.5, 0.75, 2.0, 1.0])
    affine[:3, 3] = [10, -20, 5]
    path = save(tmp_path / "v.nii", data, affine, getattr(nib, cls))
    assert detect_format(str(path)) == "nifti"
    vol = read_volume(path)
    assert isinstance(vol.grid, RawGrid) and vol.dtype == dtype
    assert np.array_equal(vol.data, data)
    assert vol.spacing.tolist() == [0.5, 0.75, 2.0] and vol.origin.tolist() == [10, -20, 5]
    assert "coordinates in RAS (NIfTI's frame)" in vol.notes
    level = 0.5 if dtype == np.float32 else 25.5
    whole = extract(read_volume(path), level)
    assert whole.n_cells > 0
    same_mesh(extract(vol, level, blocks=Blocks(size=3)), whole)


def test_gz_is_read_into_memory_and_equals_nii(tmp_path, xyz):
    plain = save(tmp_path / "v.nii", xyz)
    packed = save(tmp_path / "v.nii.gz", xyz)
    assert format_suffix(packed) == ".nii.gz" and detect_format(str(packed)) == "nifti"
    assert unsupported_format(packed) is None and unsupported_format(plain) is None
    vol = read_volume(packed)
    assert vol.grid is None and np.array_equal(vol.data, xyz)
    same_mesh(extract(vol, 0.5), extract(read_volume(plain), 0.5))


def test_sform_wins_over_qform_and_qform_alone(tmp_path, xyz):
    s_aff = np.diag([2.0, 3.0, 4.0, 1.0])
    s_aff[:3, 3] = [1, 2, 3]
    q_aff = np.diag([1.0, 1.0, 1.0, 1.0])
    q_aff[:3, 3] = [-5, -6, -7]
    img = nib.Nifti1Image(xyz, s_aff)
    img.set_qform(q_aff, code=1)
    img.set_sform(s_aff, code=2)
    nib.save(img, str(tmp_path / "both.nii"))
    vol = read_volume(tmp_path / "both.nii")
    assert vol.spacing.tolist() == [2, 3, 4] and vol.origin.tolist() == [1, 2, 3]
    assert any(n.startswith("placement from the sform") for n in vol.notes)
    img.set_sform(None, code=0)
    nib.save(img, str(tmp_path / "q.nii"))
    vol = read_volume(tmp_path / "q.nii")
    assert vol.spacing.tolist() == [1, 1, 1] and vol.origin.tolist() == [-5, -6, -7]
    assert any(n.startswith("placement from the qform") for n in vol.notes)
    img.set_qform(None, code=0)
    nib.save(img, str(tmp_path / "none.nii"))
    vol = read_volume(tmp_path / "none.nii")
    assert any("fallback" in n for n in vol.notes)
    base = nib.load(str(tmp_path / "none.nii")).header.get_base_affine()
    assert np.allclose(world(vol, [1, 2, 3]), nib.affines.apply_affine(base, [1, 2, 3]))


def test_oblique_affine_puts_known_voxels_where_nibabel_does(tmp_path, xyz):
    # a rotation that is not symmetric (its transpose differs), anisotropic spacing
    c, s = np.cos(0.4), np.sin(0.4)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    c2, s2 = np.cos(0.3), np.sin(0.3)
    rx = np.array([[1, 0, 0], [0, c2, -s2], [0, s2, c2]])
    rot = rz @ rx
    assert not np.allclose(rot, rot.T)
    affine = np.eye(4)
    affine[:3, :3] = rot * [0.6, 1.1, 2.5]
    affine[:3, 3] = [12.0, -3.0, 40.0]
    path = save(tmp_path / "oblique.nii", xyz, affine)
    vol = read_volume(path)
    assert np.allclose(vol.spacing, [0.6, 1.1, 2.5])
    assert np.allclose(vol.direction, rot)
    for ijk in ([0, 0, 0], [6, 0, 0], [0, 4, 0], [0, 0, 5], [6, 4, 5], [3, 1, 2]):
        assert np.allclose(world(vol, ijk), nib.affines.apply_affine(affine, ijk)), ijk
    # the mesh's vertices map back through the inverse affine onto grid edges
    mesh = extract(vol, 0.5)
    ijk = nib.affines.apply_affine(np.linalg.inv(affine), mesh.vertices)
    on_grid = np.isclose(ijk, np.round(ijk), atol=1e-6).sum(axis=1)
    assert (on_grid >= 2).all()


def test_scaling_makes_float_in_memory(tmp_path, xyz):
    data = (xyz * 100).astype(np.int16)
    img = nib.Nifti1Image(data, np.eye(4))
    nib.save(img, str(tmp_path / "unit.nii"))
    # nibabel sets its own scaling on saving: write scl_slope and scl_inter into the header
    raw = bytearray((tmp_path / "unit.nii").read_bytes())
    struct.pack_into("<ff", raw, 112, 0.5, -3.0)
    (tmp_path / "scaled.nii").write_bytes(bytes(raw))
    vol = read_volume(tmp_path / "scaled.nii")
    assert vol.grid is None and vol.dtype.kind == "f"
    assert np.allclose(vol.data, data * 0.5 - 3.0)
    assert any("scl_slope 0.5" in n for n in vol.notes)
    # slope 1, intercept 0 (or slope NaN, as nibabel writes) is no scaling: lazy, stored type
    struct.pack_into("<ff", raw, 112, 1.0, 0.0)
    (tmp_path / "unit.nii").write_bytes(bytes(raw))
    vol = read_volume(tmp_path / "unit.nii")
    assert isinstance(vol.grid, RawGrid) and vol.dtype == np.int16
    struct.pack_into("<ff", raw, 112, 0.0, 7.0)  # slope 0: not set, the intercept ignored
    (tmp_path / "zero.nii").write_bytes(bytes(raw))
    vol = read_volume(tmp_path / "zero.nii")
    assert isinstance(vol.grid, RawGrid) and np.array_equal(vol.data, data)


def test_4d_needs_volume_index(tmp_path, xyz):
    four = np.stack([xyz, xyz + 1, xyz + 2], axis=-1)
    for name in ("t.nii", "t.nii.gz"):
        path = save(tmp_path / name, four)
        msg = one_line_error(path, VolumeError, "3 volumes", "--volume-index 0..2")
        assert name in msg
        vol = read_volume(path, volume_index=2)
        assert np.array_equal(vol.data, xyz + 2)
        assert "volume 2 of 3" in vol.notes
        assert (vol.grid is not None) == (name == "t.nii")
        one_line_error(path, VolumeError, "--volume-index 3 is out of range 0..2", volume_index=3)
    one_line_error(save(tmp_path / "three.nii", xyz), VolumeError, "one volume", volume_index=1)
    # a 4D image of one volume needs no index
    assert read_volume(save(tmp_path / "one.nii", xyz[..., None])).shape == xyz.shape


def test_volume_index_is_refused_by_other_readers(tmp_path, xyz):
    np.save(tmp_path / "v.npy", xyz.T)
    one_line_error(tmp_path / "v.npy", VolumeError, "--volume-index", volume_index=0)


def test_big_endian(tmp_path, xyz):
    data = (xyz * 100).astype(">i2")
    header = nib.Nifti1Header(endianness=">")
    header.set_data_dtype(">i2")
    nib.save(nib.Nifti1Image(data, np.eye(4), header=header), str(tmp_path / "be.nii"))
    assert nib.load(str(tmp_path / "be.nii")).header.endianness == ">"
    vol = read_volume(tmp_path / "be.nii")
    assert np.array_equal(vol.data, data) and vol.dtype.byteorder == ">"
    gz = tmp_path / "be.nii.gz"
    gz.write_bytes(gzip.compress((tmp_path / "be.nii").read_bytes()))
    vol = read_volume(gz)
    assert np.array_equal(vol.data, data) and vol.dtype.isnative
    same_mesh(extract(vol, 25.5), extract(read_volume(tmp_path / "be.nii"), 25.5))


def test_units_and_2d(tmp_path, xyz):
    img = nib.Nifti1Image(xyz, np.diag([0.3, 0.3, 0.3, 1.0]))
    img.header.set_xyzt_units("micron")
    nib.save(img, str(tmp_path / "um.nii"))
    assert read_volume(tmp_path / "um.nii").unit == "µm"
    assert read_volume(save(tmp_path / "mm.nii", xyz, xyzt_units=2)).unit == "mm"
    flat = save(tmp_path / "flat.nii", xyz[:, :, :1], np.diag([0.5, 2.0, 3.0, 1.0]))
    vol = read_volume(flat)
    assert vol.shape == (7, 5) and vol.spacing.tolist() == [0.5, 2.0]
    assert np.array_equal(vol.data, xyz[:, :, 0])
    assert nifti_ndim(flat) == 2 and nifti_ndim(tmp_path / "um.nii") == 3
    img2d = save(tmp_path / "img.nii.gz", xyz[:, :, 2])
    assert read_volume(img2d).shape == (7, 5) and nifti_ndim(img2d) == 2
    assert extract(read_volume(img2d), 0.5).cells.shape[1] == 2


# --- bad input ------------------------------------------------------------------------------


def test_bad_nifti_files_are_one_line_errors(tmp_path, xyz):
    good = save(tmp_path / "good.nii", xyz).read_bytes()
    short = tmp_path / "truncated.nii"
    short.write_bytes(good[: len(good) - 100])
    one_line_error(short, FormatError, "truncated.nii", "truncated")
    header_only = tmp_path / "header_only.nii"
    header_only.write_bytes(good[:200])
    one_line_error(header_only, FormatError, "not a readable NIfTI")
    short_gz = tmp_path / "truncated.nii.gz"
    short_gz.write_bytes(gzip.compress(good)[:-300])
    one_line_error(short_gz, FormatError, "truncated.nii.gz")
    junk = tmp_path / "junk.nii"
    junk.write_bytes(b"this is not a NIfTI file" * 30)
    one_line_error(junk, FormatError, "junk.nii", "not a readable NIfTI")
    five = save(tmp_path / "five.nii", np.zeros((3, 3, 3, 2, 2), np.uint8))
    one_line_error(five, VolumeError, "5 dimensions", "3D and 4D")
    rgb = tmp_path / "rgb.nii"
    colour = np.zeros((3, 3, 3), dtype=[("R", "u1"), ("G", "u1"), ("B", "u1")])
    nib.save(nib.Nifti1Image(colour, np.eye(4)), str(rgb))
    one_line_error(rgb, IsoconvertError, "rgb.nii", "not real numbers")


def test_missing_nibabel_is_one_line(tmp_path, xyz, monkeypatch):
    import builtins

    path = save(tmp_path / "v.nii", xyz)
    real_import = builtins.__import__

    def no_nibabel(name, *args, **kwargs):
        if name == "nibabel" or name.startswith("nibabel."):
            raise ImportError("no nibabel")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_nibabel)
    msg = one_line_error(path, FormatError)
    assert msg == f"reading NIfTI needs nibabel: {extra_hint('nifti')}"


def test_folder_of_nifti_files_says_give_the_file(tmp_path, xyz):
    folder = tmp_path / "scans"
    folder.mkdir()
    save(folder / "t1.nii.gz", xyz)
    reason = unsupported_format(folder)
    assert reason and "NIfTI file (t1.nii.gz): give that file" in reason


# --- real brains ----------------------------------------------------------------------------

BRAINS = {
    "chris_t1.nii.gz": ((188, 256, 190), 0.88),
    "avg152T1_RL_nifti.nii.gz": ((91, 109, 91), 2.0),
}


@pytest.mark.parametrize("name", list(BRAINS))
def test_real_brains_place_meshes_where_nibabel_puts_the_volume(name):
    path = dataset(name)
    shape, spacing = BRAINS[name]
    vol = read_volume(path)
    assert vol.shape == shape and vol.dtype == np.uint8 and vol.unit == "mm"
    assert np.allclose(vol.spacing, spacing, atol=1e-6)
    img = nib.load(str(path))
    assert np.array_equal(vol.data, np.asanyarray(img.dataobj))
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    corners = corners * (np.array(shape) - 1)
    nib_world = nib.affines.apply_affine(img.affine, corners)
    assert np.allclose(vol.index_to_world(corners.astype(np.float64)), nib_world, atol=1e-4)
    # a half-integer level near the mean; the mesh lies in the box of the corners
    zyx = np.ascontiguousarray(vol.data.T)
    level = float(np.floor(zyx.mean())) + 0.5
    mesh = extract(vol, level)
    lo, hi = nib_world.min(axis=0), nib_world.max(axis=0)
    assert (mesh.vertices.min(axis=0) >= lo - 1e-4).all()
    assert (mesh.vertices.max(axis=0) <= hi + 1e-4).all()
    points, cells = vtk_flying_edges(zyx, level)
    assert (mesh.n_vertices, mesh.n_cells) == (len(points), len(cells)) and len(cells) > 1000
    vtk_world = nib.affines.apply_affine(img.affine, points)
    assert np.allclose(mesh.vertices.min(axis=0), vtk_world.min(axis=0), atol=1e-4)
    assert np.allclose(mesh.vertices.max(axis=0), vtk_world.max(axis=0), atol=1e-4)
    ours_k, ours_t = edge_key(mesh.vertices - vol.origin, vol.spacing)
    vtk_k, vtk_t = edge_key(points * vol.spacing, vol.spacing)
    assert np.array_equal(ours_k, vtk_k) and np.abs(ours_t - vtk_t).max() < 1e-5
