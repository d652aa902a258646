"""Mesh checks: degenerate elements, manifoldness, orientation, topology.

The report looks at the surface as its positions define it: vertices at exactly
the same position are merged first (their number is reported). That is what a
slicer or a viewer sees, what STL (which has no shared vertices) needs, and
what turns the book's degenerate cases into findings: a ring of vertices that
all sit on the grid vertex where two spheres touch (Wenger, section 1.3) merges
into one non-manifold vertex, a vertex interpolated onto a grid vertex whose
value equals the isovalue makes zero-length edges (sections 2.2.4, 2.3.4).

Degenerate triangles
--------------------
A triangle is degenerate when it repeats a position (after merging: reason
"repeated vertex") or when it is flat: three distinct positions but zero area
within the rounding error of its coordinates (reason "zero area", decided by
:func:`isoconvert.geometry.flat_triangles`, so a sliver of area 1e-18 on a
unit-size mesh counts, and the rule does not depend on the mesh's scale).

- A flat triangle is still a 2-cell: its three edges and vertices take full
  part in the edge, boundary, manifold, orientation, duplicate, component and
  Euler analysis (an isolated flat triangle has three boundary edges and is a
  component of Euler characteristic 1).
- A triangle with a repeated position is not a 2-cell (it is a segment or a
  point): its edges are not counted, it is in no component and adds nothing to
  the Euler characteristic, but its vertices count as referenced (they are not
  ``unreferenced_vertices``).

Segments follow the same rule: a segment whose two ends are at one position is
not counted as an edge of a polyline, but its vertices are referenced.

Cell indices are checked first: an index outside ``0..V-1`` is a
:class:`~isoconvert.errors.FormatError` naming the first cell that has one.

The frame of boundaries
-----------------------
Open boundaries (edges in one triangle, ends of open polylines) are holes
unless they lie on a face of the domain: the grid the mesh was extracted from
when it is known (``mesh.info["grid"]``, or the ``grid`` argument of
:func:`check_mesh`, see :func:`grid_from_volume`), else the mesh's bounding box,
which the report then says in ``notes``. Points count as on a grid face within
1e-6 index units plus the rounding error of the stored coordinates, which is
that of float32 when ``mesh.info["stored_precision"]`` is ``"float32"`` (or,
when the precision is not stated, when every coordinate is a float32 value):
``4 * 2**-24 * (|p| @ |A^-1|.T)`` index units per axis for a point ``p`` and
the grid's index-to-world matrix ``A``.

Everything is vectorized numpy; no numba, so ``isoconvert check`` starts fast.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import FormatError, IsoconvertError, one_line
from .geometry import flat_triangles, normalized_grid, triangle_cross
from .graph import connected_components, group_sizes, row_groups
from .mesh import Mesh

if TYPE_CHECKING:
    from .volume import Volume

SCHEMA_VERSION = 1
#: The JSON schema of :meth:`Report.to_dict`, shipped with the package.
SCHEMA_PATH = Path(__file__).with_name("report.schema.json")

#: Checks on triangle meshes, for ``--require``.
TRIANGLE_CHECKS = {
    "watertight": "every edge in exactly two triangles",
    "manifold": "no edge in more than two triangles; triangles around a vertex form one fan",
    "oriented": "triangles sharing an edge use it in opposite directions",
    "no-zero-length": "no edge whose ends are at the same position",
    "no-degenerate": "no triangle with a repeated vertex or zero area",
    "no-duplicates": "no triangle listed twice",
    "no-holes": "boundary edges only on the grid (or bounding-box) boundary",
}
#: Checks on contour segments, for ``--require``.
SEGMENT_CHECKS = {
    "watertight": "every polyline closed (every vertex ends one segment and starts one)",
    "manifold": "no vertex in more than two segments",
    "oriented": "polylines run one way (no vertex starts or ends two segments)",
    "no-zero-length": "no segment whose ends are at the same position",
    "no-degenerate": "no segment with a repeated vertex",
    "no-duplicates": "no segment listed twice",
    "no-holes": "open polylines end only on the grid (or bounding-box) boundary",
}
CHECK_NAMES = tuple(TRIANGLE_CHECKS)


@dataclass
class Report:
    """The result of :func:`check_mesh`; ``to_dict()`` is the JSON form.

    Attributes
    ----------
    kind : str
        "triangles" or "segments".
    counts : dict
        Sizes: vertices, merged vertices, edges, triangles (or segments), ...
    checks : dict of str -> bool
        Pass/fail of each check in :data:`TRIANGLE_CHECKS` / :data:`SEGMENT_CHECKS`.
    problems : dict of str -> dict
        For each kind of problem, ``count`` and up to N ``examples`` (indices
        into the input's vertices/cells, and a position).
    topology : dict
        Components, Euler characteristic, genus per closed component (triangles);
        open/closed polylines and vertex degrees (segments).
    measures : dict
        Area and enclosed volume (triangles), or total length (segments).
    boundary_frame : str
        "grid" when boundaries were judged against the volume's grid, else
        "bounding box".
    """

    kind: str
    counts: dict
    checks: dict
    problems: dict
    topology: dict
    measures: dict
    boundary_frame: str
    source: str = ""
    notes: list[str] = field(default_factory=list)

    def failures(self, required: list[str]) -> list[str]:
        """Names among ``required`` whose check failed."""
        return [name for name in required if not self.checks.get(name, False)]

    def to_dict(self) -> dict:
        return {
            "schema": "isoconvert-report",
            "schema_version": SCHEMA_VERSION,
            "source": self.source,
            "kind": self.kind,
            "boundary_frame": self.boundary_frame,
            "counts": self.counts,
            "checks": self.checks,
            "problems": self.problems,
            "topology": self.topology,
            "measures": self.measures,
            "notes": self.notes,
        }


def parse_requirements(text: str | None) -> list[str]:
    """``"watertight,manifold"`` -> names; the error lists the known names."""
    if not text:
        return []
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in CHECK_NAMES]
    if unknown:
        raise IsoconvertError(
            f"unknown check {', '.join(map(repr, unknown))} for --require; "
            f"choose from: {', '.join(CHECK_NAMES)}"
        )
    return names


# --- the boundary of the domain ------------------------------------------------------

#: Unit roundoff (half an ulp, relative) of each stored precision.
_UNIT_ROUNDOFF = {"float32": 2.0**-24, "float64": 2.0**-53}
#: Index units within which a point counts as on a grid face, besides rounding.
_GRID_TOLERANCE = 1e-6

#: ``Report.notes`` entry when boundaries had to be judged against the bounding box.
BOUNDING_BOX_NOTE = (
    "boundaries judged against the bounding box: no grid is recorded with the mesh; "
    "pass --grid VOLUME to judge them against the volume's grid"
)


def grid_from_volume(volume: Volume) -> dict:
    """The grid of a volume, as extracted meshes record it in ``info["grid"]``.

    Pass it as ``check_mesh(mesh, grid=...)`` to judge a mesh file's boundaries
    against the volume it was extracted from (``isoconvert check --grid VOLUME``).

    Parameters
    ----------
    volume : Volume
        Only its shape and placement are used (no samples are read).

    Returns
    -------
    dict
        ``shape`` (ndim,) list of int, ``origin`` (ndim,) list of float and
        ``affine`` (ndim, ndim) nested list of float (index offsets to world
        offsets, :attr:`Volume.affine`): plain lists, ready for JSON or a
        file header.
    """
    return {
        "shape": [int(n) for n in volume.shape],
        "origin": np.asarray(volume.origin, dtype=np.float64).tolist(),
        "affine": np.asarray(volume.affine, dtype=np.float64).tolist(),
    }


def _stored_precision(info: dict, vertices: np.ndarray) -> str:
    """The stored precision, "float32" or "float64": as ``info`` states, else
    float32 when every finite coordinate is a float32 value (as STL's, or an
    older PLY's)."""
    stated = info.get("stored_precision")
    if stated in _UNIT_ROUNDOFF:
        return stated
    with np.errstate(over="ignore", invalid="ignore"):
        as32 = vertices.astype(np.float32)
    exact = (as32 == vertices) | ~np.isfinite(vertices)
    return "float32" if len(vertices) and exact.all() else "float64"


class _Frame:
    """Tells whether points lie on a face of the grid (or of the bounding box).

    ``used`` becomes True once a non-empty set of points has been judged.
    """

    def __init__(self, vertices: np.ndarray, grid: dict | None, info: dict, source: str) -> None:
        self._vertices = vertices
        self._info = info
        self._roundoff: float | None = None
        self.used = False
        if grid is not None:
            shape, origin, affine = _parse_grid(grid, source)
            nd = len(shape)
            self.name = "grid"
            self._origin = origin
            self._inverse = np.linalg.inv(affine)
            self._abs_inverse = np.abs(self._inverse)
            self._lo = np.zeros(nd)
            self._hi = shape - 1.0
            self._nd = nd
        else:
            self.name = "bounding box"
            self._origin = None
            self._nd = 3
            finite = vertices[np.isfinite(vertices).all(axis=1)]
            self._lo = finite.min(axis=0) if len(finite) else np.zeros(3)
            self._hi = finite.max(axis=0) if len(finite) else np.zeros(3)
            extent = float(np.max(self._hi - self._lo))
            self._magnitude = float(np.abs(finite).max()) if len(finite) else 0.0
            self._base = 1e-9 * max(extent, 1e-300)

    def roundoff(self) -> float:
        """Unit roundoff of the stored coordinates (decided on first use)."""
        if self._roundoff is None:
            precision = _stored_precision(self._info, self._vertices)
            self._roundoff = _UNIT_ROUNDOFF[precision]
        return self._roundoff

    def faces(self, points: np.ndarray) -> np.ndarray:
        """(N, 2 * nd) bool: point on the low / high face of each axis.

        Parameters
        ----------
        points : (N, 3) float64
        """
        if len(points):
            self.used = True
        p = points[:, : self._nd]
        # stored coordinates are off by up to roundoff * |p|; with float64
        # arithmetic on top, 4 units of it bound the error comfortably
        slack = 4.0 * self.roundoff()
        if self._origin is not None:
            tol = _GRID_TOLERANCE + slack * (np.abs(p) @ self._abs_inverse.T)
            p = (p - self._origin) @ self._inverse.T
        else:
            tol = max(self._base, slack * self._magnitude)
        low = np.abs(p - self._lo) <= tol
        high = np.abs(p - self._hi) <= tol
        return np.concatenate([low, high], axis=1)

    def same_face(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(N,) bool: segment a-b lies in one face of the domain.

        Parameters
        ----------
        a, b : (N, 3) float64
        """
        return (self.faces(a) & self.faces(b)).any(axis=1)


def _parse_grid(grid: dict, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shape (nd,), origin (nd,) and invertible affine (nd, nd) of a grid dict."""
    clean = normalized_grid(grid)
    if clean is None:
        raise FormatError(
            f"{source}: the grid {one_line(grid, limit=200)} is not usable: it needs 2 or 3 "
            "whole sizes >= 1, as many finite origin coordinates and an invertible square "
            "affine of that size"
        )
    return (
        np.asarray(clean["shape"], dtype=np.float64),
        np.asarray(clean["origin"], dtype=np.float64),
        np.asarray(clean["affine"], dtype=np.float64),
    )


# --- helpers -----------------------------------------------------------------------------


def _merge(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge vertices at exactly equal positions.

    Returns unique positions (U, 3), the inverse map (V,) and, for each unique
    position, its first index in the input (U,).
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64) + 0.0  # -0.0 -> 0.0
    if len(v) == 0:
        return v.reshape(0, 3), np.zeros(0, np.int64), np.zeros(0, np.int64)
    order, new = row_groups(v)
    group = np.cumsum(new) - 1
    inverse = np.empty(len(v), dtype=np.int64)
    inverse[order] = group
    starts = np.flatnonzero(new)
    first = np.minimum.reduceat(order, starts)  # the first input index of each position
    return v[order[starts]], inverse, first


def _renumber(labels: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, int]:
    """Components numbered 0..n-1 for ``nodes`` (labels are root node indices)."""
    is_root = np.zeros(len(labels), dtype=bool)
    is_root[labels[nodes]] = True
    rank = np.cumsum(is_root) - 1
    return rank[labels[nodes]], int(is_root.sum())


def _problem(count: int, examples: list) -> dict:
    return {"count": int(count), "examples": examples}


def _pos(p) -> list[float]:
    return [float(x) for x in p]


# --- triangles ---------------------------------------------------------------------------


def check_mesh(
    mesh: Mesh, *, examples: int = 5, source: str = "", grid: dict | None = None
) -> Report:
    """Check a triangle mesh or a set of contour segments.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)`` with indices in
        ``0..V-1``. ``mesh.info["grid"]`` (extracted meshes carry it, files
        written by isoconvert record it) tells the grid boundaries are judged
        against; ``mesh.info["stored_precision"]`` ("float32" or "float64")
        how precisely the positions were stored.
    examples : int
        How many examples to give per kind of problem.
    source : str
        Name for the report and for errors; default ``mesh.info["source"]``.
    grid : dict or None
        ``{"shape", "origin", "affine"}`` as :func:`grid_from_volume` makes it:
        judge boundaries against this grid instead of ``mesh.info["grid"]``.
        With neither, boundaries are judged against the mesh's bounding box
        and, when there are any, ``notes`` says so.

    Returns
    -------
    Report

    Raises
    ------
    FormatError
        A cell refers to a vertex index outside ``0..V-1``, or the grid is malformed.
    IsoconvertError
        The arrays do not have the shapes above.
    """
    name = source or str(mesh.info.get("source", "")) or "mesh"
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if (
        vertices.ndim != 2
        or vertices.shape[1] != 3
        or cells.ndim != 2
        or cells.shape[1] not in (2, 3)
    ):
        raise IsoconvertError(f"{name}: expected (V, 3) vertices and (C, 3) or (C, 2) cells")
    _check_indices(cells, len(vertices), name)
    finite = np.isfinite(vertices).all(axis=1)
    if grid is None:
        grid = mesh.info.get("grid")
    frame = _Frame(vertices, grid, mesh.info, name)
    if cells.shape[1] == 3:
        report = _check_triangles(vertices, cells, frame, examples)
    else:
        report = _check_segments(vertices, cells, frame, examples)
    report.source = source or str(mesh.info.get("source", ""))
    bad = np.flatnonzero(~finite)
    report.problems["non_finite_vertices"] = _problem(
        len(bad), [{"vertex": int(i)} for i in bad[:examples]]
    )
    if len(bad):
        report.checks = {check: False for check in report.checks}
    if frame.name == "bounding box" and frame.used:
        report.notes.append(BOUNDING_BOX_NOTE)
    return report


def _check_indices(cells: np.ndarray, n_vertices: int, name: str) -> None:
    """Raise FormatError naming the first cell with an index outside ``0..V-1``."""
    if cells.size == 0 or (cells.min() >= 0 and cells.max() < n_vertices):
        return
    bad = (cells < 0) | (cells >= n_vertices)
    row = int(np.flatnonzero(bad.any(axis=1))[0])
    index = int(cells[row][bad[row]][0])
    kind = "triangle" if cells.shape[1] == 3 else "segment"
    if index < 0:
        why = "but vertex indices start at 0"
    elif n_vertices == 0:
        why = "but there are no vertices"
    elif n_vertices == 1:
        why = "but there is only 1 vertex"
    else:
        why = f"but there are only {n_vertices} vertices"
    raise FormatError(f"{name}: {kind} {row} refers to vertex {index}, {why}")


def _check_triangles(vertices, cells, frame, n_examples) -> Report:
    n_vertices, n_tris = len(vertices), len(cells)
    unique, inverse, first = _merge(vertices)
    tris = inverse[cells]
    problems: dict = {}

    # edges of the input, by vertex index; zero-length when the ends coincide
    ea = cells.reshape(-1)
    eb = np.roll(cells, -1, axis=1).reshape(-1)
    collapsed = (inverse[ea] == inverse[eb]) & (ea != eb)
    zero_keys = np.unique(
        np.minimum(ea, eb)[collapsed] * n_vertices + np.maximum(ea, eb)[collapsed]
    )
    zero = np.column_stack([zero_keys // max(n_vertices, 1), zero_keys % max(n_vertices, 1)])
    problems["zero_length_edges"] = _problem(
        len(zero),
        [
            {"vertices": [int(a), int(b)], "position": _pos(vertices[a])}
            for a, b in zero[:n_examples]
        ],
    )

    # degenerate triangles: a repeated position (not a 2-cell), or flat (a 2-cell
    # of zero area within rounding); see the module docstring
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    cross = triangle_cross(unique, tris)
    area2 = np.linalg.norm(cross, axis=1)
    flat = flat_triangles(unique, tris, cross) & ~repeated
    degenerate = repeated | flat
    examples_deg = [
        {
            "triangle": int(t),
            "reason": "repeated vertex" if repeated[t] else "zero area",
            "position": _pos(unique[tris[t, 0]]),
        }
        for t in np.flatnonzero(degenerate)[:n_examples]
    ]
    problems["degenerate_triangles"] = _problem(degenerate.sum(), examples_deg)

    n_u = len(unique)
    if repeated.any():
        keep = np.flatnonzero(~repeated)  # the 2-cells
        tv = tris[keep]
        referenced = np.zeros(n_u, dtype=bool)
        referenced[tris.reshape(-1)] = True
        n_referenced = int(referenced.sum())
    else:
        keep = np.arange(n_tris)
        tv = tris
        n_referenced = -1  # every vertex a 2-cell uses: set below

    # edges of the kept triangles: occurrence o = 3 * i + j runs tv[i, j] -> tv[i, j + 1]
    a = tv.reshape(-1)
    b = np.roll(tv, -1, axis=1).reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order, starts, sizes = group_sizes(lo * n_u + hi)
    first_occ = order[starts]
    edge_lo, edge_hi = lo[first_occ], hi[first_occ]
    n_edges = len(starts)

    boundary = np.flatnonzero(sizes == 1)
    on_domain = frame.same_face(unique[edge_lo[boundary]], unique[edge_hi[boundary]])
    holes = boundary[~on_domain]

    def edge_examples(groups):
        return [
            {
                "vertices": [int(first[edge_lo[g]]), int(first[edge_hi[g]])],
                "position": _pos(0.5 * (unique[edge_lo[g]] + unique[edge_hi[g]])),
            }
            for g in groups[:n_examples]
        ]

    problems["boundary_edges_on_domain_boundary"] = _problem(
        on_domain.sum(), edge_examples(boundary[on_domain])
    )
    problems["boundary_edges_inside"] = _problem(len(holes), edge_examples(holes))
    nonmanifold_edges = np.flatnonzero(sizes > 2)
    problems["non_manifold_edges"] = _problem(
        len(nonmanifold_edges), edge_examples(nonmanifold_edges)
    )

    # orientation: an edge shared by two triangles must be used once each way
    pairs = np.flatnonzero(sizes == 2)
    o1, o2 = order[starts[pairs]], order[starts[pairs] + 1]
    same_way = a[o1] == a[o2]
    problems["inconsistently_oriented_edges"] = _problem(
        same_way.sum(), edge_examples(pairs[same_way])
    )

    # duplicate triangles (same three vertices, either orientation)
    duplicates = _duplicate_triangles(tv, o1, o2, len(nonmanifold_edges) == 0)
    problems["duplicate_triangles"] = _problem(
        sum(len(g) - 1 for g in duplicates),
        [
            {"triangles": [int(keep[t]) for t in g], "position": _pos(unique[tv[g[0], 0]])}
            for g in duplicates[:n_examples]
        ],
    )

    fans = _fans_per_vertex(a, o1, o2, same_way, n_u, len(nonmanifold_edges) == 0)
    bad_vertices = np.flatnonzero(fans > 1)
    problems["non_manifold_vertices"] = _problem(
        len(bad_vertices),
        [
            {"vertex": int(first[w]), "fans": int(fans[w]), "position": _pos(unique[w])}
            for w in bad_vertices[:n_examples]
        ],
    )

    # components, Euler characteristic and genus, of the 2-cells
    used = np.flatnonzero(np.bincount(tv.reshape(-1), minlength=n_u))
    if n_referenced < 0:
        n_referenced = len(used)
    comp = connected_components(n_u, edge_lo, edge_hi)
    comp_of, n_comp = _renumber(comp, used)
    lookup = np.full(n_u, -1, dtype=np.int64)
    lookup[used] = comp_of
    v_c = np.bincount(comp_of, minlength=n_comp)
    e_c = np.bincount(lookup[edge_lo], minlength=n_comp)
    f_c = np.bincount(lookup[tv[:, 0]], minlength=n_comp) if len(tv) else np.zeros(n_comp, int)
    open_c = np.bincount(lookup[edge_lo[sizes != 2]], minlength=n_comp) > 0
    bad_c = (
        np.bincount(lookup[bad_vertices], minlength=n_comp) > 0
        if len(bad_vertices)
        else np.zeros(n_comp, bool)
    )
    chi_c = v_c - e_c + f_c
    components = []
    for c in np.argsort(-f_c, kind="stable"):
        entry = {
            "triangles": int(f_c[c]),
            "vertices": int(v_c[c]),
            "euler": int(chi_c[c]),
            "closed": bool(not open_c[c]),
        }
        if not open_c[c] and not bad_c[c] and chi_c[c] % 2 == 0:
            entry["genus"] = int((2 - chi_c[c]) // 2)
        components.append(entry)

    watertight = len(tv) > 0 and len(boundary) == 0 and len(nonmanifold_edges) == 0
    oriented = not same_way.any()
    # a repeated position makes the cross product exactly zero: summing over
    # every triangle is summing over the 2-cells
    area = 0.5 * float(area2.sum())
    measures = {"area": area}
    if watertight and oriented:
        # det[p0 - c, p1 - c, p2 - c] = (p0 - c) . ((p1 - p0) x (p2 - p0)); c near the
        # mesh keeps the sum well conditioned
        c = unique[used].mean(axis=0)
        measures["volume"] = float(np.einsum("ij,ij->", unique[tris[:, 0]] - c, cross) / 6.0)

    counts = {
        "vertices": n_vertices,
        "merged_vertices": n_vertices - n_u,
        "unreferenced_vertices": int(n_u - n_referenced),
        "edges": int(n_edges),
        "triangles": n_tris,
    }
    checks = {
        "watertight": bool(watertight),
        "manifold": bool(len(nonmanifold_edges) == 0 and len(bad_vertices) == 0),
        "oriented": bool(oriented),
        "no-zero-length": bool(len(zero) == 0),
        "no-degenerate": bool(not degenerate.any()),
        "no-duplicates": bool(len(duplicates) == 0),
        "no-holes": bool(len(holes) == 0),
    }
    topology = {
        "components": n_comp,
        "euler_characteristic": int(len(used) - n_edges + len(tv)),
        "per_component": components,
    }
    return Report("triangles", counts, checks, problems, topology, measures, frame.name)


def _duplicate_triangles(tv, o1, o2, edge_manifold) -> list[list[int]]:
    """Groups of triangles with the same three vertices (indices into ``tv``).

    When no edge has more than two triangles, two triangles are duplicates
    exactly when all three of their edges pair them with each other, which the
    edge pairs (occurrences ``o1``, ``o2``) tell without sorting triangles.
    """
    if edge_manifold:
        partner = np.full(3 * len(tv), -1, dtype=np.int64)
        partner[o1] = o2 // 3
        partner[o2] = o1 // 3
        p = partner.reshape(-1, 3)
        same = (p[:, 0] >= 0) & (p[:, 0] == p[:, 1]) & (p[:, 1] == p[:, 2])
        first = np.flatnonzero(same & (np.arange(len(tv)) < p[:, 0]))
        return [[int(i), int(p[i, 0])] for i in first]
    order, new = row_groups(np.sort(tv, axis=1))
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, len(tv)))
    return [
        [int(t) for t in order[starts[g] : starts[g] + sizes[g]]] for g in np.flatnonzero(sizes > 1)
    ]


def _fans_per_vertex(a, o1, o2, same_way, n_u, edge_manifold) -> np.ndarray:
    """Number of fans (groups of triangles joined across edges) at each vertex.

    Corners are the (triangle, vertex) pairs: corner ``c = 3 * i + j`` sits at
    vertex ``a[c]``. Two triangles sharing a manifold edge join their corners at
    both ends of it. A vertex whose corners form more than one group is
    non-manifold (e.g. where two surfaces touch at a point).

    Parameters
    ----------
    a : (3F,) int64
        Vertex of each corner (edge occurrence ``o`` starts at corner ``o``).
    o1, o2 : (P,) int64
        The two occurrences of each edge used by exactly two triangles.
    same_way : (P,) bool
        Whether both use it in the same direction (inconsistent orientation).
    n_u : int
        Number of vertices.
    edge_manifold : bool
        No edge is used by more than two triangles.
    """

    def end(o):  # the corner where occurrence o ends
        return o - o % 3 + (o % 3 + 1) % 3

    n = len(a)
    if n == 0:
        return np.zeros(n_u, dtype=np.int64)
    if edge_manifold and not same_way.any():
        # Oriented: around each vertex the corners form chains (boundary) or cycles,
        # "next" stepping across the edge that leaves the vertex. Label each chain
        # by its last corner and each cycle by its smallest, with pointer doubling.
        nxt = np.arange(n, dtype=np.int64)
        # occurrence o1 runs v -> w from corner o1; the other triangle runs w -> v
        # and ends at v in corner end(o2): its corner at v follows o1's
        nxt[o1] = end(o2)
        nxt[o2] = end(o1)
        # after k rounds, low[c] is the smallest of the 2**k corners from c on and
        # step[c] the corner 2**k on (or the chain's end); a chain or cycle is at
        # most as long as its vertex has corners
        rounds = int(np.ceil(np.log2(max(2, np.bincount(a).max()))))
        low = np.arange(n, dtype=np.int64)
        step = nxt
        for _ in range(rounds):
            low = np.minimum(low, low[step])
            step = step[step]
        chain = nxt[step] == step
        labels = np.where(chain, step, low)
    else:
        u = np.concatenate([o1, end(o1)])
        v = np.concatenate([np.where(same_way, o2, end(o2)), np.where(same_way, end(o2), o2)])
        labels = connected_components(n, u, v)
    # each group has exactly one corner that is its own label
    roots = labels == np.arange(n)
    return np.bincount(a[roots], minlength=n_u)


# --- segments ----------------------------------------------------------------------------


def _check_segments(vertices, cells, frame, n_examples) -> Report:
    unique, inverse, first = _merge(vertices)
    segs = inverse[cells]
    n_u = len(unique)
    problems: dict = {}
    index_repeat = cells[:, 0] == cells[:, 1]
    zero = (segs[:, 0] == segs[:, 1]) & ~index_repeat
    problems["zero_length_segments"] = _problem(
        zero.sum(),
        [
            {"segment": int(s), "position": _pos(unique[segs[s, 0]])}
            for s in np.flatnonzero(zero)[:n_examples]
        ],
    )
    problems["degenerate_segments"] = _problem(
        index_repeat.sum(), [{"segment": int(s)} for s in np.flatnonzero(index_repeat)[:n_examples]]
    )
    keep = np.flatnonzero(segs[:, 0] != segs[:, 1])
    sv = segs[keep]
    key = np.sort(sv, axis=1)
    order, starts, sizes = group_sizes(key[:, 0] * n_u + key[:, 1])
    dups = np.flatnonzero(sizes > 1)
    problems["duplicate_segments"] = _problem(
        int((sizes[dups] - 1).sum()),
        [
            {"segments": [int(keep[s]) for s in order[starts[g] : starts[g] + sizes[g]]]}
            for g in dups[:n_examples]
        ],
    )
    out_deg = np.bincount(sv[:, 0], minlength=n_u)
    in_deg = np.bincount(sv[:, 1], minlength=n_u)
    degree = out_deg + in_deg
    used = np.flatnonzero(degree > 0)
    ends = np.flatnonzero(degree == 1)
    inside = ends[~frame.faces(unique[ends]).any(axis=1)] if len(ends) else ends
    branch = np.flatnonzero(degree > 2)
    misdirected = np.flatnonzero((out_deg > 1) | (in_deg > 1))

    def vertex_examples(ids):
        return [
            {"vertex": int(first[w]), "degree": int(degree[w]), "position": _pos(unique[w])}
            for w in ids[:n_examples]
        ]

    problems["open_ends_on_domain_boundary"] = _problem(
        len(ends) - len(inside), vertex_examples(np.setdiff1d(ends, inside))
    )
    problems["open_ends_inside"] = _problem(len(inside), vertex_examples(inside))
    problems["branch_vertices"] = _problem(len(branch), vertex_examples(branch))
    problems["inconsistently_oriented_vertices"] = _problem(
        len(misdirected), vertex_examples(misdirected)
    )

    comp = connected_components(n_u, sv[:, 0], sv[:, 1])
    comp_of, n_comp = _renumber(comp, used)
    lookup = np.full(n_u, -1, dtype=np.int64)
    lookup[used] = comp_of
    not_two = np.bincount(lookup[used[degree[used] != 2]], minlength=n_comp) > 0
    closed = int((~not_two).sum())
    lengths = np.linalg.norm(unique[sv[:, 0]] - unique[sv[:, 1]], axis=1)
    degrees = {str(d): int(n) for d, n in enumerate(np.bincount(degree[used])) if n}
    counts = {
        "vertices": len(vertices),
        "merged_vertices": len(vertices) - n_u,
        # a segment with both ends at one position is no edge, but uses its vertices
        "unreferenced_vertices": int(n_u - len(np.unique(segs))),
        "segments": len(cells),
    }
    checks = {
        "watertight": bool(len(sv) > 0 and (degree[used] == 2).all()),
        "manifold": bool(len(branch) == 0),
        "oriented": bool(len(misdirected) == 0),
        "no-zero-length": bool(not zero.any()),
        "no-degenerate": bool(not index_repeat.any()),
        "no-duplicates": bool(len(dups) == 0),
        "no-holes": bool(len(inside) == 0),
    }
    topology = {
        "components": int(n_comp),
        "closed_polylines": closed,
        "open_polylines": int(n_comp - closed),
        "vertex_degrees": degrees,
    }
    return Report(
        "segments", counts, checks, problems, topology, {"length": float(lengths.sum())}, frame.name
    )


# --- text ---------------------------------------------------------------------------------


def format_report(report: Report) -> str:
    """A compact table with PASS / FAIL marks, the first examples of each problem,
    then the notes (among them why boundaries were judged against the bounding box)."""
    c = report.counts
    lines = [f"{report.source or 'mesh'}: {report.kind}"]
    if report.kind == "triangles":
        lines.append(
            f"  {c['vertices']:,} vertices ({c['merged_vertices']:,} merged at equal positions), "
            f"{c['edges']:,} edges, {c['triangles']:,} triangles"
        )
        t = report.topology
        genus = [str(p["genus"]) for p in t["per_component"] if "genus" in p]
        lines.append(
            f"  {t['components']} component(s), Euler characteristic {t['euler_characteristic']}"
            + (f", genus {', '.join(genus[:8])}{' ...' if len(genus) > 8 else ''}" if genus else "")
        )
        m = report.measures
        lines.append(
            f"  area {m['area']:.6g}"
            + (f", enclosed volume {m['volume']:.6g}" if "volume" in m else "")
        )
        descriptions = TRIANGLE_CHECKS
    else:
        lines.append(
            f"  {c['vertices']:,} vertices ({c['merged_vertices']:,} merged), "
            f"{c['segments']:,} segments"
        )
        t = report.topology
        lines.append(
            f"  {t['closed_polylines']} closed and {t['open_polylines']} open polyline(s), "
            f"length {report.measures['length']:.6g}"
        )
        descriptions = SEGMENT_CHECKS
    lines.append("")
    for name, ok in report.checks.items():
        lines.append(f"  {'PASS' if ok else 'FAIL'}  {name:<15} {descriptions[name]}")
    shown = [(k, p) for k, p in report.problems.items() if p["count"]]
    if shown:
        lines.append("")
    for name, p in shown:
        lines.append(f"  {name.replace('_', ' ')}: {p['count']:,}")
        for ex in p["examples"]:
            lines.append("    " + ", ".join(f"{k} {_short(v)}" for k, v in ex.items()))
    for note in report.notes:
        lines.append(f"  note: {note}")
    if BOUNDING_BOX_NOTE not in report.notes:
        lines.append(f"  (boundaries judged against the {report.boundary_frame})")
    return "\n".join(lines)


def _short(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in value) + ")"
    return str(value)
