"""Folders that are volumes: which files are TIFF slices, their natural order, and
which folders are Zarr stores.

Without numpy, so that format detection and batch discovery stay light.
"""

from __future__ import annotations

import re
from pathlib import Path

TIFF_SUFFIXES = (".tif", ".tiff")


def natural_key(path: Path) -> list:
    """Sort key putting slice2 before slice10."""
    return natural_text_key(path.name)


def natural_text_key(text: str) -> list:
    """Sort key comparing runs of digits as numbers ("a2/b" before "a10/b")."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", text)]


#: Files whose presence makes a folder a Zarr store (an array or a group), Zarr 2 and 3.
ZARR_METADATA = (".zarray", ".zgroup", ".zattrs", "zarr.json")


def is_zarr_store(path: Path) -> bool:
    """True when ``path`` is a folder holding Zarr metadata (Zarr 2 or 3): one volume,
    not a folder of slices."""
    try:
        return path.is_dir() and any((path / name).is_file() for name in ZARR_METADATA)
    except OSError:
        return False
