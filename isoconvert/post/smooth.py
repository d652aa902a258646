"""Smoothing that keeps volume: windowed-sinc (default), Taubin lambda/mu, Laplacian.

All three move each vertex by the umbrella operator ``L x_i = x_i - mean(x_j)``
over its neighbours ``j`` (uniform weights), whose stencil is built once from
the triangles; every iteration is then one compiled pass that applies ``L`` and
the method's update together (src/smooth.cpp). They differ in the polynomial of ``L``
they apply (Taubin, Zhang and Golub, "Optimal surface smoothing as filter
design", IBM RC-20404, 1996):

``sinc``
    A low-pass filter: the Chebyshev expansion of an ideal step at the pass band
    ``k_PB`` (eigenvalues of ``L`` below it pass, above it are removed), its
    terms weighted by a Nuttall window (VTK 9.4's default; the Hamming window
    VTK used before scales the result by up to 1 %) and its cut-off shifted by
    Newton's method until the gain at ``k_PB`` is 1 within 1e-3. This is the
    algorithm of VTK's ``vtkWindowedSincPolyDataFilter`` (``NormalizeCoordinatesOn``,
    Nuttall window) with one change: the coefficients are scaled to sum to 1,
    so that the gain at frequency 0 is exactly 1. VTK's is 1 within 4e-6 from
    10 iterations on, but 0.9995 for 2 and 0.14 for 1, which shrinks the mesh
    towards its centre and moves free vertices against held ones; for 50
    iterations the two differ by about 1e-6 of the bounding-box diagonal.
    N iterations evaluate a polynomial of degree N, one application of ``L`` each.
``taubin``
    Alternating steps ``x -= lam L x`` and ``x -= mu L x`` (``mu < -lam < 0``);
    one iteration is one pair. ``mu`` defaults to ``1 / (k_PB - 1 / lam)``, the
    pass band ``k_PB = 1/lam + 1/mu`` of the paper (-0.526 for lam 0.5, k_PB 0.1).
``laplacian``
    ``x -= lam L x``: every frequency is damped, so the surface shrinks
    (a sphere loses volume with every iteration). Offered for comparison only.

Constraints
-----------
- Vertices on the volume grid's boundary (index coordinate 0 or ``shape - 1``
  along an axis, ``mesh.info["grid"]`` or the ``grid`` argument) stay on that
  plane: the component of each Laplacian step along the constrained index axes
  is removed, so a vertex on one plane slides in it, on two planes along their
  common edge line, and on three stays put. The constrained coordinates are
  restored exactly at the end (bit for bit on an axis-aligned grid).
- Vertices on an open boundary of the mesh (an edge in one triangle) are
  smoothed along their boundary curve only, with their two boundary neighbours,
  as VTK does with ``BoundarySmoothing`` on. Where the curve lies on a grid
  boundary plane it stays in it as above.
- Vertices on a non-manifold edge, non-manifold vertices (more than one fan of
  triangles), boundary vertices with other than two boundary edges, and
  vertices in no triangle do not move.

Coordinates are centred on the bounding box and divided by its diagonal during
filtering (VTK's ``NormalizeCoordinates``), so the polynomial's large
alternating sums are formed on numbers of order 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import IsoconvertError
from ..geometry import normalized_grid
from ..graph import index_dtype
from ..mesh import Mesh
from ..threads import kernel_threads

#: Smoothing methods, the default first.
METHODS = ("sinc", "taubin", "laplacian")

#: Nuttall's four-term window (minimum 4-term Blackman-Harris, continuous first
#: derivative): w(t) = a0 + a1 cos(t) + a2 cos(2t) + a3 cos(3t), t = pi i / (N + 1).
NUTTALL = (0.355768, 0.487396, 0.144232, 0.012604)

#: The pass-band gain Newton's method aims at is 1 within this (as in VTK).
_GAIN_TOLERANCE = 1e-3
#: Index units, relative to the grid's largest size, within which a vertex lies
#: on a grid boundary plane.
_PLANE_TOLERANCE = 1e-9

#: Components of fewer vertices are held as they are: a low-pass filter removes
#: every shape from a component that small (a single voxel's octahedron, 6
#: vertices, shrinks to a point; noise specks of 15-30 vertices to a third of
#: their size in 30 iterations), while balls of 78 vertices or more keep their
#: volume within 3 %.
MIN_COMPONENT_VERTICES = 64

# bits of the stencil kernel's vertex codes (src/smooth.cpp)
_PLANES, _FIXED, _CURVE = 7, 16, 32


@dataclass(frozen=True)
class SmoothOptions:
    """What :func:`smooth` does; validated on construction.

    Attributes
    ----------
    iterations : int
        Degree of the sinc polynomial, or number of Taubin pairs / Laplacian
        steps; 0 returns the mesh unchanged.
    method : str
        One of :data:`METHODS`.
    passband : float
        ``k_PB`` in (0, 2): the sinc filter's cut-off, and Taubin's pass band
        when ``mu`` is None. Smaller smooths more.
    lam : float
        Taubin's and Laplacian's positive step, in (0, 1].
    mu : float or None
        Taubin's negative step, below ``-lam``; None derives it from ``passband``.
    hold_below : int
        Components of fewer vertices are held as they are
        (:data:`MIN_COMPONENT_VERTICES`; 0 smooths every component).
    """

    iterations: int = 20
    method: str = "sinc"
    passband: float = 0.1
    lam: float = 0.5
    mu: float | None = None
    hold_below: int = MIN_COMPONENT_VERTICES

    def __post_init__(self) -> None:
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int | np.integer):
            raise IsoconvertError(
                f"smoothing iterations must be a whole number, got {self.iterations!r}"
            )
        if self.iterations < 0:
            raise IsoconvertError(
                f"smoothing iterations must be 0 or more, got {self.iterations}; 0 turns it off"
            )
        if self.method not in METHODS:
            raise IsoconvertError(
                f"unknown smoothing method {self.method!r}; choose from: {', '.join(METHODS)}"
            )
        if not (0.0 < self.passband < 2.0):
            raise IsoconvertError(
                f"passband must be between 0 and 2 (exclusive), got {self.passband}; "
                "0.1 is usual, smaller smooths more"
            )
        if not (0.0 < self.lam <= 1.0):
            raise IsoconvertError(f"lambda must be in (0, 1], got {self.lam}; 0.5 is usual")
        if self.method == "taubin" and not self.taubin_mu < -self.lam:
            raise IsoconvertError(
                f"Taubin's mu must be below -lambda = {-self.lam}, got {self.taubin_mu}; "
                "leave it out to derive it from the passband"
            )

    @property
    def taubin_mu(self) -> float:
        """``mu``, or ``1 / (k_PB - 1 / lam)`` when it is None."""
        if self.mu is not None:
            return float(self.mu)
        return 1.0 / (self.passband - 1.0 / self.lam)


def smooth(
    mesh: Mesh,
    iterations: int = 20,
    method: str = "sinc",
    *,
    passband: float = 0.1,
    lam: float = 0.5,
    mu: float | None = None,
    grid: dict | None = None,
    hold_below: int = MIN_COMPONENT_VERTICES,
) -> Mesh:
    """Smooth a triangle mesh, keeping its volume (``sinc``, ``taubin``).

    Parameters
    ----------
    mesh : Mesh
        Triangles: ``vertices`` (V, 3) float, ``cells`` (C, 3) int.
    iterations : int
        See :class:`SmoothOptions`.
    method : {"sinc", "taubin", "laplacian"}
        ``laplacian`` shrinks the surface (see the module docstring).
    passband, lam, mu : float
        See :class:`SmoothOptions`.
    hold_below : int
        See :class:`SmoothOptions`.
    grid : dict or None
        The volume's grid (``shape``, ``origin``, ``affine``, as
        :func:`isoconvert.report.grid_from_volume` gives); default
        ``mesh.info["grid"]``. Vertices on its boundary stay on it.

    Returns
    -------
    Mesh
        New vertices (V, 3) float64; the same ``cells`` and ``edge_ids``;
        ``info`` with ``info["smoothing"]`` describing what was done.

    Raises
    ------
    IsoconvertError
        An empty mesh, segments, non-finite vertices or bad options.
    """
    options = SmoothOptions(iterations, method, passband, lam, mu, hold_below)
    return smooth_with(mesh, options, grid)


def smooth_with(mesh: Mesh, options: SmoothOptions, grid: dict | None = None) -> Mesh:
    """:func:`smooth` with its options gathered in a :class:`SmoothOptions`."""
    cells = np.asarray(mesh.cells)
    source = mesh.info.get("source") or "mesh"
    if cells.ndim != 2 or cells.shape[1] != 3:
        raise IsoconvertError(
            f"{source}: smoothing needs triangles, got cells of shape {cells.shape} "
            "(2D contours are not smoothed)"
        )
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    if len(vertices) == 0 or len(cells) == 0:
        raise IsoconvertError(f"{source}: the mesh is empty, there is nothing to smooth")
    if not np.isfinite(vertices).all():
        raise IsoconvertError(f"{source}: the mesh has non-finite vertices; cannot smooth it")
    if cells.min() < 0 or cells.max() >= len(vertices):
        raise IsoconvertError(f"{source}: a triangle refers to a vertex that does not exist")

    info = dict(mesh.info)
    record: dict = {"method": options.method, "iterations": int(options.iterations)}
    if options.method == "sinc":
        record.update(passband=float(options.passband), window="nuttall")
    elif options.method == "taubin":
        record.update(lam=float(options.lam), mu=float(options.taubin_mu))
    else:
        record.update(lam=float(options.lam), note="Laplacian smoothing shrinks the surface")
    if options.iterations == 0:
        info["smoothing"] = record
        return Mesh(vertices.copy(), mesh.cells, mesh.edge_ids, info)

    grid = grid if grid is not None else mesh.info.get("grid")
    stencil = _Stencil(vertices, cells, grid, source, options.hold_below)

    # filter on coordinates centred on the bounding box of the used vertices and
    # divided by its diagonal (VTK's NormalizeCoordinates): the sinc polynomial's
    # terms alternate in sign and grow with the iterations, which is better
    # conditioned on numbers of order 1 (VTK does the same)
    center = 0.5 * (stencil.lo + stencil.hi)
    length = float(np.linalg.norm(stencil.hi - stencil.lo)) or 1.0

    if options.method == "sinc":
        c, converged = sinc_coefficients(options.iterations, options.passband)
        out = stencil.sinc(vertices, c, center, length)
        record["converged"] = bool(converged)
    else:
        out = vertices.copy()
        steps = [options.lam]
        if options.method == "taubin":
            steps.append(options.taubin_mu)
        stencil.steps(out, steps * options.iterations, center, length)

    stencil.restore(out, vertices)
    record.update(
        fixed_vertices=int(np.count_nonzero(stencil.fixed)),
        boundary_curve_vertices=int(np.count_nonzero(stencil.code & _CURVE)),
        grid_constrained_vertices=len(stencil.constrained),
        held_small_components=stencil.n_small,
    )
    info["smoothing"] = record
    return Mesh(out, mesh.cells, mesh.edge_ids, info)


def sinc_coefficients(iterations: int, passband: float) -> tuple[np.ndarray, bool]:
    """Chebyshev coefficients of the windowed-sinc low-pass filter.

    The filter is ``f(k) = sum_i c_i T_i(1 - k / 2)`` for an eigenvalue ``k`` of
    the umbrella operator (in [0, 2]): the Chebyshev series of a step at
    ``theta_PB + sigma`` (``theta = acos(1 - k / 2)``), weighted by a Nuttall
    window, with the offset ``sigma`` found by Newton's method so that
    ``f(k_PB) = 1`` within 1e-3 (Taubin, Zhang and Golub, section 6); then
    scaled so that ``f(0) = sum_i c_i = 1`` (a translation passes unchanged).

    Parameters
    ----------
    iterations : int
        The degree N >= 1.
    passband : float
        ``k_PB`` in (0, 2).

    Returns
    -------
    c : (N + 1,) float64
    converged : bool
        Whether Newton's method brought the gain at ``k_PB`` to 1 within the
        tolerance (True for N = 1, which has no offset to tune).
    """
    n = int(iterations)
    i = np.arange(n + 1, dtype=np.float64)
    t = i * math.pi / (n + 1)
    w = sum(a * np.cos(j * t) for j, a in enumerate(NUTTALL))
    theta = math.acos(1.0 - 0.5 * passband)
    # T_i evaluated at the pass band, x = 1 - k_PB / 2 = cos(theta)
    at_passband = np.cos(i * theta)
    at_passband[1] = 1.0 - 0.5 * passband  # T_1(x) = x, as exactly as it can be

    def series(sigma: float) -> np.ndarray:
        c = np.empty(n + 1)
        c[0] = w[0] * (theta + sigma) / math.pi
        c[1:] = 2.0 * w[1:] * np.sin(i[1:] * (theta + sigma)) / (i[1:] * math.pi)
        return c

    if n < 2:
        c = series(0.0)
        return c / c.sum(), True
    sigma = 0.0
    for _ in range(500):
        c = series(sigma)
        gain = float(c @ at_passband)
        if abs(gain - 1.0) < _GAIN_TOLERANCE:
            return c / c.sum(), True
        # the slope Newton's method steps with: the Chebyshev series of the
        # derivative (recurrence d_i = d_{i+2} + 2 (i + 1) c_{i+1}, truncated at
        # degree N - 2 as VTK does, so that both stop at the same offset)
        d = np.zeros(n + 1)
        d[n - 2] = 2.0 * (n - 1) * c[n - 1]
        for k in range(n - 3, -1, -1):
            d[k] = d[k + 2] + 2.0 * (k + 1) * c[k + 1]
        sigma -= (gain - 1.0) / float(d @ at_passband)
    c = series(sigma)
    return c / c.sum(), abs(float(c @ at_passband) - 1.0) < _GAIN_TOLERANCE


class _Stencil:
    """Which neighbours each vertex averages, and which directions it may move in:
    the compiled ``SmoothingStencil`` (src/smooth.cpp), which the filters run on.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int
        Checked to be in ``0..V-1``.
    grid : dict or None
    source : str
        For messages.
    hold_below : int
        Components of fewer used vertices are fixed.

    Attributes
    ----------
    code : (V,) uint8
        Bits 0-2: on a grid boundary plane of index axis 0, 1, 2; then used,
        fixed, boundary curve and held small component (src/smooth.cpp).
    fixed : (V,) bool
    constrained : (K,) int64
        Free vertices on a grid boundary plane, and ``mask`` (K, 3) bool its axes.
    lo, hi : (3,) float64
        The bounding box of the vertices in triangles.
    n_small : int
        Components held for their size.
    """

    def __init__(
        self, vertices: np.ndarray, cells: np.ndarray, grid, source: str, hold_below: int
    ) -> None:
        from .. import _native

        itype = index_dtype(len(vertices), 3 * len(cells))
        self.threads = kernel_threads()
        planes = _grid_planes(grid, source)
        if planes is None:
            packed, self.affine, self.inverse, self.aligned = (
                np.zeros(0),
                np.eye(3),
                np.eye(3),
                True,
            )
        else:
            packed, self.affine, self.inverse, self.aligned = planes
        build = getattr(_native, f"smoothing_stencil_{'int32' if itype == np.int32 else 'int64'}")
        self.kernel = build(
            np.ascontiguousarray(cells, dtype=itype).reshape(-1),
            vertices,
            packed,
            self.affine,
            self.aligned,
            int(hold_below),
            self.threads,
        )
        self.code = self.kernel.code
        self.n_small = int(self.kernel.small_components)
        lo, hi = self.kernel.bounds
        self.lo, self.hi = np.array(lo), np.array(hi)
        self.fixed = (self.code & _FIXED) != 0
        self.constrained = np.flatnonzero(((self.code & _PLANES) != 0) & ~self.fixed)
        bits = self.code[self.constrained, None] >> np.arange(3, dtype=np.uint8)
        self.mask = (bits & 1).astype(bool)

    def rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The neighbours each vertex averages: offsets (V + 1,) int64 and
        neighbours (E,), vertex i's being ``neighbours[offsets[i] : offsets[i + 1]]``."""
        return self.kernel.rows()

    def sinc(self, x: np.ndarray, c: np.ndarray, center, length: float) -> np.ndarray:
        """``sum_i c_i T_i(I - L / 2) x`` by the three-term Chebyshev recurrence, on
        ``(x - center) / length``, scaled back.

        Parameters
        ----------
        x : (V, 3) float64
        c : (N + 1,) float64
        center : (3,) float64
        length : float

        Returns
        -------
        (V, 3) float64
        """
        out = np.empty_like(x)
        self.kernel.sinc(
            np.ascontiguousarray(c, np.float64), x, _frame(center), length, self.threads, out
        )
        return out

    def steps(self, x: np.ndarray, factors: list[float], center, length: float) -> None:
        """``x -= f L x`` for each factor ``f`` in turn, on ``(x - center) / length``,
        in place; x (V, 3) float64."""
        self.kernel.steps(np.asarray(factors, np.float64), x, _frame(center), length, self.threads)

    def restore(self, out: np.ndarray, original: np.ndarray) -> None:
        """Put fixed vertices and constrained coordinates back exactly, in place.

        The filter keeps them up to rounding (of the normalized coordinates and
        of the sinc polynomial's sums).

        Parameters
        ----------
        out : (V, 3) float64
            Smoothed positions.
        original : (V, 3) float64
        """
        out[self.fixed] = original[self.fixed]
        c = self.constrained
        if not len(c):
            return
        if self.aligned:
            moved = out[c]
            moved[self.mask] = original[c][self.mask]
            out[c] = moved
        else:
            index_step = (out[c] - original[c]) @ self.inverse.T
            index_step[~self.mask] = 0.0
            out[c] -= index_step @ self.affine.T


