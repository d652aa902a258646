"""Surfaces of every label of a label volume, by Surface Nets.

Surface Nets (S. Frisken Gibson, "Constrained elastic surface nets", MICCAI 1998;
multi-label: S. Frisken, JCGT 2022; VTK's ``vtkSurfaceNets3D``, Schroeder et al.)
is the dual method for segmentations: every pair of face-adjacent samples with
different labels gets a quad (two triangles) across the face between them, whose
corners are the centres of the dual cells (2x2x2 blocks of samples) around that
face. One pass over the volume gives the boundaries of every label at once, and
two labels that touch share their common boundary exactly.

The volume is treated as padded by background outside the grid, so every label
surface is closed even where the label touches the grid's boundary. No padded
copy is made: the faces on the grid's six sides are found from its first and
last slab along each axis, compared with the background value.

Non-manifold configurations
---------------------------
Where one label touches itself only along an edge (two samples diagonal in a
2x2 block, the others of other labels), four quads meet on one dual edge; where
it touches itself only at a corner, two cones of quads meet at one dual vertex.
As in VTK 9.7, such vertices are split into copies, one per sheet of surface,
so that every label's surface is a closed 2-manifold and smoothing can pull the
sheets apart:

- around a dual edge with four quads (its ring of four samples alternates)
  the quads are paired into two copies of the edge, each pair wrapping around
  one ring sample. When the ring holds two labels diagonally, the pairs wrap
  around the inside label's samples (see ``boundary_labels``), separating
  them: in a binary volume the object is face-connected only, as in VTK. When
  one label is diagonal and the other two samples differ, the pairs must wrap
  around those two (each needs a closed surface), so the diagonal label's
  sheets join across the edge. When all four samples differ (a junction of
  four labels) the quads are not paired: each label sees only two of them;
- around each dual vertex, the quads that share a (paired) dual edge are
  connected; each connected group gets its own vertex.

The combined mesh therefore has one vertex per dual cell except at those
configurations. The copies of a split vertex start 1/64 of the way from the dual
cell's centre to the mean of the centres of their own faces (where naive Surface
Nets would put them), i.e. a little into their own side: they differ in position,
not only in index, so the surface does not touch itself there and the report,
which judges positions, finds it manifold at every smoothing setting. Unsmoothed,
the surface is the voxel faces but at those copies; each moves at most 0.011
voxel, changing the enclosed volume by less than 0.05 voxel.

Not every configuration can be resolved while two labels share their boundary
exactly (one vertex per quad corner, used by both labels): where a label touches
itself along an edge or at a corner and another extracted label touches both
pieces there, that label's fan around the vertex holds faces of both pieces, so
they cannot get separate copies, and the label stays pinched (a vertex with two
fans, or an edge in four of its triangles). ``LabelMeshes.unresolved`` counts
these places (the kernel finds them per 2x2x2 block, and per dual edge whose two
copies still end on the same vertices), ``unresolved_outside`` the same for the
background's surface (judged in a ``--single-file`` mesh's report), and the note
says so instead of "kept manifold". In a volume of one label both are 0.

Smoothing
---------
Constrained relaxation, Jacobi style: each iteration moves every vertex by
``relaxation`` times the way to the average of its neighbours along quad edges
(the smoothing stencil of Surface Nets: quad edges, never quad diagonals), then
clamps it to the box of half-size ``constraint`` voxels around its dual cell's
centre (0.5: the dual cell itself, Frisken's original constraint). Vertices on a
junction of three or more labels keep sharp junction curves as in Frisken 2022:
they average only their neighbours that are on a junction too, and stay fixed
where junction curves meet (not exactly two such neighbours). All of it runs in
index space (the average and the box commute with the index-to-world map).

Kernels
-------
The work runs in compiled kernels (``src/labels.cpp``): one pass for the labels
present (a table of the values for 8- and 16-bit samples, no sort of the
volume), one sweep over the dual cells that finds each cell's sheets from its
2x2x2 block of samples (every vertex is one), then the quads, the smoothing and
the per-label meshes. The arrays are those of the numpy formulation they
replaced, bit for bit and in the same order (quads in ``np.nonzero`` order per
axis: interior faces, low side, high side; vertices by their first quad corner),
whatever the number of threads; except that an axis of a single sample now has
its high side's quads facing out of the labels as they should (the numpy
version took both sides of such an axis for low sides), and that split copies
start off their dual cell's centre (see above).
"""

