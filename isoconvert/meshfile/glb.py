"""GLB (binary glTF 2.0)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, one_line
from ..mesh import Mesh
from .common import _check_indices, _extraction, _Unreadable

_GLTF_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_GLTF_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_GLTF_TRIANGLES, _GLTF_LINES = 4, 1


def _read_glb(path: Path) -> Mesh:
    """GLB: the triangle (mode 4) or line (mode 1) primitives of the meshes the
    default scene's nodes place, with the nodes' transforms; indexed or not."""
    import json
    import struct

    data = path.read_bytes()
    if len(data) < 20:
        raise _Unreadable("shorter than a GLB header")
    magic, version, total = struct.unpack_from("<III", data)
    if magic != 0x46546C67:
        raise _Unreadable("not a GLB file (it does not start with 'glTF')")
    if version != 2:
        raise _Unreadable(f"glTF version {version}; check reads glTF 2.0")
    if total > len(data):
        raise _Unreadable(f"its header says {total} bytes, but the file has {len(data)}")
    chunks: list[tuple[int, bytes]] = []
    offset = 12
    while offset + 8 <= total:
        length, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + length > total:
            raise _Unreadable("the file ends inside a chunk")
        chunks.append((kind, data[offset + 8 : offset + 8 + length]))
        offset += 8 + length
    if not chunks or chunks[0][0] != 0x4E4F534A:
        raise _Unreadable("its first chunk is not JSON")
    try:
        gltf = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _Unreadable(f"its JSON chunk is not JSON ({exc})") from None
    if not isinstance(gltf, dict):
        raise _Unreadable("its JSON chunk is not a glTF object")
    required = gltf.get("extensionsRequired") or []
    if required:  # Draco or meshopt compressed data: not read (nor inflated)
        names = ", ".join(one_line(name, 60) for name in required)
        raise _Unreadable(f"it requires glTF extensions check does not read ({names})")
    binary = next((chunk for kind, chunk in chunks[1:] if kind == 0x004E4942), None)
    buffers = [_gltf_buffer(b, binary) for b in gltf.get("buffers", [])]
    extras = gltf.get("asset", {}).get("extras", {})
    ours = extras.get("isoconvert") if isinstance(extras, dict) else None
    # isoconvert's files scale the volume's units to meters in their node: back to
    # the volume's units, where the grid record and the other formats have the mesh
    # (divided, not multiplied by an inverse, so that their own scale gives 1 exactly)
    scaled = isinstance(ours, dict) and _positive(ours.get("meters_per_unit"))
    per_unit = float(ours["meters_per_unit"]) if scaled else 1.0
    vertices_list, cells_list, kinds = [], [], set()
    n = 0
    transformed = False
    for mesh_index, matrix in _gltf_instances(gltf):
        matrix[:3] /= per_unit
        mesh = gltf["meshes"][mesh_index]
        for primitive in mesh.get("primitives", []):
            mode = primitive.get("mode", _GLTF_TRIANGLES)
            if mode not in (_GLTF_TRIANGLES, _GLTF_LINES):
                raise _Unreadable(
                    f"a primitive has mode {mode}; check reads triangles (4) and lines (1)"
                )
            if "POSITION" not in primitive.get("attributes", {}):
                raise _Unreadable("a primitive has no POSITION attribute")
            positions = _gltf_accessor(
                gltf, buffers, primitive["attributes"]["POSITION"], len(data)
            )
            if positions.ndim != 2 or positions.shape[1] != 3:
                raise _Unreadable("its POSITION accessor is not VEC3")
            with np.errstate(invalid="ignore", over="ignore"):  # the report names non-finite ones
                positions = positions.astype(np.float64)
            if not np.array_equal(matrix, np.eye(4)):
                positions = positions @ matrix[:3, :3].T + matrix[:3, 3]
                transformed = True
            size = 3 if mode == _GLTF_TRIANGLES else 2
            if "indices" in primitive:
                indices = _gltf_accessor(gltf, buffers, primitive["indices"], len(data)).astype(
                    np.int64
                )
            else:
                indices = np.arange(len(positions), dtype=np.int64)
            if indices.size % size:
                raise _Unreadable(f"a primitive's {indices.size} indices are no whole cells")
            cells = indices.reshape(-1, size)
            _check_indices(path, cells, len(positions), "triangle" if size == 3 else "segment")
            vertices_list.append(positions)
            cells_list.append(cells + n)
            kinds.add(size)
            n += len(positions)
    if not cells_list or not sum(len(c) for c in cells_list):
        raise FormatError(f"{path}: holds no triangles or segments")
    if len(kinds) > 1:
        raise _Unreadable("it holds both triangles and lines; check reads one kind")
    info: dict = {
        "source": str(path),
        # float32 positions placed by a transform are float64 values
        "stored_precision": "float64" if transformed else "float32",
    }
    if isinstance(ours, dict):
        from ..geometry import normalized_grid

        info["cut_by_grid"] = True  # isoconvert's file: extracted from a volume
        lines = ours.get("provenance")
        info.update(_extraction(lines if isinstance(lines, list) else []))
        grid = normalized_grid(ours.get("grid"))
        if grid is not None:
            info["grid"] = grid
        if scaled:
            info["unit"] = str(ours.get("unit"))  # the unit the positions are back in
    return Mesh(np.concatenate(vertices_list), np.concatenate(cells_list), info=info)


def _positive(value) -> bool:
    """Whether ``value`` is a finite number above 0."""
    return isinstance(value, int | float) and not isinstance(value, bool) and 0 < value < np.inf


def _gltf_buffer(buffer: dict, binary: bytes | None) -> bytes:
    """A buffer's bytes: the BIN chunk, or a base64 ``data:`` URI."""
    import base64
    import binascii

    uri = buffer.get("uri")
    if uri is None:
        if binary is None:
            raise _Unreadable("it has a buffer but no BIN chunk")
        data = binary
    elif uri.startswith("data:") and ";base64," in uri:
        try:
            data = base64.b64decode(uri.split(";base64,", 1)[1])
        except binascii.Error as exc:
            raise _Unreadable(f"a buffer's data URI is not base64 ({exc})") from None
    else:
        raise _Unreadable(f"a buffer refers to another file ({one_line(uri, 80)}), not read")
    if len(data) < int(buffer.get("byteLength", 0)):
        raise _Unreadable("a buffer is shorter than its byteLength (a truncated file?)")
    return data


