"""3MF (3D Manufacturing Format, core specification 1.x), for 3D printing.

A ZIP package (deflated) of three parts::

    [Content_Types].xml      the content types of .rels and .model parts
    _rels/.rels              the start part relationship to /3D/3dmodel.model
    3D/3dmodel.model         <model unit="millimeter" xmlns="...core/2015/02">
                               <metadata name="Application">isoconvert VERSION</metadata>
                               <metadata name="Description">provenance lines</metadata>
                               <metadata name="isoconvert:grid">{grid record JSON}</metadata>
                               <resources><object id="1" type="model"><mesh>
                                 <vertices><vertex x= y= z=/>...</vertices>
                                 <triangles><triangle v1= v2= v3=/>...</triangles>
                               </mesh></object></resources>
                               <build><item objectid="1"/></build>
                             </model>

Coordinates are written with 9 significant digits (the float32 values come
back exactly), in the volume's world unit, never converted: the model's
``unit`` is that unit where 3MF has a name for it (micron, millimeter,
centimeter, inch, foot, meter), else "millimeter", what a volume's spacing
usually is, and the metadata says the unit was not known. The model XML is
streamed into the ZIP entry block by block; every entry has the same fixed time
stamp (1980-01-01), so the same mesh always gives the same bytes.
"""

from __future__ import annotations

import zipfile
from typing import BinaryIO
from xml.sax.saxutils import escape

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from ..units import meters_per_unit
from .chunks import row_chunks
from .header import escape_comment, grid_comment, provenance
from .text import write_rows

CORE_NAMESPACE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
#: Namespace of isoconvert's own metadata names (the spec asks non-standard
#: metadata names to be namespace-qualified).
ISOCONVERT_NAMESPACE = "urn:isoconvert:3mf-metadata"
MODEL_PART = "3D/3dmodel.model"
#: ZIP time stamp of every part: fixed, so the output is reproducible.
TIMESTAMP = (1980, 1, 1, 0, 0, 0)

CONTENT_TYPES = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">\n'
    ' <Default Extension="rels" '
    'ContentType="application/vnd.openxmlformats-package.relationships+xml"/>\n'
    ' <Default Extension="model" '
    'ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>\n'
    "</Types>\n"
)
RELATIONSHIPS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">\n'
    f' <Relationship Target="/{MODEL_PART}" Id="rel0" '
    'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>\n'
    "</Relationships>\n"
)
_VERTEX = '<vertex x="%.9g" y="%.9g" z="%.9g"/>\n'
_TRIANGLE = '<triangle v1="%d" v2="%d" v3="%d"/>\n'


#: 3MF's unit names, by meters per unit.
UNITS_3MF = {1e-6: "micron", 1e-3: "millimeter", 1e-2: "centimeter", 0.0254: "inch",
             0.3048: "foot", 1.0: "meter"}  # fmt: skip


def model_unit(mesh: Mesh) -> tuple[str, str]:
    """The model's ``unit`` attribute for ``mesh``, and what the metadata says of it."""
    unit = mesh.info.get("unit")
    name = UNITS_3MF.get(meters_per_unit(unit))
    if name is not None:
        return name, f"the volume's world coordinates, in its unit ({unit})"
    why = f"its unit {unit!r} has no 3MF name" if unit else "its unit is not known"
    return "millimeter", f"the volume's world coordinates as they are ({why}): not converted"


def _metadata(mesh: Mesh) -> list[str]:
    from .. import __version__

    lines = [escape_comment(line) for line in provenance(mesh)]
    items = [
        ("Application", f"isoconvert {__version__}"),
        ("Description", "\n".join(lines)),
    ]
    grid = grid_comment(mesh.info.get("grid"))
    if grid is not None:
        items.append(("isoconvert:grid", grid))
    items.append(("isoconvert:coordinates", model_unit(mesh)[1]))
    return [f' <metadata name="{name}">{escape(value)}</metadata>' for name, value in items]


def _model_head(mesh: Mesh) -> str:
    return "\n".join(
        [
            '<?xml version="1.0" encoding="UTF-8"?>',
            f'<model unit="{model_unit(mesh)[0]}" xml:lang="en-US" xmlns="{CORE_NAMESPACE}" '
            f'xmlns:isoconvert="{ISOCONVERT_NAMESPACE}">',
            *_metadata(mesh),
            " <resources>",
            '  <object id="1" type="model">',
            "   <mesh>",
            "    <vertices>",
            "",
        ]
    )


_MIDDLE = "    </vertices>\n    <triangles>\n"
_TAIL = (
    "    </triangles>\n"
    "   </mesh>\n"
    "  </object>\n"
    " </resources>\n"
    " <build>\n"
    '  <item objectid="1"/>\n'
    " </build>\n"
    "</model>\n"
)


def _size_bound(head: int, n_vertices: int, n_cells: int) -> int:
    """An upper bound of the model part's bytes (whether ZIP64 is needed)."""
    number = len("-1.23456789e-308")
    index = len(str(max(n_vertices - 1, 0)))
    return (
        head
        + len(_MIDDLE)
        + len(_TAIL)
        + n_vertices * (len(_VERTEX % (0, 0, 0)) + 3 * number)
        + n_cells * (len(_TRIANGLE % (0, 0, 0)) + 3 * index)
    )


def write_3mf(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write a 3MF package holding ``mesh`` as one object (``type="model"``) and
    one build item.

    Triangles keep isoconvert's orientation (counter-clockwise seen from the
    negative side, i.e. from outside a bright object), which is 3MF's
    outward-facing rule. ``metadata`` says what made the mesh (``Application``,
    ``Description``: the provenance lines, escaped as in PLY/OBJ headers) and
    records the grid (``isoconvert:grid``). Written block by block.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)``.
    fh : binary file
    ascii : bool
        Ignored (3MF is a ZIP of XML).
    """
    if not mesh.is_triangles:
        raise FormatError("3MF holds triangles only; write contours as OBJ, PLY or VTP")
    for block in row_chunks(mesh.vertices):
        with np.errstate(over="ignore", invalid="ignore"):
            if not np.isfinite(block.astype(np.float32)).all():
                raise FormatError(
                    "3MF coordinates are written as float32: some are not finite there; "
                    "write PLY or OBJ, or move the origin nearer the mesh"
                )
    head = _model_head(mesh).encode("utf-8")
    n_vertices, n_cells = len(mesh.vertices), len(mesh.cells)
    big = _size_bound(len(head), n_vertices, n_cells) >= zipfile.ZIP64_LIMIT
    with zipfile.ZipFile(fh, "w") as package:
        for name, text in (("[Content_Types].xml", CONTENT_TYPES), ("_rels/.rels", RELATIONSHIPS)):
            package.writestr(_entry(name), text)
        with package.open(_entry(MODEL_PART), "w", force_zip64=big) as part:
            part.write(head)
            write_rows(part, mesh.vertices, _VERTEX, dtype=np.float32)
            part.write(_MIDDLE.encode("ascii"))
            write_rows(part, mesh.cells, _TRIANGLE)
            part.write(_TAIL.encode("ascii"))


def _entry(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=TIMESTAMP)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    return info
