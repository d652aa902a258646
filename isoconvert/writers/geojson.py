"""GeoJSON: 2D contours as a FeatureCollection of LineStrings, in world units.

One Feature per polyline of the contour (:func:`isoconvert.mesh.polylines`):
a closed loop repeats its first position at its end, an open chain (one that
ends at the image border) does not. Each Feature's ``properties`` hold
``level``, ``closed`` and, where the mesh knows them, ``source``, ``method``,
``frame`` and ``unit``. The collection carries a foreign member
``"isoconvert"`` with the provenance lines PLY and OBJ headers get, the grid
record and a note on the coordinates.

Coordinates are planar world coordinates (the volume's spacing and origin,
usually millimeters), as GIS-for-images tools (QGIS on a non-georeferenced
raster, napari, shapely) use them; they are **not** the longitude and
latitude RFC 7946 expects, and no coordinate reference system is named.
Squares on a 2D image give ``[x, y]`` positions; squares on a 3D volume (one
slice at a time, ``--axis``) give ``[x, y, z]``.

Segments run with the higher values on their left, so in a y-up view a loop
around a bright blob is counter-clockwise (its signed area is positive) and a
loop around a dark hole clockwise.
"""

from __future__ import annotations

import json
import numbers
from typing import BinaryIO

import numpy as np

from ..errors import FormatError
from ..geometry import normalized_grid
from ..mesh import Mesh, polylines
from .header import escape_comment, provenance

#: What ``isoconvert.coordinates`` of the collection says.
COORDINATES_NOTE = (
    "planar world coordinates of the volume (its spacing and origin, usually mm), "
    "not longitude and latitude"
)


def _text(value: object) -> str:
    """``value`` as a string JSON can hold: text that is no valid Unicode (the
    undecodable bytes of a file name) escaped as in file headers."""
    text = str(value)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return escape_comment(text)
    return text


def _number(value: object) -> object:
    """A level as JSON: a finite number as a float, anything else as text."""
    if isinstance(value, numbers.Real) and np.isfinite(float(value)):
        return float(value)
    return _text(value)


def _dimensions(mesh: Mesh, vertices: np.ndarray) -> int:
    """2 for contours of a 2D image, 3 for slice-wise contours of a volume.

    The grid decides when the mesh records one (so every file made from a 3D
    volume has 3 coordinates, even when all its contours lie in one plane);
    otherwise the vertices do: all at z = 0 is a plane image.
    """
    grid = normalized_grid(mesh.info.get("grid"))
    if grid is not None:
        return 3 if len(grid["shape"]) == 3 else 2
    return 3 if len(vertices) and np.any(vertices[:, 2] != 0) else 2


def geojson_dict(mesh: Mesh) -> dict:
    """The GeoJSON FeatureCollection of the contour ``mesh``.

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 2)`` (segments, higher values on their left).

    Returns
    -------
    dict
        ``{"type": "FeatureCollection", "bbox": [...], "isoconvert": {...},
        "features": [...]}``; positions are lists of 2 or 3 floats.

    Raises
    ------
    FormatError
        Triangles, or coordinates that are not finite.
    """
    if mesh.is_triangles:
        raise FormatError(
            "GeoJSON holds 2D contours (squares); write surfaces as PLY, OBJ, STL or VTP"
        )
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(vertices).all():
        raise FormatError("GeoJSON needs finite coordinates; some vertex coordinates are not")
    dims = _dimensions(mesh, vertices)
    info = mesh.info
    common: dict = {"level": _number(info.get("level", "?"))}
    for key in ("source", "method", "frame", "unit"):
        if key in info:
            common[key] = _text(info[key])
    features = []
    for line, closed in polylines(mesh.cells):
        if closed:
            # GeoJSON closes a ring by repeating its first position
            line = np.append(line, line[0])
        features.append(
            {
                "type": "Feature",
                "properties": {**common, "closed": bool(closed)},
                "geometry": {
                    "type": "LineString",
                    # tolist gives Python floats, which json writes as the shortest
                    # text that reads back as the same double
                    "coordinates": vertices[line, :dims].tolist(),
                },
            }
        )
    extras: dict = {"provenance": [_text(line) for line in provenance(mesh)]}
    grid = normalized_grid(info.get("grid"))
    if grid is not None:
        extras["grid"] = grid
    extras["coordinates"] = COORDINATES_NOTE
    collection: dict = {"type": "FeatureCollection"}
    if len(mesh.cells):
        used = vertices[np.unique(mesh.cells), :dims]
        collection["bbox"] = used.min(axis=0).tolist() + used.max(axis=0).tolist()
    collection["isoconvert"] = extras
    collection["features"] = features
    return collection


def write_geojson(mesh: Mesh, fh: BinaryIO, ascii: bool = True) -> None:
    """Write the contour ``mesh`` as a GeoJSON FeatureCollection (UTF-8).

    Parameters
    ----------
    mesh : Mesh
        ``vertices (V, 3)``, ``cells (C, 2)``; see :func:`geojson_dict`.
    fh : binary file
    ascii : bool
        Ignored (GeoJSON is text).
    """
    collection = geojson_dict(mesh)
    # one Feature a line: readable, diffable, and still compact for long contours
    features = collection.pop("features")
    head = json.dumps(collection, ensure_ascii=False, allow_nan=False)
    fh.write((head[:-1] + ', "features": [\n').encode("utf-8"))
    for number, feature in enumerate(features):
        text = json.dumps(feature, ensure_ascii=False, allow_nan=False)
        fh.write((text + (",\n" if number + 1 < len(features) else "\n")).encode("utf-8"))
    fh.write(b"]}\n")
