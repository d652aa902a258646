"""Mesh: an indexed (face-vertex) surface or contour, book section 1.7.3."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Mesh:
    """Indexed triangles (or line segments) and their vertices.

    Attributes
    ----------
    vertices : (V, 3) float64
        Vertex positions in world units.
    cells : (C, 3) or (C, 2) int64
        Triangles (right-hand normals point from the positive to the negative
        side) or segments, as indices into ``vertices``.
    edge_ids : (V,) int64 or None
        For extracted meshes, the global id of the grid edge each vertex lies
        on (``3 * (i + X * (j + Y * k)) + axis`` for cubes). Blocks of a volume
        extracted separately share vertices exactly through these ids.
    info : dict
        Provenance (method, level, source) written into file headers.
    normals : (V, 3) float32 or None
        Unit normals at the vertices, pointing like the triangles' (from the
        positive to the negative side); see :func:`isoconvert.vertex_normals`.
    values : (V,) float32 or None
        A scalar at each vertex (e.g. another volume sampled there, see
        :func:`isoconvert.vertex_values`); NaN where it has none.
    cell_labels : (C, 2) int64 or None
        The labels on the two sides of each cell (label volumes): normals point
        from the label in column 0 to the one in column 1.
    """

    vertices: np.ndarray
    cells: np.ndarray
    edge_ids: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    normals: np.ndarray | None = None
    values: np.ndarray | None = None
    cell_labels: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @property
    def is_triangles(self) -> bool:
        return self.cells.ndim == 2 and self.cells.shape[1] == 3

    def flipped(self) -> Mesh:
        """The same mesh with every cell's orientation reversed (and its normals)."""
        normals = None if self.normals is None else -self.normals
        labels = None if self.cell_labels is None else self.cell_labels[:, ::-1].copy()
        return Mesh(
            self.vertices,
            self.cells[:, ::-1].copy(),
            self.edge_ids,
            dict(self.info),
            normals,
            self.values,
            labels,
        )

    def triangle_normals(self) -> np.ndarray:
        """(C, 3) float64 unit normals (right-hand rule); zero for zero-area triangles."""
        v = self.vertices
        t = self.cells
        n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        length = np.linalg.norm(n, axis=1)
        nonzero = length > 0
        n[nonzero] /= length[nonzero, np.newaxis]
        n[~nonzero] = 0.0
        return n

    def vertex_normals(self) -> np.ndarray:
        """(V, 3) float64 unit area-weighted normals of the triangles around each
        vertex; zero for vertices in no triangle of non-zero area."""
        from . import _native

        out = np.empty((len(self.vertices), 3), dtype=np.float64)
        _native.vertex_normals(
            np.ascontiguousarray(self.vertices, dtype=np.float64),
            np.ascontiguousarray(self.cells, dtype=np.int64),
            out,
        )
        return out

    def area(self) -> float:
        """Total area of the triangles."""
        v = self.vertices
        t = self.cells
        cross = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        return float(0.5 * np.linalg.norm(cross, axis=1).sum())

    def signed_volume(self) -> float:
        """Volume enclosed by a closed triangle mesh; positive when normals point outward."""
        v = self.vertices
        t = self.cells
        # Divergence theorem over tetrahedra from the centroid (better conditioned than the origin).
        c = v.mean(axis=0) if len(v) else np.zeros(3)
        a, b, d = v[t[:, 0]] - c, v[t[:, 1]] - c, v[t[:, 2]] - c
        return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)


def polylines(segments: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Chain directed segments into polylines.

    Parameters
    ----------
    segments : (C, 2) int
        Segments as vertex indices, each running from its first to its second.

    Returns
    -------
    list of ((n,) int64, bool)
        Vertex indices of each polyline and whether it is closed (its last
        vertex joins its first, which is not repeated). A vertex where more
        than one segment starts or ends (non-manifold) ends the polylines
        through it.
    """
    segments = np.asarray(segments, dtype=np.int64)
    starts, ends = segments[:, 0], segments[:, 1]
    out_degree = np.bincount(starts, minlength=0)
    in_degree = np.bincount(ends, minlength=0)
    size = max(len(out_degree), len(in_degree))
    out_degree = np.pad(out_degree, (0, size - len(out_degree)))
    in_degree = np.pad(in_degree, (0, size - len(in_degree)))
    following = {int(a): int(b) for a, b in segments if out_degree[a] == 1 and in_degree[b] == 1}
    result: list[tuple[np.ndarray, bool]] = []
    used = set()
    # open chains start where nothing (or more than one thing) leads in
    for a, b in segments.tolist():
        if (a, b) in used or (in_degree[a] == 1 and out_degree[a] == 1):
            continue
        chain = [a, b]
        used.add((a, b))
        while b in following and (b, following[b]) not in used and in_degree[b] == 1:
            used.add((b, following[b]))
            b = following[b]
            chain.append(b)
        result.append((np.array(chain, dtype=np.int64), False))
    # what is left are closed loops through regular vertices
    for a, b in segments.tolist():
        if (a, b) in used:
            continue
        chain = [a]
        used.add((a, b))
        while b != a:
            chain.append(b)
            nxt = following[b]
            used.add((b, nxt))
            b = nxt
        result.append((np.array(chain, dtype=np.int64), True))
    return result
