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
:func:`check_mesh`, see :func:`grid_from_volume`). Without a grid, the mesh's
bounding box stands in for it only when the mesh records that a grid cut it
(``mesh.info["cut_by_grid"]``: files written by isoconvert, which are all
extracted from a volume, say so), and the report then says so in ``notes``;
any other mesh has no domain (``boundary_frame`` "none"): an open box is not
excused by its own bounding box, every boundary edge is a hole. Points count
as on a grid face within 1e-6 index units plus the rounding error of the stored
coordinates, which is that of float32 when ``mesh.info["stored_precision"]`` is ``"float32"`` (or,
when the precision is not stated, when every coordinate is a float32 value):
``4 * 2**-24 * (|p| @ |A^-1|.T)`` index units per axis for a point ``p`` and
the grid's index-to-world matrix ``A``.

Speed and memory
----------------
The triangle checks are three passes of compiled kernels (``src/report.cpp``,
in ``isoconvert._native``): merging equal positions by hash buckets, one pass
over the triangles, and one over the vertices with their corners listed by a
counting sort (the edges of a vertex are its corners' two neighbours). No
pass sorts the whole mesh, and the memory they need is of the order of the
mesh's own (int32 indices where they fit). Contour segments, which are small,
are checked with vectorized numpy. No numba, so ``isoconvert check`` starts fast.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .checks import CHECK_NAMES as CHECK_NAMES  # the names, and their parsing, live there
from .checks import SEGMENT_CHECKS, TRIANGLE_CHECKS
from .checks import parse_requirements as parse_requirements
from .errors import FormatError, IsoconvertError, one_line
from .geometry import flat_among, flat_bound, normalized_grid, triangle_cross
from .graph import (
    MergedPositions,
    connected_components,
    group_sizes,
    index_dtype,
    merge_positions,
    mix64,
    row_groups,
)
from .mesh import Mesh, as_mesh
from .threads import kernel_threads

# the grid description belongs to the model (extraction records it too); offered here still
from .volume import grid_from_volume as grid_from_volume

SCHEMA_VERSION = 1
#: The JSON schema of :meth:`Report.to_dict`, shipped with the package.
SCHEMA_PATH = Path(__file__).with_name("report.schema.json")


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
        "grid" when boundaries were judged against the volume's grid,
        "bounding box" when the mesh records that a grid cut it but not which,
        else "none" (every open boundary is a hole).
    extraction : dict
        What the mesh records of how it was extracted (:func:`extraction_record`);
        empty when it records nothing.
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
    extraction: dict = field(default_factory=dict)

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
            **({"extraction": self.extraction} if self.extraction else {}),
        }


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
#: ``Report.notes`` entry when open boundaries had no domain to be judged against.
NO_FRAME_NOTE = (
    "every open boundary counts as a hole: the mesh records no grid, nor that a grid "
    "cut it; pass --grid VOLUME to judge them against the volume's grid"
)
#: ``Report.notes`` entry for a mesh with no face (or segment) to check.
NO_FACE_NOTE = (
    "no triangle is a face (there are none, or every one repeats a position; for "
    "contours, every segment): there is no surface to check, so every check fails"
)
#: What the report says of a label mesh (``--labels --single-file``).
LABEL_NOTE = (
    "a label mesh: watertight, manifold, oriented and no-holes are judged on each "
    "label's surface (its triangles, facing out of it; topology.per_label); edges where "
    "three or more labels meet are counted as non-manifold edges of the whole mesh"
)
#: The checks a label mesh passes when every label's surface passes them.
LABEL_CHECKS = ("watertight", "manifold", "oriented", "no-holes")
#: Labels listed one per line in the printed report.
_LABEL_LINES = 12


