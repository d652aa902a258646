"""The built-in extractors' table entries and :func:`extract`, which checks a
request and hands it to its method (in memory, or block-wise through
:mod:`isoconvert.extract.blocks`). The package's contract and layering are in
:mod:`isoconvert.extract`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..methods import (
    CUBE_AMBIGUITY_RULES,
    EXTRACTORS,
    NO_DEGENERATE_OFFSET,
    PLUGIN_GROUP,
    Extractor,
)
from ..volume import Volume
from .blocks import BLOCK_METHODS, Blocks, extract_blocks
from .cubes import marching_cubes
from .prepare import count_equal, resolve_vertex_offset
from .squares import SQUARE_AMBIGUITY_RULES, marching_squares
from .tables import AMBIGUITY_RULES, DEFAULT_AMBIGUITY
from .tetra import marching_tetrahedra


def _from_plugin(name: str, obj: object) -> Extractor:
    if isinstance(obj, Extractor):
        return obj
    if callable(obj):
        doc = (getattr(obj, "__doc__", None) or f"plugin {name}").strip().splitlines()[0]
        return Extractor(name, doc, (3,), obj)
    raise IsoconvertError(f"extractor plugin {name!r} is neither an Extractor nor a function")


# The built-ins, which :data:`isoconvert.methods.EXTRACTORS` names and loads on first use.
CUBES = Extractor(
    "cubes",
    EXTRACTORS.summary("cubes"),
    (3,),
    marching_cubes,
    CUBE_AMBIGUITY_RULES,
    frozenset({"vertex_offset"}),
    prepared=True,
)
TETRA = Extractor(
    "tetra",
    EXTRACTORS.summary("tetra"),
    (3,),
    marching_tetrahedra,
    options=frozenset({"vertex_offset"}),
    prepared=True,
)
SQUARES = Extractor(
    "squares",
    EXTRACTORS.summary("squares"),
    (2, 3),
    marching_squares,
    SQUARE_AMBIGUITY_RULES,
    frozenset({"axis", "vertex_offset"}),
    prepared=True,
)


def default_method(volume: Volume) -> str:
    """squares for 2D images, cubes for 3D volumes."""
    return "squares" if volume.ndim == 2 else "cubes"


def extract(
    volume: Volume,
    level: float | str,
    *,
    method: str | None = None,
    flip: bool = False,
    ambiguity: str | None = None,
    nan_as: float | None = None,
    on_status: Callable[[str], None] | None = None,
    blocks: Blocks | None = None,
    normals: bool = False,
    **options,
) -> Mesh:
    """Extract the isosurface (or isocontour) of ``volume`` at ``level``.

    Parameters
    ----------
    volume : Volume
    level : float or "auto"
        The isovalue; "auto" takes Otsu's threshold of the volume's histogram.
    method : str or None
        Name in :data:`EXTRACTORS` (``cubes``, ``tetra``, ``squares`` or a
        plugin); None picks squares for 2D and cubes for 3D.
    flip : bool
        Reverse the orientation.
    ambiguity : str or None
        Rule for ambiguous faces, one the method accepts; None is its default.
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    on_status : callable or None
        Receives one-line notices for the user.
    blocks : Blocks or None
        Block-wise extraction (:mod:`isoconvert.extract.blocks`): a slab size,
        a memory budget, a Dask scheduler. None (or the defaults) extracts a
        volume read from its file block-wise (plugins excepted) and an array
        in memory at once; the mesh is the same either way.
    **options
        Method-specific options: ``axis`` (squares on 3D volumes),
        ``vertex_offset`` (built-ins: keep vertices this fraction of their edge
        away from grid vertices, so that a level equal to grid values makes no
        zero-length edges). Left out or None, it is :data:`NO_DEGENERATE_OFFSET`
        when some sample equals the level and 0 otherwise (a notice says so);
        0 places every vertex exactly by linear interpolation.
    normals : bool
        Give ``mesh.normals`` (those of :func:`isoconvert.vertex_normals`, the
        same bits) where the extraction computes them in its filling pass, from
        the gradients at the ends of each bipolar edge: Marching Cubes on a
        volume in memory, or block-wise with its slabs run here (each read with
        2 more layers each way, see
        :func:`~isoconvert.extract.blocks.extract_blocks`). Elsewhere
        ``mesh.normals`` stays None, for ``vertex_normals`` to sample after
        extraction: block-wise with the trilinear rule (its interior vertices
        need the samples again) or on a cluster, tetrahedra (vertices on cube
        diagonals, where the gradient is not linear along the edge), squares
        and plugins. A mesh without triangles gets none either.

    Returns
    -------
    Mesh
    """
    name = method or default_method(volume)
    extractor = EXTRACTORS.get(name)
    if volume.ndim not in extractor.ndims:
        other = "squares" if volume.ndim == 2 else "cubes or tetra"
        raise IsoconvertError(
            f"{volume.source}: {name} needs a {' or '.join(f'{d}D' for d in extractor.ndims)} "
            f"volume, got shape {volume.shape}; use --method {other}"
        )
    if ambiguity is None:
        ambiguity = extractor.ambiguity[0]
    if ambiguity not in extractor.ambiguity:
        raise IsoconvertError(
            f"{name} takes --ambiguity {', '.join(extractor.ambiguity)}; got {ambiguity!r}"
        )
    stray = set(options) - extractor.options
    if stray:
        raise IsoconvertError(f"{name} has no option {', '.join(sorted(stray))}")
    if isinstance(level, str):
        level = resolve_level(volume, level, on_status, nan_as)
    blocks = blocks or Blocks()
    block_wise = extractor.prepared and name in BLOCK_METHODS
    if blocks.asked and not block_wise:
        raise IsoconvertError(
            f"{name} does not run block-wise; use --method {', '.join(BLOCK_METHODS)}"
        )
    if block_wise and blocks.wanted(volume):
        return extract_blocks(
            volume,
            float(level),
            method=name,
            flip=flip,
            ambiguity=ambiguity,
            nan_as=nan_as,
            blocks=blocks,
            on_status=on_status,
            normals=normals,
            **options,
        )
    placement_note = None
    if "vertex_offset" in extractor.options and not extractor.prepared:
        given = options.get("vertex_offset")
        equal = count_equal(volume.samples, level) if given in (None, 0) else 0
        options["vertex_offset"], placement_note = resolve_vertex_offset(
            volume.dtype, float(level), given, equal
        )
    if normals and extractor.run is marching_cubes:
        options["normals"] = True
    mesh = extractor.run(
        volume,
        float(level),
        flip=flip,
        ambiguity=ambiguity,
        nan_as=nan_as,
        on_status=on_status,
        **options,
    )
    if not extractor.prepared:
        _check_result(name, mesh)
        if "vertex_offset" in options:
            mesh.info["vertex_offset"] = options["vertex_offset"]
    if placement_note and on_status:  # only once the level proved usable
        on_status(placement_note)
    return mesh


def _check_result(name: str, mesh: object) -> None:
    """A plugin's result must keep the Mesh contract before a writer sees it."""
    ok = (
        isinstance(mesh, Mesh)
        and mesh.vertices.ndim == 2
        and mesh.vertices.shape[1] == 3
        and mesh.cells.ndim == 2
        and mesh.cells.shape[1] in (2, 3)
        and (
            mesh.cells.size == 0
            or (0 <= mesh.cells.min() and mesh.cells.max() < len(mesh.vertices))
        )
    )
    if not ok:
        raise IsoconvertError(f"extractor {name!r} returned something that is not a valid Mesh")
    mesh.cells = np.asarray(mesh.cells, dtype=np.int64)


