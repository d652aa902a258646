"""VTP (VTK XML PolyData), what ParaView opens: binary appended data or ASCII.

Layout of the binary file (``byte_order="LittleEndian"``,
``header_type="UInt64"``, no compression)::

    <?xml version="1.0"?>
    <!-- made by isoconvert ... -->            provenance and grid, one comment a line
    <VTKFile type="PolyData" ...>
      <PolyData>
        <FieldData>                             the same lines as a String array
          <Array type="String" Name="isoconvert" NumberOfTuples="n" format="appended" offset="0"/>
        </FieldData>
        <Piece NumberOfPoints="V" NumberOfPolys="C" ...>   (NumberOfLines for segments)
          <PointData Normals="Normals" Scalars="value">     (only with normals or values)
            Normals (Float32, 3 components), value (Float32) </PointData>
          <CellData Scalars="labels">                       (only for label meshes)
            labels (Int32, 2 components: inside, outside) </CellData>
          <Points> <DataArray type="Float32|Float64" NumberOfComponents="3" .../> </Points>
          <Polys>  connectivity (Int64), offsets (Int64: 3, 6, 9, ...) </Polys>
        </Piece>
      </PolyData>
      <AppendedData encoding="raw">
       _[UInt64 byte count][bytes] for each array, in the order above
      </AppendedData>
    </VTKFile>

Every byte count follows from V and C, so the header is written first and the
arrays are streamed block by block after it.
"""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from ..mesh import Mesh
from .chunks import ROWS, row_chunks
from .header import escape_comment, grid_comment, provenance
from .text import write_rows

#: Name of the FieldData string array holding the provenance and grid lines.
FIELD_NAME = "isoconvert"


def _lines(mesh: Mesh) -> list[str]:
    """Provenance and grid record, escaped for an ASCII XML comment (no ``--``);
    the grid record (JSON of numbers) comes out unchanged."""
    lines = list(provenance(mesh))
    grid = grid_comment(mesh.info.get("grid"))
    if grid is not None:
        lines.append(grid)
    return [escape_comment(line, ascii=True, xml=True) for line in lines]


