"""Label surfaces slab by slab (issue 25): the in-memory net, bit for bit.

A label volume larger than ``--max-memory``, or one given ``--block-size`` or a
Dask scheduler, is meshed in z-slabs read with a halo and merged by key
(:mod:`isoconvert.extract.label_blocks`). Every array of the result must be the
one the whole volume gives: positions to the bit (the smoothing's sums in the
same order), vertices and triangles in the same order, the same counts.
The cluster's runs are in tests/test_distributed.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import cli_peak_mib, dataset
from hypothesis import given, settings
from hypothesis import strategies as st

from isoconvert import read_volume
from isoconvert.errors import IsoconvertError, LevelError, VolumeError
from isoconvert.extract import label_blocks
from isoconvert.extract.blocks import Blocks
from isoconvert.extract.label_samples import narrowed_layers
from isoconvert.extract.labels import label_surfaces
from isoconvert.grid import RawGrid
from isoconvert.memory import _file_map
from isoconvert.volume import Volume


def _same(a, b) -> None:
    """Every array and count of two LabelMeshes equal, bit for bit."""
    assert a.labels == b.labels
    np.testing.assert_array_equal(a.combined.vertices, b.combined.vertices, strict=True)
    np.testing.assert_array_equal(a.combined.cells, b.combined.cells, strict=True)
    np.testing.assert_array_equal(a.boundary_labels, b.boundary_labels, strict=True)
    np.testing.assert_array_equal(a.dual_cells, b.dual_cells, strict=True)
    assert (a.split_vertices, a.unresolved, a.unresolved_outside) == (
        b.split_vertices,
        b.unresolved,
        b.unresolved_outside,
    )
    assert a.value_range == b.value_range
    for label in a.labels:
        np.testing.assert_array_equal(a[label].vertices, b[label].vertices, strict=True)
        np.testing.assert_array_equal(a[label].cells, b[label].cells, strict=True)
        np.testing.assert_array_equal(a.vertex_map[label], b.vertex_map[label], strict=True)
        np.testing.assert_array_equal(a.face_map[label], b.face_map[label], strict=True)


def _labels(rng: np.random.Generator, shape, kinds: int, blobs: bool) -> np.ndarray:
    """Random labels: noise (every non-manifold configuration, rings paired the
    other way) or blobs of a few labels in background."""
    if blobs:
        inside = rng.random(shape) < 0.5
        return (inside * rng.integers(1, kinds + 1, shape)).astype(np.uint8)
    return rng.integers(0, kinds, shape).astype(np.uint8)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    nz=st.integers(2, 30),
    kinds=st.integers(2, 4),
    blobs=st.booleans(),
    iterations=st.integers(0, 4),
    size=st.integers(1, 5),
    mirrored=st.booleans(),
)
def test_slabs_give_the_in_memory_net(seed, nz, kinds, blobs, iterations, size, mirrored):
    rng = np.random.default_rng(seed)
    data = _labels(rng, (int(rng.integers(2, 7)), int(rng.integers(2, 7)), nz), kinds, blobs)
    if not data.any():
        data[0, 0, 0] = 1
    direction = np.diag([1.0, -1.0, 1.0]) if mirrored else None  # quads turned
    volume = Volume(data, spacing=(0.7, 1.0, 1.3), origin=(5.0, -2.0, 0.25), direction=direction)
    reference = label_surfaces(volume, smoothing=iterations)
    _same(reference, label_surfaces(volume, smoothing=iterations, blocks=Blocks(size=size)))


def test_the_halo_is_what_makes_slabs_exact(monkeypatch):
    """Without the margin (a halo of only the smoothing iterations) some volume's
    slabs differ from the whole: the test above could fail, and the margin is needed."""
    rng = np.random.default_rng(11)
    cases = []
    for n in range(40):
        data = _labels(rng, (5, 5, 24), 3, n % 2 == 1)
        cases.append((Volume(data), int(rng.integers(0, 3))))
    references = [label_surfaces(v, smoothing=it) for v, it in cases]
    for (volume, it), reference in zip(cases, references, strict=True):
        _same(reference, label_surfaces(volume, smoothing=it, blocks=Blocks(size=2)))
    monkeypatch.setattr(label_blocks, "HALO_MARGIN", 0)
    differ = 0
    for (volume, it), reference in zip(cases, references, strict=True):
        try:
            _same(reference, label_surfaces(volume, smoothing=it, blocks=Blocks(size=2)))
        except (AssertionError, IsoconvertError):  # differ, or the slabs disagree
            differ += 1
    assert differ > 0


@pytest.mark.parametrize(
    "dtype, values, background, labels",
    [
        (np.int64, [0, 3, 2**40, -5], 0, None),  # wider than int32: float64 in the kernel
        (np.float32, [0.0, 1.0, 7.0], 0, None),
        (np.int16, [-3, 4, 9, 12], 4, None),  # a background that is not 0
        (np.uint16, [0, 1, 2, 3, 5], 0, [2, 5]),  # some labels only
        (np.bool_, [False, True], 0, None),
    ],
)
def test_slabs_of_every_label_type(dtype, values, background, labels):
    rng = np.random.default_rng(3)
    data = np.asarray(values, dtype=dtype)[rng.integers(0, len(values), (6, 7, 26))]
    data[:2] = values[0]  # runs of one value too
    volume = Volume(data)
    options = {"labels": labels, "background": background, "smoothing": 3}
    _same(
        label_surfaces(volume, **options),
        label_surfaces(volume, **options, blocks=Blocks(size=3)),
    )


def test_a_file_larger_than_the_budget_is_read_in_slabs(tmp_path, monkeypatch):
    """A label volume read from its file, over ``--max-memory``, is never read
    whole: every read is a slab with its halo, and the net is the whole's."""
    rng = np.random.default_rng(5)
    data = _labels(rng, (120, 16, 18), 3, True).astype(np.uint32)  # (Z, Y, X) in the file
    np.save(tmp_path / "labels.npy", data)
    volume = read_volume(tmp_path / "labels.npy")
    assert volume.grid is not None
    reads = []
    original = RawGrid.read_zyx

    def recording(self, k0, k1):
        reads.append((k0, k1))
        return original(self, k0, k1)

    monkeypatch.setattr(RawGrid, "read_zyx", recording)
    budget = 16 * 18 * 4 * 3 * 2 * 60  # 60 layers of samples per slab
    got = label_surfaces(volume, smoothing=2, blocks=Blocks(max_memory=budget))
    assert len(reads) > 2
    assert max(k1 - k0 for k0, k1 in reads) <= 60 < 120
    assert reads[0][0] == 0 and reads[-1][1] == 120
    monkeypatch.setattr(RawGrid, "read_zyx", original)
    _same(label_surfaces(Volume(data.T), smoothing=2), got)
    # within the budget no slab is read: the volume is meshed whole
    reads.clear()
    monkeypatch.setattr(RawGrid, "read_zyx", recording)
    label_surfaces(volume, smoothing=2, blocks=Blocks())
    assert all(r == (0, 120) for r in reads)


