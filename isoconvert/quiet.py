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
    global _silenced
    _silenced = True
    _drop("tifffile")  # its warnings about odd files
    silence_distributed()


#: Whether :func:`silence_third_party` ran in this process.
_silenced = False


def _drop(name: str) -> None:
    """Give logger ``name`` only a handler that drops everything."""
    log = logging.getLogger(name)
    log.handlers[:] = [logging.NullHandler()]
    log.propagate = False


def silence_distributed() -> None:
    """Drop a Dask client's log lines (lost connections, rescheduled keys: isoconvert
    turns what matters into one-line errors), when :func:`silence_third_party`
    ran. Called again once ``distributed`` is imported, which sets up handlers
    of its own."""
    if _silenced:
        _drop("distributed")
