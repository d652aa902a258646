"""Marching Squares (Wenger, *Isosurfaces*, section 2.2): 2D isocontours.

On a 2D volume it contours the image; on a 3D volume it contours every slice
across one axis (the slice-by-slice approach of book section 1.4), giving a
stack of 3D polylines.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import IsoconvertError
from ..mesh import Mesh
from ..volume import Volume
from .jit import compile_notice
from .placement import finish_mesh
from .prepare import check_level, check_vertex_offset, kernel_array
from .tables import AMBIGUITY_RULES, DEFAULT_AMBIGUITY, marching_squares_table

#: Ambiguity rules for squares: the two fixed ones and the asymptotic decider.
SQUARE_AMBIGUITY_RULES = (*AMBIGUITY_RULES, "asymptotic")
_AXES = {"x": 0, "y": 1, "z": 2}


def marching_squares(
    volume: Volume,
    level: float,
    *,
    flip: bool = False,
    ambiguity: str = DEFAULT_AMBIGUITY,
    nan_as: float | None = None,
    vertex_offset: float = 0.0,
    axis: str = "z",
    on_status: Callable[[str], None] | None = None,
) -> Mesh:
    """Extract isocontours: of a 2D image, or of every slice of a 3D volume.

    Parameters
    ----------
    volume : Volume
        2D, or 3D (then every slice across ``axis`` is contoured).
    level : float
        The isovalue; grid vertices with value >= level are positive.
    flip : bool
        Reverse segment directions (positive side on the right).
    ambiguity : str
        "separate-positive" (default, as scikit-image's ``find_contours``),
        "separate-negative", or "asymptotic" (the bilinear saddle decides).
    nan_as : float or None
        Treat NaN/Inf samples as this value; None makes them an error.
    vertex_offset : float
        Keep every vertex at least this fraction of its edge's length away from
        the edge's ends (0 <= f < 0.5). With f > 0, a level equal to grid values
        gives no zero-length edges (see :func:`check_vertex_offset`).
    axis : str
        For 3D volumes: "x", "y" or "z", the axis the slices are across.
    on_status : callable or None
        Receives one-line notices.

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` (z = 0 for 2D input), ``cells (C, 2) int64``
        segments with the positive side on their left when seen from the
        positive end of the slice axis, ``edge_ids (V,) int64``.
    """
    if ambiguity not in SQUARE_AMBIGUITY_RULES:
        raise IsoconvertError(
            f"unknown ambiguity rule {ambiguity!r} for squares; "
            f"choose one of: {', '.join(SQUARE_AMBIGUITY_RULES)}"
        )
    if axis not in _AXES:
        raise IsoconvertError(f"--axis must be x, y or z, got {axis!r}")
    rule = SQUARE_AMBIGUITY_RULES.index(ambiguity)
    ndim = volume.ndim
    arr, stats = kernel_array(volume, ndim, "squares", nan_as=nan_as, on_status=on_status)
    level = check_level(level, stats, volume.source)
    offset = check_vertex_offset(vertex_offset)
    counts, table_pos = marching_squares_table("separate-positive")
    table = np.stack([table_pos, marching_squares_table("separate-negative")[1]])
    notice = f"compiling the Marching Squares kernel for {arr.dtype} data (first run only)"
    with compile_notice(on_status, notice):
        from .kernels.squares import count_squares, fill_squares

        def contour(image):
            n_vert, n_seg = count_squares(image, level, counts)
            verts = np.empty((n_vert, 2), dtype=np.float64)
            ids = np.empty(n_vert, dtype=np.int64)
            segs = np.empty((n_seg, 2), dtype=np.int64)
            xmap = np.empty(image.shape, dtype=np.int64)
            ymap = np.empty(image.shape, dtype=np.int64)
            fill_squares(image, level, offset, rule, counts, table, verts, ids, segs, xmap, ymap)
            return verts, ids, segs

        if ndim == 2:
            verts, ids, segs = contour(arr)
            mesh = finish_mesh(volume, verts, segs, ids, flip, method="squares", level=level)
            mesh.vertices = np.column_stack([mesh.vertices, np.zeros(len(verts))])
            return mesh
        return _slices(volume, arr, level, _AXES[axis], contour, flip)


def _slices(volume, arr, level, a, contour, flip) -> Mesh:
    """Contour each slice across axis ``a``; in-plane axes ``(b, c)`` follow it
    cyclically, so (b, c, a) is right-handed and "left" is seen from +a."""
    b, c = (a + 1) % 3, (a + 2) % 3
    dims = volume.shape
    data = arr.T  # (X, Y, Z) view of the validated samples
    all_verts, all_ids, all_segs = [], [], []
    base = 0
    for s in range(dims[a]):
        index = [slice(None)] * 3
        index[a] = s
        plane = data[tuple(index)]  # remaining axes in increasing order
        if b > c:  # (x, z) for a = y: make it (z, x)
            plane = plane.T
        image = np.ascontiguousarray(plane.T)  # rows along c, columns along b
        verts2, ids2, segs = contour(image)
        if len(segs) == 0:
            continue
        verts = np.empty((len(verts2), 3), dtype=np.float64)
        verts[:, b] = verts2[:, 0]
        verts[:, c] = verts2[:, 1]
        verts[:, a] = s
        axis2, lin = ids2 % 2, ids2 // 2
        u, v = lin % dims[b], lin // dims[b]
        grid = np.empty((len(ids2), 3), dtype=np.int64)
        grid[:, b], grid[:, c], grid[:, a] = u, v, s
        axis3 = np.where(axis2 == 0, b, c)
        all_ids.append(3 * (grid[:, 0] + dims[0] * (grid[:, 1] + dims[1] * grid[:, 2])) + axis3)
        all_verts.append(verts)
        all_segs.append(segs + base)
        base += len(verts)
    if not all_segs:
        raise IsoconvertError(f"{volume.source}: no slice crosses level {level:g}")
    verts = np.concatenate(all_verts)
    segs = np.concatenate(all_segs)
    ids = np.concatenate(all_ids)
    return finish_mesh(volume, verts, segs, ids, flip, method="squares", level=level)
