"""The shaded surface, rendered offscreen by VTK (imported only when a picture is made)."""

from __future__ import annotations

import sys

import numpy as np

from ..errors import IsoconvertError, extra_hint, one_line
from ..mesh import Mesh
from .views import Layout, View

#: Colour of the surface (RGB in 0..1): light grey, slightly blue.
SURFACE = (0.80, 0.82, 0.86)


class RenderError(IsoconvertError):
    """The renderer is missing or cannot draw on this machine."""


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
            f"previews need VTK, which is not installed ({one_line(exc, 120)}); "
            f"{extra_hint('render')}"
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


def _renderer_check() -> None:
    """Fail before any work when VTK, or the offscreen library it draws
    through, is missing."""
    _vtk()
    if sys.platform.startswith("linux"):
        _offscreen_libraries()


#: Public name of the early check (the CLI calls it before converting).
require_renderer = _renderer_check
