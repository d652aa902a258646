"""Options a reader may take, in one place so every reader has one signature."""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import VolumeError

if TYPE_CHECKING:
    import numpy as np


@dataclass(frozen=True)
class ReadOptions:
    """What the user said about an input beyond its path.

    Attributes
    ----------
    shape : tuple of int or None
        Raw files: samples along (x, y) or (x, y, z).
    dtype : str or None
        Raw files: sample type name (uint8, int16, float32, ...).
    endian : str
        Raw files: "little" or "big".
    header_bytes : int
        Raw files: bytes to skip before the samples.
    channel : int or None
        Multi-channel (RGB, multi-sample) images: which channel to read.
    allow_outside_data : bool
        Formats with companion files (a detached NRRD header or a MetaImage
        ``.mhd``, and their data files): read data files that resolve, after
        following symlinks, outside the header's folder and its sub-folders.
        Off by default, so that a header from an untrusted source cannot make
        the tool read any file on the machine.
    scale : int
        Multi-resolution inputs (OME-Zarr): the resolution level to read, 0
        being the full resolution.
    allow_missing_chunks : bool
        Zarr: read a chunk missing from the store as the array's fill value,
        as zarr itself does. Off by default, because a missing chunk usually
        means an incomplete copy; some writers (zarr-python 3 by default) skip
        chunks that hold only the fill value, and their stores need this.
    key : str or None
        NumPy ``.npz`` archives holding several arrays: the name of the one to
        read (not needed when the archive holds one array).
    volume_index : int or None
        4D images (NIfTI time series): the volume to read, 0 being the first.
    series : str or None
        DICOM folders holding several series: the SeriesInstanceUID of the one
        to read.
    """

    shape: tuple[int, ...] | None = None
    dtype: str | None = None
    endian: str = "little"
    header_bytes: int = 0
    channel: int | None = None
    allow_outside_data: bool = False
    scale: int = 0
    allow_missing_chunks: bool = False
    key: str | None = None
    volume_index: int | None = None
    series: str | None = None

    def given(self) -> set[str]:
        """Names of the options that differ from their defaults."""
        default = ReadOptions()
        return {f.name for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)}


class PlacementNote(str):
    """A reader's note about the spacing or origin of a volume (missing from the file,
    ignored as unusable, or where it came from), which the user may set instead.

    :func:`~isoconvert.readers.read_volume` drops it when they do
    (``--spacing``, ``--origin``): "no spacing in the file; set --spacing" is no
    longer true once they have. A ``str`` like any other note.

    Attributes
    ----------
    about : frozenset of str
        What the note is about, "spacing" and/or "origin": the note goes when
        every one of them is set by the user.
    """

    about: frozenset[str]

    def __new__(cls, text: str, about: str = "spacing") -> PlacementNote:
        note = super().__new__(cls, text)
        note.about = frozenset(about.split())
        return note

    def __reduce__(self):
        return (PlacementNote, (str(self), " ".join(sorted(self.about))))


def spacing_note(text: str) -> PlacementNote:
    """A note about the spacing alone (see :class:`PlacementNote`)."""
    return PlacementNote(text, "spacing")


def origin_note(text: str) -> PlacementNote:
    """A note about the origin alone (see :class:`PlacementNote`)."""
    return PlacementNote(text, "origin")


def without_overridden(notes: list[str], given: set[str]) -> list[str]:
    """``notes`` less the :class:`PlacementNote` s about only what the user set
    (``given``: "spacing", "origin")."""
    return [n for n in notes if not (isinstance(n, PlacementNote) and n.about <= given)]


def absolute_files(paths: Iterable[str | Path]) -> tuple[str, ...]:
    """The files a volume is read from, for :attr:`Volume.files`: absolute, in order,
    each once.

    Made absolute against the working folder but not resolved through symlinks
    (``os.path.abspath``): the name a user gave stays recognisable, and whoever
    compares files compares their device and inode.
    """
    return tuple(dict.fromkeys(os.path.abspath(os.fspath(p)) for p in paths))


def check_channel(count: int | None, channel: int | None, path: Path, what: str) -> int | None:
    """The channel to read of ``count`` (None: the file has no channel axis).

    For readers that decide from headers, before reading any sample. ``what``
    names the channels in messages ("values per sample (vector)").

    Raises
    ------
    VolumeError
        ``channel`` given without a channel axis, missing with one, or out of range.
    """
    if count is None:
        if channel is not None:
            raise VolumeError(f"{path}: --channel given, but the file has one value per sample")
        return None
    if channel is None:
        raise VolumeError(f"{path}: {count} {what}; choose one with --channel 0..{count - 1}")
    if not 0 <= channel < count:
        raise VolumeError(f"{path}: --channel {channel} is out of range 0..{count - 1}")
    return channel


def select_channel(
    array: np.ndarray, axis: int | None, channel: int | None, path: Path, what: str
) -> np.ndarray:
    """Take ``channel`` along ``axis`` (the channel axis, or None when there is none).

    ``what`` names the channels in messages ("values per sample (vector)");
    the checks are :func:`check_channel`'s.
    """
    count = None if axis is None else array.shape[axis]
    index = check_channel(count, channel, path, what)
    # the method np.take calls: ReadOptions users (the CLI) need not import numpy
    return array if index is None else array.take(index, axis=axis)
