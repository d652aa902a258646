"""What a file of each format stores (:func:`stored_mesh`), and writing it (:func:`write_mesh`).

One code path decides the stored precision, STL's three vertices per
triangle and which header records the grid; see :mod:`isoconvert.writers`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..atomic import atomic_output
from ..errors import FormatError
from ..geometry import normalized_grid
from ..mesh import Mesh
from . import WRITERS, Writer, check_attributes, output_format
from .chunks import row_chunks
from .precision import Float32Loss, float32_loss


def _check_cells(writer: Writer, mesh: Mesh, name: str | Path) -> None:
    size = mesh.cells.shape[1]
    if size not in writer.cell_sizes:
        kind = {2: "contour segments", 3: "triangles"}.get(size, f"{size}-vertex cells")
        fits = [n for n, w in WRITERS.items() if size in w.cell_sizes]
        raise FormatError(f"{name}: {writer.name} cannot hold {kind}; write {' or '.join(fits)}")
    cells = np.asarray(mesh.cells)
    n = len(mesh.vertices)
    if any(block.min() < 0 or block.max() >= n for block in row_chunks(cells) if block.size):
        bad = (cells < 0) | (cells >= n)
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        index = int(cells[row][bad[row]][0])
        kind = "triangle" if size == 3 else "segment"
        raise FormatError(
            f"{name}: {kind} {row} of the mesh refers to vertex {index}, "
            f"but the mesh has {n} vertices"
        )
    check_attributes(
        writer,
        name,
        normals=mesh.normals is not None,
        values=mesh.values is not None,
        labels=mesh.cell_labels is not None,
    )


def _refuse_layer(writer: Writer) -> None:
    """A layer format is a folder of every object, written by its own function."""
    if writer.layer:
        from .precomputed import LAYER_ONLY

        raise FormatError(LAYER_ONLY)


def _stored(
    writer: Writer, mesh: Mesh, on_status: Callable[[str], None] | None, expand: bool = True
) -> Mesh:
    """The one code path behind :func:`stored_mesh` and :func:`write_mesh`.

    With ``expand=False`` (writing) the vertices stay as they are, float64,
    and a format that ``expands`` gets only the vertices its cells use, still
    indexed: the writers round to ``info["stored_precision"]`` and expand
    block by block (as ``vertices[cells]``, which leaves an expanded mesh as it
    is), so writing needs no copy of the mesh.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    cells = np.asarray(mesh.cells, dtype=np.int64)
    normals, values = mesh.normals, mesh.values
    kind = "triangles" if cells.shape[1] == 3 else "segments"
    if writer.expands and len(cells):
        # only the vertices that cells use reach the file
        used = np.zeros(len(vertices), dtype=bool)
        for block in row_chunks(cells):
            used[block.ravel()] = True
        if not used.all():
            renumber = np.cumsum(used) - 1
            vertices, cells = vertices[used], renumber[cells]
            normals = None if normals is None else normals[used]
            values = None if values is None else values[used]
    elif writer.expands:
        vertices = vertices[:0]
    precision = writer.precision
    if precision == "adaptive":
        loss, whole = _float32_loss(vertices, cells, mesh)
        precision = "float64" if loss.any else "float32"
        if loss.any and on_status:
            on_status(
                "note: vertex coordinates written as double: in float32, "
                + ("" if whole else "at least ")
                + loss.describe(kind)
            )
    elif precision == "float32":
        loss = float32_loss(vertices, cells)
        if loss.any and on_status:
            on_status(
                f"note: {writer.name.upper()} stores float32: {loss.describe(kind)} at that "
                "precision; write PLY (which then stores doubles) or OBJ, or move the origin "
                "nearer the mesh"
            )
    if precision == "float32" and expand:
        with np.errstate(over="ignore", invalid="ignore"):
            vertices = vertices.astype(np.float32).astype(np.float64)
    info = {k: v for k, v in mesh.info.items() if k not in ("grid", "stored_precision")}
    # every file isoconvert writes itself says so (a header comment, STL's 80 bytes), and
    # the mesh readers take that as the record that a grid cut the mesh (check_mesh);
    # meshio's formats cannot: a report on them is a report on a file without it
    if writer.records_source:
        info["cut_by_grid"] = True
    if not writer.records_extraction:  # its reader cannot give the rule back
        info.pop("ambiguity", None)
    if writer.records_grid:
        grid = normalized_grid(mesh.info.get("grid"))
        if grid is not None:
            info["grid"] = grid
    if precision in ("float32", "float64"):
        info["stored_precision"] = precision
    if writer.expands and expand:
        flat = cells.ravel()
        vertices = vertices[flat]
        normals = None if normals is None else normals[flat]
        values = None if values is None else values[flat]
        cells = np.arange(len(vertices), dtype=np.int64).reshape(-1, cells.shape[1])
    # per-vertex attributes are stored as float32 by every format that has them
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32)
    if values is not None:
        values = np.asarray(values, dtype=np.float32)
    return Mesh(vertices, cells, None, info, normals, values, mesh.cell_labels)


