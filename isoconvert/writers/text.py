"""Fast text output of numeric rows, shared by the ASCII writers."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

# Rows formatted per call: one %-format over a whole block is C speed, unlike a
# Python loop (np.savetxt) per row, and bounds the size of the temporary string.
_BLOCK = 65536


def write_rows(fh: BinaryIO, rows: np.ndarray, row_format: str) -> None:
    """Write each row of ``rows`` (N, k) with ``row_format`` (k % fields, ending in newline)."""
    for start in range(0, len(rows), _BLOCK):
        block = rows[start : start + _BLOCK]
        fh.write(((row_format * len(block)) % tuple(block.ravel().tolist())).encode("ascii"))