def _stored_precision(info: dict, vertices: np.ndarray) -> str:
    """The stored precision, "float32" or "float64": as ``info`` states, else
    float32 when every finite coordinate is a float32 value (as STL's, or an
    older PLY's)."""
    stated = info.get("stored_precision")
    if stated in _UNIT_ROUNDOFF:
        return stated
    if not len(vertices):
        return "float64"
    flat = vertices.reshape(-1)
    # a few thousand coordinates settle most float64 meshes without a pass over all
    for part in (flat[:4096], flat):
        with np.errstate(over="ignore", invalid="ignore"):
            as32 = part.astype(np.float32)
        if not ((as32 == part) | ~np.isfinite(part)).all():
            return "float64"
    return "float32"


class _Frame:
    """Tells whether points lie on a face of the grid (or of the bounding box,
    for a mesh that records that a grid cut it; else of nothing: ``name`` "none").

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
            # a mesh's own bounding box excuses the boundary edges on its faces only
            # when the mesh was cut by a grid: an open box would otherwise pass
            self.name = "bounding box" if info.get("cut_by_grid") is True else "none"
            self._origin = None
            self._nd = 3
            self._lo = None  # the box is measured on first use (most meshes need no box)

    def _measure_box(self) -> None:
        vertices = self._vertices
        if np.isfinite(vertices).all():
            finite = vertices
        else:
            finite = vertices[np.isfinite(vertices).all(axis=1)]
        self._lo = finite.min(axis=0) if len(finite) else np.zeros(3)
        self._hi = finite.max(axis=0) if len(finite) else np.zeros(3)
        extent = float(np.max(self._hi - self._lo))
        self._magnitude = float(max(np.abs(self._lo).max(), np.abs(self._hi).max()))
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
        if self.name == "none":
            return np.zeros((len(points), 6), dtype=bool)
        p = points[:, : self._nd]
        # stored coordinates are off by up to roundoff * |p|; with float64
        # arithmetic on top, 4 units of it bound the error comfortably
        slack = 4.0 * self.roundoff()
        if self._origin is not None:
            tol = _GRID_TOLERANCE + slack * (np.abs(p) @ self._abs_inverse.T)
            p = (p - self._origin) @ self._inverse.T
        else:
            if self._lo is None:
                self._measure_box()
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


#: What each ambiguity rule makes of a cube's topology, for the report.
_RULE_TOPOLOGY = {
    "trilinear": "trilinear interpolant",
    "asymptotic": "bilinear interpolant on each slice",
    "separate-positive": "fixed rule (ambiguous faces separate the positive corners)",
    "separate-negative": "fixed rule (ambiguous faces separate the negative corners)",
}


def extraction_record(info: dict) -> dict:
    """``method``, ``ambiguity`` and the ``topology`` that rule follows, as
    ``info`` (an extracted mesh's, or what a file's header records) has them.

    Returns
    -------
    dict
        Empty when ``info`` records no method or no rule for ambiguous faces
        (tetra has none; STL and meshio's formats do not give it
        back); ``topology`` only for a known rule.
    """
    method, rule = info.get("method"), info.get("ambiguity")
    if not isinstance(method, str) or not isinstance(rule, str):
        return {}
    out = {"method": method, "ambiguity": rule}
    if rule in _RULE_TOPOLOGY:
        out["topology"] = _RULE_TOPOLOGY[rule]
    return out


def check_mesh(
    mesh: Mesh | object, *, examples: int = 5, source: str = "", grid: dict | None = None
) -> Report:
    """Check a triangle mesh or a set of contour segments.

    Parameters
    ----------
    mesh : Mesh, trimesh.Trimesh, pyvista.PolyData or meshio.Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)`` with indices in
        ``0..V-1``; another library's mesh is taken as
        :func:`isoconvert.mesh.as_mesh` converts it (the same vertices and
        cells). ``mesh.info["grid"]`` (extracted meshes carry it, files
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
        when ``mesh.info["cut_by_grid"]`` is True (the mesh was extracted from
        a volume whose grid is not recorded), else every boundary edge is a
        hole; when there are any, ``notes`` says which.

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
    mesh = as_mesh(mesh)
    name = source or str(mesh.info.get("source", "")) or "mesh"
    # C order for the kernels (no copy when it is already); int32 cells stay int32
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells)
    index = np.int32 if cells.dtype == np.int32 else np.int64
    cells = np.ascontiguousarray(cells, dtype=index)
    if (
        vertices.ndim != 2
        or vertices.shape[1] != 3
        or cells.ndim != 2
        or cells.shape[1] not in (2, 3)
    ):
        raise IsoconvertError(f"{name}: expected (V, 3) vertices and (C, 3) or (C, 2) cells")
    _check_indices(cells, len(vertices), name)
    if grid is None:
        grid = mesh.info.get("grid")
    frame = _Frame(vertices, grid, mesh.info, name)
    if cells.shape[1] == 3:
        report = _check_triangles(vertices, cells, frame, examples)
    else:
        report = _check_segments(vertices, cells, frame, examples)
    report.source = source or str(mesh.info.get("source", ""))
    labels = mesh.cell_labels
    if report.kind == "triangles" and labels is not None and len(labels) == len(cells):
        per_label = _label_surfaces(vertices, cells, np.asarray(labels), frame)
        report.topology["per_label"] = per_label
        for check in LABEL_CHECKS:
            report.checks[check] = all(surface[check] for surface in per_label)
        report.notes.append(LABEL_NOTE)
    report.extraction = extraction_record(mesh.info)
    unit = mesh.info.get("unit")
    if isinstance(unit, str) and unit:
        report.measures["unit"] = unit  # of lengths; areas and volumes in its square and cube
    if np.isfinite(vertices).all():  # a whole-array test first: per row costs 15 times more
        bad = np.zeros(0, np.int64)
    else:
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    report.problems["non_finite_vertices"] = _problem(
        len(bad), [{"vertex": int(i)} for i in bad[:examples]]
    )
    if len(bad):
        report.checks = {check: False for check in report.checks}
    if report.topology["components"] == 0:
        # no 2-cell (or segment) at all: "manifold" or "no holes" would hold only
        # vacuously, and --require must not pass a mesh that is nothing
        report.checks = {check: False for check in report.checks}
        report.notes.append(NO_FACE_NOTE)
    if frame.name == "bounding box" and frame.used:
        report.notes.append(BOUNDING_BOX_NOTE)
    elif frame.name == "none" and frame.used:
        report.notes.append(NO_FRAME_NOTE)
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


