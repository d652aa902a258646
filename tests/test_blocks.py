"""Block-wise extraction (issue 10): z-slabs stitched by edge id give the
in-memory mesh bit for bit, with no welding by position."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATASETS

import isoconvert
from isoconvert import Volume, extract
from isoconvert.errors import IsoconvertError, LevelError, VolumeError
from isoconvert.extract.blocks import Blocks, slab_ranges


def assert_same_mesh(whole, blocked) -> None:
    """Same vertices (to the bit, in the same order), ids and cells."""
    assert blocked.vertices.tobytes() == whole.vertices.tobytes()
    assert np.array_equal(blocked.edge_ids, whole.edge_ids)
    assert blocked.cells.dtype == whole.cells.dtype
    assert np.array_equal(blocked.cells, whole.cells)


@pytest.mark.parametrize("nz, layers", [(10, 1), (10, 3), (10, 9), (10, 10), (10, 50), (2, 1)])
def test_slabs_cover_the_grid_once_and_the_last_has_two_layers(nz, layers):
    ranges = slab_ranges(nz, layers)
    owned = [k for k0, k1 in ranges for k in range(k0, k1)]
    assert owned == list(range(nz))
    assert ranges[-1][1] - ranges[-1][0] >= 2


METHODS = [
    ("cubes", {}),
    ("cubes", {"ambiguity": "separate-negative"}),
    ("tetra", {}),
    ("squares", {"axis": "z"}),
    ("squares", {"axis": "x"}),
    ("squares", {"axis": "y"}),
]


@pytest.mark.parametrize("method, options", METHODS)
@pytest.mark.parametrize("layers", [1, 2, 3, 7, 22, 23, 40])
def test_random_field_blocks_equal_the_whole_mesh(method, options, layers):
    """Blocks of 2 samples (1 layer + overlap), sizes that do not divide the
    23 layers, one block, and a block larger than the volume."""
    rng = np.random.default_rng(5)
    zyx = rng.random((23, 17, 31)).astype(np.float32)
    vol = Volume.from_zyx(zyx, spacing=(0.7, 1.3, 2.1), origin=(5.0, -3.0, 1.5))
    whole = extract(vol, 0.5, method=method, **options)
    blocked = extract(vol, 0.5, method=method, blocks=Blocks(size=layers), **options)
    assert blocked.info["blocks"] == len(slab_ranges(23, layers))
    assert_same_mesh(whole, blocked)


def test_left_handed_and_flipped_volumes_keep_their_orientation():
    rng = np.random.default_rng(8)
    zyx = rng.random((9, 8, 7))
    direction = np.diag([1.0, -1.0, 1.0])
    vol = Volume.from_zyx(zyx, direction=direction)
    for flip in (False, True):
        whole = extract(vol, 0.4, flip=flip)
        assert_same_mesh(whole, extract(vol, 0.4, flip=flip, blocks=Blocks(size=2)))


def test_a_sample_equal_to_the_level_in_a_late_block_moves_every_vertex_alike():
    """The automatic vertex offset depends on the whole volume: a block that
    finds a sample equal to the level restarts the extraction with it."""
    rng = np.random.default_rng(3)
    zyx = (rng.random((20, 10, 12)) * 9).astype(np.uint8)  # 0..8
    zyx[zyx == 5] = 4
    zyx[17, 4, 4] = 5  # the only sample equal to the level, in the last block
    vol = Volume.from_zyx(zyx)
    notes_whole, notes_blocks = [], []
    whole = extract(vol, 5, on_status=notes_whole.append)
    blocked = extract(vol, 5, blocks=Blocks(size=3), on_status=notes_blocks.append)
    assert whole.info["vertex_offset"] == blocked.info["vertex_offset"] > 0
    assert_same_mesh(whole, blocked)
    assert notes_blocks == notes_whole  # "level 5 equals 1 sample: ..."
    exact = extract(vol, 5, vertex_offset=0, blocks=Blocks(size=3))
    assert_same_mesh(extract(vol, 5, vertex_offset=0), exact)


def test_surfaces_touching_at_a_point_on_a_block_boundary_are_not_merged():
    """Two blobs meet at one grid vertex on the first layer of a block, whose
    value equals the level: with exact placement, vertices of several edges
    lie at that point. Stitching by edge id keeps each, as the in-memory
    mesh does; welding by position (as zmesh users are told to do) would
    merge them into one vertex shared by both surfaces."""
    zyx = np.zeros((7, 7, 7), dtype=np.float32)
    zyx[1:3, 2:5, 2:5] = 2.0  # blob below the point
    zyx[4:6, 2:5, 2:5] = 2.0  # blob above it
    zyx[3, 3, 3] = 1.0  # the point, equal to the level, on layer 3
    vol = Volume.from_zyx(zyx)
    whole = extract(vol, 1.0, vertex_offset=0)
    blocked = extract(vol, 1.0, vertex_offset=0, blocks=Blocks(size=3))  # a block starts at k = 3
    assert_same_mesh(whole, blocked)
    at_point = np.flatnonzero((blocked.vertices == (3.0, 3.0, 3.0)).all(axis=1))
    assert len(at_point) >= 2 and len(np.unique(blocked.edge_ids[at_point])) == len(at_point)
    welded = np.unique(blocked.vertices, axis=0)
    assert len(welded) < blocked.n_vertices  # a weld by position would have merged them


def test_lazy_raw_volume_is_read_slab_by_slab(tmp_path, monkeypatch):
    """A raw file larger than the budget goes block-wise by itself, reading
    each slab (with its overlap layer) and never the whole array."""
    from isoconvert.grid import RawGrid

    rng = np.random.default_rng(4)
    zyx = rng.random((12, 9, 10)).astype(np.float32)
    path = tmp_path / "v_10x9x12_float32.raw"
    zyx.tofile(path)
    reads = []
    original = RawGrid.read_zyx

    def spy(self, k0, k1):
        reads.append((k0, k1))
        return original(self, k0, k1)

    monkeypatch.setattr(RawGrid, "read_zyx", spy)
    vol = isoconvert.read_volume(path)
    budget = Blocks(max_memory=zyx.nbytes // 4)
    assert vol.grid is not None and budget.wanted(vol)
    blocked = extract(vol, 0.5, blocks=budget)
    assert reads and all(k1 - k0 <= 4 for k0, k1 in reads)
    assert vol._array is None  # the whole array was never made
    assert_same_mesh(extract(Volume.from_zyx(zyx), 0.5), blocked)


def test_bad_input_is_refused_as_in_memory():
    zyx = np.zeros((6, 5, 4), dtype=np.float32)
    zyx[2, 2, 2] = 1.0
    vol = Volume.from_zyx(zyx)
    with pytest.raises(LevelError, match="outside the data range"):
        extract(vol, 3.0, blocks=Blocks(size=2))
    with pytest.raises(LevelError, match="constant"):
        extract(Volume.from_zyx(np.ones((4, 4, 4))), 1.0, blocks=Blocks(size=2))
    zyx[4, 1, 1] = np.nan
    with pytest.raises(VolumeError, match=r"NaN or infinite; pass --nan-as"):
        extract(vol, 0.5, blocks=Blocks(size=2))
    assert_same_mesh(
        extract(vol, 0.5, nan_as=0.0), extract(vol, 0.5, nan_as=0.0, blocks=Blocks(size=2))
    )
    with pytest.raises(IsoconvertError, match="at least 1 layer"):
        Blocks(size=0)
    with pytest.raises(IsoconvertError, match="2D image is contoured in memory"):
        extract(Volume.from_zyx(np.eye(3)), 0.5, blocks=Blocks(size=1))


def real_scans():
    if not DATASETS.is_dir():
        return [pytest.param(None, marks=pytest.mark.skip(reason=f"no datasets at {DATASETS}"))]
    return [
        p.name
        for p in sorted(DATASETS.iterdir())
        if p.suffix in (".raw", ".nrrd", ".tif") or p.name == "headsq_vtk"
    ]


@pytest.mark.parametrize("name", real_scans())
def test_every_real_scan_blockwise_equals_in_memory(name):
    from isoconvert.stats import histogram, otsu_level

    path = DATASETS / name
    if path.is_dir():
        path = next(path.glob("*.nhdr"))
    try:
        vol = isoconvert.read_volume(path)
    except IsoconvertError as err:
        pytest.skip(f"not read yet: {err}")
    if vol.ndim != 3:
        pytest.skip("a 2D image")
    level = otsu_level(histogram(vol.samples))
    whole = extract(vol, level)
    nz = vol.shape[2]
    for layers in sorted({1, 5, max(2, nz // 3 + 1)}):
        assert_same_mesh(whole, extract(vol, level, blocks=Blocks(size=layers)))
    tetra = extract(vol, level, method="tetra")
    assert_same_mesh(tetra, extract(vol, level, method="tetra", blocks=Blocks(size=7)))
