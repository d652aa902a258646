"""Slabs of a volume: how it is cut (:class:`Blocks`, :func:`slab_ranges`) and
how a slab reaches a Dask worker (:func:`dask_runner`, :func:`slab_task`).

Shared by the block-wise isosurface (:mod:`isoconvert.extract.blocks`) and the
block-wise label net (:mod:`isoconvert.extract.label_blocks`), and light to
import: a label run or the options of a run that never cuts a volume need
none of the extraction kernels. Where a cluster's slabs are read is described
in :mod:`isoconvert.extract.blocks`.
"""

from __future__ import annotations

import copy
import pickle
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..errors import IsoconvertError, one_line
from ..grid import LazyGrid, grid_slab_zyx
from ..runner import Task, TaskFailure, cluster_size, run_in_order, worker_threads
from ..volume import Volume

#: The default memory budget of block-wise extraction (``--max-memory``).
DEFAULT_MAX_MEMORY = 1 << 30

#: Slabs per thread of a Dask cluster, when the budget would make fewer.
_SLABS_PER_THREAD = 4

#: Copies of a slab alive at once: the one being extracted, its kernel-type or
#: NaN-free copy, and the next one being read. Slabs get half the budget;
#: the mesh, a quarter before it moves to disk (when it may).
_SLAB_COPIES = 3


