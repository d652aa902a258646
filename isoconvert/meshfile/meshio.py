"""Mesh files read through meshio: the surface formats with no reader of isoconvert's own.

VTU, legacy VTK, Gmsh MSH, XDMF, Abaqus INP, Medit, MED, Nastran, Exodus, ...:
meshio reads them (imported on first use); :meth:`isoconvert.Mesh.from_meshio`
takes their triangles (and quads, split in two), or their lines when there
are no faces. The formats isoconvert reads itself (PLY, OBJ, OFF, STL, VTP,
GLB, 3MF) stay with their own readers.
"""

from __future__ import annotations

import contextlib
import io
import warnings
from pathlib import Path

from ..errors import FormatError, install_hint, one_line
from ..mesh import Mesh

#: suffix -> (meshio's format name, or names tried in turn; the optional package it
#: needs or None)
FORMATS: dict[str, tuple[str | tuple[str, ...], str | None]] = {
    ".vtu": ("vtu", None),
    ".vtk": ("vtk", None),
    ".msh": (("gmsh", "ansys"), None),  # meshio writes ANSYS for .msh by default
    ".xdmf": ("xdmf", None),  # inline XML without h5py; HDF5 data needs it
    ".xmf": ("xdmf", None),
    ".inp": ("abaqus", None),
    ".mesh": ("medit", None),
    ".meshb": ("medit", None),
    ".med": ("med", "h5py"),
    ".bdf": ("nastran", None),
    ".fem": ("nastran", None),
    ".nas": ("nastran", None),
    ".avs": ("avsucd", None),
    ".mdpa": ("mdpa", None),
    ".su2": ("su2", None),
    ".ugrid": ("ugrid", None),
    ".vol": ("netgen", None),
    ".f3grid": ("flac3d", None),
    ".tec": ("tecplot", None),
    ".wkt": ("wkt", None),
    ".e": ("exodus", "netCDF4"),
    ".exo": ("exodus", "netCDF4"),
    ".ex2": ("exodus", "netCDF4"),
    ".cgns": ("cgns", "h5py"),
    ".h5m": ("h5m", "h5py"),
    ".hmf": ("hmf", "h5py"),
}

MESHIO_SUFFIXES = tuple(FORMATS)


def _read_meshio(path: Path, suffix: str | None = None) -> Mesh:
    """Read ``path`` with meshio as the format of ``suffix`` (default: its own; see
    :data:`FORMATS`).

    Raises
    ------
    FormatError
        meshio, or a package the format needs, is missing (the pip install
        hint), or meshio cannot read the file (one line, no traceback).
    """
    suffix = (suffix or path.suffix).lower()
    file_format, needs = FORMATS[suffix]
    what = suffix[1:].upper()
    if needs is not None:
        try:
            __import__(needs)
        except ImportError:
            raise FormatError(
                f"{path}: reading {what} needs the {needs} package; {install_hint(needs)}"
            ) from None
    try:
        import meshio
    except ImportError:
        raise FormatError(f"{path}: reading {what} needs meshio; pip install meshio") from None
    printed = io.StringIO()
    try:
        with (
            warnings.catch_warnings(),
            contextlib.redirect_stdout(printed),  # meshio prints notes, and its read errors
            contextlib.redirect_stderr(io.StringIO()),
        ):
            warnings.simplefilter("ignore")
            read = _read_as(meshio, path, file_format)
    except ImportError as exc:  # a package meshio needs for this file (HDF5 in an XDMF)
        package = getattr(exc, "name", None) or "a package"
        raise FormatError(
            f"{path}: reading this {what} needs the {package} package; {install_hint(package)}"
        ) from None
    except SystemExit:  # meshio prints why a reader failed, then exits
        lines = [line.strip() for line in printed.getvalue().splitlines()]
        why = next((x for x in lines if x and not x.startswith("Error: Couldn't read")), "")
        told = f" ({one_line(why)})" if why else ""
        raise FormatError(f"{path}: not a readable {what} mesh{told}") from None
    except MemoryError:
        raise
    except OSError as exc:
        raise FormatError(f"{path}: cannot read it ({exc.strerror or one_line(exc)})") from None
    except Exception as exc:  # meshio's ReadError and whatever its parsers raise
        why = one_line(exc) or type(exc).__name__
        raise FormatError(f"{path}: not a readable {what} mesh ({why})") from None
    mesh = Mesh.from_meshio(read, name=str(path))
    mesh.info["source"] = str(path)
    return mesh


def _read_as(meshio, path: Path, file_format: str | tuple[str, ...]):
    """meshio's read of ``path`` as ``file_format``, or each of several in turn (the
    error is the first one's)."""
    if isinstance(file_format, str):
        return meshio.read(path, file_format=file_format)
    first = None
    for name in file_format:
        try:
            return meshio.read(path, file_format=name)
        except (Exception, SystemExit) as exc:  # noqa: BLE001 - the next format may read it
            first = first or exc
    raise first
