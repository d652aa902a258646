"""Writers: one module per format and the table of built-ins below."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from ..atomic import atomic_output
from ..errors import FormatError
from ..mesh import Mesh
from ..registry import Registry
from .obj import write_obj
from .ply import write_ply
from .stl import write_stl
from .svg import write_svg


@dataclass(frozen=True)
class Writer:
    """A mesh format: its file suffixes and how to write it to a binary stream."""

    name: str
    summary: str
    suffixes: tuple[str, ...]
    write: Callable[[Mesh, BinaryIO, bool], None]
    #: whether the format has a binary form (``ascii=False``)
    has_binary: bool
    #: cell sizes it can hold: 3 (triangles), 2 (segments)
    cell_sizes: frozenset[int] = frozenset({2, 3})
    #: cell sizes it can hold: 3 (triangles), 2 (segments)
    cell_sizes: frozenset[int] = frozenset({2, 3})


WRITERS: Registry[Writer] = Registry("output format")
_TRIANGLES = frozenset({3})
_SEGMENTS = frozenset({2})
for _writer in (
    Writer("ply", "Stanford PLY, indexed; binary (default) or --ascii", (".ply",), write_ply, True),
    Writer("obj", "Wavefront OBJ, indexed; text", (".obj",), write_obj, False),
    Writer(
        "stl",
        "STL, one record per triangle; binary (default) or --ascii",
        (".stl",),
        write_stl,
        True,
        _TRIANGLES,
    ),
    Writer(
        "svg",
        "SVG picture of 2D contours (squares on a 2D image)",
        (".svg",),
        write_svg,
        False,
        _SEGMENTS,
    ),
):
    WRITERS.register(_writer.name, _writer)


def output_format(path: str | Path, format: str | None = None) -> Writer:
    """The writer named by ``format``, else by the file suffix."""
    if format:
        return WRITERS.get(format)
    suffix = Path(path).suffix.lower()
    found = WRITERS.by_suffix(suffix)
    if found:
        return found[1]
    raise FormatError(
        f"{path}: unknown output extension {suffix or '(none)'!r}; "
        f"known output formats: {WRITERS.suffix_listing()}; or name one with --format"
    )


def write_mesh(
    mesh: Mesh,
    path: str | Path,
    *,
    format: str | None = None,
    ascii: bool = False,
    force: bool = False,
) -> Path:
    """Write ``mesh`` to ``path`` atomically (a temporary file, then a rename).

    Parameters
    ----------
    mesh : Mesh
    path : str or Path
    format : str or None
        ``ply``, ``obj`` or ``stl``; None takes it from the suffix.
    ascii : bool
        Text instead of binary for PLY and STL (OBJ is always text).
    force : bool
        Overwrite an existing file.
    """
    writer = output_format(path, format)
    size = mesh.cells.shape[1]
    if size not in writer.cell_sizes:
        kind = {2: "contour segments", 3: "triangles"}.get(size, f"{size}-vertex cells")
        fits = [n for n, w in WRITERS.items() if size in w.cell_sizes]
        raise FormatError(f"{path}: {writer.name} cannot hold {kind}; write {' or '.join(fits)}")
    with atomic_output(path, force) as fh:
        writer.write(mesh, fh, ascii or not writer.has_binary)
    return Path(path)


__all__ = ["WRITERS", "Writer", "output_format", "write_mesh"]
