"""Fast text output of numeric rows, shared by the ASCII writers."""

from __future__ import annotations

from typing import BinaryIO

import numpy as np

from .chunks import row_chunks

# Rows formatted per call: one %-format over a whole block is C speed, unlike a
# Python loop (np.savetxt) per row, and bounds the size of the temporary string.
_BLOCK = 65536


def write_rows(
    fh: BinaryIO, rows: np.ndarray, row_format: str, *, dtype=None, add: int = 0
) -> None:
    """Write each row of ``rows`` (N, k) with ``row_format`` (k % fields, ending in newline).

    Parameters
    ----------
    fh : binary file
    rows : (N, k) array
    row_format : str
    dtype : numpy dtype or None
        Convert each block to this type first (e.g. float32, to print its digits).
    add : int
        Added to every value first (1-based indices).
    """
    for block in row_chunks(rows, _BLOCK):
        if dtype is not None:
            block = block.astype(dtype)
        if add:
            block = block + add
        fh.write(((row_format * len(block)) % tuple(block.ravel().tolist())).encode("ascii"))