def _label_surfaces(vertices, cells, labels, frame) -> list[dict]:
    """Per label of a label mesh, the checks of its own surface: the triangles with
    that label on either side, turned to face out of it.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int
    labels : (C, 2) int
        The labels on the two sides of each triangle; normals point from column 0
        to column 1.
    frame : _Frame
        The whole mesh's, so that boundaries are judged as for the whole mesh.

    Returns
    -------
    list of dict
        ``label``, ``triangles``, ``components``, the :data:`LABEL_CHECKS`, and
        ``volume`` (enclosed, positive: the surface faces out of the label) where
        the surface is closed.
    """
    out = []
    for value in np.unique(labels):
        tris = np.concatenate([cells[labels[:, 0] == value], cells[labels[:, 1] == value][:, ::-1]])
        used, local = np.unique(tris, return_inverse=True)
        sub = _check_triangles(vertices[used], local.reshape(-1, 3), frame, 0)
        surface = {"label": int(value), "triangles": len(tris)}
        surface["components"] = sub.topology["components"]
        surface.update({check: sub.checks[check] for check in LABEL_CHECKS})
        if "volume" in sub.measures:
            surface["volume"] = sub.measures["volume"]
        out.append(surface)
    return out


def _check_triangles(vertices, cells, frame, n_examples) -> Report:
    """The report on triangles, from three compiled passes (``src/report.cpp``).

    Vertices are named by their representative, the smallest index at their
    position, so the passes keep the memory order of the mesh. Lists come back
    in representative order; examples are then put in the order the report has
    always used, that of the merged positions (:func:`~isoconvert.graph.row_groups`),
    which the keys of :func:`~isoconvert.graph.merge_positions` give.
    """
    from . import _native

    n_vertices, n_tris = len(vertices), len(cells)
    threads = kernel_threads()
    itype = index_dtype(n_vertices, 3 * n_tris)
    merged = merge_positions(vertices, threads, itype)
    key, n_u = merged.key, merged.unique
    problems: dict = {}

    # tv (F, 3): each corner's representative, which is the cell's own vertex
    # when no two vertices share a position (the input then serves as it is);
    # area2: the sum of |cross| as numpy would compute it, to the bit
    merging = n_u < n_vertices
    tv, area2, repeated, candidates, collapsed = _native.triangle_pass(
        cells, merged.rep, vertices, flat_bound(vertices, merged.magnitude), threads, merging
    )
    if not merging:
        tv = cells

    # edges of the input, by vertex index, whose ends are at one position: two
    # indices at one position (the kernel's list), or one index twice, as the
    # edge (i, i) of a triangle (i, j, i) or (i, i, i); both kinds are among the
    # triangles with a repeated position
    if len(repeated):
        corners = cells[repeated]
        same = [corners[corners[:, j] == corners[:, (j + 1) % 3], j] for j in range(3)]
        twice = np.concatenate(same).astype(np.int64)
        collapsed = np.concatenate([collapsed, np.column_stack([twice, twice])])
    zero_keys = np.unique(collapsed[:, 0] * n_vertices + collapsed[:, 1])
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
    if len(candidates):
        corners = tv[candidates]
        with np.errstate(invalid="ignore", over="ignore"):  # inf - inf: non_finite_vertices
            norm = np.linalg.norm(triangle_cross(vertices, corners), axis=1)
        flat = candidates[flat_among(vertices, corners, norm)]
    else:
        flat = candidates
    degenerate = np.union1d(repeated, flat)
    shown = degenerate[:n_examples]
    problems["degenerate_triangles"] = _problem(
        len(degenerate),
        [
            {
                "triangle": int(t),
                "reason": "repeated vertex" if is_repeated else "zero area",
                "position": _pos(vertices[tv[t, 0]] + 0.0),
            }
            for t, is_repeated in zip(shown, np.isin(shown, repeated), strict=True)
        ],
    )

    # edges, orientation, fans, duplicates and components of the 2-cells
    table = _native.topology(tv, n_vertices, key, threads, False, wide=itype == np.int64)
    used = table["used"]  # (V,) uint8: in a 2-cell
    n_edges, n_used, n_kept = table["edges"], table["used_vertices"], table["kept"]

    def edge_examples(edges):
        lo, hi = _first_edges(edges, key, n_examples)
        return [
            {
                "vertices": [int(a), int(b)],
                "position": _pos(0.5 * ((vertices[a] + 0.0) + (vertices[b] + 0.0))),
            }
            for a, b in zip(lo, hi, strict=True)
        ]

    boundary = table["boundary"]
    on_domain = frame.same_face(vertices[boundary[:, 0]], vertices[boundary[:, 1]])
    holes = boundary[~on_domain]
    problems["boundary_edges_on_domain_boundary"] = _problem(
        on_domain.sum(), edge_examples(boundary[on_domain])
    )
    problems["boundary_edges_inside"] = _problem(len(holes), edge_examples(holes))
    nonmanifold_edges = table["non_manifold_edges"]
    problems["non_manifold_edges"] = _problem(
        len(nonmanifold_edges), edge_examples(nonmanifold_edges)
    )
    inconsistent = table["inconsistent"]
    problems["inconsistently_oriented_edges"] = _problem(
        len(inconsistent), edge_examples(inconsistent)
    )

    duplicates = _duplicate_groups(table, tv, merged, len(nonmanifold_edges) == 0)
    problems["duplicate_triangles"] = _problem(
        sum(len(g) - 1 for g in duplicates),
        [
            {"triangles": [int(t) for t in g], "position": _pos(vertices[tv[g[0], 0]] + 0.0)}
            for g in duplicates[:n_examples]
        ],
    )

    bad_vertices = table["non_manifold_vertices"]
    fans = table["fans"]
    shown = np.argsort(key[bad_vertices], kind="stable")[:n_examples]
    problems["non_manifold_vertices"] = _problem(
        len(bad_vertices),
        [
            {
                "vertex": int(bad_vertices[i]),
                "fans": int(fans[i]),
                "position": _pos(vertices[bad_vertices[i]] + 0.0),
            }
            for i in shown
        ],
    )

    # components, Euler characteristic and genus; components numbered as the
    # merged positions order their smallest vertex, then by size
    v_c, e_c, f_c = table["comp_vertices"], table["comp_edges"], table["comp_triangles"]
    open_c, bad_c = table["comp_open"].astype(bool), table["comp_bad"].astype(bool)
    chi_c = v_c - e_c + f_c
    components = []
    for c in np.lexsort((table["comp_min_key"], -f_c)):
        entry = {
            "triangles": int(f_c[c]),
            "vertices": int(v_c[c]),
            "euler": int(chi_c[c]),
            "closed": bool(not open_c[c]),
        }
        if not open_c[c] and not bad_c[c] and chi_c[c] % 2 == 0:
            entry["genus"] = int((2 - chi_c[c]) // 2)
        components.append(entry)

    if len(repeated):  # their vertices are referenced, though no 2-cell uses them
        referenced = used.view(bool).copy()
        referenced[tv[repeated].reshape(-1)] = True
        n_referenced = int(np.count_nonzero(referenced))
    else:
        n_referenced = n_used
    watertight = n_kept > 0 and len(boundary) == 0 and len(nonmanifold_edges) == 0
    oriented = len(inconsistent) == 0
    # a repeated position makes the cross product exactly zero: summing over
    # every triangle is summing over the 2-cells
    measures = {"area": 0.5 * area2}
    if watertight and oriented:
        # det[p0 - c, p1 - c, p2 - c] with c the mean used position, which keeps
        # the sum well conditioned
        measures["volume"] = float(_native.enclosed_volume(vertices, tv, used, threads))

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
        "no-degenerate": bool(len(degenerate) == 0),
        "no-duplicates": bool(len(duplicates) == 0),
        "no-holes": bool(len(holes) == 0),
    }
    topology = {
        "components": len(components),
        "euler_characteristic": int(n_used - n_edges + n_kept),
        "per_component": components,
    }
    return Report("triangles", counts, checks, problems, topology, measures, frame.name)


