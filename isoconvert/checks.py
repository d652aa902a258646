"""The names of the mesh checks and what each one asks, without the checks themselves.

``--require`` takes these names; the CLI lists them in its help without
importing :mod:`isoconvert.report` (and numpy), which runs the checks.
"""

from __future__ import annotations

from .errors import IsoconvertError

#: Checks on triangle meshes, for ``--require``.
TRIANGLE_CHECKS = {
    "watertight": "every edge in exactly two triangles",
    "manifold": "no edge in more than two triangles; triangles around a vertex form one fan",
    "oriented": "triangles sharing an edge use it in opposite directions",
    "no-zero-length": "no edge whose ends are at the same position (or are one vertex)",
    "no-degenerate": "no triangle with a repeated vertex or zero area",
    "no-duplicates": "no triangle listed twice",
    "no-holes": "boundary edges only on the grid (or bounding-box) boundary",
}
#: Checks on contour segments, for ``--require``.
SEGMENT_CHECKS = {
    "watertight": "every polyline closed (every vertex ends one segment and starts one)",
    "manifold": "no vertex in more than two segments",
    "oriented": "polylines run one way (no vertex starts or ends two segments)",
    "no-zero-length": "no segment whose ends are at the same position (or are one vertex)",
    "no-degenerate": "no segment with a repeated vertex or position",
    "no-duplicates": "no segment listed twice",
    "no-holes": "open polylines end only on the grid (or bounding-box) boundary",
}
CHECK_NAMES = tuple(TRIANGLE_CHECKS)


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


__all__ = ["CHECK_NAMES", "SEGMENT_CHECKS", "TRIANGLE_CHECKS", "parse_requirements"]
