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
As in VTK 9.7, such vertices are split into copies (coincident until smoothed),
one per sheet of surface, so that every label's surface is a closed 2-manifold
and smoothing can pull the sheets apart:

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
configurations. A label whose pieces touch only at a corner where three or more
other labels also meet can still be pinched at that vertex (not resolved).

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
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from ..errors import LevelError, VolumeError
from ..graph import connected_components
from ..mesh import Mesh
from ..volume import Volume
from .placement import mesh_info, reversed_orientation

#: Corners of a quad in its plane, as offsets along its two in-plane axes (u, v)
#: = the axes that follow the quad's axis cyclically: counter-clockwise seen from
#: the positive end of the quad's axis, so the right-hand normal is +axis.
_CORNERS = np.array([(0, 0), (1, 0), (1, 1), (0, 1)], dtype=np.int64)
#: The quad's four edges as (low corner, high corner, along u (0) or v (1)); the
#: low corner is the dual cell the dual edge starts from.
_EDGES = ((0, 1, 0), (3, 2, 0), (0, 3, 1), (1, 2, 1))


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


@dataclass
class LabelMeshes:
    """Surfaces of the labels of a label volume, and the mesh they share.

    Attributes
    ----------
    meshes : dict of int -> Mesh
        One closed surface per extracted label, normals pointing out of the
        label; its vertices are those of ``combined`` it uses, re-indexed
        compactly. ``info["label"]`` is the label value.
    combined : Mesh
        Every boundary quad once (two triangles), for ``--single-file``:
        ``vertices (V, 3) float64`` in world units, ``cells (C, 3) int64``
        with normals pointing from ``boundary_labels[:, 0]`` to
        ``boundary_labels[:, 1]``.
    boundary_labels : (C, 2) int64
        For each triangle of ``combined``: (label inside, label outside). The
        outside is the background (or a label not extracted) when one side is;
        between two extracted labels, the smaller value is inside.
    vertex_map : dict of int -> (V_L,) int64
        ``meshes[L].vertices == combined.vertices[vertex_map[L]]``.
    face_map : dict of int -> (C_L,) int64
        ``vertex_map[L][meshes[L].cells]`` is ``combined.cells[face_map[L]]``,
        reversed (``[:, ::-1]``) where ``boundary_labels[face_map[L], 1] == L``.
    dual_cells : (V,) int64
        For each vertex of ``combined``, its dual cell ``i + (X + 1) * (j + (Y +
        1) * k)``: the block of samples ``i - 1..i, j - 1..j, k - 1..k`` (index
        -1 and X, Y, Z are the background around the grid). Copies made at
        non-manifold configurations share their dual cell.
    split_vertices : int
        How many vertices were added by splitting non-manifold configurations.
    """

    meshes: dict[int, Mesh]
    combined: Mesh
    boundary_labels: np.ndarray
    vertex_map: dict[int, np.ndarray] = field(default_factory=dict)
    face_map: dict[int, np.ndarray] = field(default_factory=dict)
    dual_cells: np.ndarray | None = None
    split_vertices: int = 0

    @property
    def labels(self) -> list[int]:
        """The extracted label values, ascending."""
        return sorted(self.meshes)

    def __getitem__(self, label: int) -> Mesh:
        return self.meshes[int(label)]

    def __iter__(self):
        return iter(self.labels)

    def __len__(self) -> int:
        return len(self.meshes)


