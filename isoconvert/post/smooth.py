"""Smoothing that keeps volume: windowed-sinc (default), Taubin lambda/mu, Laplacian.

All three move each vertex by the umbrella operator ``L x_i = x_i - mean(x_j)``
over its neighbours ``j`` (uniform weights), built once from the unique edges
and applied with :func:`numpy.bincount`; they differ in the polynomial of ``L``
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
from ..graph import connected_components, group_rows, topology
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
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
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
    stencil = _Stencil(
        vertices, cells.astype(np.int64, copy=False), grid, source, options.hold_below
    )

    # filter on coordinates centred on the bounding box of the used vertices and
    # divided by its diagonal (VTK's NormalizeCoordinates): the sinc polynomial's
    # terms alternate in sign and grow with the iterations, which is better
    # conditioned on numbers of order 1 (VTK does the same)
    used = vertices[stencil.used]
    lo, hi = used.min(axis=0), used.max(axis=0)
    center = 0.5 * (lo + hi)
    length = float(np.linalg.norm(hi - lo)) or 1.0
    # coordinates as rows (3, V): the per-axis gathers and sums run on contiguous memory
    x = np.ascontiguousarray(((vertices - center) / length).T)

    if options.method == "sinc":
        c, converged = sinc_coefficients(options.iterations, options.passband)
        x = _sinc(x, stencil, c)
        record["converged"] = bool(converged)
    elif options.method == "taubin":
        for _ in range(options.iterations):
            x = x - options.lam * stencil.laplacian(x)
            x = x - options.taubin_mu * stencil.laplacian(x)
    else:
        for _ in range(options.iterations):
            x = x - options.lam * stencil.laplacian(x)

    out = np.ascontiguousarray(x.T * length + center)  # (V, 3) C order, as readers give
    stencil.restore(out, vertices)
    record.update(
        fixed_vertices=int(stencil.fixed.sum()),
        boundary_curve_vertices=int(stencil.curve.sum()),
        grid_constrained_vertices=int(stencil.n_constrained),
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


def _sinc(x0: np.ndarray, stencil: _Stencil, c: np.ndarray) -> np.ndarray:
    """``sum_i c_i T_i(I - L / 2) x0`` by the three-term Chebyshev recurrence.

    Parameters
    ----------
    x0 : (3, V) float64
    stencil : _Stencil
    c : (N + 1,) float64

    Returns
    -------
    (3, V) float64
    """
    from .. import _native

    # T_0 x = x, T_1 x = x - L x / 2, T_{i+1} x = 2 (I - L / 2) T_i x - T_{i-1} x
    x1 = x0 - 0.5 * stencil.laplacian(x0)
    out = c[0] * x0 + c[1] * x1
    for ci in c[2:]:
        x2 = stencil.laplacian(x1)  # L x1, made x2 = 2 x1 - L x1 - x0 in one pass
        _native.chebyshev_step(x0, x1, x2, float(ci), stencil.threads, out)
        x0, x1 = x1, x2
    return out


class _Stencil:
    """Which neighbours each vertex averages, and which directions it may move in.

    Parameters
    ----------
    vertices : (V, 3) float64
    cells : (C, 3) int64
    grid : dict or None
    source : str
        For messages.
    hold_below : int
        Components of fewer vertices are fixed.
    """

    def __init__(
        self, vertices: np.ndarray, cells: np.ndarray, grid, source: str, hold_below: int
    ) -> None:
        n = len(vertices)
        edges, counts, nonmanifold_vertices = _edges(cells, n)
        a, b = edges[:, 0], edges[:, 1]
        degree = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
        boundary = counts == 1
        n_boundary = np.bincount(a[boundary], minlength=n) + np.bincount(b[boundary], minlength=n)
        many = counts > 2
        on_many = (np.bincount(a[many], minlength=n) + np.bincount(b[many], minlength=n)) > 0

        fixed = (degree == 0) | on_many | ((n_boundary != 0) & (n_boundary != 2))
        fixed[nonmanifold_vertices] = True
        component = connected_components(n, a, b)
        size = np.bincount(component, weights=degree > 0, minlength=n)
        self.small = (size[component] < hold_below) & (degree > 0)
        self.n_small = int(np.count_nonzero((size > 0) & (size < hold_below)))
        fixed |= self.small
        self.used = degree > 0
        # open-boundary vertices average their two boundary neighbours only
        self.curve = (n_boundary == 2) & ~fixed

        self.planes = _grid_planes(vertices, grid, source)
        if self.planes is not None:
            mask = self.planes[0]
            fixed |= mask.all(axis=1)
        self.fixed = fixed

        # directed stencil entries target <- neighbour: every edge of a simple
        # vertex, only the boundary edges of a curve vertex, none of a fixed one
        free = ~fixed & ~self.curve
        take_ab = free[a] | (boundary & self.curve[a])
        take_ba = free[b] | (boundary & self.curve[b])
        target = np.concatenate([a[take_ab], b[take_ba]])
        neighbour = np.concatenate([b[take_ab], a[take_ba]])
        # in compressed rows for the compiled kernel: vertex i's neighbours are
        # neighbours[offsets[i] : offsets[i + 1]]
        self.offsets, self.neighbours = group_rows(n, target, neighbour)
        counts = np.diff(self.offsets)
        self.threads = kernel_threads()
        count = counts.astype(np.float64)
        self.still = np.flatnonzero(count == 0)
        self.inverse_count = np.divide(1.0, count, out=np.zeros(n), where=count > 0)
        self.n = n

        if self.planes is not None:
            mask, affine, inverse, aligned = self.planes
            constrained = mask.any(axis=1) & ~fixed
            self.constrained = np.flatnonzero(constrained)
            self.mask = mask[self.constrained]
            self.affine, self.inverse, self.aligned = affine, inverse, aligned
        else:
            self.constrained = np.zeros(0, np.int64)
        self.n_constrained = len(self.constrained)

    def laplacian(self, x: np.ndarray) -> np.ndarray:
        """``x_i - mean(x_j)`` over each vertex's stencil, zero for fixed vertices and
        without its component along the grid axes a vertex is held on.

        Parameters
        ----------
        x : (3, V) float64
            Coordinates as rows.

        Returns
        -------
        (3, V) float64
        """
        from .. import _native

        out = np.empty_like(x)
        _native.umbrella(self.offsets, self.neighbours, self.inverse_count, x, self.threads, out)
        if len(self.still):
            out[:, self.still] = 0.0
        if self.n_constrained:
            c = self.constrained
            step = out[:, c].T  # (K, 3)
            if self.aligned:
                # index axes are world axes (scaled): zero those components
                step[self.mask] = 0.0
            else:
                # remove the step's component along the constrained index axes
                # (an oblique projection that keeps those index coordinates)
                index_step = step @ self.inverse.T
                index_step[self.mask] = 0.0
                step = index_step @ self.affine.T
            out[:, c] = step.T
        return out

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
        if not self.n_constrained:
            return
        c = self.constrained
        if self.aligned:
            moved = out[c]
            moved[self.mask] = original[c][self.mask]
            out[c] = moved
        else:
            index_step = (out[c] - original[c]) @ self.inverse.T
            index_step[~self.mask] = 0.0
            out[c] -= index_step @ self.affine.T


def _edges(cells: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique edges, their triangle counts and the non-manifold vertices.

    Parameters
    ----------
    cells : (C, 3) int64
    n : int
        Number of vertices.

    Returns
    -------
    edges : (E, 2) int64
        Lower index first, ordered by the lower index.
    counts : (E,) int64
        Triangles using each edge.
    nonmanifold : (K,) int64
        Vertices whose triangles form more than one fan.

    Notes
    -----
    One pass of the compiled topology kernel the mesh report uses (the one
    behind :func:`isoconvert.graph.edge_table`), which also counts the fans
    around every vertex. Triangles that repeat a vertex are skipped.
    """
    table = topology(cells, n)
    return (
        table["all_edges"].astype(np.int64, copy=False),
        table["all_counts"].astype(np.int64, copy=False),
        np.asarray(table["non_manifold_vertices"], dtype=np.int64),
    )


def _grid_planes(vertices: np.ndarray, grid, source: str):
    """Which grid boundary planes each vertex lies on.

    Parameters
    ----------
    vertices : (V, 3) float64
    grid : dict or None

    Returns
    -------
    None, or a tuple of
        mask : (V, 3) bool, the vertex has index coordinate 0 or ``shape - 1``
        along the axis (within 1e-9 of the grid's largest size);
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
    origin = np.asarray(clean["origin"], dtype=np.float64)
    affine = np.asarray(clean["affine"], dtype=np.float64)
    inverse = np.linalg.inv(affine)
    index = (vertices - origin) @ inverse.T
    tolerance = _PLANE_TOLERANCE * max(float(shape.max()), 1.0)
    mask = (np.abs(index) <= tolerance) | (np.abs(index - (shape - 1.0)) <= tolerance)
    aligned = bool(np.count_nonzero(affine - np.diag(np.diag(affine))) == 0)
    return mask, affine, inverse, aligned
