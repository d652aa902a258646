"""Formats written through meshio: VTU, legacy VTK, Gmsh, XDMF, Abaqus, Medit, MED.

meshio writes to a path, not to an open stream, and needs the whole mesh in
memory. Each writer here builds the ``meshio.Mesh`` (vertices, triangles or
lines, the attributes the format holds), lets meshio write it into a private
temporary folder (under ``TMPDIR``) under a name with the format's suffix, and
copies that file into the stream :func:`isoconvert.write_mesh` hands it; that
stream is :func:`isoconvert.atomic.atomic_output`'s temporary file, renamed to
the output only once complete, so a failed or interrupted run leaves nothing.

meshio is imported on first use (``isoconvert --help`` never pays for it).

Attribute names, the same in every format that holds them and in
:meth:`isoconvert.Mesh.to_meshio`: point data ``Normals`` ((V, 3) float32)
and ``value`` ((V,) float32), cell data ``inside_label`` and
``outside_label`` ((C,) int32, the labels the normals point from and to).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

from ..errors import FormatError, install_hint, one_line
from ..mesh import Mesh


@dataclass(frozen=True)
class MeshioFormat:
    """How one format is written with meshio.

    Attributes
    ----------
    file_format : str
        meshio's name of the format.
    suffix : str
        The suffix of the temporary file meshio writes.
    attributes : frozenset of str
        What the format keeps: "normals", "values" (point data), "labels"
        (cell data).
    binary : dict or None
        meshio's keyword for binary (True) or text (False) output; None when
        the format has one form.
    options : dict
        Other keywords for meshio's writer.
    float64_attributes : bool
        Store attributes as float64 (XDMF's XML writes float32 with 8 digits,
        which does not give every float32 back; float64's 17 do).
    requires : str or None
        An optional package the format needs (h5py for MED).
    no_text : str or None
        Why ``--ascii`` is refused for a format whose meshio text writer
        does not give the mesh back (VTU rounds to 12 significant digits;
        MSH writes data as ``np.float32(0.5)`` under numpy 2).
    """

    file_format: str
    suffix: str
    attributes: frozenset[str] = frozenset()
    binary: str | None = None
    options: dict = field(default_factory=dict)
    float64_attributes: bool = False
    requires: str | None = None
    no_text: str | None = None


_ALL = frozenset({"normals", "values", "labels"})

#: The formats, by writer name (the table of isoconvert.writers names the same).
FORMATS = {
    "vtu": MeshioFormat(
        "vtu",
        ".vtu",
        _ALL,
        "binary",  # fmt: skip
        no_text="meshio's text VTU keeps 12 significant digits, which moves the vertices",
    ),
    "vtk": MeshioFormat("vtk", ".vtk", _ALL, "binary"),
    # Gmsh 2.2: meshio's 4.1 writer drops point and element data
    "msh": MeshioFormat(
        "gmsh22",
        ".msh",
        _ALL,
        "binary",
        no_text="meshio's text MSH writes point and element data that it cannot read back",
    ),
    # inline XML: one file (HDF5 would write a second one beside it)
    "xdmf": MeshioFormat(
        "xdmf",
        ".xdmf",
        _ALL,
        options={"data_format": "XML"},
        float64_attributes=True,
        requires="h5py",
    ),  # fmt: skip
    "inp": MeshioFormat("abaqus", ".inp"),
    "medit": MeshioFormat("medit", ".mesh"),
    "med": MeshioFormat("med", ".med", requires="h5py"),
}


def meshio_mesh(mesh: Mesh, attributes: frozenset[str] = _ALL, float64: bool = False):
    """``mesh`` as a ``meshio.Mesh``: the same vertices, cells and orientation.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` triangles or ``(C, 2)`` segments.
    attributes : frozenset of str
        Which of the mesh's "normals", "values", "labels" to carry.
    float64 : bool
        Carry normals and values as float64 (else float32).

    Returns
    -------
    meshio.Mesh
        ``points (V, 3) float64``, one cell block ``triangle`` (or ``line``) of
        ``(C, 3)`` (``(C, 2)``) int64; point data ``Normals``, ``value``, cell
        data ``inside_label``, ``outside_label`` (int32) where present.
    """
    import_meshio()
    kept = Mesh(
        mesh.vertices,
        mesh.cells,
        normals=mesh.normals if "normals" in attributes else None,
        values=mesh.values if "values" in attributes else None,
        cell_labels=mesh.cell_labels if "labels" in attributes else None,
    )
    converted = kept.to_meshio()
    if float64:
        converted.point_data = {k: v.astype(np.float64) for k, v in converted.point_data.items()}
    return converted


def import_meshio():
    """The meshio module, or a one-line FormatError saying how to install it."""
    try:
        import meshio
    except ImportError:
        raise FormatError(
            "meshio is not installed (isoconvert reads and writes VTU, VTK, MSH, XDMF, INP, "
            "MESH and MED through it); pip install meshio"
        ) from None
    return meshio


def requirement_error(name: str, package: str) -> FormatError:
    """The one-line error of a format whose optional package is missing."""
    return FormatError(f"{name}: the format needs the {package} package; {install_hint(package)}")


def write_with_meshio(name: str, mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write ``mesh`` as the format ``name`` of :data:`FORMATS` into ``fh``.

    Parameters
    ----------
    name : str
        A key of :data:`FORMATS`.
    mesh : Mesh
        ``vertices (V, 3)`` float64, ``cells (C, 3)`` or ``(C, 2)``.
    fh : binary file
        Where the bytes go (the temporary file of ``atomic_output``).
    ascii : bool
        The text form, for VTK (VTU's and MSH's are refused: ``no_text``).

    Raises
    ------
    FormatError
        meshio (or a package the format needs) is missing, or meshio refused
        the mesh; one line, no meshio traceback.
    """
    spec = FORMATS[name]
    if ascii and spec.no_text:
        raise FormatError(
            f"{name.upper()}: {spec.no_text}; leave out --ascii (the binary form is exact), "
            "or write --ascii vtk or vtp"
        )
    if spec.requires:
        try:
            __import__(spec.requires)
        except ImportError:
            raise requirement_error(name.upper(), spec.requires) from None
    meshio = import_meshio()
    converted = meshio_mesh(mesh, spec.attributes, spec.float64_attributes)
    options = dict(spec.options)
    if spec.binary is not None:
        options[spec.binary] = not ascii
    with tempfile.TemporaryDirectory(prefix="isoconvert-meshio-") as folder:
        path = os.path.join(folder, "mesh" + spec.suffix)
        try:
            with _quiet():
                meshio.write(path, converted, file_format=spec.file_format, **options)
        except OSError:
            raise  # disk full and the like: atomic_output names them
        except Exception as exc:  # meshio's own errors, and numpy's from inside it
            raise FormatError(
                f"{name.upper()}: meshio could not write the mesh ({one_line(exc)})"
            ) from None
        with open(path, "rb") as written:
            shutil.copyfileobj(written, fh, 1 << 20)


@contextlib.contextmanager
def _quiet():
    """meshio's warnings (and its prints) stay out of the user's output: the
    library never prints."""
    import io
    import warnings

    with (
        warnings.catch_warnings(),
        contextlib.redirect_stdout(io.StringIO()),
        contextlib.redirect_stderr(io.StringIO()),
    ):
        warnings.simplefilter("ignore")
        yield


def write_vtu(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """VTK XML UnstructuredGrid through meshio (binary zlib-compressed, or ASCII)."""
    write_with_meshio("vtu", mesh, fh, ascii)


def write_vtk(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Legacy VTK (5.1) UNSTRUCTURED_GRID through meshio (binary or ASCII)."""
    write_with_meshio("vtk", mesh, fh, ascii)


def write_msh(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Gmsh 2.2 through meshio (binary or ASCII)."""
    write_with_meshio("msh", mesh, fh, ascii)


def write_xdmf(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """XDMF 3 with inline XML data through meshio."""
    write_with_meshio("xdmf", mesh, fh, ascii)


def write_inp(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Abaqus input file through meshio."""
    write_with_meshio("inp", mesh, fh, ascii)


def write_medit(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Medit ``.mesh`` through meshio."""
    write_with_meshio("medit", mesh, fh, ascii)


def write_med(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Salome MED (HDF5, needs h5py) through meshio."""
    write_with_meshio("med", mesh, fh, ascii)
