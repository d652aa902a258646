"""Rows of a mesh array a block at a time, for writers.

The helpers live in the model layer (:mod:`isoconvert.memory`), which block-wise
extraction uses too; they are offered here under their old names for the
writers and for code that imported them from here.
"""

from __future__ import annotations

from ..memory import ROWS, release, row_chunks

__all__ = ["ROWS", "release", "row_chunks"]