def label_surfaces(
    volume: Volume,
    labels: Iterable[int] | None = None,
    *,
    background: int = 0,
    smoothing: SmoothingOptions | int | None = None,
    on_status: Callable[[str], None] | None = None,
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
        Receives one-line notices (non-manifold configurations split).

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
    data = _label_samples(volume)
    background = _whole(background, "--background", volume.source)
    wanted, complete = _wanted_labels(data, labels, background, volume.source)

    quads = _boundary_quads(data, wanted, background, complete)
    if len(quads.inside) == 0:
        raise LevelError(f"{volume.source}: no label surface (every sample is background)")
    net = _surface_net(quads, volume.shape)
    if net.split and on_status:
        on_status(
            f"labels: {net.split} vertices split where a label touches itself only along "
            "an edge or at a corner (kept manifold)"
        )
    positions = _smooth(net, quads, options)
    vertices = volume.index_to_world(positions)

    corners = net.quads
    # a left-handed index-to-world map mirrors the surface: write every quad reversed
    reverse = reversed_orientation(volume, False)
    flip = (quads.inside == quads.hi_value) != reverse
    corners[flip] = corners[flip][:, ::-1]
    cells = _triangulate(corners, vertices)
    pairs = np.repeat(np.column_stack([quads.inside, quads.outside]), 2, axis=0)

    info = mesh_info(volume, "labels", _level_text(wanted), flip=False)
    info["labels"] = [int(v) for v in wanted]
    info["smoothing"] = {
        "iterations": options.iterations,
        "relaxation": options.relaxation,
        "constraint": options.constraint,
    }
    combined = Mesh(vertices, cells, None, info)
    result = LabelMeshes({}, combined, pairs, dual_cells=net.dual_cells, split_vertices=net.split)
    _split_by_label(result, volume, wanted, options)
    return result


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


def _label_samples(volume: Volume) -> np.ndarray:
    """The (X, Y, Z) samples of a label volume, checked (no copy)."""
    if volume.ndim != 3:
        raise VolumeError(
            f"{volume.source}: label surfaces need a 3D volume, got shape {volume.shape}; "
            "use a 3D label volume (a stack of slices)"
        )
    data = volume.data
    if data.dtype == bool:
        return data.view(np.uint8)
    if np.issubdtype(data.dtype, np.integer):
        return data
    if not np.issubdtype(data.dtype, np.floating):
        raise VolumeError(f"{volume.source}: samples of type {data.dtype} are not labels")
    # Float samples are compared as they are (exact for whole numbers), so no
    # integer copy is made; they must all be whole numbers, though.
    bad = 0
    for k in range(0, data.shape[2], 16):
        slab = data[:, :, k : k + 16]
        bad += int(np.count_nonzero(~np.isfinite(slab) | (slab != np.round(slab))))
    if bad:
        raise VolumeError(
            f"{volume.source}: {bad} samples are not whole numbers, so this is not a label "
            "volume; use an isosurface method (cubes) or round the labels first"
        )
    return data


def _whole(value: object, name: str, source: str) -> int:
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        number = float("nan")
    if not np.isfinite(number) or number != round(number):
        raise VolumeError(f"{source}: {name} must be a whole number, got {value!r}")
    return int(round(number))


def _wanted_labels(
    data: np.ndarray, labels: Iterable[int] | None, background: int, source: str
) -> tuple[np.ndarray, bool]:
    """Sorted (L,) int64 label values to extract, checked against those present,
    and whether they are every label present but the background."""
    present = np.unique(data).astype(np.int64)  # one sort of the volume (a copy, briefly)
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


def _level_text(wanted: np.ndarray) -> str:
    """The labels as the ``level`` of file headers: ``1,2,3`` (shortened when long)."""
    text = ",".join(str(v) for v in wanted[:12])
    return text + (f",... ({len(wanted)} labels)" if len(wanted) > 12 else "")


# --- faces -------------------------------------------------------------------------------


@dataclass
class _Quads:
    """The boundary quads: ``Q`` faces between samples, in no particular order.

    Attributes
    ----------
    lower : (Q, 3) int64
        Index of the face's lower sample (-1 along ``axis`` on the grid's low side).
    axis : (Q,) int64
        The axis the face is across (its normal's).
    lo_value, hi_value : (Q,) int64
        Labels of the lower and upper sample (background outside the grid).
    inside, outside : (Q,) int64
        The label the quad's normal points out of, and into.
    """

    lower: np.ndarray
    axis: np.ndarray
    lo_value: np.ndarray
    hi_value: np.ndarray
    inside: np.ndarray = None  # type: ignore[assignment]
    outside: np.ndarray = None  # type: ignore[assignment]


def _boundary_quads(
    data: np.ndarray, wanted: np.ndarray, background: int, complete: bool
) -> _Quads:
    """Every face between two samples of different labels, one of them wanted.

    The grid is treated as padded by ``background``: faces on its sides come
    from its first and last slab along each axis. Peak memory is a boolean
    array of the volume's size per axis (not kept) plus the faces found.
    """
    # With every non-background label wanted, a face is kept when its two labels
    # differ; otherwise one of them must be wanted, which a mask of the volume says.
    mask = None if complete else np.isin(data, wanted)
    parts: list[tuple] = []
    for a in range(3):
        n = data.shape[a]
        lo = _take(data, slice(0, n - 1), a)
        hi = _take(data, slice(1, n), a)
        keep = lo != hi
        if mask is not None:
            keep &= _take(mask, slice(0, n - 1), a) | _take(mask, slice(1, n), a)
        idx = np.nonzero(keep)
        del keep
        lower = np.column_stack(idx).astype(np.int64)
        parts.append((lower, a, lo[idx], hi[idx]))
        # the two sides of the grid: background beyond them
        for side, at in ((0, -1), (n - 1, n - 1)):
            slab = _take(data, slice(side, side + 1), a)
            keep = slab != background
            if mask is not None:
                keep &= _take(mask, slice(side, side + 1), a)
            idx = np.nonzero(keep)
            lower = np.column_stack(idx).astype(np.int64)
            lower[:, a] = at
            values = slab[idx].astype(np.int64)
            bg = np.full(len(values), background, dtype=np.int64)
            parts.append((lower, a, values, bg) if side else (lower, a, bg, values))
    quads = _Quads(
        np.concatenate([p[0] for p in parts]).reshape(-1, 3),
        np.concatenate([np.full(len(p[0]), p[1], dtype=np.int64) for p in parts]),
        np.concatenate([np.asarray(p[2], dtype=np.int64) for p in parts]),
        np.concatenate([np.asarray(p[3], dtype=np.int64) for p in parts]),
    )
    # inside: the wanted side; of two wanted labels the smaller (as VTK's BoundaryLabels)
    w_lo = np.isin(quads.lo_value, wanted)
    w_hi = np.isin(quads.hi_value, wanted)
    lo_inside = w_lo & (~w_hi | (quads.lo_value < quads.hi_value))
    quads.inside = np.where(lo_inside, quads.lo_value, quads.hi_value)
    quads.outside = np.where(lo_inside, quads.hi_value, quads.lo_value)
    return quads


def _take(array: np.ndarray, index: slice, axis: int) -> np.ndarray:
    """``array[..., index, ...]`` along ``axis`` (a view)."""
    key = [slice(None)] * 3
    key[axis] = index
    return array[tuple(key)]


# --- the net -------------------------------------------------------------------------


@dataclass
class _Net:
    """Vertices (dual-cell copies) and quads of the surface net.

    Attributes
    ----------
    quads : (Q, 4) int64
        Vertex indices of each quad's corners, counter-clockwise seen from the
        positive end of its axis.
    centers : (V, 3) float64
        Each vertex's dual-cell centre in index units.
    dual_cells : (V,) int64
    edges : (E, 2) int64
        The quad edges between vertices, once each (the smoothing stencil).
    split : int
        Vertices added by splitting.
    """

    quads: np.ndarray
    centers: np.ndarray
    dual_cells: np.ndarray
    edges: np.ndarray
    split: int


def _surface_net(quads: _Quads, shape: tuple[int, ...]) -> _Net:
    """Connect the quads through shared dual edges and number the vertices."""
    dims = np.asarray(shape, dtype=np.int64) + 1  # dual cells per axis (grid padded by one)
    n = len(quads.axis)
    a = quads.axis
    u = (a + 1) % 3
    v = (a + 2) % 3
    rows = np.arange(n)
    # dual cell of corner (0, 0): one past the lower sample along the axis
    base = quads.lower.copy()
    base[rows, a] += 1
    corner_cells = np.empty((n, 4, 3), dtype=np.int64)
    for c, (ou, ov) in enumerate(_CORNERS):
        cell = base.copy()
        cell[rows, u] += ou
        cell[rows, v] += ov
        corner_cells[:, c] = cell
    x, y, z = corner_cells[..., 0], corner_cells[..., 1], corner_cells[..., 2]
    corner_ids = x + dims[0] * (y + dims[1] * z)
    del corner_cells

    # The quads' edges on dual edges: a dual edge along axis b from dual cell D
    # is surrounded by four samples (its "ring"); a quad on it lies in one of the
    # four gaps of the ring, numbered cyclically 0 (q00|q10), 1 (q10|q11),
    # 2 (q11|q01), 3 (q01|q00) with q_st the ring sample at offsets (s, t) along
    # the two other axes (s < t).
    dual_edge = np.empty((4, n), dtype=np.int64)
    gap = np.empty((4, n), dtype=np.int64)
    for e, (c_lo, _, along) in enumerate(_EDGES):
        b = u if along == 0 else v
        other = v if along == 0 else u
        # offset of the quad's samples along `other` within the ring: 1 - (corner's offset)
        off = 1 - _CORNERS[c_lo, 1 - along]
        dual_edge[e] = 3 * corner_ids[:, c_lo] + b
        gap[e] = np.where(a < other, 2 * off, 3 - 2 * off)
    dual_edge = dual_edge.reshape(-1)
    gap = gap.reshape(-1)
    quad_of = np.tile(rows, 4)
    low_node = np.concatenate([4 * rows + c_lo for c_lo, _, _ in _EDGES])
    high_node = np.concatenate([4 * rows + c_hi for _, c_hi, _ in _EDGES])

    # Pair, connect, and where both ends of a two-label ring's two edge copies
    # still end on the same two vertices (the ring's two sheets meet again at
    # both ends, so one edge would carry four triangles), pair that ring the
    # other way (separating the outside label instead) and connect again. A few
    # rounds settle it; what remains is reported by mesh checks.
    flipped = np.zeros(0, dtype=np.int64)
    for _ in range(4):
        group = _pair_quads(dual_edge, gap, quad_of, quads, flipped)
        key = 2 * dual_edge + group
        order = np.argsort(key, kind="stable")
        key_sorted = key[order]
        first = np.ones(len(order), dtype=bool)
        first[1:] = key_sorted[1:] != key_sorted[:-1]
        head = order[np.flatnonzero(first)[np.cumsum(first) - 1]]  # first entry of each run
        link = ~first
        u_nodes = np.concatenate([low_node[order[link]], high_node[order[link]]])
        v_nodes = np.concatenate([low_node[head[link]], high_node[head[link]]])
        roots = connected_components(4 * n, u_nodes, v_nodes)
        del u_nodes, v_nodes
        heads = order[first]
        ends = np.column_stack([roots[low_node[heads]], roots[high_node[heads]]])
        ring = key_sorted[first] // 2
        same = (ring[1:] == ring[:-1]) & (ends[1:] == ends[:-1]).all(axis=1)
        bad = np.setdiff1d(ring[1:][same], flipped)
        if len(bad) == 0:
            break
        flipped = np.union1d(flipped, bad)

    is_root = roots == np.arange(4 * n)
    rank = np.cumsum(is_root) - 1
    vertex_of_node = rank[roots]
    root_nodes = np.flatnonzero(is_root)
    dual_cells = corner_ids.reshape(-1)[root_nodes]
    split = len(root_nodes) - len(np.unique(dual_cells))
    i = dual_cells % dims[0]
    j = (dual_cells // dims[0]) % dims[1]
    k = dual_cells // (dims[0] * dims[1])
    # the centre of dual cell (i, j, k) is half a voxel below sample (i, j, k)
    centers = np.column_stack([i, j, k]).astype(np.float64) - 0.5
    # one stencil edge per run of quads on a dual edge copy
    edges = np.column_stack([vertex_of_node[low_node[heads]], vertex_of_node[high_node[heads]]])
    return _Net(vertex_of_node.reshape(n, 4), centers, dual_cells, edges, int(split))


def _pair_quads(
    dual_edge: np.ndarray,
    gap: np.ndarray,
    quad_of: np.ndarray,
    quads: _Quads,
    flipped: np.ndarray,
) -> np.ndarray:
    """(4Q,) 0 or 1: which copy of its dual edge each quad edge is on.

    Only dual edges with four quads (a label diagonal in the ring) get two
    copies; see the module's notes for the rule. Two-label rings whose dual
    edge id is in ``flipped`` (sorted) are paired the other way.
    """
    group = np.zeros(len(dual_edge), dtype=np.int64)
    order = np.argsort(dual_edge, kind="stable")
    sorted_ids = dual_edge[order]
    starts = np.flatnonzero(np.r_[True, sorted_ids[1:] != sorted_ids[:-1]])
    counts = np.diff(np.r_[starts, len(sorted_ids)])
    full = starts[counts == 4]
    if len(full) == 0:
        return group
    entries = order[full[:, None] + np.arange(4)]  # (G, 4) quad edges of each full ring
    ring_quads = np.empty((len(full), 4), dtype=np.int64)
    np.put_along_axis(ring_quads, gap[entries], quad_of[entries], axis=1)
    q0, q2 = ring_quads[:, 0], ring_quads[:, 2]  # gaps q00|q10 and q01|q11 (lower first)
    s00, s10 = quads.lo_value[q0], quads.hi_value[q0]
    s01, s11 = quads.lo_value[q2], quads.hi_value[q2]
    diag_a = s00 == s11
    diag_b = s10 == s01
    # 1: pair around q10 and q01 (gaps {0, 1}, {2, 3}), separating q00 from q11;
    # 2: pair around q00 and q11 (gaps {3, 0}, {1, 2}), separating q10 from q01
    mode = np.zeros(len(full), dtype=np.int64)
    mode[diag_a & ~diag_b] = 1
    mode[diag_b & ~diag_a] = 2
    both = diag_a & diag_b
    inside_is_a = quads.inside[q0] == s00
    # two labels diagonally: the inside one is separated (pairs wrap around its samples)
    mode[both & inside_is_a] = 2
    mode[both & ~inside_is_a] = 1
    if len(flipped):
        ids = sorted_ids[full]
        turn = both & np.isin(ids, flipped)
        mode[turn] = 3 - mode[turn]
    g = gap[entries]
    pairing = np.where(mode[:, None] == 1, g // 2, ((g + 1) % 4) // 2)
    group[entries] = np.where(mode[:, None] == 0, 0, pairing)
    return group


# --- smoothing and triangles ---------------------------------------------------------------


def _smooth(net: _Net, quads: _Quads, options: SmoothingOptions) -> np.ndarray:
    """(V, 3) float64 vertex positions in index units after constrained relaxation."""
    positions = net.centers.copy()
    if options.iterations == 0 or len(net.edges) == 0:
        return positions
    n_vertices = len(positions)
    # A vertex is on a junction when its quads do not all separate the same two labels.
    corners = net.quads.reshape(-1)
    quad_index = np.repeat(np.arange(len(net.quads)), 4)
    first_quad = np.empty(n_vertices, dtype=np.int64)
    first_quad[corners[::-1]] = quad_index[::-1]
    other = (quads.inside[quad_index] != quads.inside[first_quad[corners]]) | (
        quads.outside[quad_index] != quads.outside[first_quad[corners]]
    )
    junction = np.zeros(n_vertices, dtype=bool)
    junction[corners[other]] = True

    src = np.concatenate([net.edges[:, 0], net.edges[:, 1]])
    dst = np.concatenate([net.edges[:, 1], net.edges[:, 0]])
    # junction vertices follow their junction curve only
    use = ~junction[src] | junction[dst]
    src, dst = src[use], dst[use]
    degree = np.bincount(src, minlength=n_vertices)
    movable = degree > 0
    movable &= ~junction | (degree == 2)  # where junction curves meet, stay put
    moving = np.flatnonzero(movable)
    keep = movable[src]
    src, dst = src[keep], dst[keep]
    degree = degree[moving].astype(np.float64)[:, None]
    low = net.centers - options.constraint
    high = net.centers + options.constraint
    total = np.empty((n_vertices, 3))
    for _ in range(options.iterations):
        gathered = positions[dst]
        for axis in range(3):
            total[:, axis] = np.bincount(src, weights=gathered[:, axis], minlength=n_vertices)
        step = total[moving] / degree - positions[moving]
        positions[moving] += options.relaxation * step
        np.clip(positions, low, high, out=positions)
    return positions


def _triangulate(corners: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """(2Q, 3) int64 triangles of (Q, 4) quads, cut along the shorter diagonal
    (VTK's default, fewer slivers once smoothed; 0-2 on ties)."""
    v = vertices
    d02 = np.einsum("ij,ij->i", *(v[corners[:, 0]] - v[corners[:, 2]],) * 2)
    d13 = np.einsum("ij,ij->i", *(v[corners[:, 1]] - v[corners[:, 3]],) * 2)
    cut13 = d13 < d02 * (1 - 1e-9)
    tri = np.empty((len(corners), 2, 3), dtype=np.int64)
    tri[:, 0] = corners[:, [0, 1, 2]]
    tri[:, 1] = corners[:, [0, 2, 3]]
    tri[cut13, 0] = corners[cut13][:, [0, 1, 3]]
    tri[cut13, 1] = corners[cut13][:, [1, 2, 3]]
    return tri.reshape(-1, 3)


def _split_by_label(
    result: LabelMeshes, volume: Volume, wanted: np.ndarray, options: SmoothingOptions
) -> None:
    """Fill ``meshes``, ``vertex_map`` and ``face_map``: one sort of the triangles'
    two sides by label, then a slice per label (no pass over all triangles per label)."""
    pairs = result.boundary_labels
    cells = result.combined.cells
    n = len(cells)
    side_label = np.concatenate([pairs[:, 0], pairs[:, 1]])
    side_face = np.concatenate([np.arange(n), np.arange(n)])
    keep = np.isin(side_label, wanted)
    side_label, side_face = side_label[keep], side_face[keep]
    order = np.argsort(side_label, kind="stable")
    side_label, side_face = side_label[order], side_face[order]
    bounds = np.searchsorted(side_label, wanted, side="left")
    ends = np.searchsorted(side_label, wanted, side="right")
    for label, start, end in zip(wanted.tolist(), bounds, ends, strict=True):
        faces = side_face[start:end]
        tris = cells[faces]
        outside = pairs[faces, 1] == label
        tris[outside] = tris[outside][:, ::-1]  # normals out of this label
        used, local = np.unique(tris, return_inverse=True)
        info = mesh_info(volume, "labels", float(label), flip=False)
        info["label"] = int(label)
        info["smoothing"] = dict(result.combined.info["smoothing"])
        mesh = Mesh(
            result.combined.vertices[used], local.reshape(-1, 3).astype(np.int64), None, info
        )
        result.meshes[int(label)] = mesh
        result.vertex_map[int(label)] = used
        result.face_map[int(label)] = faces


__all__ = ["LabelMeshes", "SmoothingOptions", "label_surfaces"]
