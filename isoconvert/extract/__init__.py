"""Extractors: one module per method and the table of built-ins below.

An extractor is a function ``(volume, level, *, flip, ambiguity, nan_as,
on_status) -> Mesh`` taking a validated :class:`~isoconvert.volume.Volume` of
its dimension and returning vertices in world units with the orientation
convention of ARCHITECTURE.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..mesh import Mesh
from ..registry import Registry
from ..volume import Volume
from .cubes import marching_cubes
from .tables import AMBIGUITY_RULES, DEFAULT_AMBIGUITY


@dataclass(frozen=True)
class Extractor:
    """An isosurface method."""

    name: str
    summary: str
    ndim: int
    run: Callable[..., Mesh]


EXTRACTORS: Registry[Extractor] = Registry("extraction method")
EXTRACTORS.register(
    "cubes",
    Extractor(
        "cubes",
        "Marching Cubes (3D): triangles, watertight on closed surfaces; table derived in code",
        3,
        marching_cubes,
    ),
)


def extract(
    volume: Volume,
    level: float | str,
    *,
    method: str = "cubes",
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract the isosurface (or isocontour) of ``volume`` at ``level``.

    Parameters
    ----------
    volume : Volume
    level : float or "auto"
        The isovalue; "auto" takes Otsu's threshold of the volume's histogram.
    method : str
        Name of an extractor in :data:`EXTRACTORS`.
    flip : bool
        Reverse the orientation.
    ambiguity : str
        Rule for ambiguous faces, one of :data:`AMBIGUITY_RULES`.
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    on_status : callable or None
        Receives one-line notices for the user.

    Returns
    -------
    Mesh
    """
    extractor = EXTRACTORS.get(method)
    if ambiguity not in AMBIGUITY_RULES:
        from ..errors import IsoconvertError

        raise IsoconvertError(
            f"unknown ambiguity rule {ambiguity!r}; choose one of: {', '.join(AMBIGUITY_RULES)}"
        )
    if isinstance(level, str):
        level = resolve_level(volume, level, on_status)
    return extractor.run(
        volume, level, flip=flip, ambiguity=ambiguity, nan_as=nan_as, on_status=on_status
    )


def resolve_level(volume: Volume, level: str, on_status: Callable[[str], None] | None) -> float:
    """A number from the text of a level: a float, or "auto" (Otsu)."""
    from ..errors import LevelError
    from ..stats import histogram, otsu_level

    if level.strip().lower() == "auto":
        value = otsu_level(histogram(volume.data))
        if on_status:
            on_status(f"level auto: Otsu threshold {value:g}")
        return value
    try:
        return float(level)
    except ValueError:
        raise LevelError(f"--level must be a number or 'auto', got {level!r}") from None


__all__ = ["EXTRACTORS", "Extractor", "extract", "AMBIGUITY_RULES", "DEFAULT_AMBIGUITY"]
