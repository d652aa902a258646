"""Histogram, Otsu threshold and suggested isovalues, without extracting.

Everything here works over any finite range of values, up to the largest
doubles (about ±1.8e308): no step computes ``hi - lo`` or ``a + b`` of two
samples where that could overflow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import LevelError
from .volume import slabs, value_range

_FLOAT_BINS = 1024
#: Integers are counted one bin per value only where float64 holds each exactly.
_EXACT_INTEGERS = 2.0**53


def equal_bins(lo: float, hi: float, n: int) -> np.ndarray:
    """Edges of ``n`` equal bins from ``lo`` to ``hi``, for any finite ``lo <= hi``.

    As ``np.linspace(lo, hi, n + 1)`` where ``hi - lo`` is a finite double (then
    the result is exactly linspace's); where it overflows (``lo`` and ``hi`` near
    the largest doubles with opposite signs), the edges are found from the halves
    of ``lo`` and ``hi`` and doubled again, which is exact in binary. When
    ``hi <= lo`` (a constant volume) the bins span ``lo`` to ``lo + 1``, or the
    nearest wider span that float64 can tell from ``lo``.

    Parameters
    ----------
    lo, hi : float
        Finite ends of the range.
    n : int
        Number of bins, at least 1.

    Returns
    -------
    (n + 1,) float64
        Non-decreasing, finite edges; the first is ``lo``, the last ``hi`` (or
        the widened end).
    """
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"equal_bins needs finite ends, got {lo!r} .. {hi!r}")
    if n < 1:
        raise ValueError(f"equal_bins needs at least one bin, got {n}")
    if not hi > lo:
        lo, hi = _widen(lo)
    if np.isfinite(hi - lo):
        return np.linspace(lo, hi, n + 1)
    edges = 2.0 * np.linspace(lo / 2, hi / 2, n + 1)
    edges[0], edges[-1] = lo, hi
    return edges


def _widen(value: float) -> tuple[float, float]:
    """A span ``lo < hi`` holding ``value`` at its low end (its high end at the top)."""
    width = max(1.0, abs(value) * 2.0**-40)
    if np.isfinite(value + width):
        return value, value + width
    return value - width, value


def midpoint(a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray | float:
    """``(a + b) / 2`` without overflow; equal to ``0.5 * (a + b)`` wherever that is finite.

    Parameters
    ----------
    a, b : float or (N,) float64
        Finite values.

    Returns
    -------
    float or (N,) float64
    """
    # halving is exact in binary (away from subnormals), so this rounds once, as a + b does
    return 0.5 * np.asarray(a, dtype=np.float64) + 0.5 * np.asarray(b, dtype=np.float64)


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
    low, high : float
        The smallest and largest finite sample; NaN when there is none. (The
        bins of a constant volume span a made-up width beyond ``high``, so
        the range is this, not the edges.)

    A volume without finite samples has no bins: ``edges (1,)`` holding NaN,
    ``counts (0,)``.
    """

    edges: np.ndarray
    counts: np.ndarray
    integer: bool
    nonfinite: int
    low: float = math.nan
    high: float = math.nan

    @property
    def finite(self) -> int:
        """How many samples are counted (the finite ones)."""
        return int(self.counts.sum())

    @property
    def centers(self) -> np.ndarray:
        """The value each bin stands for, (B,) float64 (finite for any finite edges)."""
        if self.integer:
            return self.edges[:-1]
        return midpoint(self.edges[:-1], self.edges[1:])

    def percentile(self, q: float) -> float:
        """The value below which ``q`` percent of the samples lie (bin accuracy).

        Raises
        ------
        LevelError
            There is no finite sample.
        """
        if not self.finite:
            raise LevelError(no_levels_reason(self))
        cum = np.cumsum(self.counts)
        b = int(np.searchsorted(cum, q / 100.0 * cum[-1]))
        return float(self.centers[min(b, len(self.counts) - 1)])


