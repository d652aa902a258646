"""Stacks of slices: which files are TIFF slices, and their natural order.

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
