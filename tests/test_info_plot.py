"""`isoconvert info --plot`: the histogram with the suggested levels, and the
middle slices with their isocontour, checked on the pixels of the PNG."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest
from conftest import dataset
from PIL import Image

pytest.importorskip("matplotlib")

from isoconvert import Volume, read_volume  # noqa: E402
from isoconvert.cli import main  # noqa: E402
from isoconvert.errors import IsoconvertError, extra_hint  # noqa: E402
from isoconvert.grid import RawGrid  # noqa: E402
from isoconvert.infoplot import (  # noqa: E402
    CONTOUR_COLOR,
    middle_slices,
    require_matplotlib,
    write_info_plot,
)

AVF = "avf_float_32.nrrd"


def pixels(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def rgb(color: str) -> np.ndarray:
    return np.array([int(color[i : i + 2], 16) for i in (1, 3, 5)])


def crop(img: np.ndarray, bbox, inset: int = 2) -> tuple[np.ndarray, int, int]:
    """The pixels inside a panel's bbox (a few pixels in from its frame), and
    the column and row of the crop's first pixel."""
    left, top, right, bottom = bbox
    c0, r0 = int(np.ceil(left)) + inset, int(np.ceil(top)) + inset
    c1, r1 = int(np.floor(right)) - inset, int(np.floor(bottom)) - inset
    return img[r0:r1, c0:c1], c0, r0


def contour_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of about the contour colour (magenta; antialiased edges are lighter)."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r > 180) & (b > 180) & (g < 110)


