"""The former home of the Dask engine, kept for the names code and tests import from it.

The engine now lives in the task runner, below both of its users (issue 21):

* :mod:`isoconvert.runner.dask`: connecting to a scheduler, shipping tasks,
  gathering their results, retries, progress (``connect``, ``close_clients``,
  ``scheduler_address``, ``connect_timeout``, ``cluster_threads``,
  ``window_size``, ``SCHEDULER_ENV``, ``TIMEOUT_ENV``, ``DEFAULT_TIMEOUT``);
* :mod:`isoconvert.runner.tasks`: ``TaskFailure`` and ``worker_threads``;
* :mod:`isoconvert.extract.slabs`: the slabs of a volume as tasks
  (``dask_runner``);
* :mod:`isoconvert.extract.blocks`: a slab's isosurface (``extract_slab``);
* :mod:`isoconvert.batch`: the files of a batch as tasks (``run_on_cluster``).

Every name is looked up in those modules on use, and assigning one here
(``monkeypatch.setattr(isoconvert.distributed, "dask_runner", ...)``) assigns it
in the module that defines and uses it. Nothing in the package imports this
module: it sits above every layer, beside the CLI.
"""

from __future__ import annotations

import sys
import types
from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .batch import run_on_cluster
    from .extract.blocks import extract_slab
    from .extract.slabs import dask_runner
    from .runner.dask import (
        DEFAULT_TIMEOUT,
        SCHEDULER_ENV,
        TIMEOUT_ENV,
        close_clients,
        cluster_threads,
        connect,
        connect_timeout,
        scheduler_address,
        window_size,
    )
    from .runner.tasks import TaskFailure, worker_threads

#: Where the names live, searched in this order.
_HOMES = (
    "isoconvert.runner.dask",
    "isoconvert.runner.tasks",
    "isoconvert.extract.slabs",
    "isoconvert.extract.blocks",
    "isoconvert.batch",
)

__all__ = [
    "DEFAULT_TIMEOUT",
    "SCHEDULER_ENV",
    "TIMEOUT_ENV",
    "TaskFailure",
    "close_clients",
    "cluster_threads",
    "connect",
    "connect_timeout",
    "dask_runner",
    "extract_slab",
    "run_on_cluster",
    "scheduler_address",
    "window_size",
    "worker_threads",
]


def _home(name: str) -> types.ModuleType | None:
    """The module that defines ``name`` (its own attribute, not one imported
    there); found once, so that it stays the home while the name is patched."""
    if name not in _found:
        _found[name] = _search(name)
    return _found[name]


_found: dict[str, types.ModuleType | None] = {}


def _search(name: str) -> types.ModuleType | None:
    for home in _HOMES:
        module = import_module(home)
        value = vars(module).get(name, _MISSING)
        if value is _MISSING or isinstance(value, types.ModuleType):
            continue
        if getattr(value, "__module__", home) == home:  # not one it imported
            return module
    return None


_MISSING = object()


def __getattr__(name: str) -> Any:
    home = _home(name) if not name.startswith("__") else None
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(home, name)
    globals()[name] = value  # later look-ups are plain attribute reads
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


#: The homes' own values of the names assigned here, restored when deleted here.
_originals: dict[str, Any] = {}


class _Forwarding(types.ModuleType):
    """Assignments to a public or private name of the engine reach its home
    (and deleting it here restores the home's own value)."""

    def __setattr__(self, name: str, value: object) -> None:
        home = _home(name) if not name.startswith("__") else None
        if home is not None:
            _originals.setdefault(name, getattr(home, name))
            setattr(home, name, value)
        super().__setattr__(name, value)

    def __delattr__(self, name: str) -> None:
        home = _home(name) if not name.startswith("__") else None
        if home is not None and name in _originals:
            setattr(home, name, _originals.pop(name))
        if name in vars(self):
            super().__delattr__(name)


sys.modules[__name__].__class__ = _Forwarding
