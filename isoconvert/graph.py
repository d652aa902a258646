"""Graph helpers in plain numpy (no numba: `check` must start fast)."""

from __future__ import annotations

import numpy as np


def connected_components(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Label the connected components of a graph with ``n`` nodes and edges (u, v).

    Returns
    -------
    (n,) int64
        For each node, the smallest node index in its component.

    Notes
    -----
    Min-label hooking with pointer jumping: every round hooks each edge's larger
    root onto its smaller one, then flattens the trees; rounds stop when no edge
    joins two labels. Each round is a few vectorized passes over the edges.
    """
    labels = np.arange(n, dtype=np.int64)
    u = np.asarray(u, dtype=np.int64)
    v = np.asarray(v, dtype=np.int64)
    while len(u):
        lu, lv = labels[u], labels[v]
        differ = lu != lv
        if not differ.any():
            break
        u, v = u[differ], v[differ]
        lu, lv = lu[differ], lv[differ]
        np.minimum.at(labels, np.maximum(lu, lv), np.minimum(lu, lv))
        while True:
            jumped = labels[labels]
            if np.array_equal(jumped, labels):
                break
            labels = jumped
    return labels


def mix64(x: np.ndarray) -> np.ndarray:
    """splitmix64's finalizer: spreads every input bit over the whole word."""
    with np.errstate(over="ignore"):
        x = x.astype(np.uint64, copy=True)
        x ^= x >> np.uint64(30)
        x *= np.uint64(0xBF58476D1CE4E5B9)
        x ^= x >> np.uint64(27)
        x *= np.uint64(0x94D049BB133111EB)
        x ^= x >> np.uint64(31)
    return x


def row_groups(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group equal rows of a (N, k) array of 64-bit values.

    Returns
    -------
    order : (N,) int64
        A permutation putting equal rows next to each other.
    new : (N,) bool
        True where ``rows[order]`` starts a new group.

    Notes
    -----
    Sorts one 64-bit hash of each row (far faster than ``np.unique(axis=0)`` or
    a k-key lexsort). Should two different rows share a hash and end up
    interleaved, it falls back to the exact lexsort.
    """
    n = len(rows)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, bool)
    bits = np.ascontiguousarray(rows).view(np.uint64).reshape(n, -1)
    h = mix64(bits[:, 0])
    for col in range(1, bits.shape[1]):
        h = mix64(h ^ bits[:, col])
    order = np.argsort(h, kind="quicksort")
    s = bits[order]
    same = (s[1:] == s[:-1]).all(axis=1)
    hs = h[order]
    if np.any((hs[1:] == hs[:-1]) & ~same):
        order = np.lexsort(bits.T[::-1])
        s = bits[order]
        same = (s[1:] == s[:-1]).all(axis=1)
    new = np.ones(n, dtype=bool)
    new[1:] = ~same
    return order, new


def group_sizes(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort ``keys`` and find equal runs.

    Returns
    -------
    order : (N,) int64
        ``keys[order]`` is sorted (equal keys in no particular order: the
        unstable sort is several times faster).
    starts : (G,) int64
        Where each run of equal keys begins in the sorted order.
    sizes : (G,) int64
        Length of each run.
    """
    order = np.argsort(keys, kind="quicksort")
    sorted_keys = keys[order]
    if len(keys) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return order, empty, empty
    change = np.flatnonzero(sorted_keys[1:] != sorted_keys[:-1]) + 1
    starts = np.concatenate([[0], change]).astype(np.int64)
    sizes = np.diff(np.concatenate([starts, [len(keys)]])).astype(np.int64)
    return order, starts, sizes
