"""isoconvert: scalar volumes (raw, NRRD, TIFF, Zarr) to isosurface meshes (OBJ, PLY, STL).

The command line (``isoconvert``) is a thin shell over these functions.

The public names are imported on first use (``isoconvert.read_volume``, or
``from isoconvert import convert``), so that ``import isoconvert`` and the
command line's help do not pay for numpy and the extraction kernels.

Layers (imports run one way, down; tests/test_layers.py fails on any import
cycle among the modules and on a lower layer reaching up; ``python
bench/import_graph.py`` prints the graph)::

    cli/                                        the shell: prints, exits, typer
    batch.py  convert.py  label_convert.py      jobs: one file, many files
    preview/  infoplot.py                       pictures
    extract/  post/  writers/  readers/  meshfile/  report.py  attributes.py
    runner/                                     tasks here or on Dask; knows no job
    volume  mesh  grid  memory  methods  errors  registry  signals  ...   the model
    _native                                     compiled kernels

* ``extract/``, ``readers/``, ``writers/``, ``post/``, ``meshfile/`` and ``report.py``
  never import ``cli``, ``batch``, ``convert``, ``label_convert`` or Dask code;
  what two of them share (the grid description, chunked memory) is in the model.
* The runner (:mod:`isoconvert.runner`) imports only the model; block-wise
  extraction and batch hand it tasks, and only ``batch`` may import its Dask
  engine directly. :mod:`isoconvert.distributed` is a forwarding module for
  the engine's former names, above everything (nothing in the package imports it).
* The model never imports a layer above it. A table of a layer that the CLI
  lists without importing the layer (``methods``, the readers' and writers'
  registries) names its entries by ``"module:attribute"`` strings, imported on
  first use.
"""

from __future__ import annotations

import sys
import types
from importlib import import_module
from typing import TYPE_CHECKING

__version__ = "0.1.0"

#: Public name -> the module that defines it (relative to this package).
_PUBLIC = {
    "Blocks": ".extract.slabs",
    "ConvertOptions": ".convert",
    "ConvertResult": ".convert",
    "convert": ".convert",
    "IsoconvertError": ".errors",
    "EXTRACTORS": ".extract",
    "extract": ".extract",
    "Mesh": ".mesh",
    "as_mesh": ".mesh",
    "marching_cubes": ".arrays",
    "READERS": ".readers",
    "ReadOptions": ".readers",
    "read_volume": ".readers",
    "check_mesh": ".report",
    "Volume": ".volume",
    "WRITERS": ".writers",
    "write_mesh": ".writers",
    "vertex_normals": ".attributes",
    "vertex_values": ".attributes",
}

if TYPE_CHECKING:
    from .arrays import marching_cubes
    from .attributes import vertex_normals, vertex_values
    from .convert import ConvertOptions, ConvertResult, convert
    from .errors import IsoconvertError
    from .extract import EXTRACTORS, extract
    from .extract.slabs import Blocks
    from .mesh import Mesh, as_mesh
    from .readers import READERS, ReadOptions, read_volume
    from .report import check_mesh
    from .volume import Volume
    from .writers import WRITERS, write_mesh


def __getattr__(name: str) -> object:
    if name not in _PUBLIC:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(_PUBLIC[name], __name__), name)
    globals()[name] = value  # later look-ups are plain attribute reads
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))


class _Package(types.ModuleType):
    """This package, keeping its functions ``convert`` and ``extract`` public.

    Importing the submodule ``isoconvert.convert`` (or the subpackage
    ``isoconvert.extract``) binds its name on this package, which would hide
    the function of the same name once the names are no longer imported
    eagerly. A submodule therefore never replaces an attribute of its name:
    ``isoconvert.convert`` is the function, whatever was imported first.
    """

    def __setattr__(self, name: str, value: object) -> None:
        if name in _PUBLIC and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

__all__ = [
    "EXTRACTORS",
    "READERS",
    "WRITERS",
    "Blocks",
    "ConvertOptions",
    "ConvertResult",
    "IsoconvertError",
    "Mesh",
    "ReadOptions",
    "Volume",
    "__version__",
    "as_mesh",
    "check_mesh",
    "convert",
    "extract",
    "marching_cubes",
    "read_volume",
    "vertex_normals",
    "vertex_values",
    "write_mesh",
]
