"""The main job: read a volume, extract a surface, write it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .atomic import check_output
from .errors import OutputError
from .extract import extract
from .mesh import Mesh
from .readers import read_volume
from .volume import Volume
from .writers import output_format, write_mesh


@dataclass
class ConvertResult:
    """What :func:`convert` made; ``volume.notes`` says what the reader assumed."""

    volume: Volume
    mesh: Mesh
    output: Path


def convert(
    input: str | Path,
    output: str | Path,
    level: float | str,
    *,
    method: str | None = None,
    format: str | None = None,
    ascii: bool = False,
    force: bool = False,
    flip: bool = False,
    ambiguity: str | None = None,
    axis: str | None = None,
    vertex_offset: float | None = None,
    nan_as: float | None = None,
    input_format: str | None = None,
    spacing: tuple[float, ...] | None = None,
    origin: tuple[float, ...] | None = None,
    on_status: Callable[[str], None] | None = None,
    on_progress: Callable[[str], None] | None = None,
    **read_options,
) -> ConvertResult:
    """Read ``input``, extract the isosurface at ``level``, write it to ``output``.

    Everything that can be checked before the work is checked first (output
    format and folder, existing file), so a mistake costs no extraction time.
    Parameters are those of :func:`read_volume`, :func:`extract` and
    :func:`write_mesh`; ``on_progress`` is called with the stage starting
    ("reading", "extracting", "writing").
    """
    progress = on_progress or (lambda stage: None)
    check_output(output, force)  # first: a folder given as -o is "a folder", not a format
    writer = output_format(output, format)
    if Path(output).resolve() == Path(input).resolve():
        raise OutputError(f"{output}: is the input file; choose another output name")
    progress("reading")
    volume = read_volume(input, format=input_format, spacing=spacing, origin=origin, **read_options)
    options = {} if axis is None else {"axis": axis}
    if vertex_offset is not None:
        options["vertex_offset"] = vertex_offset
    progress("extracting")
    mesh = extract(
        volume,
        level,
        method=method,
        flip=flip,
        ambiguity=ambiguity,
        nan_as=nan_as,
        on_status=on_status,
        **options,
    )
    progress("writing")
    path = write_mesh(mesh, output, format=writer.name, ascii=ascii, force=force)
    return ConvertResult(volume, mesh, path)
