"""The labels' own voxels in a Neuroglancer precomputed segmentation layer (``--with-volume``).

A precomputed volume is cut into chunks of ``CHUNK`` voxels a side (smaller at its upper
edges), each a file named ``x0-x1_y0-y1_z0-z1`` in the scale's folder, here encoded as
Neuroglancer's ``compressed_segmentation`` (volume.md; the format of
``sliceview/compressed_segmentation/README.md``): the chunk is split into blocks of
``BLOCK`` voxels a side, padded at its upper edges with a value of the block, and each
block is stored as a lookup table of its distinct labels and, per voxel, the index of
its label in 0, 1, 2, 4, 8, 16 or 32 bits, packed into little-endian 32-bit words. It
is lossless and lets the viewer keep chunks compressed in GPU memory; segmentations
compress 10-100 fold. The format holds uint32 or uint64 labels only.

The chunks are read from the volume one slab of ``CHUNK`` z layers at a time, so a
file-backed volume is never in memory whole.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import IsoconvertError
from ...grid import grid_slab_zyx
from ...volume import Volume

#: Voxels a side of a chunk file.
CHUNK = 64
#: Voxels a side of a compressed_segmentation block.
BLOCK = 8
#: Bits per voxel the encoding allows, smallest first.
_BITS = (0, 1, 2, 4, 8, 16, 32)


def volume_data_type(largest: int) -> str:
    """The precomputed type of labels up to ``largest`` in this encoding (uint32 or uint64)."""
    return "uint32" if largest <= np.iinfo(np.uint32).max else "uint64"


def volume_scale(size: list[int], resolution: list[float]) -> dict:
    """The ``scales`` entry of the layer's ``info`` for chunks written by :func:`write_chunks`."""
    return {
        "key": "_".join(f"{r:g}" for r in resolution),
        "size": [int(s) for s in size],
        "resolution": [float(r) for r in resolution],
        "voxel_offset": [0, 0, 0],
        "chunk_sizes": [[CHUNK, CHUNK, CHUNK]],
        "encoding": "compressed_segmentation",
        "compressed_segmentation_block_size": [BLOCK, BLOCK, BLOCK],
    }


def write_chunks(folder: Path, volume: Volume, background: int, data_type: str) -> int:
    """Write the labels of ``volume`` as compressed_segmentation chunks into ``folder``.

    Parameters
    ----------
    folder : Path
        The scale's folder (created).
    volume : Volume
        3D label volume; ``background`` samples are stored as 0, Neuroglancer's "no
        segment", every other sample as its label.
    background : int
        The volume's background label.
    data_type : str
        uint32 or uint64 (:func:`volume_data_type` of the largest label).

    Returns
    -------
    int
        Bytes written.

    Raises
    ------
    IsoconvertError
        A negative label, or a label 0 while the background is another value (it would
        read as "no segment").
    """
    folder.mkdir()
    dtype = np.dtype(data_type).newbyteorder("<")
    nx, ny, nz = volume.shape
    written = 0
    for z0 in range(0, nz, CHUNK):
        z1 = min(nz, z0 + CHUNK)
        slab = _labels(grid_slab_zyx(volume.samples, z0, z1), background, dtype, volume.source)
        for y0 in range(0, ny, CHUNK):
            y1 = min(ny, y0 + CHUNK)
            for x0 in range(0, nx, CHUNK):
                x1 = min(nx, x0 + CHUNK)
                data = compressed_segmentation(slab[:, y0:y1, x0:x1])
                (folder / f"{x0}-{x1}_{y0}-{y1}_{z0}-{z1}").write_bytes(data)
                written += len(data)
    return written


def _labels(zyx: np.ndarray, background: int, dtype: np.dtype, source: str) -> np.ndarray:
    """A slab's samples as stored labels: background as 0, in ``dtype``."""
    if background != 0:
        if (zyx == 0).any():
            raise IsoconvertError(
                f"{source}: label 0 would read as no segment in Neuroglancer, with "
                f"--background {background}: leave out --with-volume, or relabel 0"
            )
        zyx = np.where(zyx == background, 0, zyx)
    if zyx.size and zyx.min() < 0:
        raise IsoconvertError(
            f"{source}: label {zyx.min()} is negative; a precomputed segmentation holds "
            "labels 0 and up: leave out --with-volume, or shift the labels"
        )
    return np.ascontiguousarray(zyx).astype(dtype, copy=False)