def write_vtp(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write vertices as ``Points`` and cells as ``Polys`` (triangles) or
    ``Lines`` (segments), indices Int64; normals and values, when the mesh has
    them, as Float32 ``PointData`` arrays ``Normals`` and ``value`` (the active
    normals and scalars); a label mesh's cell labels as the Int32 ``CellData``
    array ``labels`` (2 components: inside, outside).

    Points are Float64 when ``mesh.info["stored_precision"]`` is "float64",
    else Float32 (rounded here); :func:`isoconvert.write_mesh` decides, as
    for PLY. An XML comment and a FieldData string array named ``isoconvert``
    say what made the mesh and record the grid (``isoconvert grid {...}``).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` or ``(C, 2)``.
    fh : binary file
    ascii : bool
        ``format="ascii"`` DataArrays (17 significant digits for Float64, 9
        for Float32: the stored values come back exactly) instead of raw
        appended binary.
    """
    double = mesh.info.get("stored_precision") == "float64"
    verts = mesh.vertices
    cells = mesh.cells
    n_points, n_cells = len(verts), len(cells)
    size = cells.shape[1]
    section = "Polys" if size == 3 else "Lines"
    kind = "Float64" if double else "Float32"
    lines = _lines(mesh)
    strings = b"".join(line.encode("ascii") + b"\0" for line in lines)

    def array(tag: str, attributes: str, offset: int | None) -> str:
        where = 'format="ascii">' if offset is None else f'format="appended" offset="{offset}"/>'
        return f"<{tag} {attributes} {where}"

    # per-vertex attributes, Float32: (name, (V, k) array)
    point_data = []
    if mesh.normals is not None:
        point_data.append(("Normals", mesh.normals))
    if mesh.values is not None:
        point_data.append(("value", mesh.values.reshape(-1, 1)))
    cell_data = [] if mesh.cell_labels is None else [("labels", mesh.cell_labels)]
    # byte sizes of the appended arrays (in file order), each after its UInt64 count
    sizes = [len(strings)]
    sizes += [n_points * data.shape[1] * 4 for _, data in point_data]
    sizes += [n_cells * data.shape[1] * 4 for _, data in cell_data]
    sizes += [n_points * 3 * (8 if double else 4), n_cells * size * 8, n_cells * 8]
    starts = np.concatenate([[0], np.cumsum(np.asarray(sizes) + 8)[:-1]]).tolist()
    offsets = iter([None] * len(sizes) if ascii else starts)
    counts = {"Verts": 0, "Lines": 0, "Strips": 0, "Polys": 0}
    counts[section] = n_cells
    piece = " ".join(f'NumberOf{name}="{n}"' for name, n in counts.items())
    head = [
        '<?xml version="1.0"?>',
        *[f"<!-- {line} -->" for line in lines],
        '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64">',
        "  <PolyData>",
        "    <FieldData>",
        "      "
        + array(
            "Array",
            f'type="String" Name="{FIELD_NAME}" NumberOfTuples="{len(lines)}"',
            next(offsets),
        ),
    ]
    if ascii:
        # the string array as the byte codes of its NUL-terminated strings (as VTK writes it)
        head += ["        " + " ".join(str(b) for b in strings), "      </Array>"]
    head += ["    </FieldData>", f'    <Piece NumberOfPoints="{n_points}" {piece}>']
    # a list of text pieces and arrays, in file order: text is written as it is,
    # arrays as appended binary or as ASCII rows
    parts: list = []
    if point_data:
        roles = {"Normals": "Normals", "value": "Scalars"}
        named = " ".join(f'{roles[name]}="{name}"' for name, _ in point_data)
        head.append(f"      <PointData {named}>")
        for name, data in point_data:
            comps = f' NumberOfComponents="{data.shape[1]}"' if data.shape[1] > 1 else ""
            attrs = f'type="Float32" Name="{name}"{comps}'
            head.append("        " + array("DataArray", attrs, next(offsets)))
            parts += ["\n".join(head), (data, np.float32, "%.9g")]
            head = ["        </DataArray>"] if ascii else []
        head.append("      </PointData>")
    if cell_data:
        # the labels on the two sides of each cell: normals point from the first to the second
        head.append('      <CellData Scalars="labels">')
        for name, data in cell_data:
            attrs = f'type="Int32" Name="{name}" NumberOfComponents="{data.shape[1]}"'
            head.append("        " + array("DataArray", attrs, next(offsets)))
            parts += ["\n".join(head), (data, np.int32, "%d")]
            head = ["        </DataArray>"] if ascii else []
        head.append("      </CellData>")
    kind_of_points = f'type="{kind}" Name="Points" NumberOfComponents="3"'
    head += ["      <Points>", "        " + array("DataArray", kind_of_points, next(offsets))]
    digits = "%.17g" if double else "%.9g"
    parts += ["\n".join(head), (verts, np.float64 if double else np.float32, digits)]
    head = ["        </DataArray>"] if ascii else []
    head += [
        "      </Points>",
        f"      <{section}>",
        "        " + array("DataArray", 'type="Int64" Name="connectivity"', next(offsets)),
    ]
    parts += ["\n".join(head), (cells, np.int64, "%d")]
    head = ["        </DataArray>"] if ascii else []
    head.append("        " + array("DataArray", 'type="Int64" Name="offsets"', next(offsets)))
    parts += ["\n".join(head), ("offsets", np.int64, "%d")]
    head = ["        </DataArray>"] if ascii else []
    head += [f"      </{section}>", "    </Piece>", "  </PolyData>"]
    if ascii:
        for part in parts:
            if isinstance(part, str):
                fh.write((part + "\n").encode("ascii"))
            elif isinstance(part[0], str):
                for block in _offsets(n_cells, size):
                    write_rows(fh, block.reshape(-1, 1), "%d\n")
            else:
                data, dtype, number = part
                write_rows(fh, data, " ".join([number] * data.shape[1]) + "\n", dtype=dtype)
        fh.write(("\n".join([*head, "</VTKFile>"]) + "\n").encode("ascii"))
        return
    text = "\n".join(p for p in parts if isinstance(p, str) and p)
    head += ['  <AppendedData encoding="raw">', "   _"]
    fh.write((text + "\n" + "\n".join(head)).encode("ascii"))
    fh.write(np.uint64(len(strings)).tobytes() + strings)
    little = {np.float32: "<f4", np.float64: "<f8", np.int64: "<i8", np.int32: "<i4"}
    blocks = [p for p in parts if not isinstance(p, str)]
    for (data, dtype, _), nbytes in zip(blocks, sizes[1:], strict=True):
        fh.write(np.uint64(nbytes).tobytes())
        chunks = _offsets(n_cells, size) if isinstance(data, str) else row_chunks(data)
        for block in chunks:
            fh.write(block.astype(little[dtype], copy=False).tobytes())
    fh.write(b"\n  </AppendedData>\n</VTKFile>\n")


def _offsets(n_cells: int, size: int):
    """Blocks of the cell offsets ``size, 2 size, ..., n_cells size`` (int64)."""
    for first in range(0, n_cells, ROWS):
        stop = min(first + ROWS, n_cells)
        yield np.arange(first + 1, stop + 1, dtype=np.int64) * size