def histogram(data: np.ndarray, nan_as: float | None = None) -> Histogram:
    """Histogram of the finite samples of ``data``.

    One bin per value for integers with a range of at most 65536 values (and
    magnitudes float64 holds exactly), else 1024 equal bins (:func:`equal_bins`,
    so any finite range works). Scans slab by slab (no full-size temporary).

    Parameters
    ----------
    data : (X, Y[, Z]) array of real numbers
    nan_as : float or None
        Count NaN/Inf samples as this value, as extraction with ``--nan-as``
        sees them (``--level auto``); None leaves them out (``nonfinite``).

    Returns
    -------
    Histogram
    """
    rng = value_range(data)
    if nan_as is not None and rng.nonfinite:
        return _histogram_nan_as(data, rng, float(nan_as))
    if not np.isfinite(rng.min):
        # no finite sample: no bins (a range such as 0 .. 1 would be made up)
        return Histogram(np.array([math.nan]), np.zeros(0, np.int64), False, rng.nonfinite)
    lo, hi = rng.min, rng.max
    integer = (
        np.issubdtype(data.dtype, np.integer)
        and hi - lo < 65536
        and max(abs(lo), abs(hi)) < _EXACT_INTEGERS
    )
    if integer:
        counts = np.zeros(int(hi - lo) + 1, dtype=np.int64)
        for slab in slabs(data):
            counts += np.bincount(
                (slab.ravel() - np.int64(lo)).astype(np.intp), minlength=len(counts)
            )
        edges = np.arange(lo, hi + 2, dtype=np.float64)
        return Histogram(edges, counts, True, 0, float(lo), float(hi))
    edges = equal_bins(lo, hi, _FLOAT_BINS)
    counts = np.zeros(_FLOAT_BINS, dtype=np.int64)
    for slab in slabs(data):
        values = slab[np.isfinite(slab)] if rng.nonfinite else slab
        # explicit edges: numpy searches them (no (hi - lo) scaling that could overflow)
        counts += np.histogram(values, bins=edges)[0]
    return Histogram(edges, counts, False, rng.nonfinite, float(lo), float(hi))


def _histogram_nan_as(data: np.ndarray, rng, nan_as: float) -> Histogram:
    """:func:`histogram` of float ``data`` whose NaN/Inf samples count as ``nan_as``."""
    if not math.isfinite(nan_as):
        raise LevelError(f"--nan-as takes a finite value, got {nan_as}")
    nan_as = float(data.dtype.type(nan_as))  # as extraction casts it
    lo = nan_as if not np.isfinite(rng.min) else min(rng.min, nan_as)
    hi = nan_as if not np.isfinite(rng.max) else max(rng.max, nan_as)
    edges = equal_bins(lo, hi, _FLOAT_BINS)
    counts = np.zeros(_FLOAT_BINS, dtype=np.int64)
    for slab in slabs(data):
        values = np.where(np.isfinite(slab), slab, slab.dtype.type(nan_as))
        counts += np.histogram(values, bins=edges)[0]
    return Histogram(edges, counts, False, 0, float(lo), float(hi))


def _value(v: float) -> str:
    """A sample value for a message: whole numbers in full (int64 samples near
    2**62 too), others as short as ``:g`` allows to 10 digits."""
    if float(v).is_integer() and abs(v) < 1e21:
        return str(int(v))
    return f"{v:.10g}"


def no_levels_reason(hist: Histogram) -> str | None:
    """Why no level gives a surface, or None when some level does.

    A level gives a surface when some samples are >= it and some are below
    (the sign rule), i.e. for ``low < level <= high``: none exists when there
    is no finite sample, or when every finite sample has one value.

    Parameters
    ----------
    hist : Histogram

    Returns
    -------
    str or None
        One sentence, without the file name (the caller has it).
    """
    if not hist.finite:
        return (
            f"no finite samples (all {hist.nonfinite:,} are NaN or infinite), so no value "
            "range and no level; --nan-as VALUE would make every sample that one value "
            "(a raw file: are --dtype and --endian right?)"
        )
    if hist.low < hist.high:
        return None
    if not hist.nonfinite:
        return f"all samples are {_value(hist.low)}: no isosurface at any level"
    return (
        f"all {hist.finite:,} finite samples are {_value(hist.low)} (the other "
        f"{hist.nonfinite:,} are NaN or infinite): no isosurface at any level, unless "
        "--nan-as gives those another value"
    )


def _within(value: float, hist: Histogram) -> float:
    """``value`` moved into ``(low, high]``, where every level gives a surface.

    Bins a few ulps wide (a range of a few representable values) can put a
    bin centre on ``low``; the nearest level above it then still splits.
    """
    if not value > hist.low:
        value = min(float(np.nextafter(hist.low, math.inf)), hist.high)
    return min(value, hist.high)