@dataclass(frozen=True)
class Blocks:
    """How to cut a volume into blocks, and where to run them.

    Attributes
    ----------
    size : int or None
        z-layers each block owns (it reads one more); None chooses from
        ``max_memory``.
    max_memory : int or None
        Bytes that block-wise extraction may hold at once, beyond the
        program itself: slabs of samples take half, the mesh being built a
        quarter before it moves to ``spill_dir`` (when there is one). None is
        :data:`DEFAULT_MAX_MEMORY`.
    scheduler : str or None
        A Dask scheduler address (``tcp://host:8786``) to run the blocks on;
        None runs them here.
    spill_dir : Path or None
        Where the mesh being built moves (into nameless temporary files) once
        it is larger than a quarter of ``max_memory``; None keeps it in memory. A writer
        then streams it to its file (:func:`isoconvert.convert` sets the
        output's folder).
    """

    size: int | None = None
    max_memory: int | None = None
    scheduler: str | None = None
    spill_dir: Path | None = None

    def __post_init__(self) -> None:
        if self.size is not None and self.size < 1:
            raise IsoconvertError(f"--block-size must be at least 1 layer, got {self.size}")
        if self.max_memory is not None and self.max_memory <= 0:
            raise IsoconvertError(f"--max-memory must be positive, got {self.max_memory}")

    @property
    def budget(self) -> int:
        return self.max_memory or DEFAULT_MAX_MEMORY

    @property
    def asked(self) -> bool:
        """Whether block-wise extraction was asked for (a size or a scheduler)."""
        return self.size is not None or self.scheduler is not None

    def wanted(self, volume: Volume) -> bool:
        """Whether ``volume`` is to be extracted block-wise: asked for (a size or
        a scheduler), or read from its file (a lazy volume), whatever its size:
        the mesh, not the volume, may be what outgrows the budget, and a volume
        that fits is one slab (block-wise costs what the in-memory path does)."""
        if volume.ndim != 3:
            if self.asked:
                raise IsoconvertError(
                    f"{volume.source}: a 2D image is contoured in memory; "
                    "drop --block-size and --scheduler"
                )
            return False
        return self.asked or volume.grid is not None

    def layers(self, shape: tuple[int, int, int], itemsize: int) -> int:
        """z-layers per block: :attr:`size`, or what fits the budget."""
        if self.size is not None:
            return self.size
        layer = shape[0] * shape[1] * max(itemsize, 1) * _SLAB_COPIES
        return max(1, self.budget // 2 // layer)


def slab_ranges(nz: int, layers: int) -> list[tuple[int, int]]:
    """Owned z-ranges ``[k0, k1)`` of ``layers`` layers covering ``0 <= k < nz``.

    Every slab but the last reads layer ``k1`` too; the last owns the grid's
    last layer and reads nothing more, so it is given at least two layers (a
    lone last layer joins the slab before it).
    """
    cuts = list(range(0, nz, max(1, layers))) + [nz]
    if len(cuts) > 2 and cuts[-1] - cuts[-2] < 2:
        del cuts[-2]
    return list(zip(cuts[:-1], cuts[1:], strict=True))


class SlabJob(Protocol):
    """What :func:`dask_runner` needs of a job: the layers it owns and reads."""

    k0: int
    k1: int

    @property
    def read_range(self) -> tuple[int, int]: ...


def read_block(source: np.ndarray | LazyGrid, job: SlabJob) -> np.ndarray:
    """The samples of ``job``'s slab, ``(layers, Y, X)``, from an (X, Y, Z)
    array or a lazy grid."""
    lo, hi = job.read_range
    return grid_slab_zyx(source, lo, hi)


def slab_task(run: Callable[[Any, np.ndarray], Any], job: Any, samples: np.ndarray | LazyGrid):
    """``run(job, zyx)`` on a worker: the slab's samples read from the grid there
    (``job.read_range``) unless they were sent, the worker's own thread count, and
    an ``IsoconvertError`` returned as a :class:`~isoconvert.runner.TaskFailure`."""
    try:
        job = replace(job, threads=worker_threads())
        if isinstance(samples, LazyGrid):
            try:
                zyx = read_block(samples, job)
            except OSError as exc:
                raise IsoconvertError(_unreadable(samples, job, exc)) from None
        else:
            zyx = samples
        return run(job, zyx)
    except IsoconvertError as exc:
        return TaskFailure.of(exc)


def _unreadable(grid: LazyGrid, job: SlabJob, exc: OSError) -> str:
    import socket

    lo, hi = job.read_range
    reason = exc.strerror or one_line(exc)
    return (
        f"{getattr(grid, 'path', job.source)}: a Dask worker on {socket.gethostname()} cannot "
        f"read z-layers {lo}..{hi - 1} ({reason}); the workers need the same files at the "
        "same paths (a shared file system)"
    )


def _worker_side(source: np.ndarray | LazyGrid) -> LazyGrid | None:
    """``source`` as workers should receive it when they can read their own
    slabs (a grid read out of order, paths made absolute), else None."""
    if not isinstance(source, LazyGrid) or source.sequential:
        return None
    grid = _absolute(source)
    try:
        pickle.dumps(grid)
    except Exception:  # holds something a worker cannot receive: read here instead
        return None
    return grid


def _absolute(grid: LazyGrid) -> LazyGrid:
    """A copy of ``grid`` whose paths (attributes holding a Path, or a list or
    tuple of them) are absolute: a worker's working folder is not ours."""
    state = getattr(grid, "__dict__", {})
    if not any(_relative_paths(v) for v in state.values()):
        return grid
    out = copy.copy(grid)
    for name, value in state.items():
        if isinstance(value, Path):
            setattr(out, name, value.absolute())
        elif isinstance(value, list | tuple) and any(isinstance(v, Path) for v in value):
            fixed = [v.absolute() if isinstance(v, Path) else v for v in value]
            setattr(out, name, type(value)(fixed) if isinstance(value, tuple) else fixed)
    return out


def _relative_paths(value: Any) -> bool:
    if isinstance(value, Path):
        return not value.is_absolute()
    if isinstance(value, list | tuple):
        return any(isinstance(v, Path) and not v.is_absolute() for v in value)
    return False


def _slab_bytes(source: np.ndarray | LazyGrid, job: SlabJob) -> int:
    lo, hi = job.read_range
    nx, ny, _ = source.shape
    return (hi - lo) * nx * ny * np.dtype(source.dtype).itemsize


#: ``task(job, samples)``, run on a worker for each slab.
SlabTask = Callable[[Any, Any], Any]

#: ``runner(jobs)``: the jobs' results, in their order.
Runner = Callable[[list], Iterator]


def dask_runner(
    address: str,
    source: np.ndarray | LazyGrid,
    name: str,
    task: SlabTask,
    *,
    max_bytes: int | None = None,
) -> Runner:
    """A runner of slab jobs on the Dask cluster at ``address`` (isosurface
    slabs, :func:`isoconvert.extract.blocks.extract_blocks`, and label slabs,
    :mod:`isoconvert.extract.label_blocks`): each slab one :class:`~isoconvert.runner.Task`
    of :func:`isoconvert.runner.run_in_order`.

    Connects now (so an unreachable scheduler fails before any work); the
    runner may then be called more than once (an extraction restarted with
    another vertex offset).

    Parameters
    ----------
    address : str
        The scheduler.
    source : (X, Y, Z) array or LazyGrid
        The volume's samples (``Volume.samples``).
    name : str
        The volume's name, for messages.
    task : callable
        ``task(job, samples)`` run on a worker for each slab, ``samples`` being
        the grid to read from or the slab itself (:func:`slab_task` of the
        slab's kernel: :func:`~isoconvert.extract.blocks.extract_slab`,
        :func:`~isoconvert.extract.label_blocks.label_slab_task`). It must be
        picklable.
    max_bytes : int or None
        Bytes of slabs read here and sent with their tasks that may be in
        flight at once (at least two slabs are); None is :data:`DEFAULT_MAX_MEMORY`.

    Returns
    -------
    callable
        ``runner(jobs)``: a generator of the jobs' results, in the order of
        ``jobs``. Closing it (done, failed or abandoned) cancels
        the tasks still in flight.

    Raises
    ------
    IsoconvertError
        As :func:`isoconvert.runner.dask.connect`; and, from the generator, a
        slab whose workers kept dying, the connection to the scheduler lost,
        or an ``IsoconvertError`` of a task (its own type and message).
    """
    cluster_size(address)  # connect now: an unreachable scheduler fails before any work
    grid = _worker_side(source)
    run = task
    budget = max_bytes or DEFAULT_MAX_MEMORY

    def died(slab: Task) -> str:
        job = slab.item
        return (
            f"{name}: a Dask worker died while extracting z-layers {job.k0}..{job.k1 - 1} "
            "(out of memory?), also when retried on other workers; nothing was written. "
            "Give the workers more memory, or lower --block-size"
        )

    def runner(jobs: list[SlabJob]) -> Iterator:
        token = uuid.uuid4().hex[:12]

        def slab_task(job: SlabJob) -> Task:
            key = f"isoconvert-slab-{token}-{job.k0}"
            what = f"{name}: z-layers {job.k0}..{job.k1 - 1}"
            if grid is not None:  # each worker reads its own slab
                return Task(run, (job, grid), key=key, what=what, item=job)
            return Task(  # read here just before it is sent, in z order
                run,
                key=key,
                what=what,
                nbytes=_slab_bytes(source, job),
                load=lambda: (job, read_block(source, job)),
                item=job,
            )

        return run_in_order(
            address,
            map(slab_task, jobs),
            budget=budget,
            died=died,
            tail="; nothing was written",
        )

    return runner


__all__ = [
    "DEFAULT_MAX_MEMORY",
    "Blocks",
    "Runner",
    "SlabJob",
    "SlabTask",
    "dask_runner",
    "read_block",
    "slab_ranges",
    "slab_task",
]
