"""Block-wise extraction (issue 10): z-slabs stitched by edge id give the
in-memory mesh bit for bit, with no welding by position."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import cli_peak_mib, read_real_scan, real_scan_names

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
    """A raw file goes block-wise by itself, reading each slab (with its
    overlap layer) and never the whole array."""
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


@pytest.mark.parametrize("name", real_scan_names())
def test_every_real_scan_blockwise_equals_in_memory(name):
    from isoconvert.stats import histogram, otsu_level

    vol = read_real_scan(name)
    level = otsu_level(histogram(vol.samples))
    whole = extract(vol, level)
    nz = vol.shape[2]
    for layers in sorted({1, 5, max(2, nz // 3 + 1)}):
        assert_same_mesh(whole, extract(vol, level, blocks=Blocks(size=layers)))
    tetra = extract(vol, level, method="tetra")
    assert_same_mesh(tetra, extract(vol, level, method="tetra", blocks=Blocks(size=7)))


@pytest.fixture(scope="module")
def raw_volume(tmp_path_factory):
    """A 4 MiB float32 raw file with a bumpy surface, and its samples."""
    folder = tmp_path_factory.mktemp("raw")
    n = 128
    r = np.arange(n, dtype=np.float32) - (n - 1) / 2
    z, y, x = np.meshgrid(r[:64], r, r, indexing="ij")
    zyx = 50 - np.sqrt(x**2 + y**2 + (z + 32) ** 2) + 3 * np.sin(x / 3) * np.cos(y / 4)
    zyx = zyx.astype(np.float32)
    path = folder / f"bumps_{n}x{n}x64_float32.raw"
    zyx.tofile(path)
    return path, zyx


@pytest.mark.parametrize(
    "fmt, ascii", [("ply", False), ("ply", True), ("obj", False), ("stl", False), ("stl", True)]
)
def test_a_mesh_larger_than_the_budget_streams_to_the_same_file(raw_volume, tmp_path, fmt, ascii):
    """With a budget far below the mesh, the mesh waits for the writer in
    temporary files and the file is byte for byte the in-memory one."""
    from isoconvert.convert import convert
    from isoconvert.extract.blocks import BlockMesh

    path, _ = raw_volume
    convert(path, tmp_path / f"a.{fmt}", 0.5, ascii=ascii)
    streamed = convert(
        path, tmp_path / f"b.{fmt}", 0.5, ascii=ascii, blocks=Blocks(max_memory=1 << 18)
    )
    assert isinstance(streamed.mesh, BlockMesh) and streamed.mesh.info["blocks"] > 10
    assert (tmp_path / f"a.{fmt}").read_bytes() == (tmp_path / f"b.{fmt}").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"a.{fmt}", f"b.{fmt}"]  # no temporaries


def test_a_ply_far_from_the_origin_chooses_double_as_in_memory(raw_volume, tmp_path):
    """float32 would merge vertices 5e6 units from the origin: the slab-pair
    check of a streamed mesh decides as the whole-mesh check does (its note
    counts the first slab that loses something: "at least")."""
    from isoconvert.convert import convert

    path, _ = raw_volume
    notes = {}
    for name, blocks in (("a.ply", Blocks(size=1000)), ("b.ply", Blocks(max_memory=1 << 18))):
        notes[name] = []
        convert(
            path,
            tmp_path / name,
            0.5,
            origin=(5e6, 0, 0),
            spacing=(1e-3, 1e-3, 1e-3),
            blocks=blocks,
            on_status=notes[name].append,
        )
    data = (tmp_path / "a.ply").read_bytes()
    assert b"property double x" in data
    assert data == (tmp_path / "b.ply").read_bytes()
    # a grid step (1e-3) shorter than float32's rounding there: checked whole, same note
    [whole] = [n for n in notes["a.ply"] if "written as double" in n]
    assert "vertices merge" in whole and notes["b.ply"] == notes["a.ply"]


def test_the_slab_by_slab_float32_check_finds_what_the_whole_check_finds(tmp_path):
    """Samples a hair above the level put vertices of several edges 2e-6 from
    one grid vertex; 1e4 from the origin float32 merges them. A grid step
    (1) is far longer than that rounding, so the streamed mesh is checked
    slab by slab, and chooses double as the whole-mesh check does."""
    from isoconvert.convert import convert

    zyx = np.zeros((40, 12, 12), dtype=np.float32)
    for k in (5, 17, 33):
        zyx[k, 6, 6] = np.float32(0.5) + np.float32(1e-6)
    path = tmp_path / "hairs_12x12x40_float32.raw"
    zyx.tofile(path)
    notes = {}
    for name, blocks in (("a.ply", Blocks(size=1000)), ("b.ply", Blocks(max_memory=1 << 14))):
        notes[name] = []
        result = convert(
            path,
            tmp_path / name,
            0.5,
            origin=(1e4, 1e4, 1e4),
            blocks=blocks,
            on_status=notes[name].append,
        )
    assert type(result.mesh).__name__ == "BlockMesh" and result.mesh.float32_windows()
    data = (tmp_path / "a.ply").read_bytes()
    assert b"property double x" in data and data == (tmp_path / "b.ply").read_bytes()
    [whole] = [n for n in notes["a.ply"] if "written as double" in n]
    [streamed] = [n for n in notes["b.ply"] if "written as double" in n]
    assert "vertices merge" in whole and "at least" not in whole
    assert "at least" in streamed and "vertices merge" in streamed


def test_the_report_of_a_blockwise_mesh_is_the_in_memory_one(raw_volume, tmp_path):
    from isoconvert.convert import convert
    from isoconvert.report import check_mesh

    path, _ = raw_volume
    reports = []
    for name, blocks in (
        ("a.ply", Blocks()),
        ("b.ply", Blocks(size=3)),
        ("c.ply", Blocks(max_memory=1 << 18)),
    ):
        result = convert(path, tmp_path / name, 0.5, blocks=blocks)
        report = check_mesh(result.written, grid=result.mesh.info["grid"]).to_dict()
        reports.append(report)
    assert reports[0]["counts"]["triangles"] > 1000  # a real report of a real mesh
    assert reports[1] == reports[0] and reports[2] == reports[0]


def test_memory_stays_within_the_budget(tmp_path):
    """A 256 MiB volume converted with --max-memory 16M: the process's peak
    resident memory stays under what the same command needs for a 2 MiB
    volume plus the budget plus 16 MiB, far below the volume."""

    def peak_mib(path: str, *extra: str) -> float:
        out = tmp_path / "out.ply"
        out.unlink(missing_ok=True)
        peak = cli_peak_mib("convert", path, "-o", out, "--level", "0.5", "--quiet", *extra)
        assert out.stat().st_size > 100_000  # a real mesh was written
        return peak

    def volume(name: str, nz: int) -> str:
        n = 256
        r = np.arange(n, dtype=np.float32) - (n - 1) / 2
        yy, xx = np.meshgrid(r, r, indexing="ij")
        path = tmp_path / f"{name}_{n}x{n}x{nz}_float32.raw"
        with open(path, "wb") as fh:
            for k in range(nz):
                d = np.sqrt(xx**2 + yy**2 + (k - nz / 2) ** 2)
                fh.write((60 - d).astype(np.float32).tobytes())  # a ball of radius 60
        return str(path)

    small = peak_mib(volume("small", 8))
    big = peak_mib(volume("big", 1024), "--max-memory", "16M")
    assert big < small + 16 + 16, (small, big)
    assert big < 256, big


@pytest.mark.parametrize("layers", [1, 2, 3, 7, 12])
def test_a_chunked_store_is_decoded_once_per_chunk_row(tmp_path, monkeypatch, layers):
    """Slabs thinner or thicker than the store's chunks (5 layers deep, not
    dividing the 23 layers): the mesh is the in-memory one, and each row of
    chunks is read once."""
    zarr = pytest.importorskip("zarr")
    from isoconvert.readers.zarr import ZarrGrid

    rng = np.random.default_rng(9)
    zyx = rng.random((23, 11, 13)).astype(np.float32)
    store = zarr.create_array(
        str(tmp_path / "v.zarr"), shape=zyx.shape, chunks=(5, 7, 9), dtype="f4"
    )
    store[:] = zyx
    reads = []
    original = ZarrGrid.read_zyx

    def spy(self, k0, k1):
        reads.append((k0, k1))
        return original(self, k0, k1)

    monkeypatch.setattr(ZarrGrid, "read_zyx", spy)
    vol = isoconvert.read_volume(tmp_path / "v.zarr")
    assert vol.grid.z_chunk == 5
    blocked = extract(vol, 0.5, blocks=Blocks(size=layers))
    assert sorted(reads) == [(k, min(k + 5, 23)) for k in range(0, 23, 5)]
    assert_same_mesh(extract(Volume.from_zyx(zyx), 0.5), blocked)


def test_a_sample_equal_to_the_level_in_the_first_slab_costs_no_second_pass(monkeypatch):
    """The first slab chooses the offset and the slabs after it take it: each
    slab is extracted once."""
    from isoconvert.extract import blocks

    rng = np.random.default_rng(3)
    zyx = (rng.random((20, 10, 12)) * 9).astype(np.uint8)
    zyx[1, 4, 4] = 5
    runs = []
    original = blocks.run_block

    def counted(job, samples, allocate=None):
        runs.append(job.k0)
        return original(job, samples, allocate)

    monkeypatch.setattr(blocks, "run_block", counted)
    vol = Volume.from_zyx(zyx)
    blocked = extract(vol, 5, blocks=Blocks(size=3))
    assert runs == [k0 for k0, _ in slab_ranges(20, 3)]
    monkeypatch.setattr(blocks, "run_block", original)
    assert_same_mesh(extract(vol, 5), blocked)
