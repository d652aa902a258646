"""3MF (3D Manufacturing Format): a ZIP package with an XML model part."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError
from ..mesh import Mesh
from ..units import unit_symbol
from ..writers.header import parse_grid_comment
from .common import _as_stored, _check_indices, _extraction, _tag, _Unreadable

_3MF_MODEL = "3D/3dmodel.model"
#: A part may inflate to at most this many times its compressed size (a 3MF
#: model's XML compresses 3 to 10 times; zeros or spaces 1000 times, as in a
#: decompression bomb) ...
_MAX_RATIO = 100
#: ... unless it is this small (a tiny part may compress far better).
_SMALL_PART = 16 << 20
#: Bytes inflated at a time.
_CHUNK = 1 << 20


def _read_part(path: Path, package, name: str) -> bytes:
    """The bytes of one part of the package, inflated in bounded chunks.

    A part whose ZIP entry declares more than :data:`_MAX_RATIO` times its
    compressed size (and more than :data:`_SMALL_PART` bytes) is refused before
    it is inflated, and no part is inflated past the size its entry declares:
    a decompression bomb is a one-line FormatError, not gigabytes of memory.

    Returns
    -------
    bytes
        At most the entry's declared size.
    """
    entry = package.getinfo(name)
    declared, packed = entry.file_size, entry.compress_size
    if declared > max(_SMALL_PART, _MAX_RATIO * packed):
        raise FormatError(
            f"{path}: its part {name} declares {declared:,} bytes from {packed:,}, "
            f"more than {_MAX_RATIO} times its compressed size; the file is corrupt or "
            "a decompression bomb"
        )
    chunks = []
    # zipfile stops inflating at the size the entry declares (and then finds the
    # CRC wrong when the data goes on: BadZipFile, which the caller words)
    with package.open(entry) as fh:
        while chunk := fh.read(_CHUNK):
            chunks.append(chunk)
    return b"".join(chunks)


def _read_3mf(path: Path) -> Mesh:
    """3MF: the triangles of every build item (objects and their components,
    with their transforms), from the package's start part."""
    import zipfile
    import zlib
    from xml.etree import ElementTree

    try:
        with zipfile.ZipFile(path) as package:
            names = set(package.namelist())
            part = _3mf_start_part(path, package, names)
            xml = _read_part(path, package, part)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, NotImplementedError) as exc:
        raise _Unreadable(f"not a readable ZIP package ({exc})") from None
    except zlib.error as exc:
        raise _Unreadable(f"a part does not decompress ({exc})") from None
    try:
        root = ElementTree.fromstring(xml)
    except ElementTree.ParseError as exc:
        raise _Unreadable(f"its model part is not well-formed XML ({exc})") from None
    if _tag(root) != "model":
        raise _Unreadable("its model part has no <model> element")
    objects: dict[str, object] = {}
    for resources in (e for e in root if _tag(e) == "resources"):
        for obj in (e for e in resources if _tag(e) == "object"):
            objects[obj.get("id")] = obj
    build = next((e for e in root if _tag(e) == "build"), None)
    items = (
        [(e.get("objectid"), _3mf_transform(e)) for e in build if _tag(e) == "item"]
        if build is not None
        else [(key, np.eye(4)) for key in objects]
    )
    vertices_list, cells_list = [], []
    n = 0
    transformed = False
    stack = [(key, matrix, 0) for key, matrix in reversed(items)]
    while stack:
        key, matrix, depth = stack.pop()
        if key not in objects:
            raise _Unreadable(f"a build item or component refers to object {key}, not defined")
        if depth > len(objects):
            raise _Unreadable("its components refer to each other in a cycle")
        obj = objects[key]
        mesh = next((e for e in obj if _tag(e) == "mesh"), None)
        if mesh is not None:
            vertices, cells = _3mf_mesh(path, mesh)
            if not np.array_equal(matrix, np.eye(4)):
                vertices = vertices @ matrix[:3, :3].T + matrix[:3, 3]
                transformed = True
            vertices_list.append(vertices)
            cells_list.append(cells + n)
            n += len(vertices)
        components = next((e for e in obj if _tag(e) == "components"), None)
        if components is not None:
            children = [e for e in components if _tag(e) == "component"]
            stack.extend(
                (c.get("objectid"), matrix @ _3mf_transform(c), depth + 1)
                for c in reversed(children)
            )
    if not cells_list or not sum(len(c) for c in cells_list):
        raise FormatError(f"{path}: holds no triangles or segments")
    vertices = np.concatenate(vertices_list)
    info: dict = {"source": str(path)}
    if not transformed and _float32_text(vertices):
        info["stored_precision"] = "float32"
        vertices = _as_stored(vertices, "float32")
    else:
        info["stored_precision"] = "float64"
    unit_known = True
    for meta in (e for e in root if _tag(e) == "metadata"):
        text = (meta.text or "").strip()
        grid = parse_grid_comment(text)
        if meta.get("name", "").endswith("grid") and grid is not None:
            info["grid"] = grid
        if meta.get("name", "").startswith("isoconvert:"):
            info["cut_by_grid"] = True  # isoconvert's file: extracted from a volume
        if meta.get("name", "") == "Description":
            info.update(_extraction(text.splitlines()))
        if meta.get("name", "") == "isoconvert:coordinates" and "not converted" in text:
            unit_known = False  # isoconvert wrote "millimeter" for want of a unit
    # 3MF's unit (millimeter when the model names none), by its usual symbol
    unit = unit_symbol(root.get("unit", "millimeter"))
    if unit_known and unit is not None:
        info["unit"] = unit
    return Mesh(vertices, np.concatenate(cells_list), info=info)


