"""Code named by ``"module:attribute"`` and imported on first use.

The tables of built-in formats and methods describe their entries (names,
suffixes, summaries) without importing what runs them, so that ``isoconvert
--help`` does not pay for numpy and the readers' parsers.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any


def import_target(target: str) -> Any:
    """The object a ``"package.module:attribute"`` target names, importing its module.

    Parameters
    ----------
    target : str
        A module path and an attribute name, separated by one colon.

    Returns
    -------
    object
        ``getattr(import_module(module), attribute)``.

    Raises
    ------
    ValueError
        ``target`` has no ``":"``.
    ImportError, AttributeError
        The module or the attribute does not exist (a bug in the table that
        names it, not a user mistake).
    """
    module, sep, attribute = target.partition(":")
    if not sep or not module or not attribute:
        raise ValueError(f"expected 'package.module:attribute', got {target!r}")
    return getattr(import_module(module), attribute)


class LazyFunction:
    """A function named by ``"module:attribute"``, imported on its first call.

    Parameters
    ----------
    target : str
        Where the function is, e.g. ``"isoconvert.readers.raw:read_raw"``.

    Notes
    -----
    Pickles as its target, so an entry holding one can go to a worker process
    without importing the function first.
    """

    __slots__ = ("_function", "target")

    def __init__(self, target: str) -> None:
        if target.count(":") != 1:
            raise ValueError(f"expected 'package.module:attribute', got {target!r}")
        self.target = target
        self._function = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self._function is None:
            self._function = import_target(self.target)
        return self._function(*args, **kwargs)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, LazyFunction) and other.target == self.target

    def __hash__(self) -> int:
        return hash(self.target)

    def __repr__(self) -> str:
        return f"LazyFunction({self.target!r})"

    def __reduce__(self) -> tuple:
        return LazyFunction, (self.target,)
