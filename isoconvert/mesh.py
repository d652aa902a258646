"""Mesh: an indexed (face-vertex) surface or contour, book section 1.7.3."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass
class Mesh:
    """Indexed triangles (or line segments) and their vertices.

    Attributes
    ----------
    vertices : (V, 3) float64
        Vertex positions in world units.
    cells : (C, 3) or (C, 2) int64
        Triangles (right-hand normals point from the positive to the negative
        side) or segments, as indices into ``vertices``.
    edge_ids : (V,) int64 or None
        For extracted meshes, the global id of the grid edge each vertex lies
        on (``3 * (i + X * (j + Y * k)) + axis`` for cubes). Blocks of a volume
        extracted separately share vertices exactly through these ids.
    info : dict
        Provenance (method, level, source) written into file headers.
    normals : (V, 3) float32 or None
        Unit normals at the vertices, pointing like the triangles' (from the
        positive to the negative side); see :func:`isoconvert.vertex_normals`.
    values : (V,) float32 or None
        A scalar at each vertex (e.g. another volume sampled there, see
        :func:`isoconvert.vertex_values`); NaN where it has none.
    cell_labels : (C, 2) int64 or None
        The labels on the two sides of each cell (label volumes): normals point
        from the label in column 0 to the one in column 1.
    """

    vertices: np.ndarray
    cells: np.ndarray
    edge_ids: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    normals: np.ndarray | None = None
    values: np.ndarray | None = None
    cell_labels: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_cells(self) -> int:
        return int(self.cells.shape[0])

    @property
    def is_triangles(self) -> bool:
        return self.cells.ndim == 2 and self.cells.shape[1] == 3

    def flipped(self) -> Mesh:
        """The same mesh with every cell's orientation reversed (and its normals)."""
        normals = None if self.normals is None else -self.normals
        labels = None if self.cell_labels is None else self.cell_labels[:, ::-1].copy()
        return Mesh(
            self.vertices,
            self.cells[:, ::-1].copy(),
            self.edge_ids,
            dict(self.info),
            normals,
            self.values,
            labels,
        )

    # --- hand-offs to the mesh libraries users hold meshes in (imported lazily) ----------

    def to_meshio(self):
        """This mesh as a ``meshio.Mesh`` (needs meshio, a dependency of isoconvert).

        Returns
        -------
        meshio.Mesh
            ``points (V, 3) float64`` (the same vertices), one cell block
            ``triangle`` ``(C, 3)`` (or ``line`` ``(C, 2)``) with the same
            corner order, so the same orientation (int32 when there are fewer
            than 2**31 vertices: meshio's Gmsh and PLY writers need it); point data ``Normals``
            ``(V, 3)`` and ``value`` ``(V,)`` float32 and cell data
            ``inside_label``, ``outside_label`` ``(C,)`` int32 (the label the
            normals point from, and to) where the mesh has them.
        """
        meshio = _import("meshio", "meshio")
        # int32 indices where they fit: meshio's Gmsh 4.1 writer makes unreadable files
        # of int64 cells, and its PLY writer casts them down with a warning
        index = np.int32 if len(self.vertices) < 2**31 else np.int64
        kind = "triangle" if self.cells.shape[1] == 3 else "line"
        return meshio.Mesh(
            np.asarray(self.vertices, dtype=np.float64),
            [(kind, np.asarray(self.cells, dtype=index))],
            point_data=self._point_data(np.float32),
            cell_data={k: [v] for k, v in self._cell_data().items()},
        )

    @classmethod
    def from_meshio(cls, mesh, name: str = "meshio mesh") -> Mesh:
        """A Mesh of the surface (or contour lines) of a ``meshio.Mesh``.

        Triangles are taken as they are and quads split into two triangles
        (0, 1, 2), (0, 2, 3), keeping their orientation; without either, line
        cells are taken as contour segments. Volume cells (tetrahedra, ...)
        and vertices are left out; a mesh of nothing else is an error.

        Parameters
        ----------
        mesh : meshio.Mesh
        name : str
            Names the mesh in errors.

        Returns
        -------
        Mesh
            ``vertices (V, 3) float64`` (2D points get z = 0), ``cells (C, 3)``
            or ``(C, 2)`` int64; ``normals`` from point data ``Normals`` (or
            ``normals``), ``values`` from ``value``, ``cell_labels`` from cell
            data ``inside_label`` and ``outside_label`` when present;
            ``info["stored_precision"]`` "float32" for float32 points, else
            "float64".

        Raises
        ------
        FormatError
            No surface or line cells, or a cell refers to a missing vertex.
        """
        from .errors import FormatError

        points = np.asarray(mesh.points)
        if points.ndim != 2 or points.shape[1] not in (2, 3):
            raise FormatError(f"{name}: points are {points.shape}, not (V, 2) or (V, 3)")
        precision = "float32" if points.dtype == np.float32 else "float64"
        vertices = np.zeros((len(points), 3), dtype=np.float64)
        vertices[:, : points.shape[1]] = points
        kinds = [block.type for block in mesh.cells]
        surface = [i for i, kind in enumerate(kinds) if kind in ("triangle", "quad")]
        chosen = surface or [i for i, kind in enumerate(kinds) if kind == "line"]
        if not chosen:
            found = ", ".join(sorted(set(kinds))) or "no cells"
            raise FormatError(
                f"{name}: holds {found}, no triangles, quads or lines; isoconvert checks "
                "surfaces and contours"
            )
        parts, rows = [], []
        for i in chosen:
            data = np.asarray(mesh.cells[i].data, dtype=np.int64)
            if kinds[i] == "quad":  # two triangles each, the same turning sense
                parts.append(
                    np.stack([data[:, [0, 1, 2]], data[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
                )
                rows.append((i, 2))
            else:
                parts.append(data)
                rows.append((i, 1))
        cells = np.concatenate(parts) if len(parts) > 1 else parts[0]
        if cells.size and (cells.min() < 0 or cells.max() >= len(vertices)):
            bad = (cells < 0) | (cells >= len(vertices))
            row = int(np.flatnonzero(bad.any(axis=1))[0])
            raise FormatError(
                f"{name}: cell {row} refers to vertex {int(cells[row][bad[row]][0])}, but there "
                f"are {len(vertices)} vertices"
            )

        def per_cell(key: str) -> np.ndarray | None:
            blocks = mesh.cell_data.get(key)
            if blocks is None:
                return None
            return np.concatenate(
                [np.repeat(np.asarray(blocks[i]).reshape(-1), times) for i, times in rows]
            )

        labels = None
        inside, outside = per_cell("inside_label"), per_cell("outside_label")
        if inside is not None and outside is not None:
            labels = np.stack([inside, outside], axis=1).astype(np.int64)
        normals = mesh.point_data.get("Normals", mesh.point_data.get("normals"))
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float32).reshape(len(vertices), 3)
        values = mesh.point_data.get("value")
        if values is not None:
            values = np.asarray(values, dtype=np.float32).reshape(len(vertices))
        info = {"stored_precision": precision}
        return cls(vertices, cells, None, info, normals, values, labels)

    def to_trimesh(self):
        """This triangle mesh as a ``trimesh.Trimesh`` (needs trimesh).

        Built with ``process=False``: the same vertices in the same order
        (nothing merged or dropped) and the same faces in the same corner
        order, so the same orientation (trimesh's face normals and volume
        follow the right-hand rule, as here).

        Returns
        -------
        trimesh.Trimesh
            ``vertices (V, 3) float64``, ``faces (C, 3) int64``; the mesh's
            normals as ``vertex_normals``, its values as
            ``vertex_attributes["value"]``, its labels as
            ``face_attributes["inside_label"]`` and ``["outside_label"]``.

        Raises
        ------
        IsoconvertError
            trimesh is not installed, or the mesh is contour segments.
        """
        from .errors import IsoconvertError

        if not self.is_triangles:
            raise IsoconvertError(
                "to_trimesh: the mesh is contour segments, and trimesh.Trimesh holds "
                "triangles; use to_meshio (line cells) or to_pyvista"
            )
        trimesh = _import("trimesh", "trimesh")
        vertex_attributes = {} if self.values is None else {"value": np.asarray(self.values)}
        return trimesh.Trimesh(
            vertices=np.asarray(self.vertices, dtype=np.float64),
            faces=np.asarray(self.cells, dtype=np.int64),
            vertex_normals=None if self.normals is None else np.asarray(self.normals),
            vertex_attributes=vertex_attributes,
            face_attributes=self._cell_data(),
            process=False,
            validate=False,
        )

    @classmethod
    def from_trimesh(cls, mesh) -> Mesh:
        """A Mesh of a ``trimesh.Trimesh``: its vertices and faces as they are.

        Normals come along only where the Trimesh holds them already (given,
        or computed before): none are computed here. ``vertex_attributes
        ["value"]`` and ``face_attributes["inside_label"]``/``["outside_label"]``
        become values and labels.

        Returns
        -------
        Mesh
            ``vertices (V, 3) float64``, ``cells (C, 3) int64``.
        """
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        cells = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
        normals = None
        # trimesh keeps given (or already computed) vertex normals in its cache; asking
        # mesh.vertex_normals would compute them
        cache = getattr(mesh, "_cache", None)
        if cache is not None and "vertex_normals" in cache:
            normals = np.asarray(mesh.vertex_normals, dtype=np.float32)
        values = dict(getattr(mesh, "vertex_attributes", {}) or {}).get("value")
        faces = dict(getattr(mesh, "face_attributes", {}) or {})
        return cls._from_arrays(
            vertices, cells, normals, values, faces.get("inside_label"), faces.get("outside_label")
        )

    def to_pyvista(self):
        """This mesh as a ``pyvista.PolyData`` (needs pyvista).

        Returns
        -------
        pyvista.PolyData
            The same points and, in the same corner order, ``faces`` (or
            ``lines`` for segments) in VTK's flat ``[3, a, b, c, ...]`` layout;
            point data ``Normals`` and ``value``, cell data ``inside_label``
            and ``outside_label`` where the mesh has them.
        """
        pyvista = _import("pyvista", "pyvista")
        cells = np.asarray(self.cells, dtype=np.int64)
        flat = np.column_stack([np.full(len(cells), cells.shape[1]), cells]).ravel()
        points = np.asarray(self.vertices, dtype=np.float64)
        if self.is_triangles:
            out = pyvista.PolyData(points, faces=flat)
        else:
            out = pyvista.PolyData(points, lines=flat)
        for name, data in self._point_data(np.float32).items():
            out.point_data[name] = data
        for name, data in self._cell_data().items():
            out.cell_data[name] = data
        return out

    @classmethod
    def from_pyvista(cls, mesh) -> Mesh:
        """A Mesh of a ``pyvista.PolyData`` (other datasets: their surface,
        ``extract_surface()``): its polygons as fans of triangles, or its lines
        as segments when it has no polygons.

        Returns
        -------
        Mesh
            ``vertices (V, 3) float64``, ``cells (C, 3)`` or ``(C, 2)`` int64;
            point data ``Normals`` and ``value``, cell data ``inside_label``
            and ``outside_label`` where present.
        """
        from .errors import FormatError

        if not hasattr(mesh, "faces"):
            mesh = mesh.extract_surface()
        vertices = np.asarray(mesh.points, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        lines = np.asarray(getattr(mesh, "lines", np.empty(0)), dtype=np.int64)
        if faces.size:
            cells, source = _fans(faces, 3)
        elif lines.size:
            cells, source = _fans(lines, 2)
        else:
            raise FormatError("from_pyvista: the PolyData has no polygons or lines")
        point_data, cell_data = mesh.point_data, mesh.cell_data

        def per_cell(key):
            return np.asarray(cell_data[key])[source] if key in cell_data else None

        normals = point_data["Normals"] if "Normals" in point_data else None
        values = point_data["value"] if "value" in point_data else None
        return cls._from_arrays(
            vertices, cells, normals, values, per_cell("inside_label"), per_cell("outside_label")
        )

    @classmethod
    def _from_arrays(cls, vertices, cells, normals, values, inside, outside) -> Mesh:
        labels = None
        if inside is not None and outside is not None:
            labels = np.stack([np.asarray(inside), np.asarray(outside)], axis=1).astype(np.int64)
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float32).reshape(len(vertices), 3)
        if values is not None:
            values = np.asarray(values, dtype=np.float32).reshape(len(vertices))
        return cls(vertices, cells, None, {}, normals, values, labels)

    def _point_data(self, dtype) -> dict:
        data = {}
        if self.normals is not None:
            data["Normals"] = np.asarray(self.normals, dtype=dtype)
        if self.values is not None:
            data["value"] = np.asarray(self.values, dtype=dtype)
        return data

    def _cell_data(self) -> dict:
        if self.cell_labels is None:
            return {}
        labels = np.asarray(self.cell_labels, dtype=np.int32)
        return {
            "inside_label": np.ascontiguousarray(labels[:, 0]),
            "outside_label": np.ascontiguousarray(labels[:, 1]),
        }

    def triangle_normals(self) -> np.ndarray:
        """(C, 3) float64 unit normals (right-hand rule); zero for zero-area triangles."""
        v = self.vertices
        t = self.cells
        n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        length = np.linalg.norm(n, axis=1)
        nonzero = length > 0
        n[nonzero] /= length[nonzero, np.newaxis]
        n[~nonzero] = 0.0
        return n

    def vertex_normals(self) -> np.ndarray:
        """(V, 3) float64 unit area-weighted normals of the triangles around each
        vertex; zero for vertices in no triangle of non-zero area."""
        from . import _native

        out = np.empty((len(self.vertices), 3), dtype=np.float64)
        _native.vertex_normals(
            np.ascontiguousarray(self.vertices, dtype=np.float64),
            np.ascontiguousarray(self.cells, dtype=np.int64),
            out,
        )
        return out

    def area(self) -> float:
        """Total area of the triangles."""
        v = self.vertices
        t = self.cells
        cross = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
        return float(0.5 * np.linalg.norm(cross, axis=1).sum())

    def signed_volume(self) -> float:
        """Volume enclosed by a closed triangle mesh; positive when normals point outward."""
        v = self.vertices
        t = self.cells
        # Divergence theorem over tetrahedra from the centroid (better conditioned than the origin).
        c = v.mean(axis=0) if len(v) else np.zeros(3)
        a, b, d = v[t[:, 0]] - c, v[t[:, 1]] - c, v[t[:, 2]] - c
        return float(np.einsum("ij,ij->i", a, np.cross(b, d)).sum() / 6.0)


@dataclass(frozen=True)
class MeshSummary:
    """What a one-line account of a mesh needs (``wrote X: V vertices, C triangles``),
    without holding its arrays.

    Attributes
    ----------
    n_vertices, n_cells : int
    is_triangles : bool
    info : dict
        The mesh's provenance (shared with the mesh, not copied).
    """

    n_vertices: int
    n_cells: int
    is_triangles: bool
    info: dict

    @classmethod
    def of(cls, mesh: Mesh) -> MeshSummary:
        return cls(mesh.n_vertices, mesh.n_cells, mesh.is_triangles, mesh.info)


class MeshParts(Protocol):
    """A triangle mesh handed over a part at a time, for a consumer that needs
    only the triangles near one place at once (a layer's row of fragments): an
    object whose whole mesh would be the peak of a run is never built whole.

    ``to_index`` maps world points ``(N, 3)`` to the coordinates the parts are
    selected in, each point on its own (the same values however many are given).
    """

    def extent(self, to_index: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """The lowest and highest ``to_index`` coordinates of its vertices, (3,) each."""
        ...

    def reaching(
        self, to_index: Callable[[np.ndarray], np.ndarray], low: np.ndarray, high: np.ndarray
    ) -> Mesh:
        """At least every triangle whose ``to_index`` box meets the box ``low`` to
        ``high`` ((3,) each, unbounded in x when a layer asks), in the whole mesh's
        order, over its vertices in theirs (a whole mesh's triangles and vertices,
        some left out)."""
        ...

    def reaching_counts(
        self, to_index: Callable[[np.ndarray], np.ndarray], lows: np.ndarray, highs: np.ndarray
    ) -> np.ndarray:
        """How many triangles :meth:`reaching` gives for each box ``lows[r]`` to
        ``highs[r]`` ((R, 3) each, a layer's rows in order), (R,) int64, without
        making them: what a layer plans its tasks by."""
        ...

    def vertex_positions(
        self, to_index: Callable[[np.ndarray], np.ndarray]
    ) -> Iterator[np.ndarray]:
        """Its vertices' ``to_index`` coordinates, each vertex once, a piece at a
        time ((n, 3) float64 each): what a layer sizes its fragments by."""
        ...

    @property
    def n_cells(self) -> int:
        """How many triangles the whole mesh has."""
        ...

    def slabs(
        self, to_index: Callable[[np.ndarray], np.ndarray], count: int
    ) -> Iterator[tuple[Mesh, np.ndarray, np.ndarray]]:
        """The mesh in ``count`` z-slabs (by ``to_index``; some may be empty), each
        triangle in one: per slab its mesh (in the whole mesh's order, over its
        vertices in theirs), its vertices' ids ``(V_s,) int64`` (increasing, the
        same for a vertex in every slab), and ``(V_s,) bool``: which of them other
        slabs use too."""
        ...

    def whole(self) -> Mesh:
        """The whole mesh."""
        ...


def slab_split(
    low: np.ndarray, corners: np.ndarray, count: int, offset: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Faces in ``count`` z-slabs (:meth:`MeshParts.slabs`): equal ranges of each
    face's lowest z; with an ``offset`` (a fraction of a slab, below 1) their
    bounds moved up by that much, a slab more (the first and last shorter).

    Parameters
    ----------
    low : (F,) float64
        Each face's lowest z.
    corners : (F, k) int64
        Its vertices' ids.
    count : int
    offset : float

    Returns
    -------
    order : (F,) int64
        The faces slab by slab, in their order within each.
    ends : (S + 1,) int64
        Where each slab's faces start in ``order`` (and the last ends).
    shared : (N,) bool
        Which vertex ids, from ``base``, more than one slab's faces use.
    base : int
        The smallest id.
    """
    slabs = count + 1 if offset > 0 else count
    slab = np.zeros(len(low), dtype=np.int64)
    span = float(np.ptp(low)) if len(low) else 0.0
    if span > 0:
        where = (low - low.min()) / span * count + offset
        slab = np.minimum(where.astype(np.int64), slabs - 1)
    order = np.argsort(slab, kind="stable")
    ends = np.searchsorted(slab[order], np.arange(slabs + 1))
    base = int(corners.min()) if len(corners) else 0
    seen = np.zeros(int(corners.max()) - base + 1 if len(corners) else 0, dtype=bool)
    shared = np.zeros_like(seen)
    for n in range(slabs):
        ids = np.unique(corners[order[ends[n] : ends[n + 1]]]) - base
        shared[ids] |= seen[ids]
        seen[ids] = True
    return order, ends, shared, base


def outward_float32(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ranges ``low``..``high`` (float64) held in float32, rounded outward: half
    the memory, and a range selected by them holds at least the ones the exact
    values would select (a layer's row filters its triangles exactly again)."""
    low32, high32 = low.astype(np.float32), high.astype(np.float32)
    low32 = np.where(low32 > low, np.nextafter(low32, np.float32(-np.inf)), low32)
    high32 = np.where(high32 < high, np.nextafter(high32, np.float32(np.inf)), high32)
    return low32, high32


def meeting_each(
    z: tuple[np.ndarray, np.ndarray],
    y: tuple[np.ndarray, np.ndarray],
    lows: np.ndarray,
    highs: np.ndarray,
) -> Iterator[np.ndarray]:
    """For each box ``lows[r]`` to ``highs[r]`` ((R, 3) each, x not looked at),
    the faces whose z-ranges ``z`` and y-ranges ``y`` (each a (low, high) pair of
    (F,) arrays; float32 from :func:`outward_float32` for
    :meth:`MeshParts.reaching`) meet it: (F_r,) int64, increasing. Boxes in the order
    of a layer's rows (z-layer by z-layer): the faces meeting a z-range are found
    once for all its boxes."""
    at = None
    for low, high in zip(lows, highs, strict=True):
        if at != (low[2], high[2]):
            at = (low[2], high[2])
            in_z = np.flatnonzero((z[1] >= low[2]) & (z[0] <= high[2]))
            y_low, y_high = y[0][in_z], y[1][in_z]
        yield in_z[(y_high >= low[1]) & (y_low <= high[1])]


def meeting_counts(
    z: tuple[np.ndarray, np.ndarray],
    y: tuple[np.ndarray, np.ndarray],
    lows: np.ndarray,
    highs: np.ndarray,
) -> np.ndarray:
    """How many faces :func:`meeting_each` gives each box: (R,) int64."""
    return np.fromiter(map(len, meeting_each(z, y, lows, highs)), np.int64, len(lows))


def _import(module: str, package: str):
    """``module``, or a one-line IsoconvertError saying how to install ``package``."""
    import importlib

    from .errors import IsoconvertError

    try:
        return importlib.import_module(module)
    except ImportError:
        raise IsoconvertError(
            f"{package} is not installed (needed to hand the mesh over); pip install {package}"
        ) from None


def _fans(flat: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """VTK's flat cell list ``[n, i0, ..., i(n-1), n, ...]`` as triangles (fans
    ``(i0, ik, ik+1)``, keeping each polygon's turning sense) or as segments
    (each polyline's consecutive pairs); and, for each, the cell it came from."""
    out, source = [], []
    at, cell = 0, 0
    while at < len(flat):
        n = int(flat[at])
        ids = flat[at + 1 : at + 1 + n]
        if size == 3:
            for k in range(1, n - 1):
                out.append((ids[0], ids[k], ids[k + 1]))
                source.append(cell)
        else:
            for k in range(n - 1):
                out.append((ids[k], ids[k + 1]))
                source.append(cell)
        at += n + 1
        cell += 1
    cells = np.array(out, dtype=np.int64).reshape(-1, size)
    return cells, np.array(source, dtype=np.int64)


def as_mesh(mesh: object) -> Mesh:
    """An isoconvert Mesh of ``mesh``: a Mesh as it is, or a ``trimesh.Trimesh``,
    a ``pyvista`` dataset or a ``meshio.Mesh`` converted (:meth:`Mesh.from_trimesh`,
    :meth:`Mesh.from_pyvista`, :meth:`Mesh.from_meshio`). No library is imported:
    an object of one can only exist when it is.

    Raises
    ------
    IsoconvertError
        Anything else.
    """
    import sys

    from .errors import IsoconvertError

    if isinstance(mesh, Mesh):
        return mesh
    for module, kinds, convert in (
        ("trimesh", ("Trimesh",), Mesh.from_trimesh),
        ("pyvista", ("DataSet",), Mesh.from_pyvista),
        ("meshio", ("Mesh",), Mesh.from_meshio),
    ):
        library = sys.modules.get(module)
        if library is not None and isinstance(mesh, tuple(getattr(library, k) for k in kinds)):
            return convert(mesh)
    raise IsoconvertError(
        f"expected an isoconvert Mesh, a trimesh.Trimesh, a pyvista mesh or a meshio.Mesh, "
        f"got {type(mesh).__name__}"
    )


def polylines(segments: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Chain directed segments into polylines.

    Parameters
    ----------
    segments : (C, 2) int
        Segments as vertex indices, each running from its first to its second.

    Returns
    -------
    list of ((n,) int64, bool)
        Vertex indices of each polyline and whether it is closed (its last
        vertex joins its first, which is not repeated). A vertex where more
        than one segment starts or ends (non-manifold) ends the polylines
        through it.
    """
    segments = np.asarray(segments, dtype=np.int64)
    starts, ends = segments[:, 0], segments[:, 1]
    out_degree = np.bincount(starts, minlength=0)
    in_degree = np.bincount(ends, minlength=0)
    size = max(len(out_degree), len(in_degree))
    out_degree = np.pad(out_degree, (0, size - len(out_degree)))
    in_degree = np.pad(in_degree, (0, size - len(in_degree)))
    following = {int(a): int(b) for a, b in segments if out_degree[a] == 1 and in_degree[b] == 1}
    result: list[tuple[np.ndarray, bool]] = []
    used = set()
    # open chains start where nothing (or more than one thing) leads in
    for a, b in segments.tolist():
        if (a, b) in used or (in_degree[a] == 1 and out_degree[a] == 1):
            continue
        chain = [a, b]
        used.add((a, b))
        while b in following and (b, following[b]) not in used and in_degree[b] == 1:
            used.add((b, following[b]))
            b = following[b]
            chain.append(b)
        result.append((np.array(chain, dtype=np.int64), False))
    # what is left are closed loops through regular vertices
    for a, b in segments.tolist():
        if (a, b) in used:
            continue
        chain = [a]
        used.add((a, b))
        while b != a:
            chain.append(b)
            nxt = following[b]
            used.add((b, nxt))
            b = nxt
        result.append((np.array(chain, dtype=np.int64), True))
    return result
