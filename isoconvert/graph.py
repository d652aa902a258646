"""Graph helpers: plain numpy, and the compiled kernels of ``isoconvert._native``
that merge positions and build edge tables (no numba: `check` must start fast)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .threads import kernel_threads

_INT32_MAX = np.iinfo(np.int32).max


def connected_components(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Label the connected components of a graph with ``n`` nodes and edges (u, v).

    Returns
    -------
    (n,) int64
        For each node, the smallest node index in its component.

    Notes
    -----
    Union-find in the compiled ``connected_components`` (src/graph.cpp), the
    larger root always linked under the smaller.
    """
    from . import _native

    labels = np.empty(n, dtype=np.int64)
    _native.connected_components(
        int(n),
        np.ascontiguousarray(u, dtype=np.int64).reshape(-1),
        np.ascontiguousarray(v, dtype=np.int64).reshape(-1),
        labels,
    )
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


def row_hashes(rows: np.ndarray) -> np.ndarray:
    """(N,) uint64: one :func:`mix64` hash of each row of a (N, k) array of 64-bit
    values (equal rows, equal hashes)."""
    if not len(rows):
        return np.zeros(0, dtype=np.uint64)
    bits = np.ascontiguousarray(rows).view(np.uint64).reshape(len(rows), -1)
    h = mix64(bits[:, 0])
    for col in range(1, bits.shape[1]):
        h = mix64(h ^ bits[:, col])
    return h


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
    h = row_hashes(bits)
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


# --- compiled kernels ----------------------------------------------------------------------


def index_dtype(*counts: int) -> np.dtype:
    """int32 when every index the kernels form (below each of ``counts``) fits
    in it, else int64: half the memory traffic for any mesh that allows it."""
    return np.dtype(np.int32 if max(counts, default=0) <= _INT32_MAX else np.int64)


@dataclass(frozen=True)
class MergedPositions:
    """Vertices at equal positions, from :func:`merge_positions`.

    Attributes
    ----------
    rep : (V,) int32 or int64
        For each vertex, the smallest index of a vertex at the same position.
    key : (V,) uint64
        Equal for equal positions; ordering the distinct positions by key is
        the order :func:`row_groups` gives them (by :func:`mix64` hash, or
        lexicographically when two positions share a hash).
    unique : int
        Number of distinct positions.
    lexicographic : bool
        Keys are ranks in lexicographic order (two positions shared a hash).
    magnitude : float
        The largest absolute finite coordinate (0.0 when there is none).
    """

    rep: np.ndarray
    key: np.ndarray
    unique: int
    lexicographic: bool
    magnitude: float

    def ranks(self, vertices: np.ndarray) -> np.ndarray:
        """(K,) int64 number of each vertex's position in key order, 0..unique-1
        (what :func:`row_groups` numbers it); sorts the keys unless they are ranks."""
        if self.lexicographic:
            return self.key[vertices].astype(np.int64)
        firsts = self.rep == np.arange(len(self.rep))
        return np.searchsorted(np.sort(self.key[firsts]), self.key[vertices]).astype(np.int64)


def merge_positions(
    vertices: np.ndarray, threads: int | None = None, dtype: np.dtype | None = None
) -> MergedPositions:
    """Find vertices at exactly equal positions (-0.0 and 0.0 are equal).

    Parameters
    ----------
    vertices : (V, 3) float64
    threads : int, optional
        Default :func:`kernel_threads`.
    dtype : int32 or int64, optional
        Of ``rep``; default :func:`index_dtype` of V.

    Returns
    -------
    MergedPositions
    """
    from . import _native

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    itype = np.dtype(dtype or index_dtype(len(v)))
    merge = _native.merge_positions_int32 if itype == np.int32 else _native.merge_positions_int64
    rep, key, unique, lexicographic, magnitude = merge(v, threads or kernel_threads())
    return MergedPositions(rep, key, int(unique), bool(lexicographic), float(magnitude))


def topology(triangles: np.ndarray, n_vertices: int) -> dict:
    """The compiled topology pass of the mesh report, on vertex indices alone.

    Parameters
    ----------
    triangles : (F, 3) int
        Vertex indices in ``0..n_vertices-1`` (not checked here).
    n_vertices : int

    Returns
    -------
    dict
        ``all_edges`` (E, 2) and ``all_counts`` (E,): every undirected edge and
        its multiplicity; ``boundary``, ``non_manifold_edges`` and
        ``inconsistent`` (N, 2) edges; ``non_manifold_vertices`` (M,) vertices
        whose triangles form more than one fan; and the rest of the report's
        table. Triangles that repeat a vertex are skipped.
    """
    from . import _native

    itype = index_dtype(n_vertices, 3 * len(triangles))
    tv = np.ascontiguousarray(triangles, dtype=itype).reshape(-1, 3)
    key = np.zeros(n_vertices, np.uint64)
    return _native.topology(tv, n_vertices, key, kernel_threads(), True, wide=itype == np.int64)


def edge_table(triangles: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The undirected edges of triangles and how many triangles use each.

    Triangles that repeat a vertex index are skipped (they are no 2-cells).

    Parameters
    ----------
    triangles : (F, 3) int
        Vertex indices in ``0..n_vertices-1`` (not checked here).
    n_vertices : int

    Returns
    -------
    edges : (E, 2) int64
        Each edge once, lower index first, ordered by lower then higher index.
    counts : (E,) int64
        Its multiplicity: 1 on a boundary, 2 inside a manifold, more where it
        is not.
    """
    table = topology(triangles, n_vertices)
    edges, counts = table["all_edges"], table["all_counts"]
    order = np.lexsort((edges[:, 1], edges[:, 0]))  # the kernel lists them by lower end only
    return edges[order], counts[order]


#: Pairs (of a row and one of its items) made at once by :func:`ragged_pairs`:
#: bounds the memory of the temporaries built from them.
PAIR_CHUNK = 4_000_000


def ragged_pairs(counts: np.ndarray, chunk: int = PAIR_CHUNK):
    """Enumerate the (row, k-th item) pairs of ragged rows, whole rows at a time.

    Row ``r`` has ``counts[r]`` items; the pairs come in chunks of about
    ``chunk`` (more only when a single row has more).

    Parameters
    ----------
    counts : (R,) int64
    chunk : int

    Yields
    ------
    first, stop : int
        The rows ``first <= r < stop`` of this chunk.
    row : (P,) int64
        The row of each pair.
    k : (P,) int64
        Its rank within its row (0 .. counts[row] - 1).
    """
    counts = np.asarray(counts, dtype=np.int64)
    if not len(counts):
        return
    ends = np.cumsum(counts)
    bounds = np.searchsorted(ends, np.arange(0, ends[-1], chunk), side="right")
    bounds = np.unique(np.concatenate([[0], bounds, [len(counts)]]))
    for first, stop in zip(bounds[:-1], bounds[1:], strict=True):
        c = counts[first:stop]
        row = np.repeat(np.arange(first, stop), c)
        k = np.arange(len(row)) - np.repeat(np.cumsum(c) - c, c)
        yield int(first), int(stop), row, k
