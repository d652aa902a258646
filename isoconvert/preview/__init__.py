"""Pictures of meshes: a shaded render from four views, with the report's problems drawn on it.

Layout
------
An image of ``W x H`` pixels holds four panels of ``W // 2 x (H - F) // 2``
pixels in a 2 x 2 grid above a footer of ``F`` pixels (legend and scale bar):

=========  ===================  ======================  ============
panel      camera looks from    screen right, up        position
=========  ===================  ======================  ============
top        +z                   +x, +y                  top left
front      -y                   +x, +z                  top right
side       +x                   +y, +z                  bottom left
oblique    (+1, -1, +1)         up x toward, z-ish      bottom right
=========  ===================  ======================  ============

Every panel uses a parallel projection and one common scale (world units per
pixel), so the scale bar holds for all of them and a world point ``p`` lands at
``View.project(p)``; the tests check the rendered silhouettes against that.

Who draws what
--------------
VTK renders the shaded surface offscreen (smooth shading with the mesh's
normals, or area-weighted vertex normals computed here). Pillow draws
everything else on top with :meth:`View.project`: the problems the report
finds (boundary edges inside the grid, non-manifold edges and vertices,
zero-length edges) in flat colours that shading never produces, so they show
through the surface wherever they are, the panel titles, the axis arrows, the
legend and the scale bar.

VTK is an optional extra (``pip install isoconvert[render]``), imported only
when a picture is made: no other command pays for it.

Modules
-------
``views`` (View, Layout, make_views), ``render`` (the VTK offscreen render),
``marks`` (the report's problems as positions), ``annotate`` (Pillow drawing),
``picture`` (Preview, PNG files, ``isoconvert preview``) and ``sheet`` (the
contact sheet of ``batch --previews``).
"""

from __future__ import annotations

# Names outside __all__ that other modules and the tests import from here are
# re-exported with a redundant alias.
from .annotate import _view_title as _view_title
from .marks import MAX_MARKS as MAX_MARKS
from .marks import PROBLEMS, find_marks
from .marks import Marks as Marks
from .picture import (
    DEFAULT_SIZE,
    Preview,
    check_picture_output,
    parse_colour,
    parse_size,
    preview_file,
    render_preview,
    write_preview,
)
from .picture import PNG_KEY as PNG_KEY
from .picture import recorded_header as recorded_header
from .render import SURFACE as SURFACE
from .render import RenderError, require_renderer, vertex_normals
from .sheet import THUMBNAIL_SIZE as THUMBNAIL_SIZE
from .sheet import SheetEntry, contact_sheet, write_contact_sheet
from .sheet import batch_thumbnail as batch_thumbnail
from .sheet import read_summary as read_summary
from .sheet import thumbnail_name as thumbnail_name
from .views import Layout as Layout
from .views import View, make_views

__all__ = [
    "DEFAULT_SIZE",
    "PROBLEMS",
    "Preview",
    "RenderError",
    "SheetEntry",
    "View",
    "contact_sheet",
    "find_marks",
    "make_views",
    "parse_colour",
    "parse_size",
    "preview_file",
    "render_preview",
    "check_picture_output",
    "require_renderer",
    "vertex_normals",
    "write_contact_sheet",
    "write_preview",
]
