"""Writers: one module per format and the table of built-ins below.

:func:`write_mesh` writes what :func:`stored_mesh` says the file holds: one
code path decides the stored precision (PLY: float32 unless that would merge
vertices or make cells degenerate, then double; STL: always float32, with a
notice when that loses something; OBJ: 17 significant digits, float64), STL's
three vertices per triangle, and which header records the grid. A report on
``stored_mesh(mesh, ...)`` is therefore a report on the file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Literal

from ..errors import FormatError
from ..lazy import LazyFunction, import_target
from ..registry import Registry

if TYPE_CHECKING:
    from ..mesh import Mesh
    from .stored import stored_mesh, write_mesh

Precision = Literal["float32", "float64", "adaptive", "as given"]


@dataclass(frozen=True)
class Writer:
    """A mesh format: its file suffixes and how to write it to a binary stream.

    ``write(mesh, fh, ascii)`` receives float64 vertices and writes them at
    ``info["stored_precision"]`` (:func:`stored_mesh` decides it); formats with
    ``expands`` write each cell's vertices. The built-ins' ``write`` is a
    :class:`~isoconvert.lazy.LazyFunction`, imported on first use.
    """

    name: str
    summary: str
    suffixes: tuple[str, ...]
    write: Callable[[Mesh, BinaryIO, bool], None]
    #: whether the format has a binary form (``ascii=False``)
    has_binary: bool
    #: cell sizes it can hold: 3 (triangles), 2 (segments)
    cell_sizes: frozenset[int] = frozenset({2, 3})
    #: vertex coordinates: always "float32" or "float64"; "adaptive" (float32
    #: unless that loses something, then float64); "as given" (a picture, not
    #: read back: no ``stored_precision``)
    precision: Precision = "float64"
    #: whether every cell gets its own vertices (STL)
    expands: bool = False
    #: whether the header records ``mesh.info["grid"]``
    records_grid: bool = False
    #: whether it writes block by block, so a mesh larger than memory can
    #: wait for it in temporary files (isoconvert.writers.chunks)
    streams: bool = False
    #: attributes it stores: "normals", "values" (per vertex), "labels" (per cell)
    attributes: frozenset[str] = frozenset()
    #: whether the file says isoconvert wrote it (a header comment, STL's 80 bytes),
    #: which the mesh readers take as the record that a grid cut the mesh; meshio's
    #: formats have no place isoconvert can write that in
    records_source: bool = True
    #: whether its reader gives back the extraction rule (``mesh.info["ambiguity"]``,
    #: an ``ambiguity R`` header comment) for the report
    records_extraction: bool = False
    #: whether it writes a folder holding every object of a run (a Neuroglancer
    #: layer: ``convert --labels``) instead of one mesh file
    layer: bool = False


WRITERS: Registry[Writer] = Registry("output format")
_TRIANGLES = frozenset({3})
_SEGMENTS = frozenset({2})
_BOTH = frozenset({2, 3})
_NORMALS_VALUES = frozenset({"normals", "values"})
_ALL_ATTRIBUTES = frozenset({"normals", "values", "labels"})
for _writer in (
    Writer(
        "ply",
        "Stanford PLY, indexed; binary (default) or --ascii; double coordinates where float "
        "would merge vertices",
        (".ply",),
        LazyFunction("isoconvert.writers.ply:write_ply"),
        True,
        _BOTH,
        precision="adaptive",
        records_grid=True,
        records_extraction=True,
        streams=True,
        attributes=_ALL_ATTRIBUTES,
    ),
    Writer(
        "obj",
        "Wavefront OBJ, indexed; text",
        (".obj",),
        LazyFunction("isoconvert.writers.obj:write_obj"),
        False,
        _BOTH,
        precision="float64",
        records_grid=True,
        records_extraction=True,
        streams=True,
        attributes=frozenset({"normals"}),
    ),
    Writer(
        "stl",
        "STL, one record per triangle; binary (default) or --ascii",
        (".stl",),
        LazyFunction("isoconvert.writers.stl:write_stl"),
        True,
        _TRIANGLES,
        precision="float32",
        expands=True,
        streams=True,
    ),
    Writer(
        "off",
        "OFF (Geomview, the book's format), indexed triangles; text, float64 coordinates",
        (".off",),
        LazyFunction("isoconvert.writers.off:write_off"),
        False,
        _TRIANGLES,
        precision="float64",
        records_grid=True,
        records_extraction=True,
        streams=True,
    ),
    Writer(
        "vtp",
        "VTK XML PolyData (ParaView), indexed; binary (default) or --ascii; double "
        "coordinates where float would merge vertices",
        (".vtp",),
        LazyFunction("isoconvert.writers.vtp:write_vtp"),
        True,
        _BOTH,
        precision="adaptive",
        records_grid=True,
        records_extraction=True,
        streams=True,
        attributes=_ALL_ATTRIBUTES,
    ),
    Writer(
        "glb",
        "glTF 2.0 binary (web viewers), indexed triangles, float32; world coordinates "
        "(no swap to +Y up), scaled to meters by the node where the unit is known",
        (".glb",),
        LazyFunction("isoconvert.writers.glb:write_glb"),
        False,
        _TRIANGLES,
        precision="float32",
        records_grid=True,
        records_extraction=True,
        streams=True,
        attributes=_NORMALS_VALUES,
    ),
    Writer(
        "3mf",
        "3MF (3D printing), indexed triangles, float32; in the volume's unit (millimeter "
        "when not known), never converted",
        (".3mf",),
        LazyFunction("isoconvert.writers.threemf:write_3mf"),
        False,
        _TRIANGLES,
        precision="float32",
        records_grid=True,
        records_extraction=True,
        streams=True,
    ),
    Writer(
        "svg",
        "SVG picture of 2D contours (squares on a 2D image)",
        (".svg",),
        LazyFunction("isoconvert.writers.svg:write_svg"),
        False,
        _SEGMENTS,
        precision="as given",
        # not in a header: the grid's extent is the picture's frame and size
        records_grid=True,
    ),
    Writer(
        "geojson",
        "GeoJSON FeatureCollection of 2D contours (squares), LineStrings in planar world "
        "coordinates (not lon/lat)",
        (".geojson",),
        LazyFunction("isoconvert.writers.geojson:write_geojson"),
        False,
        _SEGMENTS,
        precision="float64",
        records_grid=True,
    ),
    # formats without a native writer, written through meshio (isoconvert.writers.meshio):
    # it needs the whole mesh in memory, so none of them streams
    Writer(
        "vtu",
        "VTK XML UnstructuredGrid, via meshio; binary (meshio's text form rounds: no "
        "--ascii); keeps normals, values (point data), labels (cell data)",
        (".vtu",),
        LazyFunction("isoconvert.writers.meshio:write_vtu"),
        True,
        _BOTH,
        attributes=_ALL_ATTRIBUTES,
        records_source=False,
    ),
    Writer(
        "vtk",
        "legacy VTK UNSTRUCTURED_GRID, via meshio; binary (default) or --ascii; keeps "
        "normals, values (point data), labels (cell data)",
        (".vtk",),
        LazyFunction("isoconvert.writers.meshio:write_vtk"),
        True,
        _BOTH,
        attributes=_ALL_ATTRIBUTES,
        records_source=False,
    ),
    Writer(
        "msh",
        "Gmsh 2.2, via meshio; binary (meshio's text form is broken: no --ascii); keeps "
        "normals, values ($NodeData), labels ($ElementData)",
        (".msh",),
        LazyFunction("isoconvert.writers.meshio:write_msh"),
        True,
        _BOTH,
        attributes=_ALL_ATTRIBUTES,
        records_source=False,
    ),
    Writer(
        "xdmf",
        "XDMF 3, inline XML, via meshio (needs h5py); keeps normals, values (point data), "
        "labels (cell data)",
        (".xdmf", ".xmf"),
        LazyFunction("isoconvert.writers.meshio:write_xdmf"),
        False,
        _BOTH,
        attributes=_ALL_ATTRIBUTES,
        records_source=False,
    ),
    Writer(
        "inp",
        "Abaqus input, via meshio; text; triangles only, no attributes",
        (".inp",),
        LazyFunction("isoconvert.writers.meshio:write_inp"),
        False,
        _TRIANGLES,
        records_source=False,
    ),
    Writer(
        "medit",
        "Medit .mesh, via meshio; text; triangles only, no attributes",
        (".mesh",),
        LazyFunction("isoconvert.writers.meshio:write_medit"),
        False,
        _TRIANGLES,
        records_source=False,
    ),
    Writer(
        "med",
        "Salome MED (HDF5), via meshio (needs h5py); triangles only, no attributes",
        (".med",),
        LazyFunction("isoconvert.writers.meshio:write_med"),
        False,
        _TRIANGLES,
        records_source=False,
    ),
    # a folder, written by isoconvert.writers.precomputed.write_precomputed
    Writer(
        "precomputed",
        "Neuroglancer precomputed segmentation layer, a folder: every label's mesh at --lods "
        "levels of detail, Draco-encoded (convert --labels; needs isoconvert[precomputed])",
        (),
        LazyFunction("isoconvert.writers.precomputed:not_a_file"),
        False,
        _TRIANGLES,
        precision="float64",
        records_source=False,
        layer=True,
    ),
):
    WRITERS.register(_writer.name, _writer)


def attribute_writers(attribute: str) -> list[str]:
    """Names of the formats that store ``attribute``: "normals", "values" (per
    vertex) or "labels" (per cell)."""
    return [name for name, w in WRITERS.items() if attribute in w.attributes]


def check_attributes(
    writer: Writer,
    name: object,
    *,
    normals: bool = False,
    values: bool = False,
    labels: bool = False,
) -> None:
    """Refuse per-vertex normals or values, or per-cell labels, for a format
    that cannot store them.

    Raises
    ------
    FormatError
    """
    wanted = {"normals": normals, "values": values, "labels": labels}
    what = {"normals": "per-vertex normals", "values": "per-vertex values",
            "labels": "per-triangle labels"}  # fmt: skip
    option = {"normals": "--normals", "values": "--values", "labels": "--single-file"}
    for attribute, asked in wanted.items():
        if asked and attribute not in writer.attributes:
            raise FormatError(
                f"{name}: {writer.name} cannot store {what[attribute]}; write "
                f"{', '.join(attribute_writers(attribute))}, or leave out {option[attribute]}"
            )


def output_format(path: str | Path, format: str | None = None) -> Writer:
    """The writer named by ``format``, else by the file suffix.

    Parameters
    ----------
    path : str or Path
        The output file; its suffix names the format when ``format`` is None.
    format : str or None
        A writer name (``ply``, ``obj``, ``stl``, ``svg``).

    Returns
    -------
    Writer

    Raises
    ------
    FormatError
        Unknown format name or suffix.
    """
    if format:
        return WRITERS.get(format)
    from ..atomic import output_stream

    if output_stream(path) is not None and not Path(path).suffix:
        raise FormatError(
            f"{path}: a stream has no extension to tell the format; give --format "
            # a layer is a folder: no stream holds one
            f"({', '.join(n for n, w in WRITERS.items() if not w.layer)})"
        )
    suffix = Path(path).suffix.lower()
    found = WRITERS.by_suffix(suffix)
    if found:
        return found[1]
    raise FormatError(
        f"{path}: unknown output extension {suffix or '(none)'!r}; "
        f"known output formats: {WRITERS.suffix_listing()}; or name one with --format"
    )


#: Public functions that need numpy, imported from :mod:`.stored` on first use, so
#: that the table above (what the CLI's help lists) imports no numpy.
_LAZY = {"stored_mesh", "write_mesh"}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        return import_target(f"{__name__}.stored:{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _LAZY)


__all__ = [
    "WRITERS",
    "Writer",
    "attribute_writers",
    "check_attributes",
    "output_format",
    "stored_mesh",
    "write_mesh",
]
