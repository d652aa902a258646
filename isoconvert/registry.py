"""A small name -> object table, used for readers, writers and extractors."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Generic, TypeVar

from .errors import FormatError

T = TypeVar("T")


class Registry(Generic[T]):
    """An ordered table of built-ins of one kind (e.g. "output format").

    Parameters
    ----------
    kind : str
        What the entries are, used in error messages ("output format").
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, T] = {}

    def register(self, name: str, entry: T) -> None:
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._entries[name] = entry

    def get(self, name: str) -> T:
        """Return the entry called ``name``; the error lists the known names."""
        try:
            return self._entries[name.lower()]
        except KeyError:
            raise FormatError(
                f"unknown {self.kind} {name!r}; choose one of: {', '.join(self.names())}"
            ) from None

    def names(self) -> list[str]:
        return list(self._entries)

    def items(self) -> Iterator[tuple[str, T]]:
        return iter(self._entries.items())

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name.lower() in self._entries
