"""Options a reader may take, in one place so every reader has one signature."""

from __future__ import annotations

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
        Formats with companion files (a detached NRRD header and its data
        files): read data files that resolve, after following symlinks, outside
        the header's folder and its sub-folders. Off by default, so that a
        header from an untrusted source cannot make the tool read any file on
        the machine.
    """

    shape: tuple[int, ...] | None = None
    dtype: str | None = None
    endian: str = "little"
    header_bytes: int = 0
    channel: int | None = None
    allow_outside_data: bool = False

    def given(self) -> set[str]:
        """Names of the options that differ from their defaults."""
        default = ReadOptions()
        return {f.name for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)}


def select_channel(
    array: np.ndarray, axis: int | None, channel: int | None, path: Path, what: str
) -> np.ndarray:
    """Take ``channel`` along ``axis`` (the channel axis, or None when there is none).

    ``what`` names the channels in messages ("values per sample (vector)").
    """
    if axis is None:
        if channel is not None:
            raise VolumeError(f"{path}: --channel given, but the file has one value per sample")
        return array
    n = array.shape[axis]
    if channel is None:
        raise VolumeError(f"{path}: {n} {what}; choose one with --channel 0..{n - 1}")
    if not 0 <= channel < n:
        raise VolumeError(f"{path}: --channel {channel} is out of range 0..{n - 1}")
    # the method np.take calls: ReadOptions users (the CLI) need not import numpy
    return array.take(channel, axis=axis)
