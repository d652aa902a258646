"""Previews: the pictures themselves (silhouettes, problem marks), errors, the contact sheet."""

from __future__ import annotations

import html
import os
import re

import numpy as np
import pytest
from conftest import SAMPLES, ball, dataset

pytest.importorskip("vtkmodules", reason="previews need isoconvert[render] (VTK)")

from PIL import Image  # noqa: E402

from isoconvert import Volume, extract  # noqa: E402
from isoconvert.cli import main  # noqa: E402
from isoconvert.errors import IsoconvertError, extra_hint  # noqa: E402
from isoconvert.mesh import Mesh  # noqa: E402
from isoconvert.preview import (  # noqa: E402
    PROBLEMS,
    Layout,
    RenderError,
    parse_size,
    render_preview,
    require_renderer,
    write_preview,
)
from isoconvert.readers import read_volume  # noqa: E402
from isoconvert.writers import write_mesh  # noqa: E402

try:
    require_renderer()
except RenderError as why:  # a machine with no offscreen OpenGL library: say what to install
    pytest.skip(str(why), allow_module_level=True)

HOLE = PROBLEMS["boundary_edges_inside"][1]
BACKGROUND = (255, 255, 255)
#: Pixels the silhouette may differ from the projected box by (rasterization, rounding).
TOLERANCE = 3


