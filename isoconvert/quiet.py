"""Keeping third-party noise (numpy warnings, tifffile log lines) off the user's stderr."""

from __future__ import annotations

import logging
import warnings

#: Messages numpy warns with that mean nothing to a batch user (NaN, overflow,
#: empty slices are handled or reported by isoconvert itself).
_NUMPY_MESSAGES = (
    r".*encountered in",  # divide by zero / overflow / invalid value / underflow
    r"Mean of empty slice",
    r"Degrees of freedom <= 0",
    r"All-NaN (slice|axis) encountered",
)


def silence_third_party() -> None:
    """Keep numpy's warnings and tifffile's log lines off stderr, in this process.

    Ignores warnings raised inside numpy, numpy's own warning classes and its
    floating-point RuntimeWarnings (raised at the caller's line), and gives the
    ``tifffile`` and ``distributed`` loggers a handler that drops everything
    (not passed on to the root logger). The CLI calls it (unless --debug), and
    so does every batch worker process. Safe to call more than once.
    """
    import numpy as np

    warnings.filterwarnings("ignore", module=r"numpy(\.|$)")
    for name in ("ComplexWarning", "VisibleDeprecationWarning", "RankWarning"):
        category = getattr(np.exceptions, name, None)
        if category is not None:
            warnings.filterwarnings("ignore", category=category)
    for message in _NUMPY_MESSAGES:
        warnings.filterwarnings("ignore", message=message, category=RuntimeWarning)
    # tifffile's warnings about odd files; a Dask client's about lost connections,
    # which isoconvert turns into one-line errors itself
    for name in ("tifffile", "distributed"):
        log = logging.getLogger(name)
        if not any(isinstance(h, logging.NullHandler) for h in log.handlers):
            log.addHandler(logging.NullHandler())
        log.propagate = False
