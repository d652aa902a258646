"""Sharded mesh folders (``neuroglancer_uint64_sharded_v1``, sharded.md).

Each object's fragment data and manifest wait in one spill file as they come
(:class:`ObjectSpill`: a layer of millions of objects does not fit in memory) and
are copied into the shard files at the end (:func:`write_shards`).
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np


def object_file(segment: int, objects: int, *, sharded: bool = False, legacy: bool = False) -> str:
    """The file of a layer's mesh folder that holds ``segment``, one of ``objects``:
    its fragments (multi-resolution), its manifest (legacy) or its shard."""
    if legacy:
        return f"{segment}:0"
    if not sharded:
        return str(segment)
    spec = sharding(objects)
    return _shard_name(_shard_of(segment, spec)[0], spec)


def sharding(objects: int) -> dict:
    """A sharding specification for ``objects`` segments: the identity hash (segment
    ids are the labels, spread over the low bits already), about 64 objects per
    minishard and 64 minishards per shard."""
    bits = max(0, int(np.ceil(np.log2(max(objects, 1) / 64))))
    minishard_bits = min(bits, 6)
    return {
        "@type": "neuroglancer_uint64_sharded_v1",
        "preshift_bits": 0,
        "hash": "identity",
        "minishard_bits": minishard_bits,
        "shard_bits": bits - minishard_bits,
        "minishard_index_encoding": "gzip",
        "data_encoding": "raw",
    }


def _shard_of(segment: int, spec: dict) -> tuple[int, int]:
    """(shard, minishard) of ``segment``: the identity hash, no preshift."""
    minishard = segment & ((1 << spec["minishard_bits"]) - 1)
    return (segment >> spec["minishard_bits"]) & ((1 << spec["shard_bits"]) - 1), minishard


def _shard_name(shard: int, spec: dict) -> str:
    digits = max(1, -(-spec["shard_bits"] // 4))
    return f"{shard:0{digits}x}.shard"


class ObjectSpill:
    """Objects' fragment data and manifests in one file, read back one at a time.

    The fragment data of an object a cluster's task wrote itself is in its own
    file of :attr:`fragments` instead, removed once read.

    Parameters
    ----------
    folder : Path
        The layer's part folder's mesh folder (so a failed run leaves nothing).
    """

    def __init__(self, folder: Path) -> None:
        self.path = folder / ".objects"
        self.fragments = folder / ".fragments"
        self.fragments.mkdir()
        self._file = open(self.path, "w+b")  # noqa: SIM115 (closed by __exit__)
        self._at = 0
        #: segment -> (offset, fragment data bytes, manifest bytes, data in fragments)
        self.sizes: dict[int, tuple[int, int, int, bool]] = {}

    def add(self, segment: int, data: bytes | int, manifest: bytes) -> None:
        """The object's bytes, or (an int) the size of those written to its file."""
        self._file.seek(self._at)
        written = isinstance(data, int)
        if not written:
            self._file.write(data)
        self._file.write(manifest)
        size = data if written else len(data)
        self.sizes[segment] = (self._at, size, len(manifest), written)
        self._at += (0 if written else size) + len(manifest)

    def read(self, segment: int) -> bytes:
        """The object's fragment data followed by its manifest."""
        at, data, manifest, written = self.sizes[segment]
        self._file.seek(at)
        if not written:
            return self._file.read(data + manifest)
        path = self.fragments / str(segment)
        fragments = path.read_bytes()
        path.unlink()
        return fragments + self._file.read(manifest)

    def __enter__(self) -> ObjectSpill:
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()
        self.path.unlink(missing_ok=True)
        shutil.rmtree(self.fragments, ignore_errors=True)


def manifest_range(folder: Path, segment: int, spec: dict) -> tuple[Path, int, int]:
    """Where :func:`write_shards` put ``segment``'s manifest: its shard file, the
    offset and the size, read from the shard and minishard indices alone."""
    shard, minishard = _shard_of(segment, spec)
    path = folder / _shard_name(shard, spec)
    header = 16 << spec["minishard_bits"]
    with open(path, "rb") as file:
        file.seek(16 * minishard)
        begin, end = np.frombuffer(file.read(16), "<u8").astype(np.int64)
        file.seek(header + int(begin))
        table = np.frombuffer(gzip.decompress(file.read(int(end - begin))), "<u8")
    ids, starts, sizes = table.reshape(3, -1).astype(np.int64)
    # ids delta-encoded, starts relative to the end of the chunk before
    ids, starts = np.cumsum(ids), np.cumsum(starts + np.r_[0, sizes[:-1]])
    at = int(np.flatnonzero(ids == segment)[0])
    return path, header + int(starts[at]), int(sizes[at])


def write_shards(folder: Path, objects: ObjectSpill, spec: dict) -> None:
    """The shard files of sharded.md: per shard, the shard index, then each object's
    fragment data followed by its manifest (the minishard index points at the
    manifest, as meshes.md asks), then the gzip-encoded minishard indices. The
    layout comes from the objects' sizes; their bytes are copied one at a time."""
    minishards = 1 << spec["minishard_bits"]
    shards: dict[int, dict[int, list[int]]] = {}
    for segment in sorted(objects.sizes):
        shard, minishard = _shard_of(segment, spec)
        shards.setdefault(shard, {}).setdefault(minishard, []).append(segment)
    for shard, by_minishard in shards.items():
        order, indices, at = [], [], 0
        for minishard in range(minishards):
            ids = by_minishard.get(minishard, [])
            starts, sizes = [], []
            for segment in ids:
                _, data, manifest, _ = objects.sizes[segment]
                order.append(segment)
                starts.append(at + data)
                sizes.append(manifest)
                at += data + manifest
            indices.append((ids, starts, sizes))
        index, tail, place = [], [], at
        for ids, starts, sizes in indices:
            if not ids:
                index.append((place, place))
                continue
            starts_, sizes_ = np.array(starts, np.int64), np.array(sizes, np.int64)
            ends = starts_ + sizes_
            # ids delta-encoded; starts relative to the end of the chunk before
            table = np.array(
                [np.diff(ids, prepend=0), starts_ - np.r_[0, ends[:-1]], sizes_], dtype="<u8"
            )
            encoded = gzip.compress(table.tobytes(), mtime=0)
            index.append((place, place + len(encoded)))
            tail.append(encoded)
            place += len(encoded)
        with open(folder / _shard_name(shard, spec), "wb") as out:
            out.write(np.array(index, dtype="<u8").tobytes())
            for segment in order:
                out.write(objects.read(segment))
            for encoded in tail:
                out.write(encoded)