def _float32_loss(vertices: np.ndarray, cells: np.ndarray, mesh: Mesh) -> tuple:
    """:func:`float32_loss` (without counting degenerate cells once anything is
    lost), and whether it counted the whole mesh. A mesh built block-wise that
    outgrew memory is checked slab by slab
    (:meth:`~isoconvert.extract.blocks.BlockMesh.float32_windows`), with memory
    of the order of a slab, up to the first slab that loses something: the
    answer is the whole mesh's, the counts those of that slab."""
    windows = getattr(mesh, "float32_windows", None)
    parts = None
    if windows is not None and vertices is mesh.vertices and cells is mesh.cells:
        parts = windows()
    if parts is None:
        return float32_loss(vertices, cells, count_degenerate=False), True
    for window_vertices, window_cells in parts:
        loss = float32_loss(window_vertices, window_cells, count_degenerate=False)
        if loss.any:
            return loss, False
    return Float32Loss(), True


def stored_mesh(
    mesh: Mesh,
    format: str,
    ascii: bool = False,
    *,
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """The mesh exactly as a file of ``format`` written by :func:`write_mesh` holds it.

    Check this, not the extracted mesh, to judge what was written:
    ``check_mesh(stored_mesh(mesh, "ply"))`` agrees with
    ``check_mesh(read_mesh("mesh.ply"))`` (but for the source name).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)``.
    format : str
        A writer name: ``ply``, ``obj``, ``stl`` or ``svg``.
    ascii : bool
        Text instead of binary; the stored values are the same either way
        (text PLY and STL carry enough digits to give them back exactly).
    on_status : callable or None
        Receives a one-line notice when the format's precision loses something
        (STL) or PLY stores doubles because float32 would have.

    Returns
    -------
    Mesh
        ``vertices (V', 3) float64`` holding values of the stored precision
        (float32 values for STL and for PLY unless float32 would merge
        vertices or make cells degenerate; float64 for OBJ and PLY
        otherwise); ``cells`` as the file lists them (STL: ``(C, 3)`` =
        ``arange(3 C)``, three vertices per triangle, only the vertices of
        triangles). ``edge_ids`` is None. ``info`` is ``mesh.info`` with
        ``stored_precision`` ("float32" or "float64"; SVG, a picture, has
        none) and with ``grid`` only where the format records it (PLY, OBJ),
        normalized to plain lists.

    Raises
    ------
    FormatError
        Unknown format, or cells it cannot hold.
    """
    writer = WRITERS.get(format)  # a layer (precomputed): each object's mesh, in float64
    _check_cells(writer, mesh, writer.name)
    return _stored(writer, mesh, on_status)


def write_mesh(
    mesh: Mesh,
    path: str | Path,
    *,
    format: str | None = None,
    ascii: bool = False,
    force: bool = False,
    on_status: Callable[[str], None] | None = None,
) -> Path:
    """Write ``mesh`` to ``path`` atomically (a temporary file, then a rename).

    The file holds :func:`stored_mesh` ``(mesh, format, ascii)``: PLY vertex
    coordinates are ``float`` unless float32 would merge distinct vertices or
    make triangles (segments) degenerate, then ``double``; STL is always
    float32. PLY and OBJ headers record where the mesh came from (escaped,
    one line each) and the grid (``mesh.info["grid"]``).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)``.
    path : str or Path
    format : str or None
        ``ply``, ``obj``, ``stl`` or ``svg``; None takes it from the suffix.
    ascii : bool
        Text instead of binary for PLY and STL (OBJ is always text).
    force : bool
        Overwrite an existing file.
    on_status : callable or None
        Receives one-line notices: PLY chose double coordinates, or STL's
        float32 merges vertices or makes triangles degenerate.

    Returns
    -------
    Path
    """
    writer = output_format(path, format)
    _refuse_layer(writer)
    _check_cells(writer, mesh, path)
    if not writer.streams and getattr(mesh, "slab_starts", None) is not None:
        # a block-wise mesh that outgrew memory (extract.blocks.BlockMesh) lives in
        # temporary files; a format written whole (meshio's) would read it all back in
        streaming = ", ".join(n for n, w in WRITERS.items() if w.streams)
        raise FormatError(
            f"{path}: {writer.name} is written whole, but this mesh was built block-wise "
            f"and moved to disk (larger than --max-memory allows); write {streaming}, or "
            "raise --max-memory"
        )
    stored = _stored(writer, mesh, on_status, expand=False)
    with atomic_output(path, force) as fh:
        writer.write(stored, fh, ascii or not writer.has_binary)
    return Path(path)


__all__ = ["stored_mesh", "write_mesh"]
