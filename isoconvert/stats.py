"""Histogram, Otsu threshold and suggested isovalues, without extracting."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .volume import slabs, value_range

_FLOAT_BINS = 1024


@dataclass(frozen=True)
class Histogram:
    """Counts of samples per bin.

    Attributes
    ----------
    edges : (B + 1,) float64
        Bin edges; for integer data, bin b holds exactly the value ``edges[b]``.
    counts : (B,) int64
    integer : bool
        Whether the samples are integers (one bin per value).
    nonfinite : int
        NaN/Inf samples, left out of the counts.
    """

    edges: np.ndarray
    counts: np.ndarray
    integer: bool
    nonfinite: int

    @property
    def centers(self) -> np.ndarray:
        if self.integer:
            return self.edges[:-1]
        return 0.5 * (self.edges[:-1] + self.edges[1:])

    def percentile(self, q: float) -> float:
        """The value below which ``q`` percent of the samples lie (bin accuracy)."""
        cum = np.cumsum(self.counts)
        b = int(np.searchsorted(cum, q / 100.0 * cum[-1]))
        return float(self.centers[min(b, len(self.counts) - 1)])


def histogram(data: np.ndarray) -> Histogram:
    """Histogram of finite samples: one bin per value for integers with a range of at most
    65536 values, else 1024 equal bins. Scans slab by slab (no full-size temporary)."""
    rng = value_range(data)
    if not np.isfinite(rng.min):
        return Histogram(np.array([0.0, 1.0]), np.zeros(1, np.int64), False, rng.nonfinite)
    lo, hi = rng.min, rng.max
    integer = np.issubdtype(data.dtype, np.integer) and hi - lo < 65536
    if integer:
        counts = np.zeros(int(hi - lo) + 1, dtype=np.int64)
        for slab in slabs(data):
            counts += np.bincount(
                (slab.ravel() - np.int64(lo)).astype(np.intp), minlength=len(counts)
            )
        edges = np.arange(lo, hi + 2, dtype=np.float64)
        return Histogram(edges, counts, True, 0)
    edges = np.linspace(lo, hi if hi > lo else lo + 1, _FLOAT_BINS + 1)
    counts = np.zeros(_FLOAT_BINS, dtype=np.int64)
    for slab in slabs(data):
        values = slab[np.isfinite(slab)] if rng.nonfinite else slab
        counts += np.histogram(values, bins=edges)[0]
    return Histogram(edges, counts, False, rng.nonfinite)


def otsu_level(hist: Histogram) -> float:
    """Otsu's threshold: the cut maximizing the between-class variance.

    Returned as a level for the sign rule (positive = value >= level): the
    midpoint between the last value of the lower class and the next bin, so
    for integer data it is a half-integer that no sample equals.
    """
    counts = hist.counts.astype(np.float64)
    centers = hist.centers
    if len(counts) < 2:
        return float(centers[0])
    w0 = np.cumsum(counts)[:-1]
    w1 = counts.sum() - w0
    m = np.cumsum(counts * centers)[:-1]
    mu0 = m / np.where(w0 > 0, w0, 1)
    mu1 = (m[-1] + counts[-1] * centers[-1] - m) / np.where(w1 > 0, w1, 1)
    between = w0 * w1 * (mu0 - mu1) ** 2
    # between[b]: lower class = bins 0..b. Ties (flat plateaus) take the middle.
    best = np.flatnonzero(between == between.max())
    b = int(best[len(best) // 2])
    return float(0.5 * (centers[b] + centers[b + 1]))


def suggested_levels(hist: Histogram) -> dict[str, float]:
    """Otsu and a few percentiles, as levels no integer sample equals."""
    levels = {"otsu": otsu_level(hist)}
    for q in (50, 90, 99):
        value = hist.percentile(q)
        if hist.integer:
            # halfway to a neighbour, inside the range
            value += 0.5 if value + 1 <= hist.edges[-2] else -0.5
        levels[f"p{q}"] = value
    return levels