def compressed_segmentation(chunk: np.ndarray, block: int = BLOCK) -> bytes:
    """One chunk in Neuroglancer's compressed_segmentation encoding, one channel.

    Parameters
    ----------
    chunk : (Z, Y, X) uint32 or uint64
        The chunk's labels, x fastest (C order of z, y, x).
    block : int
        Voxels a side of a block.

    Returns
    -------
    bytes
        The channel offset (one word: 1), then the channel's data: a 64-bit header per
        block (lookup table offset in 24 bits, bits per voxel in 8, encoded values
        offset in 32; offsets in 32-bit words from the channel's start), then each
        block's encoded values followed by its lookup table.
    """
    if chunk.dtype not in (np.uint32, np.uint64):
        raise ValueError(f"compressed_segmentation holds uint32 or uint64, not {chunk.dtype}")
    words_per_value = chunk.dtype.itemsize // 4
    nz, ny, nx = chunk.shape
    gz, gy, gx = -(-nz // block), -(-ny // block), -(-nx // block)
    # padded at the upper edges with the edge voxels' labels: no new value in a block
    padded = np.pad(chunk, ((0, gz * block - nz), (0, gy * block - ny), (0, gx * block - nx)),
                    mode="edge")  # fmt: skip
    # blocks in x-fastest grid order, each block's voxels in x-fastest order
    blocks = (
        padded.reshape(gz, block, gy, block, gx, block)
        .transpose(0, 2, 4, 1, 3, 5)
        .reshape(gz * gy * gx, block**3)
    )
    n_blocks, size = blocks.shape
    # each block's lookup table is its sorted distinct labels, a voxel's code the rank
    # of its label there; most blocks of a segmentation hold one label (code 0, no
    # bits), the others are sorted once, their runs numbered and scattered back
    mixed = np.flatnonzero(blocks.min(axis=1) != blocks.max(axis=1))
    order = np.argsort(blocks[mixed], axis=1, kind="stable")
    ranked = np.take_along_axis(blocks[mixed], order, axis=1)
    first = np.ones(ranked.shape, dtype=bool)
    first[:, 1:] = ranked[:, 1:] != ranked[:, :-1]
    codes = np.empty(ranked.shape, dtype=np.uint32)
    np.put_along_axis(codes, order, (np.cumsum(first, axis=1) - 1).astype(np.uint32), axis=1)
    counts = np.ones(n_blocks, dtype=np.int64)
    counts[mixed] = first.sum(axis=1)
    allowed = np.array(_BITS)
    bits = allowed[np.searchsorted(allowed, np.ceil(np.log2(counts)))]
    encoded_words = size * bits // 32
    table_words = counts * words_per_value
    starts = 2 * n_blocks + np.concatenate([[0], np.cumsum(encoded_words + table_words)[:-1]])
    tables = starts + encoded_words
    if n_blocks and tables[-1] >= 1 << 24:
        raise ValueError("compressed_segmentation: a chunk beyond 2**24 words")
    out = np.zeros(2 * n_blocks + int((encoded_words + table_words).sum()), dtype="<u4")
    out[0 : 2 * n_blocks : 2] = tables | (bits << 24)  # the lookup table offset, the bits
    out[1 : 2 * n_blocks : 2] = starts  # the encoded values' offset
    for b in np.unique(bits[mixed]):  # blocks of one width together
        rows = np.flatnonzero(bits[mixed] == b)
        width = size * int(b) // 32
        out[starts[mixed[rows], None] + np.arange(width)] = _pack(codes[rows], int(b))
    # the tables (uint64 labels as two little-endian words, low first)
    little = chunk.dtype.newbyteorder("<")
    uniform = np.setdiff1d(np.arange(n_blocks), mixed, assume_unique=True)
    single = blocks[uniform, 0].astype(little).view("<u4")
    several = ranked[first].astype(little).view("<u4")
    mixed_counts = counts[mixed]
    within = np.arange(int(mixed_counts.sum())) - np.repeat(
        np.cumsum(mixed_counts) - mixed_counts, mixed_counts
    )
    at = np.repeat(tables[mixed], mixed_counts) + within * words_per_value
    for word in range(words_per_value):
        out[tables[uniform] + word] = single[word::words_per_value]
        out[at + word] = several[word::words_per_value]
    return np.array([1], dtype="<u4").tobytes() + out.tobytes()


def _pack(codes: np.ndarray, bits: int) -> np.ndarray:
    """(R, N) codes below 2**bits packed ``32 // bits`` to a little-endian word, the
    first in the lowest bits: (R, N * bits / 32) words."""
    per = 32 // bits
    shifts = np.arange(per, dtype=np.uint64) * np.uint64(bits)
    grouped = codes.reshape(len(codes), -1, per).astype(np.uint64) << shifts
    return grouped.sum(axis=2).astype("<u4")


__all__ = ["BLOCK", "CHUNK", "compressed_segmentation", "volume_data_type", "write_chunks"]