def ball_volume(shape, spacing, radius) -> tuple[Volume, np.ndarray]:
    """radius - world distance from the middle sample: the level-0 contour of
    each middle slice is a circle of ``radius`` world units."""
    shape, spacing = np.asarray(shape), np.asarray(spacing, float)
    centre = (shape // 2) * spacing
    axes = [np.arange(n) * s for n, s in zip(shape, spacing, strict=True)]
    grids = np.meshgrid(*axes, indexing="ij")
    dist = np.sqrt(sum((g - c) ** 2 for g, c in zip(grids, centre, strict=True)))
    return Volume((radius - dist).astype(np.float32), spacing=spacing, unit="mm"), centre


# --- anisotropic real scan ---------------------------------------------------------------


def test_avf_slices_show_their_physical_aspect_ratio(tmp_path):
    volume = read_volume(dataset(AVF))
    out = tmp_path / "info.png"
    plot = write_info_plot(volume, out)
    img = pixels(out)
    assert img.shape[1::-1] == plot.size
    n, s = np.array(volume.shape), volume.spacing
    world = n * s  # each sample a pixel one spacing wide
    ratios = {}
    for name, (h, v) in {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}.items():
        panel = plot.panels[name]
        left, top, right, bottom = panel.bbox
        ratio = (right - left) / (bottom - top)
        ratios[name] = ratio
        assert ratio == pytest.approx(world[h] / world[v], rel=0.03), name
        # the axes show the world extent (and the panel is where it says: its frame
        # is drawn dark along the bbox's top and bottom edges)
        assert abs(panel.xlim[1] - panel.xlim[0]) == pytest.approx(world[h], rel=1e-6)
        assert abs(panel.ylim[1] - panel.ylim[0]) == pytest.approx(world[v], rel=1e-6)
        cols = slice(int(left) + 3, int(right) - 3)
        for row in (int(round(top)), int(round(bottom)) - 1):
            frame = img[row - 1 : row + 2, cols].min(axis=0).max(axis=-1)
            assert (frame < 80).mean() > 0.95, (name, row)
    # anisotropic: xz is wider per row of samples than the index counts say
    assert ratios["xz"] == pytest.approx(74 * 0.7227 / 20, rel=0.03)
    assert ratios["xz"] / (74 / 20) == pytest.approx(0.7227, rel=0.03)


def test_marked_levels_are_those_info_json_reports(tmp_path, capsys):
    path = dataset(AVF)
    assert main(["info", str(path), "--json"]) == 0
    reported = json.loads(capsys.readouterr().out)["suggested_levels"]
    out = tmp_path / "info.png"
    plot = write_info_plot(read_volume(path), out)
    assert plot.marked == reported  # exactly, not approximately
    # the command draws the same picture (so the same marks)
    cli_out = tmp_path / "cli.png"
    assert main(["info", str(path), "--plot", str(cli_out)]) == 0
    assert np.array_equal(pixels(cli_out), pixels(out))

    img = pixels(out)
    panel = plot.panels["histogram"]
    area, c0, r0 = crop(img, panel.bbox)
    left, _, right, _ = panel.bbox
    lo, hi = panel.xlim
    columns = {
        name: left + (value - lo) / (hi - lo) * (right - left) - c0
        for name, value in reported.items()
    }
    for name, x in columns.items():
        same = np.all(area == rgb(plot.colors[name]), axis=-1)
        hits = same.sum(axis=0)
        near = np.abs(np.arange(area.shape[1]) - x) <= 2.5
        # a line of its colour over (nearly) the whole height at the level's position ...
        assert hits[near].max() > 0.9 * area.shape[0], name
        # ... and that colour nowhere else in the histogram
        assert hits[~near].sum() == 0, name


# --- contour position on a synthetic ball ---------------------------------------------------


@pytest.mark.parametrize("radius", [6.0, 8.5])
def test_contour_pixels_lie_on_the_ball_in_every_slice(tmp_path, radius):
    volume, centre = ball_volume((41, 33, 15), (0.5, 0.75, 1.5), radius)
    out = tmp_path / "ball.png"
    plot = write_info_plot(volume, out, level=0.0)
    img = pixels(out)
    for name, (h, v) in {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}.items():
        panel = plot.panels[name]
        area, c0, r0 = crop(img, panel.bbox)
        rows, cols = np.nonzero(contour_mask(area))
        assert len(rows) > 50, name
        left, top, right, bottom = panel.bbox
        px = (right - left) / (panel.xlim[1] - panel.xlim[0])  # pixels per world unit
        py = (bottom - top) / abs(panel.ylim[1] - panel.ylim[0])
        assert px == pytest.approx(py, rel=0.02), name  # equal scales across and up
        cx, cy = panel.to_pixel(centre[h], centre[v])
        dist = np.hypot(cols + c0 + 0.5 - cx, rows + r0 + 0.5 - cy)
        # every contour pixel on the circle of the ball's radius (line width ~2 px)
        assert np.abs(dist - radius * px).max() < 2.5, name
        # and all around it, as a circle in world units (not an index-space ellipse)
        assert np.ptp(cols) == pytest.approx(2 * radius * px, abs=4), name
        assert np.ptp(rows) == pytest.approx(2 * radius * py, abs=4), name


def test_lazy_grid_slices_are_read_slab_by_slab(tmp_path, monkeypatch):
    """A volume read from its file gives the same slices without being read whole."""
    volume, _ = ball_volume((13, 11, 9), (1.0, 1.0, 2.0), 4.0)
    raw = tmp_path / "v.raw"
    raw.write_bytes(np.asarray(volume.data).T.astype("<f4").tobytes())
    grid = RawGrid(raw, np.dtype("<f4"), (13, 11, 9))
    monkeypatch.setattr("isoconvert.volume._CHUNK_SAMPLES", 13 * 11 * 2)  # 2 layers a slab

    def whole(*args, **kwargs):
        raise AssertionError("the whole volume was read")

    monkeypatch.setattr(RawGrid, "__array__", whole)
    lazy = Volume(grid, spacing=(1.0, 1.0, 2.0))
    got = {view.name: view.samples for view in middle_slices(lazy)}
    want = {view.name: view.samples for view in middle_slices(volume)}
    assert got.keys() == {"xy", "xz", "yz"}
    for name in got:
        assert np.array_equal(got[name], want[name]), name
    assert np.array_equal(want["xz"], np.asarray(volume.data)[:, 5, :])


def test_a_2d_image_gets_the_histogram_and_the_image_with_its_contour(tmp_path):
    y, x = np.mgrid[0:30, 0:50]
    image = 10.0 - np.hypot(x - 25, y - 15)  # the level-0 contour: a circle of radius 10
    volume = Volume.from_zyx(image.astype(np.float32), spacing=(0.5, 0.5))
    out = tmp_path / "image.png"
    plot = write_info_plot(volume, out, level=0.0)
    assert set(plot.panels) == {"histogram", "xy"}
    panel = plot.panels["xy"]
    img = pixels(out)
    area, c0, r0 = crop(img, panel.bbox)
    rows, cols = np.nonzero(contour_mask(area))
    cx, cy = panel.to_pixel(12.5, 7.5)
    px = (panel.bbox[2] - panel.bbox[0]) / 25.0
    dist = np.hypot(cols + c0 + 0.5 - cx, rows + r0 + 0.5 - cy)
    assert len(rows) > 50 and np.abs(dist - 5.0 * px).max() < 2.5


def test_level_by_name_and_a_slice_without_contour(tmp_path):
    volume, _ = ball_volume((21, 21, 21), (1.0, 1.0, 1.0), 5.0)
    plot = write_info_plot(volume, tmp_path / "a.png", level="p90")
    assert plot.level == plot.marked["p90"]
    plot = write_info_plot(volume, tmp_path / "b.png")  # default: the first, otsu
    assert plot.level == plot.marked["otsu"]
    # a level only the corner samples cross: the middle slices have no contour
    corner = float(np.asarray(volume.data).min()) + 0.01
    plot = write_info_plot(volume, tmp_path / "c.png", level=corner)
    assert plot.segments == {"xy": 0, "xz": 0, "yz": 0}
    img = pixels(tmp_path / "c.png")
    area, _, _ = crop(img, plot.panels["xy"].bbox)
    assert not contour_mask(area).any()


# --- errors: one line, non-zero exit, no file ----------------------------------------------


SPHERE = "sample_volumes/sphere.nrrd"


@pytest.mark.parametrize(
    "level, message",
    [("1e9", "outside the volume's values"), ("-5", "outside"), ("abc", "must be a number")],
)
def test_a_bad_level_is_one_line_and_leaves_no_file(tmp_path, capsys, level, message):
    from conftest import SAMPLES

    out = tmp_path / "info.png"
    code = main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(out), "--level", level])
    err = capsys.readouterr().err
    assert code == 1 and message in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_an_unwritable_output_is_one_line_and_leaves_no_file(tmp_path, capsys):
    from conftest import SAMPLES

    code = main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(tmp_path / "no" / "a.png")])
    err = capsys.readouterr().err
    assert code == 1 and "does not exist" in err and err.count("\n") == 1
    # an existing file is kept unless --force
    existing = tmp_path / "old.png"
    existing.write_bytes(b"old")
    assert main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(existing)]) == 1
    assert existing.read_bytes() == b"old"
    assert main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(existing), "-f"]) == 0
    assert existing.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_read_only_folder_is_one_line_and_leaves_no_file(tmp_path, capsys):
    from conftest import SAMPLES

    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        code = main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(locked / "a.png")])
        err = capsys.readouterr().err
        if code == 0:
            pytest.skip("running as root: permissions do not stop writing")
        assert code == 1 and "cannot write" in err and err.count("\n") == 1
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)