def resolve_level(
    volume: Volume,
    level: str,
    on_status: Callable[[str], None] | None,
    nan_as: float | None = None,
) -> float:
    """A number from the text of a level: a float, or "auto" (Otsu, of the samples
    as extraction sees them: NaN/Inf as ``nan_as`` when given)."""
    from ..errors import LevelError
    from ..stats import histogram, otsu_level

    if level.strip().lower() == "auto":
        try:
            value = otsu_level(histogram(volume.samples, nan_as))
        except LevelError as exc:  # no level gives a surface: say so, invent none
            raise LevelError(f"{volume.source}: --level auto: {exc}") from None
        if on_status:
            on_status(f"level auto: Otsu threshold {value:g}")
        return value
    try:
        return float(level)
    except ValueError:
        raise LevelError(f"--level must be a number or 'auto', got {level!r}") from None


__all__ = [
    "CUBES",
    "SQUARES",
    "TETRA",
    "AMBIGUITY_RULES",
    "Blocks",
    "DEFAULT_AMBIGUITY",
    "EXTRACTORS",
    "NO_DEGENERATE_OFFSET",
    "PLUGIN_GROUP",
    "SQUARE_AMBIGUITY_RULES",
    "Extractor",
    "default_method",
    "extract",
    "resolve_level",
]