def otsu_level(hist: Histogram) -> float:
    """Otsu's threshold: the cut maximizing the between-class variance.

    Returned as a level for the sign rule (positive = value >= level): the
    midpoint between the last value of the lower class and the next bin, so
    for integer data it is a half-integer that no sample equals.

    The variance is computed on bin positions mapped affinely onto 0 .. B - 1
    (Otsu's cut does not change under an affine map of the values), so values
    near the largest doubles do not overflow; the cut is mapped back to values.

    Parameters
    ----------
    hist : Histogram
        B bins.

    Returns
    -------
    float
        The level, with ``hist.low < level <= hist.high``.

    Raises
    ------
    LevelError
        No level gives a surface (:func:`no_levels_reason` says why).
    """
    reason = no_levels_reason(hist)
    if reason is not None:
        raise LevelError(reason)
    counts = hist.counts.astype(np.float64)
    centers = hist.centers
    if len(counts) < 2:
        return float(centers[0])
    x = _positions(centers)
    w0 = np.cumsum(counts)[:-1]
    w1 = counts.sum() - w0
    m = np.cumsum(counts * x)[:-1]
    mu0 = m / np.where(w0 > 0, w0, 1)
    mu1 = (m[-1] + counts[-1] * x[-1] - m) / np.where(w1 > 0, w1, 1)
    between = w0 * w1 * (mu0 - mu1) ** 2
    # between[b]: lower class = bins 0..b. Ties (flat plateaus) take the middle.
    best = np.flatnonzero(between == between.max())
    b = int(best[len(best) // 2])
    return _within(float(midpoint(centers[b], centers[b + 1])), hist)


def _positions(centers: np.ndarray) -> np.ndarray:
    """Bin centers (B,) mapped affinely onto 0 .. B - 1 without overflow.

    For equal bins (all this module makes) these are the bin indices, up to
    rounding; for integer bins exactly.
    """
    offset = 0.5 * centers - 0.5 * centers[0]  # finite: a difference of halves
    span = offset[-1]
    if not span > 0:
        return np.arange(len(centers), dtype=np.float64)
    if span < (len(centers) - 1) / np.finfo(np.float64).max:
        # a subnormal span, whose reciprocal overflows: divided first (offsets <= span)
        return offset / span * (len(centers) - 1)
    return offset * ((len(centers) - 1) / span)


def suggested_levels(hist: Histogram) -> dict[str, float]:
    """Otsu and a few percentiles, as levels no integer sample equals.

    Parameters
    ----------
    hist : Histogram

    Returns
    -------
    dict of str to float
        ``otsu``, ``p50``, ``p90``, ``p99``, each with ``hist.low < level <=
        hist.high`` (so ``convert`` makes a surface at it); empty when no level
        gives a surface (:func:`no_levels_reason`).
    """
    if no_levels_reason(hist) is not None:
        return {}
    levels = {"otsu": otsu_level(hist)}
    for q in (50, 90, 99):
        value = hist.percentile(q)
        if hist.integer:
            # halfway to a neighbour, inside the range
            value += 0.5 if value + 1 <= hist.edges[-2] else -0.5
        levels[f"p{q}"] = _within(value, hist)
    return levels


def text_histogram(hist: Histogram, rows: int = 12, width: int = 40) -> list[str]:
    """Bars of sample counts in ``rows`` equal value ranges from ``low`` to ``high``
    (log scale, as CT is skewed), as ``info`` prints them.

    A constant volume gets one row (its value), a volume without finite samples none:
    no row shows a value the volume does not hold.

    Parameters
    ----------
    hist : Histogram
    rows, width : int
        Rows, and characters of the longest bar.

    Returns
    -------
    list of str
    """
    if not hist.finite:
        return []
    if not hist.low < hist.high:
        return [f"{_value(hist.low):>10} {'#' * width} {hist.finite:,}"]
    bounds = equal_bins(hist.low, hist.high, rows)
    which = np.clip(np.searchsorted(bounds, hist.centers, side="right") - 1, 0, rows - 1)
    counts = np.bincount(which, weights=hist.counts, minlength=rows)
    scale = np.log1p(counts) / max(np.log1p(counts).max(), 1e-12)
    bars = ["#" * int(round(s * width)) for s in scale]
    return [
        f"{bounds[r]:>10.4g} .. {bounds[r + 1]:<10.4g} {bars[r]:<{width}} {int(counts[r]):,}"
        for r in range(rows)
    ]
