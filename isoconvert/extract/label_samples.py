"""Label samples as the label kernels take them (shared by the whole-volume and
slab-by-slab nets)."""

from __future__ import annotations

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


__all__ = ["fit_background", "kernel_labels"]