def _frame(center) -> np.ndarray:
    return np.ascontiguousarray(center, dtype=np.float64).reshape(3)


def _grid_planes(grid, source: str):
    """The grid boundary planes vertices are held on, for the stencil kernel.

    Parameters
    ----------
    grid : dict or None

    Returns
    -------
    None, or a tuple of
        packed : (16,) float64, the origin, the inverse affine (row-major), ``shape
        - 1`` and the tolerance (1e-9 of the grid's largest size, in index units)
        within which a vertex lies on a plane (index coordinate 0 or ``shape - 1``);
        affine : (3, 3) float64, index offsets to world offsets;
        inverse : (3, 3) float64;
        aligned : bool, the affine is diagonal (index axes are world axes).
    """
    if grid is None:
        return None
    clean = normalized_grid(grid)
    if clean is None or len(clean["shape"]) != 3:
        raise IsoconvertError(
            f"{source}: the grid recorded with the mesh is not a usable 3D grid "
            "(shape, origin, invertible affine); pass a volume's grid to smooth it"
        )
    shape = np.asarray(clean["shape"], dtype=np.float64)
    affine = np.asarray(clean["affine"], dtype=np.float64)
    inverse = np.linalg.inv(affine)
    tolerance = _PLANE_TOLERANCE * max(float(shape.max()), 1.0)
    packed = np.concatenate(
        [np.asarray(clean["origin"], np.float64), inverse.ravel(), shape - 1.0, [tolerance]]
    )
    aligned = bool(np.count_nonzero(affine - np.diag(np.diag(affine))) == 0)
    return packed, affine, inverse, aligned
