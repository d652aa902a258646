"""GeoJSON writer for 2D contours (issue 11): read back with json (and shapely
when installed), compared with scikit-image's find_contours in world units."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
from conftest import SAMPLES

from isoconvert import Volume, convert, extract, read_volume, write_mesh
from isoconvert.cli import main
from isoconvert.errors import FormatError
from isoconvert.writers import WRITERS

measure = pytest.importorskip("skimage.measure")

SPACING = (0.3, 0.7)  # x, y: anisotropic, so a swapped axis shows
ORIGIN = (-4.0, 12.5)


def disk_field(ny: int = 40, nx: int = 50) -> np.ndarray:
    """(rows, cols) smooth field: a bright disk, a dark hole in it, and a bright
    disk cut by the image border (an open contour)."""
    y, x = np.mgrid[0:ny, 0:nx].astype(np.float64)
    field = np.exp(-((x - 20.3) ** 2 + (y - 18.7) ** 2) / 120.0)
    field -= 0.8 * np.exp(-((x - 21.1) ** 2 + (y - 19.2) ** 2) / 12.0)
    field += np.exp(-((x - 49.5) ** 2 + (y - 5.2) ** 2) / 40.0)
    return field


def read_features(path) -> list[dict]:
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["type"] == "FeatureCollection"
    for feature in data["features"]:
        assert feature["type"] == "Feature"
        assert feature["geometry"]["type"] == "LineString"
    return data["features"]


def signed_area(xy: np.ndarray) -> float:
    """Shoelace area of a closed ring (first point repeated), positive counter-clockwise."""
    x, y = xy[:, 0], xy[:, 1]
    return float(0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def length(xy: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())


def skimage_world(contour: np.ndarray) -> np.ndarray:
    """find_contours' (row, col) points in world (x, y)."""
    return np.column_stack(
        [ORIGIN[0] + contour[:, 1] * SPACING[0], ORIGIN[1] + contour[:, 0] * SPACING[1]]
    )


@pytest.fixture
def written(tmp_path):
    image = disk_field()
    level = 0.37  # no sample equals it, so vertices are placed exactly, as skimage places them
    assert not np.any(image == level)
    volume = Volume.from_zyx(image, spacing=SPACING, origin=ORIGIN, source="disk.nrrd")
    mesh = extract(volume, level, vertex_offset=0.0)
    path = write_mesh(mesh, tmp_path / "disk.geojson")
    return image, level, path


def test_registered_for_segments_only():
    writer = WRITERS.get("geojson")
    assert writer.suffixes == (".geojson",) and writer.cell_sizes == {2}
    assert not writer.has_binary


def test_matches_skimage_find_contours(written):
    image, level, path = written
    features = read_features(path)
    ours = [np.asarray(f["geometry"]["coordinates"]) for f in features]
    closed = [f["properties"]["closed"] for f in features]
    theirs = [skimage_world(c) for c in measure.find_contours(image, level)]
    their_closed = [bool(np.array_equal(c[0], c[-1])) for c in theirs]
    assert sorted(closed) == sorted(their_closed)
    assert closed.count(True) == 2 and closed.count(False) == 1
    assert all(xy.shape[1] == 2 for xy in ours)
    for xy, is_closed in zip(ours, closed, strict=True):
        assert np.array_equal(xy[0], xy[-1]) == is_closed
        # the skimage contour with the same points (as sets: start and direction may differ)
        key = {tuple(np.round(p, 9)) for p in xy}
        (match,) = [c for c in theirs if {tuple(np.round(p, 9)) for p in c} == key]
        assert len(match) == len(xy)
        assert length(xy) == pytest.approx(length(match), rel=1e-12)
        if is_closed:
            assert abs(signed_area(xy)) == pytest.approx(abs(signed_area(match)), rel=1e-12)


def test_orientation_higher_values_on_the_left(written):
    image, level, path = written
    rings = [
        np.asarray(f["geometry"]["coordinates"])
        for f in read_features(path)
        if f["properties"]["closed"]
    ]
    areas = sorted(signed_area(xy) for xy in rings)
    # the hole (dark inside) runs clockwise, the disk around it counter-clockwise
    assert areas[0] < 0 < areas[1]
    assert abs(areas[1]) > abs(areas[0])
    if importlib.util.find_spec("shapely"):
        from shapely.geometry import LinearRing

        assert sorted(LinearRing(xy).is_ccw for xy in rings) == [False, True]


def test_properties_and_provenance(written):
    _, level, path = written
    data = json.loads(path.read_text(encoding="utf-8"))
    for feature in data["features"]:
        props = feature["properties"]
        assert props["level"] == level and props["method"] == "squares"
        assert props["source"] == "disk.nrrd"
        assert isinstance(props["closed"], bool)
    extras = data["isoconvert"]
    assert extras["grid"]["shape"] == [50, 40]
    assert "not longitude and latitude" in extras["coordinates"]
    assert len(data["bbox"]) == 4


def test_nrrd_frame_and_cli(tmp_path):
    out = tmp_path / "fig.geojson"
    result = convert(SAMPLES / "figure_2_4.nrrd", out, 4.5)
    assert result.format == "geojson"
    features = read_features(out)
    assert sum(len(f["geometry"]["coordinates"]) - f["properties"]["closed"] for f in features) == (
        len(result.mesh.vertices)
    )
    volume = read_volume(SAMPLES / "figure_2_4.nrrd")
    for feature in features:
        for key in ("frame", "unit"):
            value = getattr(volume, key)
            assert feature["properties"].get(key) == value
    cli = tmp_path / "cli.geojson"
    assert main(["convert", str(SAMPLES / "figure_2_4.nrrd"), "-o", str(cli), "-l", "4.5"]) == 0
    assert json.loads(cli.read_text())["features"] == json.loads(out.read_text())["features"]


def test_slices_of_a_volume_have_three_coordinates(tmp_path):
    out = tmp_path / "slices.geojson"
    result = convert(SAMPLES / "sphere.nrrd", out, 100.5, method="squares", axis="z")
    features = read_features(out)
    points = np.concatenate([np.asarray(f["geometry"]["coordinates"]) for f in features])
    assert points.shape[1] == 3
    assert set(np.unique(points[:, 2])) == set(np.unique(result.mesh.vertices[:, 2]))
    assert all(f["properties"]["closed"] for f in features)
    for feature in features:  # each ring lies in one slice
        assert np.ptp(np.asarray(feature["geometry"]["coordinates"])[:, 2]) == 0


def test_triangles_are_refused_without_a_file(tmp_path, capsys):
    out = tmp_path / "surface.geojson"
    with pytest.raises(FormatError, match="geojson cannot hold triangles"):
        convert(SAMPLES / "sphere.nrrd", out, 100.5)
    assert not out.exists()
    assert main(["convert", str(SAMPLES / "sphere.nrrd"), "-o", str(out), "-l", "100.5"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "geojson" in err[0] and not out.exists()
    assert list(tmp_path.iterdir()) == []
