"""The extraction methods by name: the registry, without importing the methods.

The CLI builds its help and its ``methods`` listing from here, so neither
imports numpy nor the kernels; :mod:`isoconvert.extract` holds the methods
themselves and is imported when one is first used. Third-party methods
register under the entry-point group :data:`PLUGIN_GROUP` (see
:mod:`isoconvert.extract` for the contract).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .lazy import LazyFunction
from .registry import Registry

if TYPE_CHECKING:
    from .mesh import Mesh

PLUGIN_GROUP = "isoconvert.extractors"
#: The vertex offset ``--no-degenerate`` uses: vertices keep a thousandth of
#: their edge's length from grid vertices.
NO_DEGENERATE_OFFSET = 1e-3
#: Rules for the ambiguous faces of cubes (the first is the default).
AMBIGUITY_RULES = ("separate-positive", "separate-negative")
#: The default rule. It is the one VTK's Marching Cubes / Flying Edges table and
#: scikit-image's ``method="lorensen"`` follow (and, in 2D, ``find_contours``
#: with its default ``fully_connected="low"``), so counts and connectivity agree
#: with theirs (checked on real scans in the tests).
DEFAULT_AMBIGUITY = AMBIGUITY_RULES[0]
#: Rules for ambiguous squares: those of cubes, and the asymptotic decider.
SQUARE_AMBIGUITY_RULES = (*AMBIGUITY_RULES, "asymptotic")
#: The cubes' rule that follows the trilinear interpolant (faces by the
#: asymptotic decider, the inside by its body saddles; extract/trilinear.py).
TRILINEAR = "trilinear"
#: Rules cubes take: the fixed ones, and the trilinear topology.
CUBE_AMBIGUITY_RULES = (*AMBIGUITY_RULES, TRILINEAR)
#: Every rule some method takes (the CLI's choices).
ALL_AMBIGUITY_RULES = (*SQUARE_AMBIGUITY_RULES, TRILINEAR)


# The record of a method lives here, with the table of them, so that the table
# needs nothing of isoconvert.extract (which imports this module) to be typed.
@dataclass(frozen=True)
class Extractor:
    """An isosurface (or isocontour) method.

    Attributes
    ----------
    name : str
    summary : str
        One line for ``isoconvert methods``.
    ndims : tuple of int
        Volume dimensions it accepts.
    run : callable
        The function described in :mod:`isoconvert.extract`'s docstring.
    ambiguity : tuple of str
        Ambiguity rules it accepts (the first is its default).
    options : frozenset of str
        Extra keyword options it takes (e.g. ``axis``).
    prepared : bool
        It validates its input with :func:`~isoconvert.extract.prepare.prepare`,
        which also resolves ``vertex_offset=None`` and records the offset used in
        ``mesh.info``; its result is trusted. False (plugins): :func:`isoconvert.extract.extract`
        resolves the offset beforehand and checks the result.
    """

    name: str
    summary: str
    ndims: tuple[int, ...]
    run: Callable[..., Mesh]
    ambiguity: tuple[str, ...] = (AMBIGUITY_RULES[0],)  # extract.tables.DEFAULT_AMBIGUITY
    options: frozenset[str] = field(default_factory=frozenset)
    prepared: bool = False


EXTRACTORS: Registry[Extractor] = Registry(
    "extraction method",
    plugin_group=PLUGIN_GROUP,
    adapt=LazyFunction("isoconvert.extract.dispatch:_from_plugin"),
)
EXTRACTORS.declare(
    "cubes",
    "isoconvert.extract.dispatch:CUBES",
    summary="Marching Cubes (3D): triangles; watertight closed surfaces; table derived in code",
)
EXTRACTORS.declare(
    "tetra",
    "isoconvert.extract.dispatch:TETRA",
    summary="Marching Tetrahedra (3D): six tetrahedra per cube, no ambiguous cases, more triangles",
)
EXTRACTORS.declare(
    "squares",
    "isoconvert.extract.dispatch:SQUARES",
    summary="Marching Squares (2D images, or every slice of a 3D volume across --axis): segments",
)

__all__ = [
    "ALL_AMBIGUITY_RULES",
    "AMBIGUITY_RULES",
    "CUBE_AMBIGUITY_RULES",
    "EXTRACTORS",
    "Extractor",
    "NO_DEGENERATE_OFFSET",
    "PLUGIN_GROUP",
    "SQUARE_AMBIGUITY_RULES",
    "TRILINEAR",
]
