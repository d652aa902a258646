"""Suggested levels against scikit-image's Otsu and numpy's percentiles."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SAMPLES, dataset

from isoconvert import read_volume
from isoconvert.stats import histogram, otsu_level, suggested_levels


@pytest.mark.parametrize(
    "path",
    [
        lambda: SAMPLES / "sphere.nrrd",
        lambda: dataset("engine_256x256x128_uint8.raw"),
        lambda: dataset("headsq_vtk/quarter.nhdr"),
    ],
)
def test_otsu_matches_scikit_image_on_integer_data(path):
    filters = pytest.importorskip("skimage.filters")
    data = read_volume(path()).data
    ours = otsu_level(histogram(data))
    # scikit-image puts values <= t in the lower class; our sign rule puts values
    # >= level in the upper one, so the same split is level = t + 0.5
    theirs = filters.threshold_otsu(np.asarray(data), nbins=int(data.max()) - int(data.min()) + 1)
    assert ours == pytest.approx(np.floor(theirs) + 0.5)
    assert not (data == ours).any()


def test_otsu_on_float_data_is_close_to_scikit_image():
    filters = pytest.importorskip("skimage.filters")
    data = read_volume(dataset("hydrogen_vtk_64x64x64_float32.raw")).data
    ours = otsu_level(histogram(data))
    theirs = filters.threshold_otsu(np.asarray(data), nbins=1024)
    assert ours == pytest.approx(theirs, abs=float(data.max() - data.min()) / 1024)


def test_percentiles_match_numpy_and_stay_inside_the_range():
    data = read_volume(SAMPLES / "sphere.nrrd").data
    levels = suggested_levels(histogram(data))
    for q in (50, 90, 99):
        exact = np.percentile(data, q, method="inverted_cdf")
        assert abs(levels[f"p{q}"] - exact) == 0.5
        assert data.min() < levels[f"p{q}"] <= data.max()


def test_histogram_counts_every_sample_and_skips_nan():
    data = np.array([[[0.0, 1.0], [np.nan, 3.0]], [[4.0, 5.0], [6.0, np.inf]]])
    hist = histogram(data)
    assert hist.counts.sum() == 6 and hist.nonfinite == 2