def _slabs_built(monkeypatch, note) -> list:
    """What ``note(job, zyx)`` says of each slab built from now on (in this process)."""
    seen = []
    original = label_blocks.run_label_slab

    def recording(job, zyx):
        seen.append(note(job, zyx))
        return original(job, zyx)

    monkeypatch.setattr(label_blocks, "run_label_slab", recording)
    return seen


def _small_cubes(z: int = 60, n: int = 48) -> np.ndarray:
    """(Z, Y, X) uint8: a cube of 2 voxels in every 3-voxel cell, each labelled
    (labels repeat, never side by side): a volume dense with surfaces."""
    k, j, i = np.mgrid[:z, :n, :n]
    cell = (k // 3) * 256 + (j // 3) * 16 + i // 3
    inside = (k % 3 < 2) & (j % 3 < 2) & (i % 3 < 2)
    return np.where(inside, cell % 250 + 1, 0).astype(np.uint8)


def test_the_boundary_count_is_the_nets_quads():
    """The estimate the slabs are sized by counts a quad for every pair of samples
    with different labels (the outside counting as background): the kernel's own
    quads, exactly, on random labels and on cubes touching the grid's faces."""
    rng = np.random.default_rng(8)
    for data in (_labels(rng, (23, 17, 19), 4, True), _small_cubes(14, 12)):
        count = label_blocks.boundary_layers(Volume(data.T), 0, Blocks(max_memory=1 << 16))
        assert count.shape == (data.shape[0],)
        quads = label_surfaces(Volume(data.T), smoothing=0).combined.n_cells // 2
        assert int(count.sum()) == quads


def test_within_the_budget_a_volume_dense_with_surfaces_is_built_in_slabs(tmp_path, monkeypatch):
    """Its samples fit --max-memory, its net's kernel memory would not (about 220 bytes
    a vertex): it is built in slabs, each estimated within half the budget but at the
    halo's floor, and the net is the whole's, bit for bit."""
    data = _small_cubes()
    np.save(tmp_path / "cubes.npy", data)
    volume = read_volume(tmp_path / "cubes.npy")
    slabs = _slabs_built(monkeypatch, lambda job, zyx: (job.k0, job.k1))
    budget = 16 << 20
    got = label_surfaces(volume, smoothing=0, blocks=Blocks(max_memory=budget))
    count = label_blocks.boundary_layers(volume, 0, Blocks(max_memory=budget))
    assert int(count.sum()) * label_blocks.NET_BYTES_PER_VERTEX > budget // 2 > data.nbytes
    assert len(slabs) > 2 and slabs[0][0] == 0 and slabs[-1][1] == data.shape[0] + 1
    assert all(b == c for (_, b), (c, _) in zip(slabs, slabs[1:], strict=False))
    halo = label_blocks.halo_layers(0)
    prefix = np.concatenate([[0], np.cumsum(count)])
    for k0, k1 in slabs[:-1]:
        z0, z1 = max(0, k0 - 1 - halo), min(len(count), k1 + 1 + halo)
        kernel = int(prefix[z1] - prefix[z0]) * label_blocks.NET_BYTES_PER_VERTEX
        assert kernel <= budget // 2 or k1 - k0 == halo
    _same(label_surfaces(Volume(data.T), smoothing=0), got)  # (in memory: no slab)
    # not counted where that is not wanted: no budget, a given slab size, a cluster
    # (whose workers read the slabs; here the client would read the whole volume)
    for blocks in (Blocks(), Blocks(size=8, max_memory=budget),
                   Blocks(max_memory=budget, scheduler="tcp://127.0.0.1:1")):  # fmt: skip
        assert not label_blocks.wants_net_estimate(volume, blocks)
    assert not label_blocks.wants_net_estimate(Volume(data.T), Blocks(max_memory=budget))
    # a budget its net fits: one piece, as before
    slabs.clear()
    label_surfaces(volume, smoothing=0, blocks=Blocks(max_memory=1 << 30))
    assert slabs == []


def test_bad_label_volumes_in_slabs_fail_in_one_line():
    data = np.zeros((5, 5, 30), np.float32)
    data[1:3, 1:3, 2:5] = 1
    data[2, 2, 25] = 0.5  # in the last slab
    with pytest.raises(VolumeError, match=r"not whole numbers") as info:
        label_surfaces(Volume(data), blocks=Blocks(size=4))
    assert "\n" not in str(info.value) and "z-layers" in str(info.value)
    data[2, 2, 25] = 1
    with pytest.raises(VolumeError, match=r"label 4 not in the volume; labels present: 1"):
        label_surfaces(Volume(data), labels=[4], blocks=Blocks(size=4))
    with pytest.raises(LevelError, match="every sample is background"):
        label_surfaces(Volume(np.zeros((4, 4, 12), np.uint8)), blocks=Blocks(size=4))


def _cli(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "isoconvert", *map(str, args)],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_real_scan_files_and_layers_are_byte_identical(tmp_path):
    """The bat cochlea's label surface, as PLY files and as a Neuroglancer layer with
    its voxels and two levels of detail: the same bytes with and without slabs."""
    scan = dataset("bat-cochlea-volume.tif")
    for name, extra in [("whole", []), ("slabs", ["--block-size", 16])]:
        ply = _cli("convert", scan, "--labels", "-o", f"{name}.ply", *extra, cwd=tmp_path)
        assert ply.returncode == 0, ply.stderr
        layer = _cli(
            "convert", scan, "--labels", "-o", f"{name}_layer", "--format", "precomputed",
            "--lods", 2, "--with-volume", *extra, cwd=tmp_path,
        )  # fmt: skip
        assert layer.returncode == 0, layer.stderr
    whole = (tmp_path / "whole_label255.ply").read_bytes()
    assert len(whole) > 100_000
    assert (tmp_path / "slabs_label255.ply").read_bytes() == whole
    files = _files(tmp_path / "whole_layer")
    assert len(files) >= 4 and "mesh/255.index" in files
    assert _files(tmp_path / "slabs_layer") == files


@pytest.mark.parametrize("iterations", [0, 3])
def test_slabs_over_a_quarter_of_the_budget_wait_on_disk_and_merge_the_same(
    tmp_path, monkeypatch, iterations
):
    """Past a quarter of --max-memory the slabs' merge-only arrays go to nameless
    files in the spill folder: the net is still the in-memory one, bit for bit,
    they were read back from disk (not kept), and nothing is left in the folder."""
    rng = np.random.default_rng(5)
    volume = Volume(_labels(rng, (9, 8, 30), 4, False), spacing=(0.5, 1.0, 2.0), origin=(1, 2, 3))
    reference = label_surfaces(volume, smoothing=iterations)
    spilled = []
    original = label_blocks.LabelSlab.spill

    def spill(self, folder):
        original(self, folder)
        assert all(getattr(self, name) is None for name in label_blocks.SPILLED)
        spilled.append(folder)

    monkeypatch.setattr(label_blocks.LabelSlab, "spill", spill)
    blocks = Blocks(size=3, max_memory=4096, spill_dir=tmp_path)
    tight = label_surfaces(volume, smoothing=iterations, blocks=blocks)
    _same(reference, tight)
    assert len(spilled) >= 5 and set(spilled) == {tmp_path}
    # the merged net, past its quarter too, lives in file-backed maps
    net = tight._net
    for array in (net.corners, net.vertices, tight.dual_cells, tight._quad_labels):
        assert _file_map(array) is not None
    assert list(tmp_path.iterdir()) == []  # the files had no names (and go with the maps)
    # within a budget that holds them, nothing is spilled, and the net is in memory
    spilled.clear()
    roomy = Blocks(size=3, max_memory=1 << 30, spill_dir=tmp_path)
    held = label_surfaces(volume, smoothing=iterations, blocks=roomy)
    _same(reference, held)
    assert spilled == [] and _file_map(held._net.corners) is None


def test_label_slabs_are_read_in_the_narrowest_type(tmp_path, monkeypatch):
    """A uint32 file of labels 0..3 is meshed from uint8 slabs (a quarter of the
    memory), one with a value past 255 from uint16: the net is the same."""
    rng = np.random.default_rng(8)
    data = _labels(rng, (90, 12, 14), 3, True).astype(np.uint32)  # (Z, Y, X) in the file
    wide = data.copy()
    wide[70, 5, 5] = 300  # in a later slab, past uint8 after the first pieces
    seen = _slabs_built(monkeypatch, lambda job, zyx: (job.z0, zyx.dtype))
    for name, labels in (("narrow", data), ("wide", wide)):
        np.save(tmp_path / f"{name}.npy", labels)
        seen.clear()
        blocks = Blocks(size=20, max_memory=1 << 30)
        got = label_surfaces(read_volume(tmp_path / f"{name}.npy"), smoothing=2, blocks=blocks)
        _same(label_surfaces(Volume(labels.T), smoothing=2), got)
        types = {dtype for _, dtype in seen}
        if name == "narrow":
            assert types == {np.dtype(np.uint8)}
        else:  # the slabs holding z = 70 in uint16 (the file's type is never needed)
            assert types == {np.dtype(np.uint8), np.dtype(np.uint16)}
            assert all((dtype == np.uint16) == (z0 <= 70) for z0, dtype in seen if z0 > 40)


@pytest.mark.parametrize(
    "values, background, expected",
    [
        ([0, 7, 255], 0, np.uint8),
        ([0, 7, 256], 0, np.uint16),  # widened when a later piece needs it
        ([-3, 100], 0, np.int8),
        ([0, 40], -1, np.int8),  # the background must fit too
        ([0, 40], 70000, np.uint32),  # nothing narrower holds it
        ([-40000, 1], 0, np.int32),
    ],
)
def test_narrowed_layers_pick_the_narrowest_type_that_holds_every_value(
    values, background, expected
):
    stored = np.int32 if min(values) < 0 else np.uint32
    zyx = np.zeros((20, 3, 4), stored)
    zyx[15, 1, 2] = values[-1]  # in the last piece of 8 layers
    zyx[2, 0, 0] = values[0]
    zyx[9, 2, 3] = values[1]
    reads = []

    def read(a, b):
        reads.append((a, b))
        return zyx[a:b]

    out = narrowed_layers(read, 1, 19, background)
    assert out.dtype == expected
    assert np.array_equal(out, zyx[1:19]) and reads == [(1, 9), (9, 17), (17, 19)]
    # floats and one-byte labels are what a read of the whole range gives
    for same in (zyx.astype(np.float32), zyx.astype(np.int8)):
        whole = narrowed_layers(lambda a, b, same=same: same[a:b], 0, 20, 0)
        assert whole.dtype == same.dtype and np.shares_memory(whole, same)
        assert whole.shape == same.shape


def test_a_spill_folder_that_cannot_take_files_is_one_error(tmp_path):
    volume = Volume(_labels(np.random.default_rng(2), (6, 6, 20), 3, False))
    missing = tmp_path / "gone"
    with pytest.raises(IsoconvertError, match="cannot make a temporary file there"):
        label_surfaces(volume, smoothing=0, blocks=Blocks(size=3, max_memory=1024,
                                                          spill_dir=missing))  # fmt: skip


def test_a_label_layer_twice_the_budget_stays_within_it(tmp_path):
    """A 512 MiB uint32 label volume (six balls, some touching) to a one-level layer
    within --max-memory 128M: the peak stays under what the same command needs for a tiny
    volume plus the budget plus 16 MiB (as for isosurfaces, tests/test_blocks.py),
    with the slabs read in one byte a sample and the merged net on disk; the layer
    is the in-memory one's bytes."""
    n, nz = 512, 512
    centres = [(150, 150, 130, 90), (330, 150, 130, 90), (256, 360, 260, 100),
               (150, 150, 380, 80), (330, 330, 400, 70), (256, 256, 256, 40)]  # fmt: skip
    y, x = np.meshgrid(np.arange(n, dtype=np.float32), np.arange(n, dtype=np.float32),
                       indexing="ij")  # fmt: skip
    path = tmp_path / "balls.npy"
    with open(path, "wb") as fh:  # (Z, Y, X) in the file, written a layer at a time
        np.lib.format.write_array_header_1_0(
            fh, {"descr": "<u4", "fortran_order": False, "shape": (nz, n, n)}
        )
        for z in range(nz):
            layer = np.zeros((n, n), np.uint32)
            for label, (cx, cy, cz, r) in enumerate(centres, start=1):
                layer[(x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 < r * r] = label
            fh.write(layer.tobytes())
    tiny = tmp_path / "tiny.npy"
    np.save(tiny, np.pad(np.ones((4, 4, 4), np.uint32), 2))
    # one level: coarser ones are decimated an object at a time, whole (not bounded
    # by the budget: about 500 bytes a triangle; see the README)
    common = ["--labels", "--format", "precomputed", "--lods", "1", "-q"]
    small = cli_peak_mib("convert", tiny, *common, "-o", tmp_path / "tiny_layer")
    big = cli_peak_mib("convert", path, *common, "--max-memory", "128M", "-o", tmp_path / "within")
    assert big < small + 128 + 16, (small, big)
    whole = _cli("convert", path, *common, "-o", tmp_path / "whole", cwd=tmp_path)
    assert whole.returncode == 0, whole.stderr
    files = _files(tmp_path / "whole")
    assert len(files) == 1 + 1 + 2 * len(centres)  # info, mesh/info, a manifest and fragments each
    assert _files(tmp_path / "within") == files


def test_within_the_budget_a_layers_objects_are_encoded_one_at_a_time(tmp_path, monkeypatch):
    """Each object encoded holds its coarser levels' collapses (about 500 bytes a
    triangle): within --max-memory one object at a time, else side by side on
    the kernels' threads; the same bytes either way, for labels and for levels."""
    pytest.importorskip("DracoPy")
    pytest.importorskip("meshoptimizer")
    from isoconvert.cli import main
    from isoconvert.writers.precomputed import layer as precomputed

    monkeypatch.setenv("ISOCONVERT_THREADS", "2")
    at_once = []
    original = precomputed.threaded_in_order

    def recording(function, arguments, threads):
        at_once.append(threads)
        return original(function, arguments, threads)

    monkeypatch.setattr(precomputed, "threaded_in_order", recording)
    labels = np.zeros((24, 20, 22), np.uint16)
    labels[3:12, 4:15, 3:18], labels[12:21, 5:16, 6:19] = 1, 2  # two boxes, touching
    np.save(tmp_path / "labels.npy", labels)
    layer = ["--format", "precomputed", "--lods", "2", "-q"]
    for kind in (["--labels"], ["--level", "1.5"]):
        made = {}
        for budget in ([], ["--max-memory", "64M"]):
            at_once.clear()
            out = tmp_path / f"{kind[0]}{len(budget)}"
            code = main(["convert", str(tmp_path / "labels.npy"), *kind, *layer, *budget,
                         "-o", str(out)])  # fmt: skip
            assert code == 0
            assert at_once == ([1] if budget else [2])
            made[bool(budget)] = _files(out)
        assert made[True] == made[False]
