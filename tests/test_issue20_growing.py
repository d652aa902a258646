"""A block-wise mesh's growing arrays survive a view that outlived its use.

A batch on a Dask cluster failed once with "BufferError: mmap can't resize with
extant buffers exported": a numpy view of the map was still referenced (by a
reference cycle, until the collector ran) when the map had to grow.
"""

from __future__ import annotations

import numpy as np
import pytest

from isoconvert.extract.blocks import _Growing


@pytest.mark.parametrize("spilled", [False, True], ids=["memory", "spilled"])
def test_a_held_view_does_not_stop_the_array_growing(tmp_path, spilled):
    grow = _Growing((3,), np.float64)
    if spilled:
        grow.spill(tmp_path)
    grow.reserve(1000)
    first = np.arange(3000, dtype=np.float64).reshape(1000, 3)
    grow.view(0, 1000)[:] = first
    grow.size = 1000
    held = grow.view(0, 10)  # a view nobody dropped
    grow.reserve(200_000)  # far past the map's size: it must grow or move
    assert grow.nbytes >= 201_000 * 24
    grow.view(1000, 1002)[:] = -1.0
    grow.size = 1002
    out = grow.final()
    assert np.array_equal(out[:1000], first)  # what was committed came along
    assert np.array_equal(out[1000:], np.full((2, 3), -1.0))
    assert np.array_equal(held, first[:10])  # the old view still reads its rows
    del out, held
    grow.close()
    assert list(tmp_path.iterdir()) == []  # the spill file has no name: nothing left
