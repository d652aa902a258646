"""Label samples as the label kernels take them (shared by the whole-volume and
slab-by-slab nets)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import VolumeError


def kernel_labels(data: np.ndarray) -> np.ndarray:
    """Label samples in a type :func:`kernel_type` takes, exactly (any axis order). Float
    samples are compared as they are (exact for whole numbers, which the label
    scan checks)."""
    if data.dtype != bool and not np.issubdtype(data.dtype, np.integer):
        if data.dtype.itemsize < 4:  # float16: no kernel of its own, exact in float32
            data = data.astype(np.float32)
    if np.issubdtype(data.dtype, np.integer) and data.dtype.itemsize == 8 and data.size:
        # 64-bit labels: as int32 when they fit (exact, half the memory), else float64
        lo, hi = int(data.min()), int(data.max())
        if -(2**31) <= lo and hi < 2**31:
            data = data.astype(np.int32)
    return data


def fit_background(samples: np.ndarray, background: int) -> np.ndarray:
    """The samples in a type that holds ``background`` (the value around the grid):
    a copy in a wider type in the rare case theirs does not."""
    dtype = samples.dtype
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        if info.min <= background <= info.max:
            return samples
        wide = np.int32 if -(2**31) <= background < 2**31 and dtype.itemsize < 4 else np.float64
    else:
        if float(dtype.type(background)) == background:
            return samples
        wide = np.float64
    if wide == np.float64 and abs(background) > 2**53:
        raise VolumeError(f"background {background} is beyond +-2**53, which labels cannot be")
    return samples.astype(wide)


#: Integer types a slab of labels may be narrowed to, narrowest first (kernel types all).
_NARROW_TYPES = (np.uint8, np.int8, np.uint16, np.int16)

#: Layers read and narrowed at once by :func:`narrowed_layers` (a few MB: in cache).
NARROW_LAYERS = 8


def narrowed_layers(
    read: Callable[[int, int], np.ndarray],
    k0: int,
    k1: int,
    background: int,
    step: int = NARROW_LAYERS,
) -> np.ndarray:
    """Layers ``k0 <= k < k1`` of integer labels in the narrowest integer type that
    holds them and ``background``, read ``step`` layers at a time.

    A label volume stored wider than its labels need (a 40-label atlas as uint32)
    would otherwise hold four bytes per sample in each slab in memory; the kernel
    gives the same net for any type that holds the values (they are compared, never
    computed with). Only ``step`` layers are ever held in the stored type.

    Parameters
    ----------
    read : callable
        ``read(a, b)``: layers ``a .. b - 1`` as a ``(b - a, Y, X)`` array.
    k0, k1 : int
    background : int
    step : int

    Returns
    -------
    (k1 - k0, Y, X) array
        A fresh array, or what ``read(k0, k1)`` gives for samples that are not
        integers or are one byte already.
    """
    first = read(k0, min(k0 + step, k1))
    dtype = first.dtype
    if not np.issubdtype(dtype, np.integer) or dtype.itemsize == 1 or k1 <= k0:
        return first if k1 <= k0 + step else read(k0, k1)
    lo = hi = int(background)
    out = None
    for a in range(k0, k1, step):
        piece = first if a == k0 else read(a, min(a + step, k1))
        if piece.size:
            lo, hi = min(lo, int(piece.min())), max(hi, int(piece.max()))
        fits = next(
            (t for t in _NARROW_TYPES
             if np.dtype(t).itemsize < dtype.itemsize
             and np.iinfo(t).min <= lo and hi <= np.iinfo(t).max),
            dtype,
        )  # fmt: skip
        if out is None:
            out = np.empty((k1 - k0, *piece.shape[1:]), fits)
        elif out.dtype != fits:  # a value beyond the type so far: wider from now on
            out = out.astype(fits)
        out[a - k0 : a - k0 + len(piece)] = piece
    return out


__all__ = ["NARROW_LAYERS", "fit_background", "kernel_labels", "narrowed_layers"]
