"""Label surfaces block-wise: z-slabs with a halo, the in-memory net bit for bit.

A label volume larger than memory (or than ``--max-memory``), or one sent to a
Dask cluster, is cut into z-slabs. Each slab *owns* the dual-cell layers
``k0 <= k < k1`` (dual layer k lies between sample layers k - 1 and k): their
vertices, and the quads whose lowest corner lies on them. It is read with a halo
of :func:`halo_layers` sample layers each way, and its net is built by the same
kernel as the whole volume's (``_native.label_net``) with the slab's first layer
as its z offset, so that positions are the volume's own index coordinates.

Why the halo makes the owned part exact: the kernel treats the slab's ends as
background, which changes the dual cells of its first and last layer. Every
other decision is local: a cell's sheets depend on its 2x2x2 block; the rings
paired the other way (three rounds at most) change cells one layer further per
round; a vertex's stencil is its neighbouring cells'; and each relaxation
iteration reads the neighbours' positions of the one before, one layer further.
So the vertices of layer k are those of the whole volume, to the bit, when the
slab reaches ``iterations + HALO_MARGIN`` layers beyond k both ways (or the
grid's end). Sums run in the same order (the stencil's order is the cell's own),
from the same starting coordinates, so the rounding is the same too.

The whole volume's order is rebuilt from keys, never from positions:

- quads: the kernel orders them by axis, then interior / low side / high side,
  then (x, y, z) of their lowest corner (see ``src/labels.cpp``); a quad's key
  encodes exactly that, so the owned quads of every slab, sorted by key, are in
  the whole volume's order;
- vertices: a dual cell's vertices are its sheets, numbered by the cell's own
  faces, so ``16 * dual cell + sheet`` names a vertex in every slab that builds
  it; the whole volume numbers vertices by their first quad corner, before
  reversed quads are turned (corner 0 of an unturned quad is its lowest cell).

Slabs run here, the next one read while one is built, or as tasks of a Dask
cluster (:func:`isoconvert.extract.slabs.dask_runner` with
:func:`label_slab_task`); the client merges what they return
(:func:`merge_slabs`). Memory holds a few slabs, never the volume: read from
its file, a slab's samples are held in the narrowest type that holds its labels
(:func:`~isoconvert.extract.label_samples.narrowed_layers`); when the slabs'
arrays would pass a quarter of the budget, those only the merge reads wait in
nameless files as each slab comes, and so does the merged net
(:func:`~isoconvert.memory.file_array`), whose pages are given back after each
step and each label's surface. Within ``--max-memory`` the slabs are sized by
their nets too: each layer's label boundaries are counted first
(:func:`boundary_layers`) and each slab's kernel kept within half the budget
(:func:`net_plan`). What is not bounded by the budget: a slab's kernel working
memory where the halo alone passes it (about 200 MB for a 512^2 slab of a
surface-dense volume at 16 iterations), and each label's surface while it is
written.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _native
from ..atomic import DISK_FULL_ERRNOS, disk_full_error
from ..errors import IsoconvertError, VolumeError
from ..grid import LazyGrid, SlabReader, grid_slab_zyx
from ..memory import file_array, release
from ..runner import TaskFailure, cluster_size
from ..runner.local import read_ahead
from ..threads import kernel_threads
from ..volume import Volume
from .label_samples import fit_background, kernel_labels, narrowed_layers
from .prepare import kernel_type

# slabs per cluster thread, and copies of a slab's samples alive at once (the one
# being meshed, its kernel-type copy, the next one read): as for isosurfaces
from .slabs import _SLAB_COPIES, _SLABS_PER_THREAD, Blocks, dask_runner, slab_ranges, slab_task

#: Layers of halo beyond the smoothing iterations: one for the dual cells at a
#: slab's end (which see the background), three for the rounds of rings paired
#: the other way, one for a vertex's stencil, and three to spare.
HALO_MARGIN = 8

#: Quads renumbered at once by merge_slabs (the temporary stays in cache).
_PIECE = 1 << 16

#: Bits of a vertex key taken by the sheet (a dual cell has at most 12 sheets).
SHEET_BITS = 4

#: The arrays of a :class:`LabelSlab` that only the merge reads, which wait on
#: disk once the slabs hold more than a quarter of ``--max-memory``.
SPILLED = ("vertex_keys", "positions", "corners", "turned", "pairs")

_NET_WHY = (
    "for the label surfaces' net, larger than a quarter of --max-memory (a larger one "
    "keeps it in memory)"
)

_SPILL_WHY = (
    "for the label slabs, larger than a quarter of --max-memory (a larger one keeps "
    "more of them in memory)"
)


#: Bytes a label net's kernel holds per vertex while it builds the net (the quads,
#: the smoothing's positions, stencil and buffers): about 200 measured (15,625 small
#: cubes: 660 MB for 3.4 M vertices at 16 iterations), about 175 since the stencil
#: and the constraint's centres take 32 bits (the estimate keeps its margin).
#: Within ``--max-memory`` the slabs of a volume dense with surfaces are sized by
#: it, not only by its samples.
NET_BYTES_PER_VERTEX = 220


def boundary_layers(volume: Volume, background: int, blocks: Blocks) -> np.ndarray:
    """(Z,) int64: per sample layer, the face-neighbouring sample pairs with different
    labels (those within the layer, to the next one, and to the outside at the grid's
    faces, which counts as background): a quad each, about a vertex each on closed
    surfaces, so about the net's vertices there. Read in slabs of a quarter of the
    budget (the samples as stored, and a byte a sample for each comparison)."""
    nx, ny, nz = (int(n) for n in volume.shape)
    layer = nx * ny * (np.dtype(volume.dtype).itemsize + 2)
    step = max(1, blocks.budget // 4 // layer - 1)
    counts = np.zeros(nz, np.int64)
    for z0 in range(0, nz, step):
        own = min(step, nz - z0)
        a = grid_slab_zyx(volume.samples, z0, min(nz, z0 + own + 1))  # one more: z pairs
        inside = a[:own] != background
        n = np.count_nonzero(a[:own, :, 1:] != a[:own, :, :-1], axis=(1, 2))
        n += np.count_nonzero(a[:own, 1:, :] != a[:own, :-1, :], axis=(1, 2))
        pairs = np.count_nonzero(a[1:] != a[:-1], axis=(1, 2))  # to the next layer
        if len(a) > own:
            n += pairs
        else:  # the grid's last layer: its far face instead
            n[:-1] += pairs
            n[-1] += np.count_nonzero(inside[-1])
        # the grid's side faces, and its near face
        n += np.count_nonzero(inside[:, :, [0, -1]], axis=(1, 2))
        n += np.count_nonzero(inside[:, [0, -1], :], axis=(1, 2))
        if z0 == 0:
            n[0] += np.count_nonzero(inside[0])
        counts[z0 : z0 + own] = n
    return counts


def net_plan(boundary: np.ndarray, halo: int, own: int, limit: int) -> list[tuple[int, int]]:
    """Owned dual-layer ranges ``[k0, k1)`` (as :func:`slab_ranges`) whose slabs'
    estimated kernel memory, halo included, stays within ``limit`` bytes: at most
    ``own`` layers each, at least ``halo`` (thinner slabs would read the volume more
    than three times over, and their halo would be most of their kernel's work)."""
    nz = len(boundary)
    prefix = np.concatenate([[0], np.cumsum(boundary)])

    def kernel(k0: int, k1: int) -> int:
        z0, z1 = max(0, k0 - 1 - halo), min(nz, k1 + 1 + halo)
        return int(prefix[z1] - prefix[z0]) * NET_BYTES_PER_VERTEX

    cuts = [0]
    while cuts[-1] < nz + 1:
        k0 = cuts[-1]
        k1 = min(nz + 1, k0 + max(1, min(halo, own)))
        while k1 < min(nz + 1, k0 + own) and kernel(k0, k1 + 1) <= limit:
            k1 += 1
        cuts.append(k1)
    if len(cuts) > 2 and cuts[-1] - cuts[-2] < 2:  # the last slab owns two layers or more
        del cuts[-2]
    return list(zip(cuts[:-1], cuts[1:], strict=True))


def halo_layers(iterations: int) -> int:
    """Sample layers read beyond a slab's own each way: exact for ``iterations``."""
    return int(iterations) + HALO_MARGIN


@dataclass(frozen=True)
class LabelSlabJob:
    """One slab of a label volume, as a worker needs it besides its samples.

    Attributes
    ----------
    k0, k1 : int
        Owned dual-cell layers ``k0 <= k < k1`` (the last slab owns layer Z).
    z0, z1 : int
        Sample layers read, ``[z0, z1)``: the owned ones and the halo.
    wanted : (L,) int64 or None
        The labels to extract, sorted; None: every label of the slab but the
        background.
    background : int
    iterations : int
    relaxation, constraint : float
        The smoothing (:class:`~isoconvert.extract.labels.SmoothingOptions`).
    reverse : bool
        Quads turned (a left-handed index-to-world map).
    grid_shape : (int, int, int)
        (X, Y, Z) of the whole volume.
    threads : int
    source : str
        For messages.
    """

    k0: int
    k1: int
    z0: int
    z1: int
    wanted: np.ndarray | None
    background: int
    iterations: int
    relaxation: float
    constraint: float
    reverse: bool
    grid_shape: tuple[int, int, int]
    threads: int
    source: str

    @property
    def read_range(self) -> tuple[int, int]:
        """Sample layers to read (the name :func:`~isoconvert.extract.slabs.dask_runner` uses)."""
        return self.z0, self.z1


@dataclass
class LabelSlab:
    """What one slab contributes: its own vertices and quads.

    Attributes
    ----------
    vmin, vmax : float
        The range of the slab's samples (halo included).
    present : (P,) int64
        The values in the slab's samples, sorted.
    vertex_keys : (V,) int64
        ``16 * dual cell + sheet`` of each owned vertex (dual cells numbered
        over the whole volume, as ``LabelMeshes.dual_cells``), in the kernel's order.
    positions : (V, 3) float64
        Their positions in the volume's index units.
    first_keys : (F,) int64
        The keys of the owned vertices on the first owned layer, sorted: the slab
        before finds the vertices its quads share with this one among them.
    first_index : (F,) int64
        Where those vertices are among ``vertex_keys``.
    quad_keys : (Q,) int64
        The sort key of each owned quad: axis and side group, then x, y, z of its
        lowest corner.
    corners : (Q, 4) int64
        Its corners, lowest cell first (before turning): ``c >= 0`` the owned
        vertex ``c``, ``c < 0`` the next slab's vertex ``next_keys[-1 - c]``.
    next_keys : (N,) int64
        Keys of the next slab's vertices the quads use, sorted.
    turned : (Q,) bool
        Whether the kernel turned the quad (corners in reverse order).
    pairs : (Q, 2) int64
        Label inside and outside.
    split, unresolved, outside : int
        The kernel's counts for the owned layers.
    """

    vmin: float
    vmax: float
    present: np.ndarray
    vertex_keys: np.ndarray
    positions: np.ndarray
    first_keys: np.ndarray
    first_index: np.ndarray
    quad_keys: np.ndarray
    corners: np.ndarray
    next_keys: np.ndarray
    turned: np.ndarray
    pairs: np.ndarray
    split: int = 0
    unresolved: int = 0
    outside: int = 0
    #: Where :meth:`spill` put the arrays only the merge reads: a nameless
    #: temporary file and each array's offset in it (None: in memory).
    spilled: tuple | None = field(default=None, repr=False)
    vertex_count: int = -1

    def __post_init__(self) -> None:
        if self.vertex_count < 0:
            self.vertex_count = len(self.vertex_keys)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held in memory."""
        return sum(a.nbytes for a in vars(self).values() if isinstance(a, np.ndarray))

    def spill(self, folder: Path) -> None:
        """Move the arrays only the merge reads (:data:`SPILLED`) to a nameless
        temporary file in ``folder`` (gone with the process, however it ends)."""
        try:
            fh = tempfile.TemporaryFile(dir=folder, prefix=".isoconvert-labels-")
        except OSError as exc:
            raise IsoconvertError(
                f"{folder}: cannot make a temporary file there for the label slabs "
                f"({exc.strerror}); set --max-memory higher or write elsewhere"
            ) from None
        offsets = {}
        try:
            for name in SPILLED:
                offsets[name] = fh.tell()
                np.save(fh, getattr(self, name), allow_pickle=False)
            fh.flush()
        except OSError as exc:
            written = fh.tell()
            fh.close()
            if exc.errno in DISK_FULL_ERRNOS:
                raise disk_full_error(folder, written, more=True, why=_SPILL_WHY) from None
            raise IsoconvertError(
                f"{folder}: writing the label slabs failed ({exc.strerror})"
            ) from None
        for name in SPILLED:
            setattr(self, name, None)
        self.spilled = (fh, offsets)

    def restore(self, *names: str) -> None:
        """Read the spilled arrays ``names`` back (nothing when in memory)."""
        if self.spilled is None:
            return
        fh, offsets = self.spilled
        for name in names:
            fh.seek(offsets[name])
            setattr(self, name, np.load(fh, allow_pickle=False))

    def close(self) -> None:
        """Give the spill file back."""
        if self.spilled is not None:
            self.spilled[0].close()
            self.spilled = None


@dataclass
class MergedNet:
    """The whole volume's net, as ``_native.label_net`` gives it, but for
    ``quad_labels``: its ``pairs`` once per quad, ``(Q, 2)``, not per triangle."""

    positions: np.ndarray
    dual_cells: np.ndarray
    corners: np.ndarray
    quad_labels: np.ndarray
    sides: np.ndarray
    split: int
    unresolved: int
    outside: int
    vmin: float
    vmax: float
    present: np.ndarray
    wanted: np.ndarray


def wants_blocks(
    volume: Volume, blocks: Blocks | None, itemsize: int, boundary: np.ndarray | None = None
) -> bool:
    """Whether to build ``volume``'s net slab by slab: asked for (``--block-size``,
    a scheduler), or read from its file and larger than one slab's share of the
    budget, or (``boundary``, :func:`boundary_layers`) its net's kernel memory
    would pass half the budget. A volume that fits is built whole (no halo, no
    merge)."""
    if blocks is None or volume.ndim != 3:
        return False
    if blocks.asked:
        return True
    if volume.grid is None:
        return False
    if boundary is not None and int(boundary.sum()) * NET_BYTES_PER_VERTEX > blocks.budget // 2:
        return True
    return blocks.layers(volume.shape, itemsize) < volume.shape[2]


def wants_net_estimate(volume: Volume, blocks: Blocks | None) -> bool:
    """Whether to count ``volume``'s label boundaries first (:func:`boundary_layers`):
    within ``--max-memory``, read from its file, no ``--block-size`` given, and no
    cluster (whose workers read the slabs: the client would read the whole volume)."""
    return (
        blocks is not None
        and blocks.max_memory is not None
        and blocks.size is None
        and blocks.scheduler is None
        and volume.ndim == 3
        and volume.grid is not None
    )


def slab_jobs(
    volume: Volume,
    wanted: np.ndarray | None,
    background: int,
    iterations: int,
    relaxation: float,
    constraint: float,
    reverse: bool,
    blocks: Blocks,
    itemsize: int,
    on_status: Callable[[str], None] | None = None,
    boundary: np.ndarray | None = None,
) -> list[LabelSlabJob]:
    """The slabs of ``volume``: ``--block-size`` owned layers each, or what fits
    the budget with the halo (the samples, and with ``boundary`` the net's kernel
    memory, :func:`net_plan`); on a cluster, enough for each of its threads."""
    nx, ny, nz = (int(n) for n in volume.shape)
    halo = halo_layers(iterations)
    if blocks.size is not None:
        own = blocks.size
    else:
        fits = blocks.layers(volume.shape, itemsize)  # sample layers within half the budget
        # at least as many owned layers as the halo: thinner slabs would read
        # the volume more than three times over
        own = max(fits - 2 * halo - 2, halo)
        if own + 2 * halo + 2 > fits and on_status:
            slab = (own + 2 * halo + 2) * nx * ny * itemsize * _SLAB_COPIES
            on_status(
                f"note: label slabs read {halo} layers beyond their own each way (smoothing "
                f"reaches that far), {slab / 2**20:.0f} MiB at once, more than --max-memory "
                "allows for samples"
            )
        if blocks.scheduler is not None:
            threads = max(1, cluster_size(blocks.scheduler))
            own = max(1, min(own, -(-(nz + 1) // (_SLABS_PER_THREAD * threads))))
    # dual layers 0..Z: Z + 1 of them
    if boundary is not None and blocks.size is None:
        ranges = net_plan(boundary, halo, own, blocks.budget // 2)
    else:
        ranges = slab_ranges(nz + 1, own)
    return [
        LabelSlabJob(
            k0=k0,
            k1=k1,
            z0=max(0, k0 - 1 - halo),
            z1=min(nz, k1 + 1 + halo),
            wanted=wanted,
            background=background,
            iterations=iterations,
            relaxation=relaxation,
            constraint=constraint,
            reverse=reverse,
            grid_shape=(nx, ny, nz),
            threads=kernel_threads(),
            source=volume.source,
        )
        for k0, k1 in ranges
    ]


def run_label_slab(job: LabelSlabJob, zyx: np.ndarray) -> LabelSlab:
    """Build one slab's net and keep what it owns.

    Parameters
    ----------
    job : LabelSlabJob
    zyx : (z1 - z0, Y, X) array
        The slab's samples.

    Raises
    ------
    VolumeError
        Samples that are not whole numbers.
    """
    samples = kernel_type(kernel_labels(zyx), job.source)
    vmin, vmax, bad, present = _native.label_presence(samples, job.threads)
    if bad:
        raise VolumeError(
            f"{job.source}: {bad} samples of z-layers {job.z0}..{job.z1 - 1} are not whole "
            "numbers (within +-2**53), so this is not a label volume; use an isosurface "
            "method (cubes) or round the labels first"
        )
    present = np.asarray(np.unique(samples) if present is None else present).astype(np.int64)
    wanted = present[present != job.background] if job.wanted is None else job.wanted
    if not len(wanted):
        return _empty_slab(vmin, vmax, present)
    samples = fit_background(samples, job.background)
    positions, dual, sheets, corners, pairs, _, split, unresolved, outside = _native.label_net(
        samples,
        wanted,
        float(job.background),
        vmin,
        vmax,
        job.iterations,
        job.relaxation,
        job.constraint,
        job.reverse,
        job.threads,
        job.z0,
        job.k0 - job.z0,
        job.k1 - job.z0,
    )
    nx, ny, nz = job.grid_shape
    layer = (nx + 1) * (ny + 1)
    dual = dual + job.z0 * layer
    keys = dual * (1 << SHEET_BITS) + sheets
    z = dual // layer
    own = (z >= job.k0) & (z < job.k1)
    local = np.cumsum(own) - 1  # a kernel vertex's place among the owned ones
    following = np.flatnonzero(z == job.k1)
    next_keys = keys[following]
    by_key = np.argsort(next_keys)
    next_keys = next_keys[by_key]
    local[following[by_key]] = -1 - np.arange(len(following))
    first = np.flatnonzero(z == job.k0)
    first_keys = keys[first]
    by_key = np.argsort(first_keys)

    cells = dual[corners]  # (Q, 4)
    turned = cells[:, 0] != cells.min(axis=1)
    # unturned, a quad's corners are (0, 0), (1, 0), (1, 1), (0, 1) from its lowest cell
    low = np.where(turned, cells[:, 3], cells[:, 0])
    qz = low // layer
    mine = (qz >= job.k0) & (qz < job.k1)
    corners, cells, low, qz, turned = corners[mine], cells[mine], low[mine], qz[mine], turned[mine]
    corners = np.where(turned[:, None], corners[:, ::-1], corners)
    step = np.where(turned, cells[:, 2], cells[:, 1]) - low
    qx, qy = low % (nx + 1), (low // (nx + 1)) % (ny + 1)
    # axis 0 steps along y first, axis 1 along z, axis 2 along x
    axis = np.where(step == nx + 1, 0, np.where(step == layer, 1, 2))
    along = np.choose(axis, [qx, qy, qz])
    top = np.choose(axis, [nx, ny, nz])
    group = 3 * axis + np.where(along == 0, 1, np.where(along == top, 2, 0))
    return LabelSlab(
        vmin=float(vmin),
        vmax=float(vmax),
        present=present,
        vertex_keys=keys[own],
        positions=positions[own],
        first_keys=first_keys[by_key],
        first_index=local[first[by_key]],
        quad_keys=((group * (nx + 1) + qx) * (ny + 1) + qy) * (nz + 1) + qz,
        corners=local[corners],
        next_keys=next_keys,
        turned=turned,
        pairs=pairs[mine],
        split=int(split),
        unresolved=int(unresolved),
        outside=int(outside),
    )


def _empty_slab(vmin: float, vmax: float, present: np.ndarray) -> LabelSlab:
    none = np.empty(0, np.int64)
    return LabelSlab(
        vmin=float(vmin),
        vmax=float(vmax),
        present=present,
        vertex_keys=none,
        positions=np.empty((0, 3)),
        first_keys=none,
        first_index=none,
        quad_keys=none,
        corners=np.empty((0, 4), np.int64),
        next_keys=none,
        turned=np.empty(0, bool),
        pairs=np.empty((0, 2), np.int64),
    )


def merge_slabs(
    slabs: list[LabelSlab], wanted: np.ndarray, folder: Path | None = None
) -> MergedNet:
    """The whole volume's net from its slabs (in z order): the arrays of
    ``_native.label_net`` on the whole volume, in its order, to the bit.

    Each slab's quads and vertices are put straight into their places in the
    whole net, one slab at a time, and the slab lets go of them: the peak holds
    the whole net and one slab's part, not the slabs' arrays end to end as well.

    Parameters
    ----------
    slabs : list of LabelSlab
    wanted : (L,) int64
        The labels extracted, sorted (``sides`` index them).
    folder : Path or None
        Where the net's large arrays live, in nameless temporary files
        (:func:`~isoconvert.memory.file_array`), for a net larger than the memory
        budget allows: the pages each step touched are given back after it. None:
        in memory.

    Raises
    ------
    IsoconvertError
        A quad corner that the next slab does not own (a bug, never a weld).
    DiskFullError
        No room in ``folder`` for the net.
    """

    def array(shape: tuple[int, ...], dtype) -> np.ndarray:
        if folder is None:
            return np.empty(shape, dtype)
        return file_array(shape, dtype, folder, _NET_WHY)

    starts = np.cumsum([0] + [s.vertex_count for s in slabs])
    quad_starts = np.cumsum([0] + [len(s.quad_keys) for s in slabs])
    nv, nq = int(starts[-1]), int(quad_starts[-1])
    # where each slab's quads go: the inverse of the order of their keys (stable,
    # so the quads of equal keys, never seen, would keep the slabs' order)
    order = np.argsort(_take(slabs, "quad_keys"), kind="stable")
    place = np.empty(nq, np.int64)
    place[order] = np.arange(nq)
    del order
    corners = array((nq, 4), np.int64)
    turned = np.empty(nq, bool)
    pairs = array((nq, 2), np.int64)
    for n, slab in enumerate(slabs):
        slab.restore("corners", "turned", "pairs")
        own = slab.corners + starts[n]
        if len(slab.next_keys):
            after = slabs[n + 1] if n + 1 < len(slabs) else None
            at = None if after is None else np.searchsorted(after.first_keys, slab.next_keys)
            if at is None or not np.array_equal(
                after.first_keys[np.minimum(at, len(after.first_keys) - 1)], slab.next_keys
            ):
                raise IsoconvertError(
                    "internal error: a label slab's quad uses a vertex no slab owns"
                )
            shared = slab.corners < 0
            own[shared] = (starts[n + 1] + after.first_index[at])[-1 - slab.corners[shared]]
        to = place[quad_starts[n] : quad_starts[n + 1]]
        corners[to] = own
        turned[to] = slab.turned
        pairs[to] = slab.pairs
        del own, to
        slab.corners = slab.turned = slab.pairs = None
    # each slab's quads land all over the net: its pages stay until every slab's are in
    del place
    # vertices numbered by their first quad corner, quads not yet turned
    rank = _native.first_use_numbering(corners.reshape(-1), nv)
    release(corners)
    if nv and rank.min() < 0:
        raise IsoconvertError("internal error: a label slab owns a vertex of no quad")
    sides = np.empty((nq, 2), np.int32)
    for a in range(0, nq, _PIECE):  # in place, a piece at a time: no second copy
        piece = corners[a : a + _PIECE]
        piece[:] = rank[piece]
        flip = turned[a : a + _PIECE]
        piece[flip] = piece[flip, ::-1]
        # each side's index among the labels extracted, -1 for none of them
        labels = pairs[a : a + _PIECE]
        side = np.searchsorted(wanted, labels)
        found = side < len(wanted)
        found[found] = wanted[side[found]] == labels[found]
        side[~found] = -1
        sides[a : a + _PIECE] = side
        if a % (_PIECE << 6) == 0:  # every 64 pieces, what they touched
            release(corners[: a + _PIECE])
            release(pairs[: a + _PIECE])
    release(corners)
    release(pairs)
    del turned
    positions = array((nv, 3), np.float64)
    dual_cells = array((nv,), np.int64)
    for n, slab in enumerate(slabs):
        slab.restore("positions", "vertex_keys")
        to = rank[starts[n] : starts[n + 1]]
        positions[to] = slab.positions
        dual_cells[to] = slab.vertex_keys >> SHEET_BITS
        slab.positions = slab.vertex_keys = None
        slab.close()
        release(positions)
        release(dual_cells)
    del rank
    present = np.unique(np.concatenate([s.present for s in slabs]))
    return MergedNet(
        positions=positions,
        dual_cells=dual_cells,
        corners=corners,
        quad_labels=pairs,
        sides=sides,
        split=sum(s.split for s in slabs),
        unresolved=sum(s.unresolved for s in slabs),
        outside=sum(s.outside for s in slabs),
        vmin=min(s.vmin for s in slabs),
        vmax=max(s.vmax for s in slabs),
        present=present,
        wanted=wanted,
    )


def _take(slabs: list[LabelSlab], name: str) -> np.ndarray:
    """The slabs' arrays ``name`` end to end; the slabs let go of theirs."""
    whole = np.concatenate([getattr(s, name) for s in slabs])
    for slab in slabs:
        setattr(slab, name, None)
    return whole


