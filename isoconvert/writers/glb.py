"""GLB (binary glTF 2.0), what web viewers open: one indexed triangle mesh.

Layout (all little-endian)::

    12-byte header      magic "glTF", version 2, total length (uint32)
    JSON chunk          length, "JSON", the glTF JSON padded with spaces to 4 bytes
    BIN chunk           length, "BIN\\0", then
                          POSITION  V x 3 float32   (bufferView 0, accessor 0, with min/max)
                          NORMAL    V x 3 float32   (with --normals: the next view and accessor)
                          _VALUE    V float32       (with --values: the next)
                          indices   3C uint32       (the last view and accessor)

Both arrays are multiples of 4 bytes, so the BIN chunk needs no padding. Its
length follows from V and C, so the JSON is written first and the arrays are
streamed block by block after it (a first pass over the vertices finds the
accessor's min and max).

glTF is float32 only and its convention is +Y up, meters. The positions are the
volume's world coordinates as they are (no axis swap); where the volume's unit
is known (mm from DICOM and NIfTI, NRRD's space units, µm from microscopy
files), the node's ``scale`` converts them to meters (0.001 for mm), as glTF
viewers expect, and ``asset.extras["isoconvert"]`` records the unit and the
factor (isoconvert's reader undoes it). Without a known unit nothing is scaled,
and the extras say so, beside the provenance lines and the grid record.
"""

from __future__ import annotations

import json
import struct
from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..geometry import normalized_grid
from ..mesh import Mesh
from ..units import meters_per_unit
from .chunks import row_chunks
from .header import escape_comment, provenance

#: What ``asset.extras["isoconvert"]["frame"]`` says about the coordinates.
FRAME_NOTE = (
    "vertex coordinates are the volume's world coordinates as they are (no swap to "
    "glTF's +Y up); the node's scale converts them to meters where their unit is known"
)
_MAGIC, _VERSION = 0x46546C67, 2  # "glTF"
_JSON, _BIN = 0x4E4F534A, 0x004E4942  # "JSON", "BIN\0"
_FLOAT, _UNSIGNED_INT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TRIANGLES = 4
#: The GLB header's total length is a uint32.
_MAX_BYTES = 2**32 - 1


def _extras(mesh: Mesh) -> dict:
    """Provenance lines (escaped as in PLY/OBJ headers), the grid, the frame note,
    and the unit with its meters (``meters_per_unit``, the node's scale) when known."""
    extras: dict = {"provenance": [escape_comment(line) for line in provenance(mesh)]}
    grid = normalized_grid(mesh.info.get("grid"))
    if grid is not None:
        extras["grid"] = grid
    extras["frame"] = FRAME_NOTE
    unit = mesh.info.get("unit")
    scale = meters_per_unit(unit)
    if scale is None:
        extras["unit"] = "not known: coordinates not scaled to meters"
    else:
        extras["unit"] = unit
        extras["meters_per_unit"] = scale
    return {"isoconvert": extras}


def _bounds(vertices: np.ndarray) -> tuple[list[float], list[float]]:
    """Per-axis min and max of the float32-rounded vertices, block by block."""
    low = np.full(3, np.inf, dtype=np.float32)
    high = np.full(3, -np.inf, dtype=np.float32)
    for block in row_chunks(vertices):
        with np.errstate(over="ignore", invalid="ignore"):
            stored = block.astype(np.float32)
        low = np.minimum(low, stored.min(axis=0))
        high = np.maximum(high, stored.max(axis=0))
    if not (np.isfinite(low).all() and np.isfinite(high).all()):
        raise FormatError(
            "GLB stores float32: some vertex coordinates are not finite there; "
            "write PLY or OBJ, or move the origin nearer the mesh"
        )
    return [float(v) for v in low], [float(v) for v in high]


def _node(mesh: Mesh) -> dict:
    """The one node: the mesh, scaled from the volume's unit to meters when known."""
    node: dict = {"mesh": 0, "name": "isosurface"}
    scale = meters_per_unit(mesh.info.get("unit"))
    if scale is not None and scale != 1.0:
        node["scale"] = [scale, scale, scale]
    return node


