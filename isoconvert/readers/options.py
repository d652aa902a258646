"""Options a reader may take, in one place so every reader has one signature."""

from __future__ import annotations

from dataclasses import dataclass, fields


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
    """

    shape: tuple[int, ...] | None = None
    dtype: str | None = None
    endian: str = "little"
    header_bytes: int = 0
    channel: int | None = None

    def given(self) -> set[str]:
        """Names of the options that differ from their defaults."""
        default = ReadOptions()
        return {f.name for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)}
