"""isoconvert: scalar volumes (raw, NRRD, TIFF) to isosurface meshes (OBJ, PLY, STL).

The command line (``isoconvert``) is a thin shell over these functions.
"""

__version__ = "0.1.0"

from .convert import ConvertResult, convert
from .errors import IsoconvertError
from .extract import EXTRACTORS, extract
from .mesh import Mesh
from .readers import READERS, read_volume
from .volume import Volume
from .writers import WRITERS, write_mesh

__all__ = [
    "EXTRACTORS",
    "READERS",
    "WRITERS",
    "ConvertResult",
    "IsoconvertError",
    "Mesh",
    "Volume",
    "__version__",
    "convert",
    "extract",
    "read_volume",
    "write_mesh",
]