@pytest.fixture(autouse=True)
def _headless(monkeypatch):
    """Render as on a server: no display."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)


def _object_pixels(image: np.ndarray, box, layout: Layout) -> np.ndarray:
    """(h, w) bool: pixels of a panel's fitted area that are not background.

    The panel's title strip and the axis arrows' corner are left out: only
    the area the object is fitted into (``Layout.inner``) is compared.
    """
    x0, y0, x1, y1 = box
    panel = image[y0:y1, x0:x1].astype(int)
    mask = np.abs(panel - np.array(BACKGROUND)).sum(axis=2) > 24
    # the title's text may reach just below its strip: keep to the fitted area
    k = [layout.panel_box(i) for i in range(4)].index(tuple(box))
    top = int(layout.inner(k)[1] - y0) - 2
    mask[:top] = False
    mask[:, :2] = mask[:, -2:] = False  # separators
    mask[-2:] = False
    return mask


def _assert_silhouettes(preview, mesh: Mesh, views=("top", "front", "side")) -> None:
    """Each axis view's non-background pixels span the mesh's projected bounding box."""
    layout = Layout(preview.image.shape[1], preview.image.shape[0])
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    corners = np.array([[(lo, hi)[(i >> a) & 1][a] for a in range(3)] for i in range(8)])
    for view in preview.views:
        if view.name not in views:
            continue
        xy = view.project(corners)
        x0, y0 = view.box[:2]
        # expected pixel box of the object, in panel coordinates
        ex0, ey0 = xy.min(axis=0) - (x0, y0)
        ex1, ey1 = xy.max(axis=0) - (x0, y0)
        mask = _object_pixels(preview.image, view.box, layout)
        # leave the axis-arrow corner out of the search (bottom-left 20 %)
        h, w = mask.shape
        mask[int(0.8 * h) :, : int(0.2 * w)] = False
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        assert len(rows) and len(cols), f"{view.name}: nothing drawn"
        got = (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1)
        want = (ex0, ey0, ex1, ey1)
        assert np.allclose(got, want, atol=TOLERANCE), f"{view.name}: silhouette {got} != {want}"


def _sample_mesh(name: str, level: float) -> Mesh:
    return extract(read_volume(SAMPLES / name), level)


@pytest.mark.parametrize(
    ("name", "level"), [("sphere.nrrd", 128), ("torus.nrrd", 3.0), ("two_spheres.nrrd", 0.0)]
)
def test_silhouettes_of_sample_volumes(name, level):
    mesh = _sample_mesh(name, level)
    preview = render_preview(mesh, size=(640, 480))
    assert preview.image.shape == (480, 640, 3)
    _assert_silhouettes(preview, mesh)
    # a closed surface: nothing drawn in a problem colour
    for label, colour in PROBLEMS.values():
        assert not (preview.image == colour).all(axis=2).any(), label


def test_silhouettes_of_anisotropic_mesh():
    """Stretched along z: the front and side views are tall, as the world is."""
    mesh = _sample_mesh("sphere.nrrd", 128)
    mesh = Mesh(mesh.vertices * np.array([1.0, 0.5, 3.0]), mesh.cells, info=mesh.info)
    preview = render_preview(mesh, size=(500, 700))
    _assert_silhouettes(preview, mesh)


def test_silhouettes_of_a_real_scan():
    path = dataset("engine_256x256x128_uint8.raw")
    volume = read_volume(path, shape=(256, 256, 128), dtype="uint8")
    # every other sample: the test is about the picture, not the extraction
    small = Volume(
        np.asarray(volume.data)[::2, ::2, ::2], spacing=volume.spacing * 2, origin=volume.origin
    )
    mesh = extract(small, 180)
    preview = render_preview(mesh, size=(800, 600))
    _assert_silhouettes(preview, mesh)


def _sphere_with_hole():
    """A closed sphere with the triangles near its +x pole removed: a hole there."""
    volume = Volume(ball(32, 12.0))
    mesh = extract(volume, 0.0)
    center = mesh.vertices.mean(axis=0)
    radius = np.linalg.norm(mesh.vertices - center, axis=1).max()
    pole = center + np.array([radius, 0.0, 0.0])
    centroids = mesh.vertices[mesh.cells].mean(axis=1)
    gone = np.linalg.norm(centroids - pole, axis=1) < 0.3 * radius
    hole = Mesh(mesh.vertices, mesh.cells[~gone], info={"grid": mesh.info.get("grid")})
    # the hole's rim: vertices of removed triangles that remain in kept ones
    kept = np.zeros(len(mesh.vertices), bool)
    kept[mesh.cells[~gone].reshape(-1)] = True
    removed = np.zeros(len(mesh.vertices), bool)
    removed[mesh.cells[gone].reshape(-1)] = True
    return hole, mesh.vertices[kept & removed]


def test_hole_is_drawn_where_it_is_and_nowhere_else():
    mesh, rim = _sphere_with_hole()
    preview = render_preview(mesh, size=(800, 600))
    assert preview.marks.counts["boundary_edges_inside"] > 0
    red = (preview.image == HOLE).all(axis=2)
    assert red.any()
    margin = 6  # line width and rounding
    for view in preview.views:
        x0, y0, x1, y1 = view.box
        xy = view.project(rim)
        bx0, by0 = np.floor(xy.min(axis=0)).astype(int) - margin
        bx1, by1 = np.ceil(xy.max(axis=0)).astype(int) + margin
        inside = np.zeros_like(red)
        inside[max(by0, y0) : min(by1, y1), max(bx0, x0) : min(bx1, x1)] = True
        panel = np.zeros_like(red)
        panel[y0:y1, x0:x1] = True
        assert red[panel & inside].any(), f"{view.name}: no hole colour at the hole"
        assert not red[panel & ~inside].any(), f"{view.name}: hole colour away from the hole"
    # the legend names holes, with its colour swatch in the footer
    layout = Layout(800, 600)
    assert red[600 - layout.footer :].any()


def test_closed_sphere_shows_no_hole():
    """The same sphere without removing anything: no hole colour at all."""
    mesh = extract(Volume(ball(32, 12.0)), 0.0)
    preview = render_preview(mesh, size=(400, 300))
    assert preview.marks.counts["boundary_edges_inside"] == 0
    assert not (preview.image == HOLE).all(axis=2).any()


def test_non_manifold_vertex_is_marked():
    """Two tetrahedra sharing one vertex: a non-manifold vertex, drawn there."""
    v = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float
    )
    tets = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [0, 4, 5], [0, 6, 4], [0, 5, 6]]
    tets += [[4, 6, 5]]
    mesh = Mesh(v, np.array(tets))
    preview = render_preview(mesh, size=(400, 300))
    assert preview.marks.counts["non_manifold_vertices"] == 1
    colour = PROBLEMS["non_manifold_vertices"][1]
    hits = (preview.image == colour).all(axis=2)
    top = next(view for view in preview.views if view.name == "top")
    cx, cy = top.project(v[:1])[0]
    assert hits[int(cy) - 2 : int(cy) + 3, int(cx) - 2 : int(cx) + 3].any()


def test_background_and_size():
    mesh = _sample_mesh("torus.nrrd", 3.0)
    preview = render_preview(mesh, size=(300, 200), background="#102030")
    assert preview.image.shape == (200, 300, 3)
    assert tuple(preview.image[200 - 3, 150]) == (16, 32, 48)  # footer
    assert tuple(preview.image[60, 5]) == (16, 32, 48)  # panel corner
    with pytest.raises(IsoconvertError, match="WIDTHxHEIGHT"):
        parse_size("big")


def test_anatomical_axes_in_the_titles():
    mesh = _sample_mesh("sphere.nrrd", 128)
    mesh.info["frame"] = "LPS"
    preview = render_preview(mesh, size=(400, 300))
    assert preview.frame == "LPS"
    titles = {view.name: view for view in preview.views}
    # the front view looks from -y, which is anterior in LPS
    from isoconvert.preview import _view_title

    assert _view_title(titles["front"], "LPS") == "front, from A"
    assert _view_title(titles["top"], "RAS") == "top, from S"


# --- the command line ---------------------------------------------------------------------


def _run(args, capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_preview_command_writes_a_png(tmp_path, capsys):
    mesh = _sample_mesh("two_spheres.nrrd", 0.0)
    ply = tmp_path / "m.ply"
    write_mesh(mesh, ply)
    png = tmp_path / "m.png"
    code, out, err = _run(["preview", ply, "-o", png, "--size", "320x240"], capsys)
    assert code == 0, err
    with Image.open(png) as image:
        assert image.size == (320, 240)
        assert image.format == "PNG"
        assert "isoconvert-preview" in image.text


def test_convert_with_preview(tmp_path, capsys):
    png = tmp_path / "s.png"
    code, out, err = _run(
        ["convert", SAMPLES / "torus.nrrd", "-o", tmp_path / "t.ply", "-l", "3", "--preview", png],
        capsys,
    )
    assert code == 0, err
    with Image.open(png) as image:
        assert image.size == (1024, 768)


def _assert_one_line_error(code, err, tmp_path, keep=()):
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("isoconvert: error:"), err
    left = sorted(p.name for p in tmp_path.iterdir() if p.name not in keep)
    assert left == [], left  # no picture, no temporary file


def test_empty_mesh_is_an_error_and_leaves_nothing(tmp_path, capsys):
    with pytest.raises(IsoconvertError, match="no triangles"):
        render_preview(Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    empty = tmp_path / "empty.ply"
    empty.write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
    )
    code, out, err = _run(["preview", empty, "-o", tmp_path / "e.png"], capsys)
    _assert_one_line_error(code, err, tmp_path, keep=("empty.ply",))


def test_unreadable_file_is_an_error_and_leaves_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\nend_header\n\x00")
    code, out, err = _run(["preview", bad, "-o", tmp_path / "b.png"], capsys)
    _assert_one_line_error(code, err, tmp_path, keep=("bad.ply",))
    code, out, err = _run(["preview", tmp_path / "missing.ply", "-o", tmp_path / "b.png"], capsys)
    _assert_one_line_error(code, err, tmp_path, keep=("bad.ply",))


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_unwritable_output_is_an_error(tmp_path, capsys):
    mesh = _sample_mesh("torus.nrrd", 3.0)
    ply = tmp_path / "t.ply"
    write_mesh(mesh, ply)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code, out, err = _run(["preview", ply, "-o", locked / "t.png"], capsys)
        assert code == 1 and len(err.strip().splitlines()) == 1
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)


def test_output_in_a_missing_folder_or_existing_file(tmp_path, capsys):
    mesh = _sample_mesh("torus.nrrd", 3.0)
    ply = tmp_path / "t.ply"
    write_mesh(mesh, ply)
    code, out, err = _run(["preview", ply, "-o", tmp_path / "nope" / "t.png"], capsys)
    _assert_one_line_error(code, err, tmp_path, keep=("t.ply",))
    existing = tmp_path / "x.png"
    existing.write_bytes(b"keep")
    code, out, err = _run(["preview", ply, "-o", existing], capsys)
    assert code == 1 and existing.read_bytes() == b"keep"


def test_write_preview_failing_leaves_no_file(tmp_path):
    mesh = _sample_mesh("torus.nrrd", 3.0)
    preview = render_preview(mesh, size=(200, 150))
    with pytest.raises(IsoconvertError):
        write_preview(preview, tmp_path / "missing" / "p.png")
    assert list(tmp_path.iterdir()) == []


def test_batch_previews_contact_sheet(tmp_path, capsys):
    out = tmp_path / "out"
    inputs = [SAMPLES / "sphere.nrrd", SAMPLES / "two_spheres.nrrd"]
    code, _, err = _run(["batch", *inputs, "-o", out, "-l", "0.5", "--previews", "-j", "1"], capsys)
    assert code == 0, err
    page = (out / "index.html").read_text()
    assert "http://" not in page and "https://" not in page and "<script" not in page
    sources = re.findall(r'<img src="([^"]+)"', page)
    assert len(sources) == len(inputs)
    for name in ("sphere", "two_spheres"):
        assert f"{name}.ply" in page
        assert f"{name}.png" in sources
    for src in sources:
        path = out / src  # relative to the page, so it opens from disk
        with Image.open(path) as image:
            image.verify()
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size == (400, 300)
    assert "level 0.5" in page and "no holes, non-manifold or zero-length edges found" in page


def test_contact_sheet_links_survive_url_characters(tmp_path, capsys):
    """File names with # ? % & ' and spaces: the links are URLs that lead to the files."""
    import shutil
    import urllib.parse

    src = tmp_path / "in"
    src.mkdir()
    odd = src / "n \u00e9 #1%20?&'_40x40x40_uint8.raw"
    shutil.copy(SAMPLES / "sphere_40x40x40_uint8.raw", odd)
    out = tmp_path / "out"
    code, _, err = _run(["batch", src, "-o", out, "-l", "127.5", "--previews", "-j", "1"], capsys)
    assert code == 0, err
    page = (out / "index.html").read_text()
    targets = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert len(targets) == 3  # the picture, its link and the mesh's
    for target in targets:
        url = html.unescape(target)
        assert "#" not in url and "?" not in url  # would be a fragment or a query
        assert (out / urllib.parse.unquote(url)).is_file()


