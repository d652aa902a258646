"""isoconvert: scalar volumes (raw, NRRD, TIFF) to isosurface meshes (OBJ, PLY, STL).

The command line (``isoconvert``) is a thin shell over these functions.
"""

__version__ = "0.1.0"

from .convert import ConvertOptions, ConvertResult, convert
from .errors import IsoconvertError
from .extract import EXTRACTORS, extract
from .mesh import Mesh
from .readers import READERS, ReadOptions, read_volume
from .report import check_mesh
from .volume import Volume
from .writers import WRITERS, write_mesh

__all__ = [
    "EXTRACTORS",
    "READERS",
    "WRITERS",
    "ConvertOptions",
    "ConvertResult",
    "IsoconvertError",
    "Mesh",
    "ReadOptions",
    "Volume",
    "__version__",
    "check_mesh",
    "convert",
    "extract",
    "read_volume",
    "write_mesh",
]
