"""Extractors: one module per method, and the table of built-ins in `dispatch.py`.

Contract (for built-ins and plugins alike): an extractor is a function

    run(volume, level, *, flip, ambiguity, nan_as, on_status, **options) -> Mesh

that receives a :class:`~isoconvert.volume.Volume` (not yet validated: use
:func:`isoconvert.extract.prepare.kernel_array` and ``check_level``) and a float
level, and returns a :class:`~isoconvert.mesh.Mesh` with vertices ``(V, 3)`` in
world units (``volume.index_to_world``) and cells ``(C, 3)`` triangles whose
normals point from values >= level to values < level, or ``(C, 2)`` segments
with the higher values on their left. ``flip`` reverses that.

Third-party extractors register under the entry-point group
``isoconvert.extractors``: the entry point's name is the method name and it
points to an :class:`Extractor` (or to a bare ``run`` function, taken as a 3D
method described by its docstring's first line). Built-in names win.

Layering (tests/test_layers.py checks it): this package sits beside
``readers/``, ``writers/``, ``post/``, ``meshfile/`` and ``report.py``, above
the model (``volume``, ``mesh``, ``grid``, ``memory``, ``methods``, ``errors``, the
compiled kernels) and the task runner. What it shares with the writers and
the report lives in the model: the grid description a mesh records is
:func:`isoconvert.volume.grid_from_volume`, the chunked-memory helpers are
:mod:`isoconvert.memory`. It never imports ``cli``, ``batch``, ``convert`` or
``label_convert`` (not even lazily), nor the runner's Dask code
(:mod:`isoconvert.runner.dask`, ``dask``, ``distributed``): block-wise
extraction hands its slabs to the engine-neutral :mod:`isoconvert.runner`,
which reaches a cluster on its behalf. :mod:`isoconvert.methods` holds the
table of methods (and :class:`Extractor`) below this package, so that the CLI
can list them without importing it.

The package's names (:func:`extract`, the table entries) live in
:mod:`isoconvert.extract.dispatch` and are imported on first use, so that a
module of the package (the label net, the tables) can be imported without the
isosurface kernels.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .dispatch import (
        AMBIGUITY_RULES,
        CUBES,
        DEFAULT_AMBIGUITY,
        EXTRACTORS,
        NO_DEGENERATE_OFFSET,
        PLUGIN_GROUP,
        SQUARE_AMBIGUITY_RULES,
        SQUARES,
        TETRA,
        Blocks,
        Extractor,
        default_method,
        extract,
        resolve_level,
    )

#: The names :mod:`isoconvert.extract.dispatch` gives the package.
__all__ = [
    "AMBIGUITY_RULES",
    "Blocks",
    "CUBES",
    "DEFAULT_AMBIGUITY",
    "EXTRACTORS",
    "Extractor",
    "NO_DEGENERATE_OFFSET",
    "PLUGIN_GROUP",
    "SQUARE_AMBIGUITY_RULES",
    "SQUARES",
    "TETRA",
    "default_method",
    "extract",
    "resolve_level",
]
_PUBLIC = frozenset(__all__)


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:  # a submodule not yet imported, or no such name
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(".dispatch", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | _PUBLIC)
