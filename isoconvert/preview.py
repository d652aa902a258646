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
"""

from __future__ import annotations

import html
import io
import json
import math
import os
import re
import sys
import urllib.parse
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import IsoconvertError, one_line
from .mesh import Mesh

#: Default picture size (width, height) in pixels.
DEFAULT_SIZE = (1024, 768)
#: Thumbnail size for ``batch --previews``.
THUMBNAIL_SIZE = (400, 300)
#: Install hint when VTK is missing.
INSTALL_HINT = "pip install 'isoconvert[render]'"
#: Problems drawn per kind at most (a mesh in pieces can have millions; the
#: legend says when only some were drawn).
MAX_MARKS = 20_000
#: PNG text key under which a preview records what it shows (read by the contact sheet).
PNG_KEY = "isoconvert-preview"

#: Report problem name -> (legend label, RGB). Saturated colours a grey shaded
#: surface never takes, so a pixel of one of them is that problem.
PROBLEMS: dict[str, tuple[str, tuple[int, int, int]]] = {
    "boundary_edges_inside": ("holes (boundary edges inside)", (230, 0, 0)),
    "non_manifold_edges": ("non-manifold edges", (200, 0, 200)),
    "non_manifold_vertices": ("non-manifold vertices", (255, 140, 0)),
    "zero_length_edges": ("zero-length edges", (0, 110, 255)),
}
#: Colour of the surface (RGB in 0..1): light grey, slightly blue.
SURFACE = (0.80, 0.82, 0.86)

#: Names of the positive and negative axis directions per frame.
_AXIS_NAMES = {
    None: (("+x", "+y", "+z"), ("-x", "-y", "-z")),
    "LPS": (("L", "P", "S"), ("R", "A", "I")),
    "RAS": (("R", "A", "S"), ("L", "P", "I")),
}


class RenderError(IsoconvertError):
    """The renderer is missing or cannot draw on this machine."""


# --- views -------------------------------------------------------------------------------


@dataclass
class View:
    """One panel: a parallel projection of the world onto pixels.

    Attributes
    ----------
    name : str
        "top", "front", "side" or "oblique".
    toward : (3,) float64
        Unit vector from the object toward the camera.
    right, up : (3,) float64
        Unit screen directions in world coordinates (``right x up = toward``).
    center : (3,) float64
        World point drawn at ``pixel_center``.
    pixel_center : (2,) float64
        Image coordinates (x to the right, y down, pixel edges at integers).
    scale : float
        World units per pixel.
    box : (4,) int
        The panel's pixels: x0, y0, x1, y1 (exclusive).
    """

    name: str
    toward: np.ndarray
    right: np.ndarray
    up: np.ndarray
    center: np.ndarray
    pixel_center: np.ndarray
    scale: float
    box: tuple[int, int, int, int]

    def project(self, points: np.ndarray) -> np.ndarray:
        """Image coordinates of world points.

        Parameters
        ----------
        points : (N, 3) float

        Returns
        -------
        (N, 2) float64
            x (column) and y (row) in pixels, continuous: pixel (c, r) covers
            ``c <= x < c + 1``, ``r <= y < r + 1``.
        """
        d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.center
        x = self.pixel_center[0] + d @ self.right / self.scale
        y = self.pixel_center[1] - d @ self.up / self.scale
        return np.column_stack([x, y])


def _directions() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, toward, up) of the four views; right = up x toward."""
    oblique = np.array([1.0, -1.0, 1.0]) / math.sqrt(3.0)
    z = np.array([0.0, 0.0, 1.0])
    oblique_up = z - oblique * (z @ oblique)
    return [
        ("top", np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
        ("front", np.array([0.0, -1.0, 0.0]), z),
        ("side", np.array([1.0, 0.0, 0.0]), z),
        ("oblique", oblique, oblique_up / np.linalg.norm(oblique_up)),
    ]


@dataclass(frozen=True)
class Layout:
    """Where panels, titles and the footer go in a ``width x height`` image."""

    width: int
    height: int

    @property
    def footer(self) -> int:
        return max(18, round(self.height * 0.075))

    @property
    def panel(self) -> tuple[int, int]:
        return self.width // 2, (self.height - self.footer) // 2

    @property
    def title(self) -> int:
        return max(11, round(self.panel[1] * 0.07))

    @property
    def font(self) -> int:
        return max(9, round(self.title * 0.8))

    def panel_box(self, k: int) -> tuple[int, int, int, int]:
        pw, ph = self.panel
        x0, y0 = (k % 2) * pw, (k // 2) * ph
        return x0, y0, x0 + pw, y0 + ph

    def inner(self, k: int) -> tuple[float, float, float, float]:
        """The part of panel ``k`` the object is fitted into: x0, y0, x1, y1."""
        x0, y0, x1, y1 = self.panel_box(k)
        mx, my = 0.08 * (x1 - x0), 0.06 * (y1 - y0)
        return x0 + mx, y0 + self.title + my, x1 - mx, y1 - my


def make_views(bounds: np.ndarray, layout: Layout) -> list[View]:
    """The four views that fit a bounding box into the layout's panels.

    Parameters
    ----------
    bounds : (2, 3) float
        Lowest and highest corner of the object.
    layout : Layout

    Returns
    -------
    list of View
        One scale for all four: the largest any panel needs to hold the box.
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = 0.5 * (lo + hi)
    corners = np.array([[(lo, hi)[(i >> a) & 1][a] for a in range(3)] for i in range(8)])
    scale = 0.0
    directions = _directions()
    for k, (_, toward, up) in enumerate(directions):
        right = np.cross(up, toward)
        x0, y0, x1, y1 = layout.inner(k)
        d = corners - center
        scale = max(scale, np.ptp(d @ right) / (x1 - x0), np.ptp(d @ up) / (y1 - y0))
    if not scale > 0:  # a single point: any scale shows it
        scale = max(float(np.abs(center).max()), 1.0) * 1e-3
    views = []
    for k, (name, toward, up) in enumerate(directions):
        x0, y0, x1, y1 = layout.inner(k)
        views.append(
            View(
                name,
                toward,
                np.cross(up, toward),
                up,
                center,
                np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)]),
                float(scale),
                layout.panel_box(k),
            )
        )
    return views


# --- the renderer -------------------------------------------------------------------------


def _vtk():
    """The VTK modules the renderer uses, imported on first use.

    Raises
    ------
    RenderError
        VTK is not installed.
    """
    try:
        import vtkmodules.vtkRenderingOpenGL2 as opengl  # registers the OpenGL classes
        from vtkmodules import vtkCommonCore, vtkCommonDataModel, vtkRenderingCore
        from vtkmodules.util import numpy_support
    except ImportError as exc:
        raise RenderError(
            f"previews need VTK, which is not installed ({one_line(exc, 120)}); {INSTALL_HINT}"
        ) from None
    # VTK logs to stderr (e.g. that there is no X server before it falls back to
    # EGL); the CLI promises one line per error, so errors come through exceptions.
    vtkCommonCore.vtkLogger.SetStderrVerbosity(vtkCommonCore.vtkLogger.VERBOSITY_OFF)
    return opengl, vtkCommonCore, vtkCommonDataModel, vtkRenderingCore, numpy_support


#: Offscreen OpenGL libraries VTK's Linux wheel can draw through, and the window
#: class of each, in the order they are tried.
_OFFSCREEN = (
    ("libEGL.so.1", "vtkEGLRenderWindow"),
    ("libOSMesa.so", "vtkOSOpenGLRenderWindow"),
    ("libOSMesa.so.8", "vtkOSOpenGLRenderWindow"),
)


def _offscreen_libraries() -> list[str]:
    """The window classes whose offscreen library this Linux machine has.

    Raises
    ------
    RenderError
        Neither EGL nor OSMesa is there (creating their windows without them
        crashes the process, so they are looked for first).
    """
    import ctypes

    found = []
    for library, window in _OFFSCREEN:
        try:
            ctypes.CDLL(library)
        except OSError:
            continue
        found.append(window)
    if not found:
        raise RenderError(
            "previews need an offscreen OpenGL library, and neither EGL nor OSMesa was "
            "found; install Mesa's (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri)"
        )
    return found


def _offscreen_window(opengl, core):
    """A render window that draws without a display.

    On Linux, VTK's pip wheel draws offscreen through EGL (with Mesa's
    llvmpipe on a machine without a GPU) or OSMesa, whichever system library
    is there (:func:`_offscreen_libraries`).
    """
    if sys.platform.startswith("linux"):
        for window in _offscreen_libraries():
            win = getattr(opengl, window)()
            if win.SupportsOpenGL():
                break
        else:
            raise RenderError(
                "previews need offscreen OpenGL, and the EGL/OSMesa libraries found cannot "
                "provide it; install Mesa's (Debian/Ubuntu: apt install libegl1 libgl1-mesa-dri)"
            )
    else:  # macOS and Windows: the native window renders offscreen
        win = core.vtkRenderWindow()
    win.SetOffScreenRendering(1)
    win.SetMultiSamples(0)  # exact silhouettes; llvmpipe pays for every sample
    return win


def vertex_normals(mesh: Mesh) -> np.ndarray:
    """(V, 3) float32 unit area-weighted vertex normals (:meth:`Mesh.vertex_normals`)."""
    return mesh.vertex_normals().astype(np.float32)


def _render_surface(
    mesh: Mesh, views: list[View], layout: Layout, background: tuple[int, int, int]
) -> np.ndarray:
    """The shaded surface in every panel, (H, W, 3) uint8, footer left blank."""
    opengl, core, data, rendering, numpy_support = _vtk()
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    cells = np.asarray(mesh.cells)
    normals = mesh.normals if mesh.normals is not None else vertex_normals(mesh)
    normals = np.ascontiguousarray(normals, dtype=np.float32)

    points = core.vtkPoints()
    points.SetData(numpy_support.numpy_to_vtk(vertices, deep=True))
    connectivity = np.ascontiguousarray(cells.reshape(-1), dtype=np.int64)
    offsets = np.arange(0, 3 * len(cells) + 1, 3, dtype=np.int64)
    polys = data.vtkCellArray()
    polys.SetData(
        numpy_support.numpy_to_vtkIdTypeArray(offsets, deep=True),
        numpy_support.numpy_to_vtkIdTypeArray(connectivity, deep=True),
    )
    polydata = data.vtkPolyData()
    polydata.SetPoints(points)
    polydata.SetPolys(polys)
    vtk_normals = numpy_support.numpy_to_vtk(normals, deep=True)
    vtk_normals.SetName("Normals")
    polydata.GetPointData().SetNormals(vtk_normals)

    mapper = rendering.vtkPolyDataMapper()
    mapper.SetInputData(polydata)
    mapper.ScalarVisibilityOff()
    window = _offscreen_window(opengl, rendering)
    window.SetSize(layout.width, layout.height)
    bg = tuple(c / 255.0 for c in background)
    span = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    for view in views:
        actor = rendering.vtkActor()
        actor.SetMapper(mapper)
        prop = actor.GetProperty()
        prop.SetColor(*SURFACE)
        prop.SetInterpolationToPhong()
        prop.SetAmbient(0.15)
        prop.SetDiffuse(0.8)
        prop.SetSpecular(0.15)
        prop.SetSpecularPower(20.0)
        renderer = rendering.vtkRenderer()
        renderer.AddActor(actor)
        renderer.SetBackground(*bg)
        x0, y0, x1, y1 = view.box
        # VTK's viewports count from the bottom left, in fractions of the window
        renderer.SetViewport(
            x0 / layout.width,
            1.0 - y1 / layout.height,
            x1 / layout.width,
            1.0 - y0 / layout.height,
        )
        # VTK puts the focal point at the viewport's centre; shift it so that
        # view.center lands at view.pixel_center, as View.project says
        dx = view.pixel_center[0] - 0.5 * (x0 + x1)
        dy = view.pixel_center[1] - 0.5 * (y0 + y1)
        focal = view.center - view.right * dx * view.scale + view.up * dy * view.scale
        camera = renderer.GetActiveCamera()
        camera.ParallelProjectionOn()
        camera.SetFocalPoint(*focal)
        camera.SetPosition(*(focal + view.toward * (2.0 * span + 1.0)))
        camera.SetViewUp(*view.up)
        camera.SetParallelScale(0.5 * (y1 - y0) * view.scale)
        renderer.ResetCameraClippingRange()
        window.AddRenderer(renderer)
    window.Render()
    grab = rendering.vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.ShouldRerenderOff()  # the window was just rendered; a second render costs as much
    grab.ReadFrontBufferOff()
    grab.Update()
    image = grab.GetOutput()
    width, height, _ = image.GetDimensions()
    pixels = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
    pixels = pixels.reshape(height, width, -1)[::-1, :, :3]  # VTK's rows run bottom-up
    window.Finalize()
    return np.ascontiguousarray(pixels)


# --- problems -----------------------------------------------------------------------------


@dataclass
class Marks:
    """The problems to draw, as world positions.

    Attributes
    ----------
    edges : dict of str -> (N, 2, 3) float64
        Ends of the edges of each edge problem.
    points : dict of str -> (N, 3) float64
        Positions of each point problem.
    counts : dict of str -> int
        How many the report found (may exceed what is drawn, see :data:`MAX_MARKS`).
    boundary_frame : str
        What boundaries were judged against ("grid" or "bounding box").
    """

    edges: dict = field(default_factory=dict)
    points: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    boundary_frame: str = ""


def find_marks(mesh: Mesh, grid: dict | None = None, limit: int = MAX_MARKS) -> Marks:
    """The report's problems of ``mesh`` as positions to draw.

    Parameters
    ----------
    mesh : Mesh
        Triangles, as checked (for a file, as the file holds them).
    grid : dict or None
        The grid boundaries are judged against (default ``mesh.info["grid"]``).
    limit : int
        At most this many of each kind (the report's first ones).
    """
    from .report import check_mesh

    report = check_mesh(mesh, examples=limit, grid=grid)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    marks = Marks(boundary_frame=report.boundary_frame)
    for name in PROBLEMS:
        problem = report.problems[name]
        marks.counts[name] = int(problem["count"])
        examples = problem["examples"]
        if name == "non_manifold_vertices":
            ids = np.array([e["vertex"] for e in examples], dtype=np.int64)
            marks.points[name] = v[ids].reshape(-1, 3)
        elif name == "zero_length_edges":  # both ends at one place: a point
            ids = np.array([e["vertices"][0] for e in examples], dtype=np.int64)
            marks.points[name] = v[ids].reshape(-1, 3)
        else:
            ids = np.array([e["vertices"] for e in examples], dtype=np.int64).reshape(-1, 2)
            marks.edges[name] = v[ids].reshape(-1, 2, 3)
    return marks


# --- annotations ------------------------------------------------------------------------------


def _font(size: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _ink(background: tuple[int, int, int]) -> tuple[int, int, int]:
    """Black on light backgrounds, white on dark ones."""
    r, g, b = background
    return (0, 0, 0) if 0.299 * r + 0.587 * g + 0.114 * b > 128 else (255, 255, 255)


def _finite(points: np.ndarray) -> np.ndarray:
    return points[np.isfinite(points).all(axis=tuple(range(1, points.ndim)))]


def _draw_marks(draw, views: list[View], marks: Marks, layout: Layout) -> None:
    """Problems over the surface, clipped to each panel, in their flat colours."""
    width = max(1, round(min(layout.width, layout.height) / 350))
    radius = max(2, round(min(layout.width, layout.height) / 200))
    for view in views:
        x0, y0, x1, y1 = view.box
        for name, ends in marks.edges.items():
            ends = _finite(ends)
            if not len(ends):
                continue
            colour = PROBLEMS[name][1]
            xy = view.project(ends.reshape(-1, 3)).reshape(-1, 4)
            for a, b, c, d in xy.tolist():
                if max(a, c) < x0 or min(a, c) >= x1 or max(b, d) < y0 or min(b, d) >= y1:
                    continue
                draw.line([(a, b), (c, d)], fill=colour, width=width)
        for name, points in marks.points.items():
            points = _finite(points)
            if not len(points):
                continue
            colour = PROBLEMS[name][1]
            for a, b in view.project(points).tolist():
                if x0 <= a < x1 and y0 <= b < y1:
                    draw.ellipse([a - radius, b - radius, a + radius, b + radius], fill=colour)
        # a mark near a panel's edge must not spill into the neighbour
    return None


def _nice_length(most: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``most``."""
    if not most > 0:
        return 0.0
    power = 10.0 ** math.floor(math.log10(most))
    for step in (5.0, 2.0, 1.0):
        if step * power <= most:
            return step * power
    return power


def _axis_arrows(draw, view: View, layout: Layout, frame: str | None, ink, font) -> None:
    """Small labelled arrows for the world axes, in the panel's bottom-left corner."""
    x0, y0, x1, y1 = view.box
    length = 0.09 * min(x1 - x0, y1 - y0)
    ox, oy = x0 + 0.05 * (x1 - x0) + 4, y1 - 0.05 * (y1 - y0) - 4
    positive, _ = _AXIS_NAMES.get(frame, _AXIS_NAMES[None])
    for a in range(3):
        axis = np.zeros(3)
        axis[a] = 1.0
        sx, sy = axis @ view.right, -(axis @ view.up)
        if math.hypot(sx, sy) < 0.2:  # pointing at the viewer: not drawn
            continue
        tip = (ox + sx * length, oy + sy * length)
        draw.line([(ox, oy), tip], fill=ink, width=1)
        label = positive[a].lstrip("+")
        draw.text((tip[0] + 2 * sx, tip[1] + 2 * sy), label, fill=ink, font=font, anchor="mm")


def _view_title(view: View, frame: str | None) -> str:
    positive, negative = _AXIS_NAMES.get(frame, _AXIS_NAMES[None])
    if view.name == "oblique":
        return "oblique"
    a = int(np.argmax(np.abs(view.toward)))
    side = positive[a] if view.toward[a] > 0 else negative[a]
    return f"{view.name}, from {side}"


def _footer(draw, layout: Layout, marks: Marks | None, scale: float, unit: str, ink, font) -> None:
    """Legend (problem colours and counts) on the left, scale bar on the right."""
    top = layout.height - layout.footer
    mid = top + layout.footer / 2
    x = 6.0
    swatch = max(6, round(layout.font * 0.8))
    if marks is not None and not any(marks.counts.values()):
        text = "no holes, non-manifold or zero-length edges found"
        draw.text((x, mid), text, fill=ink, font=font, anchor="lm")
        x += draw.textlength(text, font=font) + 10
    elif marks is not None:  # only what was found, so the legend fits beside the scale bar
        for name, (label, colour) in PROBLEMS.items():
            count = marks.counts.get(name, 0)
            if not count:
                continue
            shown = len(marks.edges.get(name, marks.points.get(name, ())))
            text = f"{label} {count:,}" + (f" ({shown:,} drawn)" if shown < count else "")
            draw.rectangle([x, mid - swatch / 2, x + swatch, mid + swatch / 2], fill=colour)
            x += swatch + 3
            draw.text((x, mid), text, fill=ink, font=font, anchor="lm")
            x += draw.textlength(text, font=font) + 10
    # scale bar: a round length of at most a fifth of a panel's width
    length = _nice_length(0.2 * layout.panel[0] * scale)
    if length > 0:
        pixels = length / scale
        label = f"{length:g} {unit}".strip()
        right = layout.width - 8
        left = right - pixels
        text_width = draw.textlength(label, font=font)
        if left - text_width - 6 > x:  # room beside the legend
            draw.line([(left, mid), (right, mid)], fill=ink, width=2)
            for end in (left, right):
                draw.line([(end, mid - 4), (end, mid + 4)], fill=ink, width=1)
            draw.text((left - 6, mid), label, fill=ink, font=font, anchor="rm")


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
    """

    image: np.ndarray
    views: list[View]
    marks: Marks | None
    frame: str | None = None

    def summary(self) -> dict:
        """What the picture shows, as recorded in the PNG's text chunk."""
        return {
            "problems": None if self.marks is None else dict(self.marks.counts),
            "scale": self.views[0].scale,
            "frame": self.frame,
        }

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
    if not finite.all():  # a NaN vertex would poison VTK's bounds: drop its triangles
        keep = finite[mesh.cells].all(axis=1)
        normals = mesh.normals
        mesh = Mesh(mesh.vertices, mesh.cells[keep], info=mesh.info, normals=normals)
    pixels = _render_surface(mesh, views, layout, rgb)
    pixels[layout.height - layout.footer :] = rgb
    marks = find_marks(checked if checked is not None else mesh, grid) if problems else None
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
    return Preview(np.asarray(image), views, marks, frame)


def check_picture_output(output: str | Path, force: bool = False) -> Path:
    """Fail before any work when ``output`` is not a ``.png`` name that can be written.

    Raises
    ------
    OutputError
    """
    from .atomic import check_output
    from .errors import OutputError

    output = Path(output)
    if output.is_dir():
        return check_output(output, force, example="preview.png")  # says it is a folder
    if output.suffix.lower() != ".png":
        raise OutputError(f"{output}: previews are PNG pictures; name the file .png")
    return check_output(output, force, example="preview.png")


def write_preview(preview: Preview, output: str | Path, force: bool = False) -> Path:
    """Write ``preview`` as PNG, whole or not at all.

    Raises
    ------
    OutputError
        The output exists (without ``force``) or cannot be written.
    """
    from .atomic import atomic_output

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
) -> Preview:
    """Read a mesh file and write its preview PNG (``isoconvert preview``).

    Raises
    ------
    IsoconvertError
        The file cannot be read, holds no triangles, or the output cannot be
        written; no output file is left behind.
    """
    from .meshfile import read_mesh

    check_picture_output(output, force)  # before the work
    _renderer_check()
    mesh = read_mesh(path)
    for key, value in recorded_header(path).items():
        mesh.info.setdefault(key, value)
    preview = render_preview(mesh, size=size, background=background)
    write_preview(preview, output, force)
    return preview


def _renderer_check() -> None:
    """Fail before any work when VTK, or the offscreen library it draws
    through, is missing."""
    _vtk()
    if sys.platform.startswith("linux"):
        _offscreen_libraries()


#: Public name of the early check (the CLI calls it before converting).
require_renderer = _renderer_check


# --- the contact sheet ------------------------------------------------------------------------


def thumbnail_name(mesh_path: str | Path) -> Path:
    """Where ``batch --previews`` puts a mesh's thumbnail: beside it, ``NAME.png``."""
    return Path(mesh_path).with_suffix(".png")


def read_summary(png: str | Path) -> dict | None:
    """What a preview PNG records under :data:`PNG_KEY` (None when it is no preview)."""
    from PIL import Image

    try:
        with Image.open(png) as image:
            text = image.text.get(PNG_KEY)  # type: ignore[attr-defined]
    except (OSError, ValueError, AttributeError):
        return None
    try:
        return json.loads(text) if text else None
    except ValueError:
        return None


@dataclass
class SheetEntry:
    """One row of the contact sheet.

    Attributes
    ----------
    input, output : str
        The volume and the mesh file.
    status : str
        The batch status (ok, failed, check-failed, skipped, ...).
    level : float or None
    vertices, cells : int or None
    message : str
    """

    input: str
    output: str
    status: str
    level: float | None = None
    vertices: int | None = None
    cells: int | None = None
    message: str = ""


def contact_sheet(entries: Sequence[SheetEntry], folder: str | Path) -> str:
    """An HTML page of thumbnails, openable from disk (links relative to ``folder``).

    Parameters
    ----------
    entries : sequence of SheetEntry
    folder : str or Path
        Where the page goes; thumbnails and meshes are linked relative to it.

    Returns
    -------
    str
        The page: no script, no style sheet or font from the network.
    """
    folder = Path(folder)

    def relative(path: Path) -> str:
        try:
            rel = os.path.relpath(path, folder)
        except ValueError:  # another drive (Windows)
            rel = str(path.resolve())
        # a URL (# ? % and spaces in file names would be read as URL syntax), then
        # escaped for the attribute
        return html.escape(urllib.parse.quote(Path(rel).as_posix(), safe="/"), quote=True)

    cards = []
    for e in entries:
        mesh = Path(e.output) if e.output else None
        thumb = thumbnail_name(mesh) if mesh else None
        summary = read_summary(thumb) if thumb and thumb.is_file() else None
        if summary is not None:
            picture = f'<a href="{relative(thumb)}"><img src="{relative(thumb)}" alt=""></a>'
        else:
            picture = '<div class="none">no preview</div>'
        problems = (summary or {}).get("problems") or {}
        found = [f"{PROBLEMS[k][0]} {v:,}" for k, v in problems.items() if v and k in PROBLEMS]
        if e.status not in ("ok", "check-failed"):
            report = ""
        elif summary is None:
            report = "not checked"
        else:
            report = "; ".join(found) if found else "no problems found"
        status = e.status + (f": {e.message}" if e.message and e.status != "ok" else "")
        name = html.escape(mesh.name if mesh else Path(e.input).name)
        link = f'<a href="{relative(mesh)}">{name}</a>' if mesh and mesh.is_file() else name
        facts = [
            f"from {html.escape(e.input)}",
            "" if e.level is None else f"level {e.level:g}",
            "" if e.vertices is None else f"{e.vertices:,} vertices, {e.cells or 0:,} triangles",
            f"report: {html.escape(report)}" if report else "",
        ]
        klass = "bad" if (e.status != "ok" or found) else "good"
        cards.append(
            f'<figure class="{klass}">{picture}<figcaption><b>{link}</b><br>'
            + "<br>".join(f for f in facts if f)
            + f'<br><span class="status">{html.escape(status)}</span></figcaption></figure>'
        )
    return (
        '<!DOCTYPE html>\n<html><head><meta charset="utf-8">'
        "<title>isoconvert previews</title><style>"
        "body{font-family:sans-serif;margin:1em}"
        "figure{display:inline-block;vertical-align:top;width:410px;margin:6px;"
        "border:1px solid #ccc;padding:4px}"
        "figure.bad{border-color:#e00}img{width:400px}"
        ".none{width:400px;height:300px;background:#eee;line-height:300px;text-align:center}"
        "figcaption{font-size:13px;word-wrap:break-word}.status{color:#555}"
        "</style></head><body>\n"
        f"<h1>isoconvert previews ({len(entries)} files)</h1>\n"
        + "\n".join(cards)
        + "\n</body></html>\n"
    )


def write_contact_sheet(
    entries: Sequence[SheetEntry], folder: str | Path, name: str = "index.html"
) -> Path:
    """Write :func:`contact_sheet` as ``folder/name`` (replacing an older one)."""
    from .atomic import atomic_output

    path = Path(folder) / name
    with atomic_output(path, force=True) as fh:
        fh.write(contact_sheet(entries, folder).encode("utf-8"))
    return path


def batch_thumbnail(mesh: Mesh, checked: Mesh, output: str | Path, grid: dict | None) -> str:
    """Write a batch job's thumbnail beside its mesh; returns "" or why it failed.

    Called in the worker that converted the mesh, so the mesh is not read again.
    """
    try:
        preview = render_preview(mesh, size=THUMBNAIL_SIZE, checked=checked, grid=grid)
        write_preview(preview, thumbnail_name(output), force=True)
    except IsoconvertError as exc:
        return f"no preview: {exc}"
    return ""


__all__ = [
    "DEFAULT_SIZE",
    "INSTALL_HINT",
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
