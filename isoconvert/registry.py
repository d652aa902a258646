"""A small name -> object table, used for readers, writers and extractors."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

from .errors import FormatError, IsoconvertError

T = TypeVar("T")


class Registry(Generic[T]):
    """An ordered table of built-ins of one kind (e.g. "output format").

    Parameters
    ----------
    kind : str
        What the entries are, used in error messages ("output format").
    plugin_group : str or None
        Entry-point group whose entries are added after the built-ins, loaded
        only when first named (a broken plugin breaks only its own use).
    adapt : callable or None
        Turns a loaded plugin object into an entry, ``adapt(name, obj)``.
    """

    def __init__(
        self,
        kind: str,
        plugin_group: str | None = None,
        adapt: Callable[[str, object], T] | None = None,
    ) -> None:
        self.kind = kind
        self.plugin_group = plugin_group
        self._adapt = adapt
        self._entries: dict[str, T] = {}
        self._plugins: dict[str, EntryPoint] | None = None

    def register(self, name: str, entry: T) -> None:
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._entries[name] = entry

    def _plugin_points(self) -> dict[str, EntryPoint]:
        if self._plugins is None:
            self._plugins = {}
            if self.plugin_group:
                for ep in entry_points(group=self.plugin_group):
                    if ep.name not in self._entries:
                        self._plugins.setdefault(ep.name, ep)
        return self._plugins

    def reload_plugins(self) -> None:
        """Forget plugins found so far (after installing one in a running process)."""
        for name in list(self._plugins or {}):
            self._entries.pop(name, None)
        self._plugins = None

    def get(self, name: str) -> T:
        """Return the entry called ``name``; the error lists the known names."""
        key = name.lower()
        if key in self._entries:
            return self._entries[key]
        point = self._plugin_points().get(key)
        if point is None:
            raise FormatError(
                f"unknown {self.kind} {name!r}; choose one of: {', '.join(self.names())}"
            )
        try:
            obj = point.load()
        except Exception as exc:  # a third party's bug: report it, do not crash
            raise IsoconvertError(
                f"{self.kind} plugin {key!r} ({point.value}) failed to load: {exc}"
            ) from None
        entry = self._adapt(key, obj) if self._adapt else obj
        self._entries[key] = entry
        return entry

    def names(self) -> list[str]:
        return list(self._entries) + [n for n in self._plugin_points() if n not in self._entries]

    def items(self) -> Iterator[tuple[str, T]]:
        """Built-ins and already loaded plugins; :meth:`get` loads the others."""
        return iter(list(self._entries.items()))

    def by_suffix(self, suffix: str) -> tuple[str, T] | None:
        """The first entry whose ``suffixes`` include ``suffix`` (readers, writers)."""
        for name, entry in self._entries.items():
            if suffix.lower() in getattr(entry, "suffixes", ()):
                return name, entry
        return None

    def suffix_listing(self) -> str:
        """``"ply (.ply), obj (.obj)"``: the entries and their suffixes, for messages."""
        return ", ".join(
            f"{n} ({' '.join(getattr(e, 'suffixes', ()))})" for n, e in self._entries.items()
        )

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name.lower() in self.names()
