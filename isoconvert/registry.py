"""A small name -> object table, used for readers, writers and extractors."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

from .errors import FormatError, IsoconvertError
from .lazy import import_target

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

T = TypeVar("T")


@dataclass(frozen=True)
class Declared:
    """A built-in entry known by name before it is imported (see :meth:`Registry.declare`).

    Attributes
    ----------
    target : str
        ``"package.module:attribute"`` of the entry.
    summary : str
        One line for listings, as the entry's own ``summary``.
    suffixes : tuple of str
        File suffixes it claims, as the entry's own ``suffixes``.
    """

    target: str
    summary: str
    suffixes: tuple[str, ...] = ()


class Registry(Generic[T]):
    """An ordered table of built-ins of one kind (e.g. "output format").

    Built-ins are either registered as objects or declared by name, summary
    and target, and imported on first :meth:`get`: listing the names and the
    summaries (the CLI's help) then imports none of them.

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
        # built-ins (objects, or Declared until first used), then loaded plugins
        self._entries: dict[str, T | Declared] = {}
        self._plugins: dict[str, EntryPoint] | None = None

    def register(self, name: str, entry: T) -> None:
        """Add a built-in ``entry`` under ``name``."""
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._entries[name] = entry

    def declare(
        self, name: str, target: str, *, summary: str, suffixes: tuple[str, ...] = ()
    ) -> None:
        """Add a built-in by name, imported from ``target`` when first used.

        Parameters
        ----------
        name : str
        target : str
            ``"package.module:attribute"`` of the entry.
        summary : str
            What :meth:`summary` says before the entry is imported; the
            entry's own ``summary`` should say the same.
        suffixes : tuple of str
            The suffixes :meth:`by_suffix` matches before the entry is imported.
        """
        self.register(name, Declared(target, summary, tuple(suffixes)))  # type: ignore[arg-type]

    def _plugin_points(self) -> dict[str, EntryPoint]:
        if self._plugins is None:
            self._plugins = {}
            if self.plugin_group:
                # importlib.metadata costs ~30 ms to import: only registries with plugins pay
                from importlib.metadata import entry_points

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
            entry = self._entries[key]
            if isinstance(entry, Declared):
                # a built-in that fails to import is a bug of ours: no one-line message
                entry = self._entries[key] = import_target(entry.target)
            return entry  # type: ignore[return-value]
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

    def summary(self, name: str) -> str:
        """The one-line summary of ``name``, importing only a plugin (built-ins say it).

        Raises
        ------
        IsoconvertError
            ``name`` is unknown, or a plugin that fails to load.
        """
        entry = self._entries.get(name.lower())
        if isinstance(entry, Declared):
            return entry.summary
        return getattr(self.get(name), "summary", "")

    def names(self) -> list[str]:
        """Built-in names in order, then the plugins' (not loaded)."""
        return list(self._entries) + [n for n in self._plugin_points() if n not in self._entries]

    def items(self) -> Iterator[tuple[str, T]]:
        """Built-ins (imported now where declared) and already loaded plugins;
        :meth:`get` loads the others."""
        return iter([(name, self.get(name)) for name in list(self._entries)])

    def by_suffix(self, suffix: str) -> tuple[str, T] | None:
        """The first entry whose ``suffixes`` include ``suffix`` (readers, writers)."""
        for name, entry in list(self._entries.items()):
            if suffix.lower() in getattr(entry, "suffixes", ()):
                return name, self.get(name)
        return None

    def suffix_listing(self) -> str:
        """``"ply (.ply), obj (.obj)"``: the entries and their suffixes, for messages
        (an entry no suffix names, such as a folder format, by its name alone:
        ``--format`` gives it)."""

        def listed(name: str, entry: T) -> str:
            suffixes = " ".join(getattr(entry, "suffixes", ()))
            return f"{name} ({suffixes})" if suffixes else f"{name} (--format {name})"

        return ", ".join(listed(n, e) for n, e in self._entries.items())

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name.lower() in self.names()