def test_a_failure_while_drawing_leaves_no_file(tmp_path, monkeypatch):
    import isoconvert.infoplot as infoplot

    def broken(*args, **kwargs):
        raise IsoconvertError("broken on purpose")

    monkeypatch.setattr(infoplot, "render", broken)
    volume, _ = ball_volume((9, 9, 9), (1.0, 1.0, 1.0), 3.0)
    with pytest.raises(IsoconvertError, match="broken on purpose"):
        write_info_plot(volume, tmp_path / "a.png")
    assert list(tmp_path.iterdir()) == []


def test_missing_matplotlib_is_one_line_naming_the_extra(tmp_path, monkeypatch, capsys):
    from conftest import SAMPLES

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import fails
    with pytest.raises(IsoconvertError, match=re.escape(extra_hint("plot"))):
        require_matplotlib()
    out = tmp_path / "a.png"
    assert main(["info", str(SAMPLES / "sphere.nrrd"), "--plot", str(out)]) == 1
    err = capsys.readouterr().err
    assert extra_hint("plot") in err and err.count("\n") == 1
    assert not out.exists()


def test_level_needs_plot(capsys):
    from conftest import SAMPLES

    assert main(["info", str(SAMPLES / "sphere.nrrd"), "--level", "3"]) == 1
    assert "--plot" in capsys.readouterr().err


def test_contour_colour_is_not_in_the_grey_slices():
    """The contour check above relies on magenta being absent from grey images."""
    assert contour_mask(np.array([[[g, g, g] for g in range(256)]])).sum() == 0
    assert contour_mask(rgb(CONTOUR_COLOR)[None, None, :])[0, 0]