def run_slabs(volume: Volume, jobs: list[LabelSlabJob], scheduler: str | None, budget: int):
    """Each job's :class:`LabelSlab`, in order: here (the next slab read while one
    is built) or on the Dask cluster at ``scheduler``."""
    if scheduler is not None:
        runner = dask_runner(
            scheduler, volume.samples, volume.source, label_slab_task, max_bytes=budget
        )
        return runner(jobs)
    return _run_here(volume.samples, jobs)


def _run_here(source, jobs: list[LabelSlabJob]) -> Iterator[LabelSlab]:
    reader = SlabReader(source)

    def read(job: LabelSlabJob) -> np.ndarray:
        if not isinstance(source, LazyGrid):  # in memory: a view, no copy
            return reader.read(job.z0, job.z1)
        # read from its file: in the narrowest type (a uint32 atlas of 40 labels
        # holds a quarter of the memory per slab, the one built and the next read)
        return narrowed_layers(reader.read, job.z0, job.z1, job.background)

    for job, zyx in read_ahead(jobs, read, lambda job: reader.ready(job.z0, job.z1)):
        yield run_label_slab(job, zyx)
        del zyx


def label_slab_task(job: LabelSlabJob, samples) -> LabelSlab | TaskFailure:
    """One slab as a task of a cluster: read it (unless sent), build it
    (:func:`~isoconvert.extract.slabs.slab_task` of :func:`run_label_slab`).

    Parameters
    ----------
    job : LabelSlabJob
        Its ``threads`` is replaced by the worker's (the net is the same for any number).
    samples : LazyGrid or (z1 - z0, Y, X) array
        The grid to read the slab from, or the slab itself.
    """
    return slab_task(run_label_slab, job, samples)


__all__ = [
    "HALO_MARGIN",
    "SPILLED",
    "LabelSlab",
    "LabelSlabJob",
    "MergedNet",
    "halo_layers",
    "label_slab_task",
    "merge_slabs",
    "run_label_slab",
    "run_slabs",
    "slab_jobs",
    "wants_blocks",
]