def test_pictures_must_be_png_and_follow_the_mesh_names(tmp_path, capsys):
    mesh = tmp_path / "s.ply"
    assert main(["convert", str(SAMPLES / "sphere.nrrd"), "-l", "127.5", "-o", str(mesh)]) == 0
    code = main(["preview", str(mesh), "-o", str(tmp_path / "p.svg")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "name the file .png" in err[-1]
    assert not (tmp_path / "p.svg").exists()
    args = ["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(tmp_path / "em.ply"), "-q"]
    assert main([*args, "-l", "100.5", "-l", "200.5", "--preview", str(tmp_path / "pic.png")]) == 0
    assert sorted(p.name for p in tmp_path.glob("pic*")) == [
        "pic_level100.5.png",
        "pic_level200.5.png",
    ]


def test_previews_are_lazy_about_vtk():
    """Other commands never import VTK."""
    import subprocess
    import sys

    code = (
        "import sys; from isoconvert.cli import main; main(['formats']); "
        "sys.exit(1 if any(m.startswith('vtkmodules') for m in sys.modules) else 0)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True)
    assert result.returncode == 0, "VTK imported by `formats`"


def test_missing_vtk_is_a_one_line_error(monkeypatch, tmp_path, capsys):
    import builtins

    real_import = builtins.__import__

    def no_vtk(name, *args, **kwargs):
        if name.startswith("vtkmodules"):
            raise ImportError("No module named 'vtkmodules'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_vtk)
    mesh = _sample_mesh("torus.nrrd", 3.0)
    ply = tmp_path / "t.ply"
    write_mesh(mesh, ply)
    code, out, err = _run(["preview", ply, "-o", tmp_path / "t.png"], capsys)
    assert code == 1 and extra_hint("render") in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t.png").exists()


def test_example_picture_is_small(tmp_path):
    """The README's picture: a few tens of kB."""
    mesh = _sample_mesh("torus.nrrd", 3.0)
    data = render_preview(mesh, size=(640, 480)).png()
    assert 5_000 < len(data) < 120_000