def _float32_text(values: np.ndarray) -> bool:
    """Whether decimal coordinates are float32 values: each one either is a
    float32 value or is the 9-significant-digit text of one (as isoconvert's
    3MF writer prints them: the nearest float32 gives the value back exactly,
    the nearest double does not)."""
    flat = values.reshape(-1)
    # a few thousand coordinates settle most float64 meshes without a pass over all
    for part in (flat[:4096], flat):
        with np.errstate(over="ignore", invalid="ignore"):
            as32 = part.astype(np.float32).astype(np.float64)
        differ = as32 != part
        if differ.any():
            printed = np.char.mod("%.9g", as32[differ]).astype(np.float64)
            if not (printed == part[differ]).all():
                return False
    return True


def _3mf_start_part(path: Path, package, names: set[str]) -> str:
    """The model part the package's relationships name (else ``3D/3dmodel.model``)."""
    from xml.etree import ElementTree

    if "_rels/.rels" in names:
        try:
            rels = ElementTree.fromstring(_read_part(path, package, "_rels/.rels"))
        except ElementTree.ParseError:
            rels = None
        for rel in rels if rels is not None else []:
            if rel.get("Type", "").endswith("/3dmodel"):
                target = rel.get("Target", "").lstrip("/")
                if target in names:
                    return target
    if _3MF_MODEL in names:
        return _3MF_MODEL
    raise _Unreadable("the package has no 3D model part (3D/3dmodel.model)")


def _3mf_transform(element) -> np.ndarray:
    """A ``transform="m00 m01 m02 m10 ... m32"`` attribute as a 4x4 matrix acting
    on column vectors (3MF multiplies row vectors on the left)."""
    text = element.get("transform")
    matrix = np.eye(4)
    if text:
        values = np.array(text.split(), dtype=np.float64)
        if values.size != 12:
            raise _Unreadable(f"a transform has {values.size} numbers, not 12")
        matrix[:3, :] = values.reshape(4, 3).T
    return matrix


def _3mf_mesh(path: Path, mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (T, 3) int64 triangles of one ``<mesh>``."""
    vertices_element = next((e for e in mesh if _tag(e) == "vertices"), None)
    triangles_element = next((e for e in mesh if _tag(e) == "triangles"), None)
    rows = [] if vertices_element is None else list(vertices_element)
    try:
        vertices = np.array(
            [(v.get("x"), v.get("y"), v.get("z")) for v in rows], dtype=np.float64
        ).reshape(-1, 3)
    except (TypeError, ValueError):
        raise _Unreadable("a vertex lacks x, y or z, or they are not numbers") from None
    rows = [] if triangles_element is None else list(triangles_element)
    try:
        cells = np.array(
            [(t.get("v1"), t.get("v2"), t.get("v3")) for t in rows], dtype=np.int64
        ).reshape(-1, 3)
    except (TypeError, ValueError):
        raise _Unreadable("a triangle lacks v1, v2 or v3, or they are not integers") from None
    _check_indices(path, cells, len(vertices), "triangle")
    return vertices, cells
