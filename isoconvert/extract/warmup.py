"""Compiling the kernels ahead of time, so a batch job or CI pays numba once.

numba compiles each kernel for each sample type on first use (10-25 s each on
a 2-core machine) and caches the result on disk. ``isoconvert warmup`` runs
each chosen method on a tiny volume of each chosen type, through the same
:func:`~isoconvert.extract.extract` call as real data, so every specialization a
later run needs is already in the cache.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import IsoconvertError
from ..volume import SUPPORTED_DTYPES, Volume

#: The sample types of most scans: CT (int16, uint16), 8-bit data, float fields.
DEFAULT_DTYPES = ("uint8", "int16", "uint16", "float32")
#: The built-in methods that compile a kernel.
COMPILED_METHODS = ("cubes", "tetra", "squares")


@dataclass(frozen=True)
class Warmed:
    """One method and sample type made ready, and how long it took."""

    method: str
    dtype: str
    seconds: float
    compiled: bool


def warmup(
    methods: Sequence[str] = ("cubes",),
    dtypes: Sequence[str] = DEFAULT_DTYPES,
    on_status: Callable[[str], None] | None = None,
) -> list[Warmed]:
    """Compile (or load from the cache) the kernels of ``methods`` for ``dtypes``.

    Parameters
    ----------
    methods : sequence of str
        Names among :data:`COMPILED_METHODS`.
    dtypes : sequence of str
        Sample type names among :data:`~isoconvert.volume.SUPPORTED_DTYPES`.
    on_status : callable or None
        Receives a line when a kernel starts compiling.

    Returns
    -------
    list of Warmed
        One per method and type; ``compiled`` is False when the cache had it.
    """
    from . import extract
    from .jit import compile_notice

    unknown = [m for m in methods if m not in COMPILED_METHODS]
    if unknown:
        raise IsoconvertError(
            f"warmup: unknown method {', '.join(unknown)}; "
            f"choose from {', '.join(COMPILED_METHODS)}"
        )
    bad = [d for d in dtypes if d not in SUPPORTED_DTYPES]
    if bad:
        raise IsoconvertError(
            f"warmup: unknown sample type {', '.join(bad)}; "
            f"choose from {', '.join(SUPPORTED_DTYPES)} (or all)"
        )
    done = []
    for method in methods:
        for dtype in dtypes:
            volume = _tiny_volume(np.dtype(dtype), 2 if method == "squares" else 3)
            compiled: list[str] = []
            start = time.perf_counter()
            with compile_notice(compiled.append, ""):
                extract(volume, 1.5, method=method, vertex_offset=0.0, on_status=on_status)
            done.append(Warmed(method, dtype, time.perf_counter() - start, bool(compiled)))
    return done


def _tiny_volume(dtype: np.dtype, ndim: int) -> Volume:
    """A 4^ndim block of 0 with a 2 in the middle: one small closed surface at 1.5."""
    data = np.zeros((4,) * ndim, dtype=dtype)
    data[(slice(1, 3),) * ndim] = 2
    return Volume.from_zyx(data, source=f"warmup {dtype}")
