"""The report's problems of a mesh as positions to draw."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..mesh import Mesh

#: Problems drawn per kind at most (a mesh in pieces can have millions; the
#: legend says when only some were drawn).
MAX_MARKS = 20_000

#: Report problem name -> (legend label, RGB). Saturated colours a grey shaded
#: surface never takes, so a pixel of one of them is that problem.
PROBLEMS: dict[str, tuple[str, tuple[int, int, int]]] = {
    "boundary_edges_inside": ("holes (boundary edges inside)", (230, 0, 0)),
    "non_manifold_edges": ("non-manifold edges", (200, 0, 200)),
    "non_manifold_vertices": ("non-manifold vertices", (255, 140, 0)),
    "zero_length_edges": ("zero-length edges", (0, 110, 255)),
}


# --- problems -----------------------------------------------------------------------------


@dataclass
class Marks:
    """The problems to draw, as world positions.

    Attributes
    ----------
    edges : dict of str -> (N, 2, 3) float64
        Ends of the edges of each edge problem.
    points : dict of str -> (N, 3) float64
        Positions of each point problem.
    counts : dict of str -> int
        How many the report found (may exceed what is drawn, see :data:`MAX_MARKS`).
    boundary_frame : str
        What boundaries were judged against ("grid", "bounding box" or "none").
    failed : list of str
        The checks the report fails (:data:`isoconvert.checks.CHECK_NAMES`), so
        that the picture says what ``isoconvert check`` says, drawn or not.
    non_finite : int
        Vertices with a NaN or infinite coordinate (not drawn; the report then
        fails every check).
    """

    edges: dict = field(default_factory=dict)
    points: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    boundary_frame: str = ""
    failed: list = field(default_factory=list)
    non_finite: int = 0


def find_marks(mesh: Mesh, grid: dict | None = None, limit: int = MAX_MARKS, report=None) -> Marks:
    """The report's problems of ``mesh`` as positions to draw.

    Parameters
    ----------
    mesh : Mesh
        Triangles, as checked (for a file, as the file holds them).
    grid : dict or None
        The grid boundaries are judged against (default ``mesh.info["grid"]``).
    limit : int
        At most this many of each kind (the report's first ones).
    report : MeshReport or None
        The report of ``mesh`` when the caller has it, made with ``examples=limit``
        (a batch checks each mesh once for ``--require`` and the thumbnail).
    """
    if report is None:
        from ..report import check_mesh

        report = check_mesh(mesh, examples=limit, grid=grid)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    marks = Marks(boundary_frame=report.boundary_frame)
    marks.failed = [name for name, ok in report.checks.items() if not ok]
    marks.non_finite = int(report.problems.get("non_finite_vertices", {}).get("count", 0))
    for name in PROBLEMS:
        problem = report.problems[name]
        marks.counts[name] = int(problem["count"])
        examples = problem["examples"]
        if name == "non_manifold_vertices":
            ids = np.array([e["vertex"] for e in examples], dtype=np.int64)
            marks.points[name] = v[ids].reshape(-1, 3)
        elif name == "zero_length_edges":  # both ends at one place: a point
            ids = np.array([e["vertices"][0] for e in examples], dtype=np.int64)
            marks.points[name] = v[ids].reshape(-1, 3)
        else:
            ids = np.array([e["vertices"] for e in examples], dtype=np.int64).reshape(-1, 2)
            marks.edges[name] = v[ids].reshape(-1, 2, 3)
    return marks