from __future__ import annotations

import copy
import functools
import weakref
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from .. import _native
from ..atomic import DiskFullError, disk_full_error, free_space
from ..errors import LevelError, VolumeError
from ..memory import release, release_freed_memory
from ..mesh import Mesh, MeshSummary, meeting_counts, meeting_each, outward_float32, slab_split
from ..threads import kernel_threads
from ..volume import Volume
from .label_blocks import (
    MergedNet,
    boundary_layers,
    merge_slabs,
    run_slabs,
    slab_jobs,
    wants_blocks,
    wants_net_estimate,
)
from .label_samples import fit_background, kernel_labels
from .placement import mesh_info, reversed_orientation
from .prepare import kernel_type
from .slabs import Blocks


@dataclass(frozen=True)
class SmoothingOptions:
    """Constrained smoothing of the surface net (VTK-like defaults).

    Attributes
    ----------
    iterations : int
        Relaxation iterations (VTK's default 16); 0 leaves the blocky surface of
        voxel faces (vertices at dual-cell centres).
    relaxation : float
        Fraction of the way to the neighbours' average moved per iteration
        (0 < r <= 1; VTK's default 0.5).
    constraint : float
        Half-size, in voxels along each grid axis, of the box around its dual
        cell's centre a vertex must stay in (> 0; 0.5 = the dual cell).
    """

    iterations: int = 16
    relaxation: float = 0.5
    constraint: float = 0.5

    def __post_init__(self) -> None:
        if int(self.iterations) != self.iterations or self.iterations < 0:
            raise VolumeError(
                f"smoothing iterations must be a whole number >= 0, got {self.iterations!r}"
            )
        if not 0.0 < self.relaxation <= 1.0:
            raise VolumeError(f"smoothing relaxation must be in (0, 1], got {self.relaxation!r}")
        if not self.constraint > 0.0:
            raise VolumeError(f"smoothing constraint must be > 0 voxels, got {self.constraint!r}")


