"""Linear interpolation on a bipolar edge (Wenger, Algorithm 1.1), shared by every kernel."""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, inline="always")
def edge_fraction(s0, s1, level, offset):
    """Where ``level`` lies between samples ``s0`` and ``s1`` (float64), as a
    fraction of the edge from ``s0``, clamped to ``[offset, 1 - offset]``.

    Samples of opposite sign near the largest doubles make ``s1 - s0``
    overflow to infinity; the same ratio is then taken at half scale, where
    nothing overflows.
    """
    d = s1 - s0
    if d - d == 0.0:  # finite
        t = (level - s0) / d
    else:
        t = (0.5 * level - 0.5 * s0) / (0.5 * s1 - 0.5 * s0)
    return min(max(t, offset), 1.0 - offset)