def _first_edges(edges: np.ndarray, key: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The first ``n`` edges in the order of the merged positions.

    Parameters
    ----------
    edges : (E, 2) int
        Representatives of each edge's ends.
    key : (V,) uint64
        Position keys (:func:`~isoconvert.graph.merge_positions`).
    n : int

    Returns
    -------
    lo, hi : (min(n, E),) int64
        Each edge's ends, the one with the smaller key first, ordered by the
        keys of ``lo`` then of ``hi`` (as the report has always listed them).
    """
    if n <= 0 or len(edges) == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty
    a, b = edges[:, 0].astype(np.int64), edges[:, 1].astype(np.int64)
    swap = key[a] > key[b]
    lo, hi = np.where(swap, b, a), np.where(swap, a, b)
    k_lo = key[lo]
    if len(lo) > 4 * n:  # only edges whose first key is among the n smallest can come first
        cut = np.partition(k_lo, n - 1)[n - 1]
        pick = np.flatnonzero(k_lo <= cut)
        lo, hi, k_lo = lo[pick], hi[pick], k_lo[pick]
    order = np.lexsort((key[hi], k_lo))[:n]
    return lo[order], hi[order]


def _duplicate_groups(
    table: dict, tv: np.ndarray, merged: MergedPositions, edge_manifold: bool
) -> list:
    """Groups of triangles with the same three vertices, in the report's order.

    Parameters
    ----------
    table : dict
        From the topology kernel: ``dup_triangles`` and ``dup_starts`` (groups
        found at their lowest edge, triangles ascending in each).
    tv : (F, 3) int
        Representatives of each triangle's corners.
    merged : MergedPositions
    edge_manifold : bool
        No edge is used by more than two triangles.

    Returns
    -------
    list of (k,) int64
        When no edge is used by more than two triangles, pairs ordered by their
        first triangle; otherwise groups ordered by the hash of their merged
        vertex numbers (:func:`~isoconvert.graph.row_groups` of the sorted
        triples), as the report has always listed them.
    """
    starts, members = table["dup_starts"], table["dup_triangles"]
    groups = [members[starts[g] : starts[g + 1]] for g in range(len(starts) - 1)]
    if len(groups) < 2:
        return groups
    if edge_manifold:
        return sorted(groups, key=lambda g: int(g[0]))
    firsts = np.array([g[0] for g in groups])
    triples = np.sort(merged.ranks(tv[firsts].reshape(-1)).reshape(-1, 3), axis=1)
    h = mix64(triples[:, 0])
    for col in (1, 2):
        h = mix64(h ^ triples[:, col].view(np.uint64))
    # equal hashes of different triples (never seen) fall back to their order
    order = np.lexsort((triples[:, 2], triples[:, 1], triples[:, 0], h))
    return [groups[i] for i in order]


# --- segments ----------------------------------------------------------------------------


def _check_segments(vertices, cells, frame, n_examples) -> Report:
    unique, inverse, first = _merge(vertices)
    segs = inverse[cells]
    n_u = len(unique)
    problems: dict = {}
    # a segment whose ends are at one position, by two indices or by one index
    # twice, has zero length and is degenerate (as a triangle that repeats a
    # position is), whichever way its ends meet
    zero = segs[:, 0] == segs[:, 1]
    problems["zero_length_segments"] = _problem(
        zero.sum(),
        [
            {"segment": int(s), "position": _pos(unique[segs[s, 0]])}
            for s in np.flatnonzero(zero)[:n_examples]
        ],
    )
    problems["degenerate_segments"] = _problem(
        zero.sum(), [{"segment": int(s)} for s in np.flatnonzero(zero)[:n_examples]]
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
        "no-degenerate": bool(not zero.any()),
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
    made = report.extraction
    if made:
        # post-processing (--keep-largest, --decimate, ...) may change the topology since
        lines.append(
            f"  extracted by {made['method']}, --ambiguity {made['ambiguity']}"
            + (f" (topology as extracted: {made['topology']})" if "topology" in made else "")
        )
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
        unit = m.get("unit")
        squared, cubed = (f" {unit}²", f" {unit}³") if unit else ("", "")
        lines.append(
            f"  area {m['area']:.6g}{squared}"
            + (f", enclosed volume {m['volume']:.6g}{cubed}" if "volume" in m else "")
        )
        surfaces = t.get("per_label", [])
        for surface in surfaces[:_LABEL_LINES]:
            failed = [check for check in LABEL_CHECKS if not surface[check]]
            lines.append(
                f"  label {surface['label']}: {surface['triangles']:,} triangles, "
                f"{surface['components']} component(s)"
                + (f", volume {surface['volume']:.6g}{cubed}" if "volume" in surface else "")
                + (f", not {', '.join(failed)}" if failed else ", closed")
            )
        if len(surfaces) > _LABEL_LINES:
            lines.append(f"  ... and {len(surfaces) - _LABEL_LINES} more labels (--json lists all)")
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
            + (f" {report.measures['unit']}" if report.measures.get("unit") else "")
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
    if report.boundary_frame == "none":
        if NO_FRAME_NOTE not in report.notes:
            lines.append("  (no grid recorded: an open boundary would count as a hole)")
    elif BOUNDING_BOX_NOTE not in report.notes:
        lines.append(f"  (boundaries judged against the {report.boundary_frame})")
    return "\n".join(lines)


def _short(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in value) + ")"
    return str(value)