def _gltf_accessor(gltf: dict, buffers: list[bytes], index: int, most: int) -> np.ndarray:
    """The values of accessor ``index``: (count,) for SCALAR, (count, k) for VECk.

    An accessor with no buffer view is all zeros, values the file's bytes do
    not back: it may have at most ``most`` values (the file's size), so that a
    count of 10**12 in a small file is refused, not allocated."""
    accessor = gltf["accessors"][index]
    if "sparse" in accessor:
        raise _Unreadable("a sparse accessor, which check does not read")
    code = _GLTF_COMPONENTS.get(accessor.get("componentType"))
    width = _GLTF_WIDTH.get(accessor.get("type"))
    if code is None or width is None:
        raise _Unreadable(f"accessor {index} has an unsupported component type or type")
    count = int(accessor["count"])
    if count < 0:
        raise _Unreadable(f"accessor {index} has a negative count ({count})")
    dtype = np.dtype("<" + code)
    if "bufferView" not in accessor:  # glTF: all zeros
        if count * width > most:
            raise _Unreadable(
                f"accessor {index} declares {count:,} elements of zeros (no bufferView), "
                f"more values than the file has bytes ({most:,}); the file is corrupt"
            )
        values = np.zeros((count, width), dtype)
        return values[:, 0] if width == 1 else values
    view = gltf["bufferViews"][accessor["bufferView"]]
    data = buffers[view["buffer"]]
    start = int(view.get("byteOffset", 0)) + int(accessor.get("byteOffset", 0))
    stride = int(view.get("byteStride", 0)) or width * dtype.itemsize
    end = start + (count - 1) * stride + width * dtype.itemsize if count else start
    view_end = int(view.get("byteOffset", 0)) + int(view["byteLength"])
    if start < 0 or end > min(len(data), view_end):
        raise _Unreadable(f"accessor {index} reaches past the end of its buffer view")
    if count == 0:
        values = np.zeros((0, width), dtype)
    else:
        values = np.ndarray((count, width), dtype, data, start, (stride, dtype.itemsize))
    return values[:, 0] if width == 1 else values


def _gltf_instances(gltf: dict) -> list[tuple[int, np.ndarray]]:
    """(mesh index, 4x4 world matrix) of every node with a mesh in the default
    scene; every mesh, untransformed, when the file has no scene."""
    meshes = gltf.get("meshes", [])
    nodes = gltf.get("nodes", [])
    scenes = gltf.get("scenes", [])
    if not scenes:
        return [(i, np.eye(4)) for i in range(len(meshes))]
    scene = scenes[gltf.get("scene", 0)]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(i, np.eye(4), 0) for i in scene.get("nodes", [])]
    while stack:
        index, parent, depth = stack.pop()
        if depth > len(nodes):  # a cycle: glTF nodes form trees
            raise _Unreadable("its nodes form a cycle")
        node = nodes[index]
        matrix = parent @ _gltf_local(node)
        if "mesh" in node:
            out.append((int(node["mesh"]), matrix))
        stack.extend((child, matrix, depth + 1) for child in node.get("children", []))
    return out


def _gltf_local(node: dict) -> np.ndarray:
    """A node's local transform: its ``matrix`` (column-major) or T * R * S."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    local = np.eye(4)
    local[:3, :3] = rotation * np.asarray(node.get("scale", [1.0, 1.0, 1.0]), dtype=np.float64)
    local[:3, 3] = node.get("translation", [0.0, 0.0, 0.0])
    return local
