"""Mesh checks: degenerate elements, manifoldness, orientation, topology.

The report looks at the surface as its positions define it: vertices at exactly
the same position are merged first (their number is reported). That is what a
slicer or a viewer sees, what STL (which has no shared vertices) needs, and
what turns the book's degenerate cases into findings: a ring of vertices that
all sit on the grid vertex where two spheres touch (Wenger, section 1.3) merges
into one non-manifold vertex, a vertex interpolated onto a grid vertex whose
value equals the isovalue makes zero-length edges (sections 2.2.4, 2.3.4).

Everything is vectorized numpy; no numba, so ``isoconvert check`` starts fast.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .graph import connected_components, group_sizes, row_groups
from .mesh import Mesh

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
    from .errors import IsoconvertError

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


class _Frame:
    """Tells whether points lie on a face of the grid (or of the bounding box)."""

    def __init__(self, mesh: Mesh, vertices: np.ndarray) -> None:
        grid = mesh.info.get("grid")
        if grid is not None:
            shape = np.asarray(grid["shape"], dtype=np.float64)
            nd = len(shape)
            self.name = "grid"
            self._origin = np.asarray(grid["origin"], dtype=np.float64)
            self._inverse = np.linalg.inv(np.asarray(grid["affine"], dtype=np.float64))
            self._lo = np.zeros(nd)
            self._hi = shape - 1
            self._nd = nd
            self._tol = 1e-6
        else:
            self.name = "bounding box"
            self._origin = None
            self._nd = 3
            finite = vertices[np.isfinite(vertices).all(axis=1)]
            self._lo = finite.min(axis=0) if len(finite) else np.zeros(3)
            self._hi = finite.max(axis=0) if len(finite) else np.zeros(3)
            self._tol = 1e-9 * max(float(np.max(self._hi - self._lo)), 1e-300)

    def faces(self, points: np.ndarray) -> np.ndarray:
        """(N, 2 * nd) bool: point on the low / high face of each axis."""
        p = points[:, : self._nd]
        if self._origin is not None:
            p = (p - self._origin) @ self._inverse.T
        low = np.abs(p - self._lo) <= self._tol
        high = np.abs(p - self._hi) <= self._tol
        return np.concatenate([low, high], axis=1)

    def same_face(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(N,) bool: segment a-b lies in one face of the domain."""
        return (self.faces(a) & self.faces(b)).any(axis=1)


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


def check_mesh(mesh: Mesh, *, examples: int = 5, source: str = "") -> Report:
    """Check a triangle mesh or a set of contour segments.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)``. When
        ``mesh.info["grid"]`` describes the volume it came from (extracted
        meshes carry it), boundaries are judged against that grid; otherwise
        against the mesh's bounding box.
    examples : int
        How many examples to give per kind of problem.
    source : str
        Name for the report.

    Returns
    -------
    Report
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    if (
        vertices.ndim != 2
        or vertices.shape[1] != 3
        or cells.ndim != 2
        or cells.shape[1] not in (2, 3)
    ):
        from .errors import IsoconvertError

        raise IsoconvertError(
            f"{source or 'mesh'}: expected (V, 3) vertices and (C, 3) or (C, 2) cells"
        )
    finite = np.isfinite(vertices).all(axis=1)
    frame = _Frame(mesh, vertices)
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
        report.checks = {name: False for name in report.checks}
    return report


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

    # degenerate triangles: a repeated vertex (after merging), or zero area
    repeated = (tris[:, 0] == tris[:, 1]) | (tris[:, 1] == tris[:, 2]) | (tris[:, 0] == tris[:, 2])
    p0, p1, p2 = unique[tris[:, 0]], unique[tris[:, 1]], unique[tris[:, 2]]
    cross = np.cross(p1 - p0, p2 - p0)
    area2 = np.linalg.norm(cross, axis=1)
    flat = ~repeated & (area2 == 0)
    degenerate = repeated | flat
    examples_deg = [
        {
            "triangle": int(t),
            "reason": "repeated vertex" if repeated[t] else "zero area",
            "position": _pos(p0[t]),
        }
        for t in np.flatnonzero(degenerate)[:n_examples]
    ]
    problems["degenerate_triangles"] = _problem(degenerate.sum(), examples_deg)

    keep = np.flatnonzero(~degenerate)
    tv = tris[keep]
    n_u = len(unique)

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

    # components, Euler characteristic and genus
    used = np.flatnonzero(np.bincount(tv.reshape(-1), minlength=n_u))
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
    area = 0.5 * float(area2[keep].sum())
    measures = {"area": area}
    if watertight and oriented:
        # det[p0 - c, p1 - c, p2 - c] = (p0 - c) . ((p1 - p0) x (p2 - p0)); c near the
        # mesh keeps the sum well conditioned
        c = unique[used].mean(axis=0)
        measures["volume"] = float(np.einsum("ij,ij->", p0[keep] - c, cross[keep]) / 6.0)

    counts = {
        "vertices": n_vertices,
        "merged_vertices": n_vertices - n_u,
        "unreferenced_vertices": int(n_u - len(used)),
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
        "unreferenced_vertices": int(n_u - len(used)),
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
    """A compact table with PASS / FAIL marks, then the first examples of each problem."""
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
    lines.append(f"  (boundaries judged against the {report.boundary_frame})")
    return "\n".join(lines)


def _short(value) -> str:
    if isinstance(value, list):
        return "(" + ", ".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in value) + ")"
    return str(value)
