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


# --- issue 8: any finite range, up to the largest doubles ------------------------------------

BIGGEST = float(np.finfo(np.float64).max)


def huge_volume(rng: np.random.Generator, shape=(12, 10, 8)) -> np.ndarray:
    """(X, Y, Z) float64 from -1.7e308 to 1.7e308 (both present) and values between."""
    data = 2.0 * rng.uniform(-0.85e308, 0.85e308, size=shape)  # halves: no overflow
    data.flat[0], data.flat[1] = -1.7e308, 1.7e308
    return data


def bimodal_huge(rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
    """(X, Y, Z) float64: a cluster in [-1.7e308, -1.5e308] and one in [1.5e308, 1.7e308];
    also the top of the lower cluster and the bottom of the upper one."""
    low = rng.uniform(-1.7e308, -1.5e308, size=700)
    high = rng.uniform(1.5e308, 1.7e308, size=500)
    low[0], high[0] = -1.7e308, 1.7e308
    data = rng.permutation(np.concatenate([low, high])).reshape(12, 10, 10)
    return data, float(low.max()), float(high.min())


def test_histogram_and_levels_are_finite_near_the_largest_doubles():
    data = huge_volume(np.random.default_rng(8))
    hist = histogram(data)
    assert np.all(np.isfinite(hist.edges)) and np.all(np.diff(hist.edges) >= 0)
    assert hist.edges[0] == -1.7e308 and hist.edges[-1] == 1.7e308
    assert hist.counts.sum() == data.size
    assert np.all(np.isfinite(hist.centers))
    assert np.all((hist.centers > hist.edges[:-1]) & (hist.centers < hist.edges[1:]))
    levels = suggested_levels(hist)
    assert all(np.isfinite(v) and -1.7e308 < v < 1.7e308 for v in levels.values())
    assert levels["p50"] < levels["p90"] < levels["p99"]
    # the same as for the volume scaled down to an ordinary range, scaled back up
    small = suggested_levels(histogram(data / 1e300))
    for name, value in levels.items():
        assert value == pytest.approx(small[name] * 1e300, rel=1e-9, abs=1e297)


def test_otsu_separates_two_clusters_near_the_largest_doubles():
    from isoconvert.extract import resolve_level
    from isoconvert.volume import Volume

    data, low_max, high_min = bimodal_huge(np.random.default_rng(3))
    level = otsu_level(histogram(data))
    assert low_max < level <= high_min
    # --level auto goes the same way
    assert resolve_level(Volume(data), "auto", None) == level


def test_equal_bins_cover_every_finite_range():
    from isoconvert.stats import equal_bins

    for lo, hi in [(-BIGGEST, BIGGEST), (-1.7e308, 1.7e308), (-BIGGEST, 0.0), (1e308, BIGGEST)]:
        edges = equal_bins(lo, hi, 1024)
        assert edges.shape == (1025,) and edges[0] == lo and edges[-1] == hi
        assert np.all(np.isfinite(edges)) and np.all(np.diff(edges / 2) > 0)
        steps = np.diff(edges / 2)
        assert steps.max() - steps.min() <= 1e-9 * steps.max()  # equal widths
    # an ordinary range: exactly numpy's edges
    assert np.array_equal(equal_bins(-3.5, 1e4, 1024), np.linspace(-3.5, 1e4, 1025))
    # a constant volume gets a bin that float64 can tell apart, even at the top
    for value in (5.0, 1e300, BIGGEST, -BIGGEST):
        edges = equal_bins(value, value, 4)
        assert np.all(np.isfinite(edges)) and edges[-1] > edges[0] and value in edges[[0, -1]]


def otsu_in_values(hist) -> float:
    """Otsu's cut computed directly on the bin centers (as isoconvert did before
    issue 8), as a level for the sign rule."""
    counts, centers = hist.counts.astype(np.float64), hist.centers
    w0 = np.cumsum(counts)[:-1]
    w1 = counts.sum() - w0
    sums = np.cumsum(counts * centers)
    mu0 = sums[:-1] / np.maximum(w0, 1)
    mu1 = (sums[-1] - sums[:-1]) / np.maximum(w1, 1)
    between = w0 * w1 * (mu0 - mu1) ** 2
    best = np.flatnonzero(between == between.max())
    b = int(best[len(best) // 2])
    return float(0.5 * (centers[b] + centers[b + 1]))


def ordinary_bimodal(seed: int) -> np.ndarray:
    """(20, 20, 25) float64: two normal clusters, scaled and shifted at random."""
    rng = np.random.default_rng(seed)
    data = np.concatenate(
        [rng.normal(0, 1, 6000), rng.normal(rng.uniform(3, 9), rng.uniform(0.5, 2), 4000)]
    )
    return (10.0 ** rng.uniform(-3, 6) * data + rng.uniform(-1e3, 1e3)).reshape(20, 20, 25)


@pytest.mark.parametrize("seed", range(6))
def test_float_levels_on_ordinary_ranges_are_unchanged(seed):
    """On ordinary ranges, Otsu on bin positions gives the cut Otsu on values gave
    (within one bin; in practice the same), and percentiles stay within one bin;
    the same data stretched to the largest doubles give the same levels, stretched."""
    data = ordinary_bimodal(seed)
    hist = histogram(data)
    width = (data.max() - data.min()) / 1024
    assert otsu_level(hist) == pytest.approx(otsu_in_values(hist), abs=width)
    levels = suggested_levels(hist)
    for q in (50, 90, 99):
        exact = np.percentile(data, q, method="inverted_cdf")
        assert levels[f"p{q}"] == pytest.approx(exact, abs=width)
    stretch = 1.7e308 / np.abs(data).max()
    stretched = suggested_levels(histogram(data * stretch))
    for name, value in levels.items():
        assert stretched[name] / stretch == pytest.approx(value, abs=width)


@pytest.mark.parametrize("scale", [1.0, 37.5, 2.5e5])
def test_float_otsu_is_within_one_bin_of_scikit_image(scale):
    filters = pytest.importorskip("skimage.filters")
    rng = np.random.default_rng(int(scale))
    data = scale * np.concatenate([rng.normal(0, 1, 6000), rng.normal(6, 1.5, 4000)])
    data = data.reshape(20, 20, 25)
    width = (data.max() - data.min()) / 1024
    theirs = filters.threshold_otsu(data, nbins=1024)
    assert otsu_level(histogram(data)) == pytest.approx(theirs, abs=width)
    # and where scikit-image's sums would overflow, ours still finds that cut
    stretch = 1.7e308 / np.abs(data).max()
    assert otsu_level(histogram(data * stretch)) / stretch == pytest.approx(theirs, abs=width)


def test_uint64_near_its_maximum_does_not_crash():
    top = np.iinfo(np.uint64).max
    data = np.array([top, top - 4, top - 3000, top - 3004], dtype=np.uint64).reshape(2, 2, 1)
    levels = suggested_levels(histogram(data))
    assert all(np.isfinite(v) for v in levels.values())
