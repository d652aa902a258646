"""SVG contours: a size in world units, the image's frame as view box, a white background."""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import Volume, extract, write_mesh
from isoconvert.cli import main
from isoconvert.writers.svg import nice_scale, write_svg

NS = {"s": "http://www.w3.org/2000/svg"}


def disk(unit: str | None) -> Volume:
    """A 50 x 20 image, spacing 0.25 x 0.5, origin (10, -3): 12.5 x 10 world units."""
    x, y = np.meshgrid(np.arange(50) * 0.25 + 10, np.arange(20) * 0.5 - 3, indexing="ij")
    field = 3.0 - np.hypot(x - 16, y - 1.75)
    return Volume(field, spacing=(0.25, 0.5), origin=(10.0, -3.0), unit=unit)


def parse(path) -> ET.Element:
    return ET.parse(path).getroot()


def view_box(root: ET.Element) -> np.ndarray:
    return np.array(root.get("viewBox").split(), dtype=float)


def test_width_and_height_are_the_world_extent_in_mm(tmp_path):
    path = write_mesh(extract(disk("mm"), 0.0), tmp_path / "c.svg")
    root = parse(path)
    assert root.get("width") == "12.5mm" and root.get("height") == "10mm"
    # the image's pixel extent: half a spacing beyond the first and last samples
    assert np.allclose(view_box(root), [10 - 0.125, -3 - 0.25, 12.5, 10])


def test_a_white_rectangle_covers_the_view_box_behind_the_paths(tmp_path):
    path = write_mesh(extract(disk("mm"), 0.0), tmp_path / "c.svg")
    root = parse(path)
    children = list(root)
    rect = root.find("s:rect", NS)
    assert rect is not None and rect.get("fill") == "white"
    box = [float(rect.get(k)) for k in ("x", "y", "width", "height")]
    assert np.allclose(box, view_box(root))
    group = root.find("s:g", NS)
    assert children.index(rect) < children.index(group)  # drawn first: behind
    # every contour point inside the picture
    x0, y0, w, h = view_box(root)
    for el in root.findall(".//s:path", NS):
        pts = np.array([p.split() for p in el.get("d").rstrip(" Z").lstrip("M").split(" L")], float)
        assert (pts[:, 0] >= x0).all() and (pts[:, 0] <= x0 + w).all()
        assert (pts[:, 1] >= y0).all() and (pts[:, 1] <= y0 + h).all()


def test_background_none_leaves_it_transparent():
    buf = io.BytesIO()
    write_svg(extract(disk("mm"), 0.0), buf, background=None)
    root = ET.fromstring(buf.getvalue())
    assert root.find("s:rect", NS) is None and root.get("width") == "12.5mm"


@pytest.mark.parametrize(
    "unit, width, height", [("cm", "12.5cm", "10cm"), ("m", "12500mm", "10000mm")]
)
def test_other_svg_units(tmp_path, unit, width, height):
    root = parse(write_mesh(extract(disk(unit), 0.0), tmp_path / "c.svg"))
    assert (root.get("width"), root.get("height")) == (width, height)


@pytest.mark.parametrize("unit", [None, "µm", "pixel"])
def test_without_an_svg_unit_the_size_is_user_units_at_a_round_scale(tmp_path, unit):
    root = parse(write_mesh(extract(disk(unit), 0.0), tmp_path / "c.svg"))
    width, height = float(root.get("width")), float(root.get("height"))  # unitless
    box = view_box(root)
    scale = width / box[2]
    assert height / box[3] == pytest.approx(scale)  # world proportions kept
    assert scale == 50.0  # 800 / 12.5 = 64 -> the round 50
    assert 320 <= max(width, height) <= 800


def test_nice_scale():
    assert [nice_scale(x) for x in (64, 160, 1.0, 0.3, 9.99, 10.0)] == [50, 100, 1, 0.2, 5, 10]


def test_the_command_writes_a_sized_svg_of_figure_2_4(tmp_path):
    out = tmp_path / "c.svg"
    assert main(["convert", str(SAMPLES / "figure_2_4.nrrd"), "-o", str(out), "-l", "5.5"]) == 0
    root = parse(out)
    # 5 x 5 samples, spacing 1, no unit: 5 x 5 world units at 100 user units each
    assert np.allclose(view_box(root), [-0.5, -0.5, 5, 5])
    assert (root.get("width"), root.get("height")) == ("500", "500")
    assert root.find("s:rect", NS).get("fill") == "white"


def test_a_mesh_without_its_grid_is_framed_by_its_contours():
    mesh = extract(disk("mm"), 0.0)
    mesh.info.pop("grid")
    buf = io.BytesIO()
    write_svg(mesh, buf)
    box = view_box(ET.fromstring(buf.getvalue()))
    lo, hi = mesh.vertices[:, :2].min(axis=0), mesh.vertices[:, :2].max(axis=0)
    pad = 0.02 * (hi - lo).max()
    assert np.allclose(box, [*(lo - pad), *(hi - lo + 2 * pad)])