def gltf_json(mesh: Mesh) -> dict:
    """The glTF JSON of a GLB holding ``mesh`` (no data; the BIN chunk follows it)."""
    from .. import __version__

    n_vertices, n_cells = len(mesh.vertices), len(mesh.cells)
    gltf: dict = {
        "asset": {
            "version": "2.0",
            "generator": f"isoconvert {__version__}",
            "extras": _extras(mesh),
        },
        "scene": 0,
    }
    if n_cells == 0:
        gltf["scenes"] = [{}]  # an empty scene: glTF has no empty accessors
        return gltf
    low, high = _bounds(mesh.vertices)
    # (attribute, accessor type, bytes per vertex) after POSITION, in BIN order
    extra = []
    if mesh.normals is not None:
        extra.append(("NORMAL", "VEC3", 12))
    if mesh.values is not None:
        extra.append(("_VALUE", "SCALAR", 4))  # an application-specific attribute
    views = [{"byteLength": n_vertices * 12, "target": _ARRAY_BUFFER}]
    accessors = [
        {"componentType": _FLOAT, "count": n_vertices, "type": "VEC3", "min": low, "max": high}
    ]
    attributes = {"POSITION": 0}
    for name, kind, width in extra:
        attributes[name] = len(accessors)
        views.append({"byteLength": n_vertices * width, "target": _ARRAY_BUFFER})
        accessors.append({"componentType": _FLOAT, "count": n_vertices, "type": kind})
    attributes_end = len(accessors)
    views.append({"byteLength": n_cells * 12, "target": _ELEMENT_ARRAY_BUFFER})
    accessors.append({"componentType": _UNSIGNED_INT, "count": 3 * n_cells, "type": "SCALAR"})
    offset = 0
    for number, (view, accessor) in enumerate(zip(views, accessors, strict=True)):
        view.update(buffer=0, byteOffset=offset)
        offset += view["byteLength"]
        accessor["bufferView"] = number
    gltf.update(
        {
            "scenes": [{"nodes": [0]}],
            "nodes": [_node(mesh)],
            "meshes": [
                {
                    "name": "isosurface",
                    "primitives": [
                        {"attributes": attributes, "indices": attributes_end, "mode": _TRIANGLES}
                    ],
                }
            ],
            "buffers": [{"byteLength": offset}],
            "bufferViews": views,
            "accessors": accessors,
        }
    )
    return gltf


def write_glb(mesh: Mesh, fh: BinaryIO, ascii: bool = False) -> None:
    """Write one mesh, one primitive of triangles (mode 4) with POSITION (float32
    VEC3, with min and max), NORMAL and ``_VALUE`` (float32) when the mesh has
    normals and values, and uint32 indices, a node and a scene.

    ``asset.generator`` is ``isoconvert VERSION``; ``asset.extras["isoconvert"]``
    holds ``provenance`` (the lines PLY and OBJ headers get, escaped the same
    way), ``grid`` (the grid record, a JSON object) and ``frame`` (the
    coordinates are the volume's world coordinates, not swapped to glTF's +Y up),
    and, where the volume's unit is known, ``unit`` and ``meters_per_unit``, which
    is also the node's ``scale``. Written block by block.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 3)`` (glTF triangles; no segments here).
    fh : binary file
    ascii : bool
        Ignored (GLB is binary).
    """
    if not mesh.is_triangles:
        raise FormatError("GLB holds triangles only here; write contours as OBJ, PLY or VTP")
    n_vertices, n_cells = len(mesh.vertices), len(mesh.cells)
    if n_vertices >= 2**32 - 1:
        raise FormatError(
            f"GLB indices are uint32: {n_vertices} vertices are too many; write PLY or VTP"
        )
    text = json.dumps(
        gltf_json(mesh), separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode("utf-8")
    text += b" " * (-len(text) % 4)
    per_vertex = 12 + 12 * (mesh.normals is not None) + 4 * (mesh.values is not None)
    data = per_vertex * n_vertices + 12 * n_cells if n_cells else 0
    total = 12 + 8 + len(text) + (8 + data if data else 0)
    if total > _MAX_BYTES:
        raise FormatError(
            f"GLB files hold at most 4 GiB; this mesh needs {total / 2**30:.1f} GiB: "
            "write PLY or VTP, or decimate"
        )
    fh.write(struct.pack("<III", _MAGIC, _VERSION, total))
    fh.write(struct.pack("<II", len(text), _JSON) + text)
    if not data:
        return
    fh.write(struct.pack("<II", data, _BIN))
    for block in row_chunks(mesh.vertices):
        with np.errstate(over="ignore", invalid="ignore"):
            fh.write(block.astype("<f4").tobytes())
    for attribute in (mesh.normals, mesh.values):
        if attribute is not None:
            for block in row_chunks(attribute):
                fh.write(block.astype("<f4").tobytes())
    for block in row_chunks(mesh.cells):
        fh.write(block.astype("<u4").tobytes())