class LabelMeshes:
    """Surfaces of the labels of a label volume, and the mesh they share.

    Each label's surface, and the combined mesh's triangles, are built from the
    surface net when they are asked for: a caller writing one file per label
    never holds the combined triangles, nor every label's surface at once. A
    label's surface is kept while someone holds it (asked for again then, it is
    the same object) and built again, the same, once nobody does.

    Attributes
    ----------
    meshes : mapping of int -> Mesh
        One closed surface per extracted label, normals pointing out of the
        label; its vertices are those of ``combined`` it uses, re-indexed
        compactly. ``info["label"]`` is the label value. A read-only mapping
        (``[]``, ``items()``, ``values()``, ``len()``, iteration in label order),
        each mesh built on access (see above); ``dict(meshes)`` gives a dict.
    combined : Mesh
        Every boundary quad once (two triangles), for ``--single-file``:
        ``vertices (V, 3) float64`` in world units, ``cells (C, 3) int64``
        with normals pointing from ``boundary_labels[:, 0]`` to
        ``boundary_labels[:, 1]``. Its cells are built on first access.
    boundary_labels : (C, 2) int64
        For each triangle of ``combined``: (label inside, label outside). The
        outside is the background (or a label not extracted) when one side is;
        between two extracted labels, the smaller value is inside.
    vertex_map : mapping of int -> (V_L,) int64
        ``meshes[L].vertices == combined.vertices[vertex_map[L]]`` (a mapping
        as ``meshes``).
    face_map : mapping of int -> (C_L,) int64
        ``vertex_map[L][meshes[L].cells]`` is ``combined.cells[face_map[L]]``,
        reversed (``[:, ::-1]``) where ``boundary_labels[face_map[L], 1] == L``
        (a mapping as ``meshes``).
    dual_cells : (V,) int64
        For each vertex of ``combined``, its dual cell ``i + (X + 1) * (j + (Y +
        1) * k)``: the block of samples ``i - 1..i, j - 1..j, k - 1..k`` (index
        -1 and X, Y, Z are the background around the grid). Copies made at
        non-manifold configurations share their dual cell.
    split_vertices : int
        How many vertices were added by splitting non-manifold configurations.
    unresolved : int
        Places where a label's surface is still not manifold (0 in a volume of
        one label; see the module notes): a vertex where it is pinched, or an
        edge in four of its triangles.
    unresolved_outside : int
        The same for the surface of the background (and of labels not
        extracted), which only a ``--single-file`` mesh's report judges.
    value_range : (float, float)
        The smallest and largest sample of the volume (labels and background).
    """

    def __init__(
        self,
        net: _Net,
        quad_labels: np.ndarray,
        dual_cells: np.ndarray,
        split_vertices: int = 0,
        unresolved: int = 0,
        unresolved_outside: int = 0,
        value_range: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self._net = net
        # weakly: every label's mesh held at once is what made a large layer's peak
        self._meshes: weakref.WeakValueDictionary[int, Mesh] = weakref.WeakValueDictionary()
        self._summaries: dict[int, MeshSummary] = {}
        self._maps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._combined: Mesh | None = None
        self._quad_labels = quad_labels  # (Q, 2): boundary_labels of each quad's two triangles
        self.dual_cells = dual_cells
        self.split_vertices = split_vertices
        self.unresolved = unresolved
        self.unresolved_outside = unresolved_outside
        self.value_range = value_range
        self.meshes = _PerLabel(self, 0)
        self.vertex_map = _PerLabel(self, 1)
        self.face_map = _PerLabel(self, 2)

    @functools.cached_property
    def boundary_labels(self) -> np.ndarray:
        # built when asked for (--single-file): one row per triangle, two per quad,
        # twice the memory of the quads' own (80 MB on a 512^3 atlas)
        return np.repeat(self._quad_labels, 2, axis=0)

    @property
    def combined(self) -> Mesh:
        if self._combined is None:
            net = self._net
            cells = _native.label_triangles(net.corners, net.cut, kernel_threads())
            self._combined = Mesh(net.vertices, cells, None, net.info)
        return self._combined

    @property
    def grid(self) -> dict:
        """The grid the net was extracted on (``info["grid"]`` of every mesh)."""
        return self._net.info["grid"]

    def summary(self, label: int) -> MeshSummary:
        """Label ``label``'s surface's counts and info, kept from when it was built."""
        summary = self._summaries.get(int(label))
        return summary if summary is not None else MeshSummary.of(self.meshes[label])

    @property
    def labels(self) -> list[int]:
        """The extracted label values, ascending."""
        return list(self._net.index)

    def __getitem__(self, label: int) -> Mesh:
        return self.meshes[int(label)]

    def __iter__(self):
        return iter(self.labels)

    def __len__(self) -> int:
        return len(self._net.index)

    def _part(self, label: int, which: int) -> Mesh | np.ndarray:
        """The mesh (0), vertex map (1) or face map (2) of ``label``, built on first
        use. The maps are kept only once asked for: writing every label's mesh
        needs neither (a quarter of the memory of the meshes)."""
        if which == 0:
            mesh = self._meshes.get(label)
            if mesh is None:
                mesh = self._meshes.setdefault(label, self._build(label)[0])
            return mesh
        maps = self._maps.get(label)
        if maps is None:
            mesh, *built = self._build(label)
            self._meshes.setdefault(label, mesh)
            maps = self._maps.setdefault(label, tuple(built))
        return maps[which - 1]

    def parts(self, label: int) -> LabelParts:
        """Label ``label``'s surface in parts (:class:`~isoconvert.mesh.MeshParts`),
        built from the net a part at a time; its summary is kept as its mesh's is."""
        return LabelParts(self, int(label))

    def _build(self, label: int) -> tuple[Mesh, np.ndarray, np.ndarray]:
        """(mesh, vertex map, face map) of ``label``, anew."""
        net = self._net
        n = net.index[label]  # KeyError for a label not extracted
        q0, q1 = net.offsets[n], net.offsets[n + 1]
        faces, used, local, verts = _native.label_mesh(
            net.corners, net.cut, net.vertices, net.quads[q0:q1], int(net.inside[n])
        )
        release(net.corners)  # a net on disk: one label's pages at a time
        release(net.vertices)
        mesh = Mesh(verts, local, None, self._info(label))
        self._summaries.setdefault(int(label), MeshSummary.of(mesh))
        return mesh, used, faces

    def _info(self, label: int) -> dict:
        """A label's mesh's info."""
        net = self._net
        info = copy.deepcopy(net.label_info)
        info["level"] = float(label)
        info["label"] = int(label)
        info["smoothing"] = dict(net.info["smoothing"])
        return info


class LabelParts:
    """One label's surface in parts (:class:`~isoconvert.mesh.MeshParts`): the
    triangles of the net's quads that reach a z-range, made by the kernel that
    makes its whole mesh (``label_mesh``) from only those quads, so that they come
    in the whole mesh's order over its vertices in theirs. Holds each quad's
    z-range and y-range (the latter in float32, rounded outward: 24 bytes a quad),
    not the mesh (about 80).
    """

    #: Quads whose corners' positions are converted at once.
    PIECE = 1 << 16

    def __init__(self, owner: LabelMeshes, label: int) -> None:
        net = owner._net
        n = net.index[label]  # KeyError for a label not extracted
        self._owner, self._label = owner, label
        self._quads = net.quads[net.offsets[n] : net.offsets[n + 1]]
        self._inside = int(net.inside[n])
        self._low = self._high = self._y = self._box = None

    def extent(self, to_index: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        if self._box is not None:
            return self._box
        net = self._owner._net
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        n = len(self._quads)
        low, high = np.empty(n), np.empty(n)
        y_low, y_high = np.empty(n, np.float32), np.empty(n, np.float32)
        corners = net.corners[self._quads]  # (n, 4)
        for a in range(0, len(corners), self.PIECE):
            p = to_index(net.vertices[corners[a : a + self.PIECE].reshape(-1)]).reshape(-1, 4, 3)
            lo, hi = np.minimum(lo, p.min(axis=(0, 1))), np.maximum(hi, p.max(axis=(0, 1)))
            low[a : a + self.PIECE] = p[:, :, 2].min(axis=1)
            high[a : a + self.PIECE] = p[:, :, 2].max(axis=1)
            y = outward_float32(p[:, :, 1].min(axis=1), p[:, :, 1].max(axis=1))
            y_low[a : a + self.PIECE], y_high[a : a + self.PIECE] = y
        self._low, self._high, self._y = low, high, (y_low, y_high)
        release(net.corners)
        release(net.vertices)
        # what the results say of the surface, without building it
        used = len(_distinct(corners.reshape(-1)))
        info = self._owner._info(self._label)
        summary = MeshSummary(used, 2 * len(self._quads), True, info)
        self._owner._summaries.setdefault(self._label, summary)
        self._box = lo, hi
        return lo, hi

    def vertex_positions(
        self, to_index: Callable[[np.ndarray], np.ndarray]
    ) -> Iterator[np.ndarray]:
        net = self._owner._net
        used = _distinct(net.corners[self._quads].reshape(-1))  # the surface's vertices
        release(net.corners)
        for a in range(0, len(used), 4 * self.PIECE):
            yield to_index(net.vertices[used[a : a + 4 * self.PIECE]])
            release(net.vertices)

    def reaching(
        self, to_index: Callable[[np.ndarray], np.ndarray], low: np.ndarray, high: np.ndarray
    ) -> Mesh:
        if self._low is None:
            self.extent(to_index)
        net = self._owner._net
        (taken,) = meeting_each((self._low, self._high), self._y, low[None], high[None])
        # the quads it is inside of come first, as in the whole mesh
        inside = int(np.searchsorted(taken, self._inside))
        _, _, local, verts = _native.label_mesh(
            net.corners, net.cut, net.vertices, self._quads[taken], inside
        )
        release(net.corners)
        release(net.vertices)
        return Mesh(verts, local)

    def reaching_counts(
        self, to_index: Callable[[np.ndarray], np.ndarray], lows: np.ndarray, highs: np.ndarray
    ) -> np.ndarray:
        if self._low is None:
            self.extent(to_index)
        return 2 * meeting_counts((self._low, self._high), self._y, lows, highs)

    @property
    def n_cells(self) -> int:
        return 2 * len(self._quads)

    def slabs(
        self, to_index: Callable[[np.ndarray], np.ndarray], count: int
    ) -> Iterator[tuple[Mesh, np.ndarray, np.ndarray]]:
        # a quad's slab by its lowest corner
        if self._low is None:
            self.extent(to_index)
        net = self._owner._net
        order, ends, shared, base = slab_split(self._low, net.corners[self._quads], count)
        release(net.corners)
        for n in range(count):
            taken = order[ends[n] : ends[n + 1]]
            inside = int(np.searchsorted(taken, self._inside))
            _, used, local, verts = _native.label_mesh(
                net.corners, net.cut, net.vertices, self._quads[taken], inside
            )
            release(net.corners)
            release(net.vertices)
            used = np.asarray(used, dtype=np.int64)
            yield Mesh(verts, local), used, shared[used - base]

    def whole(self) -> Mesh:
        return self._owner.meshes[self._label]


def _distinct(ids: np.ndarray) -> np.ndarray:
    """The distinct values of ``ids`` (int64), increasing: a bitmap over their
    range when it is not much wider than they are many (a large label's
    vertices), else a sort."""
    if not len(ids):
        return np.empty(0, np.int64)
    lo, hi = int(ids.min()), int(ids.max())
    if hi - lo >= 16 * len(ids):
        return np.unique(ids).astype(np.int64)
    mark = np.zeros(hi - lo + 1, bool)
    mark[ids - lo] = True
    return np.flatnonzero(mark) + lo


@dataclass(frozen=True)
class _Net:
    """What the per-label surfaces and the combined mesh are built from."""

    vertices: np.ndarray  # (V, 3) world positions
    corners: np.ndarray  # (Q, 4) quads
    cut: np.ndarray  # (Q,) uint8: how each quad is cut into triangles
    quads: np.ndarray  # each label's quads (label_quads)
    offsets: np.ndarray  # (L + 1,)
    inside: np.ndarray  # (L,)
    index: dict[int, int]  # label value -> its index among the extracted, ascending
    info: dict  # the combined mesh's
    label_info: dict  # a label's, but for its level and label


class _PerLabel(Mapping):
    """One of a LabelMeshes' per-label mappings, built on first access."""

    def __init__(self, owner: LabelMeshes, which: int) -> None:
        self._owner, self._which = owner, which

    def __getitem__(self, label: int):
        if isinstance(label, (bool, np.bool_)) or not isinstance(label, (int, np.integer)):
            raise KeyError(label)
        return self._owner._part(int(label), self._which)

    def __iter__(self):
        return iter(self._owner.labels)

    def __len__(self) -> int:
        return len(self._owner)

    def __contains__(self, label: object) -> bool:
        return isinstance(label, (int, np.integer)) and int(label) in self._owner._net.index

    def __repr__(self) -> str:
        return f"<{len(self)} labels: {self._owner.labels[:10]}{'...' if len(self) > 10 else ''}>"


def label_surfaces(
    volume: Volume,
    labels: Iterable[int] | None = None,
    *,
    background: int = 0,
    smoothing: SmoothingOptions | int | None = None,
    on_status: Callable[[str], None] | None = None,
    blocks: Blocks | None = None,
) -> LabelMeshes:
    """Extract the surface of every label of a label volume (Surface Nets).

    Parameters
    ----------
    volume : Volume
        3D, integer samples (float samples must be whole numbers).
    labels : iterable of int or None
        Label values to extract; None: every value present but ``background``.
        Faces between two labels neither of which is extracted are left out.
    background : int
        The value of no label; the grid is treated as surrounded by it.
    smoothing : SmoothingOptions, int or None
        Smoothing options, a number of iterations (other options default), or
        None for the defaults (16 iterations). 0 gives the blocky surface.
    on_status : callable or None
        Receives one-line notices (non-manifold configurations split, and where
        a label could not be kept manifold).
    blocks : Blocks or None
        Build the net slab by slab (:mod:`isoconvert.extract.label_blocks`) when
        asked for (a slab size, a Dask scheduler) or when the volume is read from
        its file and is larger than the budget allows for one slab; the result is
        the same, bit for bit. None: in memory.

    Returns
    -------
    LabelMeshes
        One :class:`~isoconvert.mesh.Mesh` per label and the combined mesh.

    Raises
    ------
    VolumeError
        A 2D volume, non-integer samples, a requested label that is not in the
        volume or equals the background, or bad smoothing options.
    LevelError
        Nothing but background in the volume.
    """
    options = _smoothing_options(smoothing)
    _check_3d(volume)
    background = _whole(background, "--background", volume.source)
    threads = kernel_threads()
    # a left-handed index-to-world map mirrors the surface: the kernel writes every quad reversed
    reverse = reversed_orientation(volume, False)
    itemsize = kernel_type(kernel_labels(np.zeros(1, volume.dtype)), "").itemsize
    # an axis-aligned grid is placed by the kernel, in the pass that writes the
    # positions, with the two roundings of Volume.index_to_world (a product, a sum)
    aligned = np.array_equal(volume.direction, np.eye(3))
    placed = False
    # within --max-memory, a volume dense with surfaces is built in slabs even when
    # its samples fit: its net's kernel memory, not the samples, is the peak
    boundary = None
    if wants_net_estimate(volume, blocks):
        boundary = boundary_layers(volume, background, blocks)
    if wants_blocks(volume, blocks, itemsize, boundary):
        net = _net_in_slabs(volume, labels, background, options, reverse, blocks, itemsize,
                            on_status, boundary)  # fmt: skip
        wanted = net.wanted
        positions, dual_cells, corners, quad_labels, sides = (
            net.positions, net.dual_cells, net.corners, net.quad_labels, net.sides)  # fmt: skip
        split, unresolved, outside, vmin, vmax = (
            net.split, net.unresolved, net.outside, net.vmin, net.vmax)  # fmt: skip
    else:
        samples = _label_samples(volume)
        vmin, vmax, present = _present_labels(samples, volume.source, threads)
        wanted, _ = _wanted_labels(present, labels, background, volume.source)
        samples = fit_background(samples, background)
        positions, dual_cells, _, corners, quad_labels, sides, split, unresolved, outside = (
            _native.label_net(
                samples,
                wanted,
                float(background),
                vmin,
                vmax,
                int(options.iterations),
                float(options.relaxation),
                float(options.constraint),
                bool(reverse),
                threads,
                scale=volume.spacing if aligned else None,
                shift=volume.origin if aligned else None,
            )
        )
        placed = aligned
        del samples
    if len(corners) == 0:
        raise LevelError(f"{volume.source}: no label surface (every sample is background)")
    if (split or unresolved or outside) and on_status:
        on_status(_split_note(int(split), int(unresolved), int(outside)))
    vertices = positions if placed else volume.index_to_world(positions)  # (in place)
    cut, quads, offsets, inside = _native.label_quads(
        corners, vertices, sides, len(wanted), threads
    )
    del sides
    for array in (vertices, corners, quad_labels, dual_cells):
        release(array)  # (a net on disk: the pages read so far)

    info = mesh_info(volume, "labels", _level_text(wanted), flip=False)
    info["labels"] = [int(v) for v in wanted]
    info["smoothing"] = {
        "iterations": options.iterations,
        "relaxation": options.relaxation,
        "constraint": options.constraint,
    }
    net = _Net(
        vertices,
        corners,
        cut,
        quads,
        offsets,
        inside,
        {int(v): n for n, v in enumerate(wanted.tolist())},
        info,
        mesh_info(volume, "labels", 0.0, flip=False),
    )
    return LabelMeshes(
        net,
        quad_labels,
        dual_cells,
        split_vertices=int(split),
        unresolved=int(unresolved),
        unresolved_outside=int(outside),
        value_range=(vmin, vmax),
    )


def _net_in_slabs(
    volume: Volume,
    labels: Iterable[int] | None,
    background: int,
    options: SmoothingOptions,
    reverse: bool,
    blocks: Blocks,
    itemsize: int,
    on_status: Callable[[str], None] | None,
    boundary: np.ndarray | None = None,
) -> MergedNet:
    """The net of ``volume`` built slab by slab (see :mod:`.label_blocks`), with the
    labels checked against every slab's once all are seen."""
    asked = None
    if labels is not None:  # checked now but for presence, which the slabs tell
        asked = np.unique(np.array([_whole(v, "--label", volume.source) for v in labels],
                                   dtype=np.int64))  # fmt: skip
        _wanted_labels(asked, labels, background, volume.source)
    jobs = slab_jobs(volume, asked, background, options.iterations, options.relaxation,
                     options.constraint, reverse, blocks, itemsize, on_status,
                     boundary=boundary)  # fmt: skip
    slabs: list = []
    held = made = 0  # bytes of the slabs' arrays in memory, and as made
    full = None  # (folder, what) of a full disk
    spilling = False
    results = run_slabs(volume, jobs, blocks.scheduler, blocks.budget)
    try:
        for slab in results:
            slabs.append(slab)
            held += slab.nbytes
            made += slab.nbytes
            # when all the slabs' arrays would pass a quarter of the budget (as a
            # mesh being built), those only the merge reads wait on disk, each
            # slab's as it comes: held, they would take the memory of the next
            # slabs' kernels (200 MB for a 512^2 slab at 16 iterations)
            spilling = spilling or made * len(jobs) > blocks.budget // 4 * len(slabs)
            if blocks.spill_dir is None:
                continue
            if spilling:
                for waiting in slabs:
                    if waiting.spilled is None:
                        held -= waiting.nbytes
                        waiting.spill(blocks.spill_dir)
                        held += waiting.nbytes
            # kept, the kernel's freed memory would stay beside the next slab's,
            # which is laid out elsewhere in the heap
            release_freed_memory()
        present = np.unique(np.concatenate([s.present for s in slabs]))
        wanted, _ = _wanted_labels(present, labels, background, volume.source)
        # the net waits on disk as a mesh being built does, past a quarter of the budget
        net_bytes = sum(48 * len(s.quad_keys) + 32 * s.vertex_count for s in slabs)
        spill = blocks.spill_dir is not None and net_bytes > blocks.budget // 4
        if spill:  # what the slabs' kernels freed, for the net's pages
            release_freed_memory()
        net = merge_slabs(slabs, wanted, blocks.spill_dir if spill else None)
    except DiskFullError as exc:
        full = exc.path, exc.why
    finally:
        results.close()
        for slab in slabs:
            slab.close()
    if full is not None:
        # told once this run's files there are gone (the slabs', the net's): then
        # all the space the disk has was not enough
        raise disk_full_error(full[0], free_space(full[0]) or 0, more=True, why=full[1])
    release_freed_memory()  # the slabs' memory, which the net's large arrays do not reuse
    return net


# --- input ----------------------------------------------------------------------------


def _smoothing_options(smoothing: SmoothingOptions | int | None) -> SmoothingOptions:
    if smoothing is None:
        return SmoothingOptions()
    if isinstance(smoothing, SmoothingOptions):
        return smoothing
    if isinstance(smoothing, (bool, float)) or not isinstance(smoothing, (int, np.integer)):
        raise VolumeError(
            f"smoothing must be a number of iterations or SmoothingOptions, got {smoothing!r}"
        )
    return SmoothingOptions(iterations=int(smoothing))


def _check_3d(volume: Volume) -> None:
    if volume.ndim != 3:
        raise VolumeError(
            f"{volume.source}: label surfaces need a 3D volume, got shape {volume.shape}; "
            "use a 3D label volume (a stack of slices)"
        )
    kind = np.dtype(volume.dtype)
    if kind != np.bool_ and not np.issubdtype(kind, np.integer):
        if not np.issubdtype(kind, np.floating):
            raise VolumeError(f"{volume.source}: samples of type {kind} are not labels")


def _label_samples(volume: Volume) -> np.ndarray:
    """The samples of a label volume as the kernels take them: (Z, Y, X), C-contiguous,
    one of the kernels' types (a view when they already are)."""
    _check_3d(volume)
    return kernel_type(kernel_labels(volume.data).T, volume.source)


def _present_labels(
    samples: np.ndarray, source: str, threads: int
) -> tuple[float, float, np.ndarray]:
    """(min, max, sorted (P,) int64 values present), in one compiled pass: a table of
    the values for 8- and 16-bit samples or a narrow range, a sort only otherwise."""
    vmin, vmax, bad, present = _native.label_presence(samples, threads)
    if bad:
        raise VolumeError(
            f"{source}: {bad} samples are not whole numbers (within +-2**53), so this is not "
            "a label volume; use an isosurface method (cubes) or round the labels first"
        )
    if present is None:
        present = np.unique(samples)
    return float(vmin), float(vmax), np.asarray(present).astype(np.int64)


def _whole(value: object, name: str, source: str) -> int:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        number = float("nan")
    if not np.isfinite(number) or number != round(number):
        raise VolumeError(f"{source}: {name} must be a whole number, got {value!r}")
    return int(round(number))


def _wanted_labels(
    present: np.ndarray, labels: Iterable[int] | None, background: int, source: str
) -> tuple[np.ndarray, bool]:
    """Sorted (L,) int64 label values to extract, checked against the sorted values
    ``present``, and whether they are every label present but the background."""
    if labels is None:
        wanted = present[present != background]
        if len(wanted) == 0:
            raise LevelError(
                f"{source}: every sample is background ({background}); "
                "check --background or the file"
            )
        return wanted, True
    wanted = np.unique(np.array([_whole(v, "--label", source) for v in labels], dtype=np.int64))
    if len(wanted) == 0:
        raise VolumeError(f"{source}: no label requested; give at least one with --label")
    if background in wanted:
        raise VolumeError(
            f"{source}: label {background} is the background; drop it from --label "
            "or set --background to another value"
        )
    missing = np.setdiff1d(wanted, present)
    if len(missing):
        shown = ", ".join(str(v) for v in missing[:10])
        some = ", ".join(str(v) for v in present[present != background][:20])
        raise VolumeError(
            f"{source}: label {shown} not in the volume; labels present: {some or 'none'}"
        )
    return wanted, len(wanted) == int(np.count_nonzero(present != background))


def _split_note(split: int, unresolved: int, outside: int) -> str:
    """The note on the vertices split: kept manifold, or where and why not."""
    text = (
        f"note: labels: {split} vertices split where labels touch only along an edge or at a corner"
    )
    if not unresolved and not outside:
        return text + " (kept manifold)"
    why = []
    if unresolved:
        why.append(
            f"at {unresolved} places a label touches itself where another label touches "
            "both pieces, so its surface stays pinched there (no split keeps both surfaces "
            "closed and their boundary shared)"
        )
    if outside:
        why.append(
            "the background's surface, which a --single-file mesh's report judges too, "
            f"stays pinched at {outside} places between labels"
        )
    return f"{text}; {'; '.join(why)}" if split else f"note: labels: {'; '.join(why)}"


def _level_text(wanted: np.ndarray) -> str:
    """The labels as the ``level`` of file headers: ``1,2,3`` (shortened when long)."""
    text = ",".join(str(v) for v in wanted[:12])
    return text + (f",... ({len(wanted)} labels)" if len(wanted) > 12 else "")


__all__ = ["LabelMeshes", "SmoothingOptions", "label_surfaces"]
