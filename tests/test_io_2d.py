"""2D inputs (images, single-page TIFF, 2D NRRD) and contour outputs (OBJ, PLY, SVG)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import nrrd
import numpy as np
import pytest
import tifffile
import trimesh
from PIL import Image

from isoconvert import Volume, extract, read_volume, write_mesh
from isoconvert.errors import FormatError, VolumeError
from isoconvert.mesh import polylines


@pytest.fixture
def gray():
    y, x = np.mgrid[:40, :50]
    return np.clip(200 - 8 * np.hypot(x - 24.3, y - 19.6), 0, 255).astype(np.uint8)


def test_png_gray_and_16_bit(tmp_path, gray):
    Image.fromarray(gray).save(tmp_path / "g.png")
    vol = read_volume(tmp_path / "g.png")
    assert vol.ndim == 2 and np.array_equal(vol.data, gray.T)
    deep = (gray.astype(np.uint16) * 250).astype(np.uint16)
    Image.fromarray(deep).save(tmp_path / "d.png")
    assert np.array_equal(read_volume(tmp_path / "d.png").data, deep.T)


def test_colour_images_become_luma_or_a_channel(tmp_path, gray):
    rgb = np.stack([gray, 255 - gray, gray // 2], axis=-1)
    Image.fromarray(rgb).save(tmp_path / "c.png")
    vol = read_volume(tmp_path / "c.png")
    expected = np.asarray(Image.fromarray(rgb).convert("L"))
    assert np.array_equal(vol.data, expected.T)
    assert any("gray" in n for n in vol.notes)
    assert np.array_equal(read_volume(tmp_path / "c.png", channel=1).data, (255 - gray).T)
    with pytest.raises(VolumeError, match="--channel 5 is out of range 0..2"):
        read_volume(tmp_path / "c.png", channel=5)


def test_jpeg_and_corrupt_image(tmp_path, gray):
    Image.fromarray(gray).save(tmp_path / "g.jpg", quality=95)
    vol = read_volume(tmp_path / "g.jpg")
    assert vol.shape == (50, 40) and np.abs(vol.data.astype(int) - gray.T).max() < 12
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    with pytest.raises(FormatError, match="bad.png: not a readable image"):
        read_volume(tmp_path / "bad.png")


def test_single_page_tiff_and_2d_nrrd_give_the_same_contours(tmp_path, gray):
    Image.fromarray(gray).save(tmp_path / "g.png")
    tifffile.imwrite(tmp_path / "g.tif", gray)
    nrrd.write(str(tmp_path / "g.nrrd"), gray.T, index_order="F")
    meshes = [extract(read_volume(tmp_path / n), 100.5) for n in ("g.png", "g.tif", "g.nrrd")]
    for m in meshes[1:]:
        assert np.array_equal(m.vertices, meshes[0].vertices)
        assert np.array_equal(m.cells, meshes[0].cells)


@pytest.fixture
def contours(gray):
    return extract(Volume.from_zyx(gray, spacing=(0.5, 2.0), origin=(10.0, -3.0)), 100.5)


def test_contour_is_closed_and_counter_clockwise_around_bright(contours):
    ((line, closed),) = polylines(contours.cells)
    assert closed
    x, y = contours.vertices[line, 0], contours.vertices[line, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0


@pytest.mark.parametrize("ascii", [False, True])
def test_ply_edges_read_back_by_trimesh(tmp_path, contours, ascii):
    path = write_mesh(contours, tmp_path / "c.ply", ascii=ascii)
    back = trimesh.load(path, process=False)
    assert isinstance(back, trimesh.path.Path3D)
    assert np.allclose(back.vertices, contours.vertices, atol=1e-4)
    # trimesh chains the edges into polylines: compare the segments they hold
    theirs = {
        frozenset(p) for e in back.entities for p in zip(e.points[:-1], e.points[1:], strict=True)
    }
    assert theirs == {frozenset(c) for c in contours.cells.tolist()}
    assert sum(len(e.points) - 1 for e in back.entities) == contours.n_cells


def test_obj_lines_read_back_by_vtk(tmp_path, contours):
    vtk = pytest.importorskip("vtk")
    from vtk.util import numpy_support

    path = write_mesh(contours, tmp_path / "c.obj")
    reader = vtk.vtkOBJReader()
    reader.SetFileName(str(path))
    reader.Update()
    out = reader.GetOutput()
    points = numpy_support.vtk_to_numpy(out.GetPoints().GetData())
    assert np.allclose(points, contours.vertices, atol=1e-6)
    lines = numpy_support.vtk_to_numpy(out.GetLines().GetConnectivityArray()).reshape(-1, 2)
    assert np.array_equal(lines, contours.cells)


def test_svg_paths_hold_the_polylines(tmp_path, contours):
    path = write_mesh(contours, tmp_path / "c.svg")
    root = ET.parse(path).getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}
    paths = root.findall(".//s:path", ns)
    lines = polylines(contours.cells)
    assert len(paths) == len(lines)
    for el, (line, closed) in zip(paths, lines, strict=True):
        d = el.get("d")
        assert d.endswith(" Z") == closed
        pts = np.array([p.split() for p in d.rstrip(" Z").lstrip("M").split(" L")], float)
        assert np.allclose(pts, contours.vertices[line, :2], atol=1e-3)


def test_stl_and_svg_refuse_what_they_cannot_hold(tmp_path, contours):
    with pytest.raises(FormatError, match=r"c.stl: stl cannot hold contour segments; write ply"):
        write_mesh(contours, tmp_path / "c.stl")
    cube_mesh = extract(Volume(np.pad(np.ones((3, 3, 3)), 1)), 0.5)
    with pytest.raises(FormatError, match=r"c.svg: svg cannot hold triangles"):
        write_mesh(cube_mesh, tmp_path / "c.svg")
    stack = extract(Volume(np.pad(np.ones((3, 3, 3)), 1)), 0.5, method="squares", axis="z")
    with pytest.raises(FormatError, match="several planes"):
        write_mesh(stack, tmp_path / "s.svg")
    assert list(tmp_path.iterdir()) == []
