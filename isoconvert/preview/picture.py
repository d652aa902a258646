"""The Preview object: rendering, PNG writing, output checks and previews of mesh files."""

from __future__ import annotations

import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from .annotate import _axis_arrows, _draw_marks, _font, _footer, _ink, _view_title, footer_items
from .marks import Marks, find_marks
from .render import _render_surface, _renderer_check
from .views import Layout, View, make_views

#: Default picture size (width, height) in pixels.
DEFAULT_SIZE = (1024, 768)
#: PNG text key under which a preview records what it shows (read by the contact sheet).
PNG_KEY = "isoconvert-preview"


# --- the picture ----------------------------------------------------------------------------


@dataclass
class Preview:
    """A rendered preview.

    Attributes
    ----------
    image : (H, W, 3) uint8
    views : list of View
    marks : Marks or None
        The problems drawn (None when not checked).
    frame : str or None
        "LPS" or "RAS" when the axes are labelled anatomically.
    footer : list of str
        The legend's texts, as drawn in the footer (:func:`footer_items`).
    """

    image: np.ndarray
    views: list[View]
    marks: Marks | None
    frame: str | None = None
    footer: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        """What the picture shows, as recorded in the PNG's text chunk: the problem
        counts drawn, the checks the report fails, the vertices not drawn for being
        NaN or infinite, and the footer's texts."""
        marks = self.marks
        return {
            "problems": None if marks is None else dict(marks.counts),
            "failed_checks": None if marks is None else list(marks.failed),
            "non_finite_vertices": None if marks is None else marks.non_finite,
            "footer": list(self.footer),
            "scale": self.views[0].scale,
            "frame": self.frame,
        }

    def describe(self) -> str:
        """One line of what the picture shows, as its footer says it (e.g. "holes
        (boundary edges inside) 8; check fails watertight, no-holes")."""
        return "; ".join(self.footer) if self.footer else "not checked"

    def png(self) -> bytes:
        """The image as PNG bytes, with :meth:`summary` under :data:`PNG_KEY`."""
        from PIL import Image
        from PIL.PngImagePlugin import PngInfo

        info = PngInfo()
        info.add_text(PNG_KEY, json.dumps(self.summary()))
        out = io.BytesIO()
        Image.fromarray(self.image).save(out, format="PNG", optimize=True, pnginfo=info)
        return out.getvalue()


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` as (width, height); both in 64..8192.

    Raises
    ------
    IsoconvertError
        Not two whole numbers in range.
    """
    match = re.fullmatch(r"\s*(\d+)\s*[xX*,]\s*(\d+)\s*", text or "")
    size = (int(match.group(1)), int(match.group(2))) if match else None
    if size is None or not all(64 <= s <= 8192 for s in size):
        raise IsoconvertError(
            f"--size takes WIDTHxHEIGHT in pixels, each 64 to 8192, e.g. 1024x768; got {text!r}"
        )
    return size


def parse_colour(text: str) -> tuple[int, int, int]:
    """A colour name or ``#rrggbb`` as RGB.

    Raises
    ------
    IsoconvertError
        Pillow does not know the colour.
    """
    from PIL import ImageColor

    try:
        return ImageColor.getrgb(text)[:3]
    except ValueError:
        raise IsoconvertError(
            f"--background takes a colour name or #rrggbb, e.g. white or #202020; got {text!r}"
        ) from None


def render_preview(
    mesh: Mesh,
    *,
    size: tuple[int, int] = DEFAULT_SIZE,
    background: str | tuple[int, int, int] = "white",
    checked: Mesh | None = None,
    grid: dict | None = None,
    problems: bool = True,
    report=None,
) -> Preview:
    """Render ``mesh`` from four views with its problems drawn on it.

    Parameters
    ----------
    mesh : Mesh
        Triangles ``vertices (V, 3)``, ``cells (C, 3)``; ``normals (V, 3)``
        when it has them (else area-weighted vertex normals); ``info["frame"]``
        ("LPS"/"RAS") labels the axes anatomically, ``info["unit"]`` the scale bar.
    size : (int, int)
        Width and height in pixels.
    background : str or (int, int, int)
        A colour name, ``#rrggbb`` or RGB.
    checked : Mesh or None
        The mesh the report checks (e.g. as a file stores it); default ``mesh``.
    grid : dict or None
        The grid boundaries are judged against (default ``info["grid"]``).
    problems : bool
        Check the mesh and draw its problems.
    report : MeshReport or None
        The report of ``checked`` when the caller has it (see :func:`find_marks`).

    Returns
    -------
    Preview

    Raises
    ------
    IsoconvertError
        No triangles, or contour segments.
    RenderError
        VTK is missing or cannot render here.
    """
    from PIL import Image, ImageDraw

    name = str(mesh.info.get("source", "")) or "mesh"
    if not mesh.is_triangles:
        raise IsoconvertError(f"{name}: previews draw triangle meshes; this holds contour segments")
    finite = np.isfinite(mesh.vertices).all(axis=1)
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[np.asarray(mesh.cells).reshape(-1)] = True
    if mesh.n_cells == 0 or not (used & finite).any():
        raise IsoconvertError(f"{name}: the mesh has no triangles; there is nothing to preview")
    rgb = parse_colour(background) if isinstance(background, str) else tuple(background)
    layout = Layout(*size)
    points = mesh.vertices[used & finite]
    views = make_views(np.array([points.min(axis=0), points.max(axis=0)]), layout)
    drawn = mesh
    if not finite.all():
        # a NaN or infinite vertex would poison VTK's bounds and camera: its
        # triangles are not drawn, and it is moved onto a drawn vertex (no triangle
        # left uses it); the report, and so the marks and footer, keep the mesh as it is
        keep = finite[mesh.cells].all(axis=1)
        vertices = mesh.vertices.copy()
        vertices[~finite] = points[0]
        normals = mesh.normals
        if normals is not None:
            normals = np.where(finite[:, None], normals, 0.0)
        drawn = Mesh(vertices, mesh.cells[keep], info=mesh.info, normals=normals)
    pixels = _render_surface(drawn, views, layout, rgb)
    pixels[layout.height - layout.footer :] = rgb
    marks = None
    if problems:
        marks = find_marks(checked if checked is not None else mesh, grid, report=report)
    frame = str(mesh.info.get("frame", "")).upper() or None
    frame = frame if frame in ("LPS", "RAS") else None
    image = Image.fromarray(pixels)
    draw = ImageDraw.Draw(image)
    ink = _ink(rgb)
    font = _font(layout.font)
    if marks is not None:
        _draw_marks(draw, views, marks, layout)
    for view in views:
        x0, y0, x1, y1 = view.box
        draw.text((x0 + 5, y0 + 3), _view_title(view, frame), fill=ink, font=font)
        _axis_arrows(draw, view, layout, frame, ink, font)
    # panel separators, so four views read as four pictures
    grey = tuple((c + i) // 2 for c, i in zip(rgb, ink, strict=True))
    pw, ph = layout.panel
    draw.line([(pw, 0), (pw, 2 * ph)], fill=grey, width=1)
    draw.line([(0, ph), (layout.width, ph)], fill=grey, width=1)
    draw.line([(0, 2 * ph), (layout.width, 2 * ph)], fill=grey, width=1)
    _footer(draw, layout, marks, views[0].scale, str(mesh.info.get("unit", "")), ink, font)
    footer = [text for _, text in footer_items(marks)]
    return Preview(np.asarray(image), views, marks, frame, footer)


def check_picture_output(
    output: str | Path, force: bool = False, inputs: Sequence[str | Path] = ()
) -> Path:
    """Fail before any work when ``output`` is not a ``.png`` name that can be written
    (or is one of ``inputs``).

    Raises
    ------
    OutputError
    """
    from ..atomic import check_output
    from ..errors import OutputError

    output = Path(output)
    if output.is_dir():
        return check_output(output, force, example="preview.png")  # says it is a folder
    if output.suffix.lower() != ".png":
        raise OutputError(f"{output}: previews are PNG pictures; name the file .png")
    return check_output(output, force, example="preview.png", inputs=inputs)


def write_preview(preview: Preview, output: str | Path, force: bool = False) -> Path:
    """Write ``preview`` as PNG, whole or not at all.

    Raises
    ------
    OutputError
        The output exists (without ``force``) or cannot be written.
    """
    from ..atomic import atomic_output

    data = preview.png()
    with atomic_output(output, force) as fh:
        fh.write(data)
    return Path(output)


def recorded_header(path: str | Path) -> dict:
    """``frame`` and ``unit`` that isoconvert's writers record in a mesh file's header.

    :func:`isoconvert.meshfile.read_mesh` reads the grid but not these; they
    are header comment lines (``frame LPS``, ``unit mm``) in the first 64 kB.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except OSError:
        return {}
    found = {}
    frame = re.search(rb"(?:^|[\n#]|comment)\s*frame (LPS|RAS)\b", head)
    if frame:
        found["frame"] = frame.group(1).decode()
    unit = re.search(rb"(?:^|[\n#]|comment)\s*unit ([A-Za-z\xb5]{1,8})\s", head)
    if unit:
        found["unit"] = unit.group(1).decode("latin-1")
    return found


def preview_file(
    path: str | Path,
    output: str | Path,
    *,
    size: tuple[int, int] = DEFAULT_SIZE,
    background: str | tuple[int, int, int] = "white",
    force: bool = False,
    format: str | None = None,
) -> Preview:
    """Read a mesh file and write its preview PNG (``isoconvert preview``).

    ``path`` may be ``-`` (standard input) with ``format``, the mesh's format by
    its usual extension (``ply``, ``stl``, ...), as for
    :func:`isoconvert.meshfile.read_mesh`.

    Raises
    ------
    IsoconvertError
        The file cannot be read, holds no triangles, or the output cannot be
        written; no output file is left behind.
    """
    from ..meshfile import read_mesh

    check_picture_output(output, force, [path] if str(path) != "-" else [])  # before the work
    _renderer_check()
    mesh = read_mesh(path, format=format)
    if str(path) != "-":  # standard input cannot be read twice
        for key, value in recorded_header(path).items():
            mesh.info.setdefault(key, value)
    preview = render_preview(mesh, size=size, background=background)
    write_preview(preview, output, force)
    return preview
