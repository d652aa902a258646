"""Isosurfaces of plain numpy arrays, called the way scikit-image users call theirs.

``skimage.measure.marching_cubes(volume, level, spacing=(dz, dy, dx))`` takes a
C-ordered ``(z, y, x)`` array and returns vertices in ``(z, y, x)`` columns.
:func:`marching_cubes` takes the same array, level and ``(z, y, x)`` spacing
(and an origin, in the same order) and returns an isoconvert
:class:`~isoconvert.mesh.Mesh`, whose vertices are ``(x, y, z)`` like every
mesh file and library downstream (``mesh.vertices[:, ::-1]`` gives
scikit-image's columns). No copy of the array is made: its transpose is the
``(x, y, z)`` view isoconvert's volumes hold.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .errors import VolumeError
from .mesh import Mesh
from .volume import Volume


def volume_from_zyx(
    volume_zyx: np.ndarray,
    spacing: Sequence[float] = (1.0, 1.0, 1.0),
    origin: Sequence[float] = (0.0, 0.0, 0.0),
) -> Volume:
    """A :class:`~isoconvert.volume.Volume` of a ``(z, y, x)`` array.

    Parameters
    ----------
    volume_zyx : (Z, Y, X) array
        Samples, C order as numpy, scikit-image and most readers give them.
    spacing, origin : 3 floats, (z, y, x) order
        Distance between samples along z, y, x and the world position of
        sample ``[0, 0, 0]``.

    Returns
    -------
    Volume
        ``data`` the ``(X, Y, Z)`` transpose (a view), spacing and origin
        reversed into (x, y, z).
    """
    array = np.asarray(volume_zyx)
    if array.ndim != 3:
        raise VolumeError(f"marching_cubes: expected a 3D (z, y, x) array, got shape {array.shape}")
    spacing = np.asarray(spacing, dtype=np.float64).reshape(-1)
    origin = np.asarray(origin, dtype=np.float64).reshape(-1)
    for name, given in (("spacing", spacing), ("origin", origin)):
        if given.shape != (3,):
            raise VolumeError(f"marching_cubes: {name} needs 3 numbers (z, y, x), got {given}")
    return Volume.from_zyx(array, spacing=spacing[::-1].copy(), origin=origin[::-1].copy())


def marching_cubes(
    volume_zyx: np.ndarray,
    level: float | str | None = None,
    *,
    spacing: Sequence[float] = (1.0, 1.0, 1.0),
    origin: Sequence[float] = (0.0, 0.0, 0.0),
    method: str = "cubes",
    normals: bool = False,
    flip: bool = False,
    **options,
) -> Mesh:
    """The isosurface of a ``(z, y, x)`` numpy array, as scikit-image is called.

    Parameters
    ----------
    volume_zyx : (Z, Y, X) array
        The samples (any dtype isoconvert extracts from; no copy is made).
    level : float, "auto" or None
        The isovalue; None takes ``(min + max) / 2`` as scikit-image does,
        "auto" Otsu's threshold.
    spacing : 3 floats, (z, y, x)
        As scikit-image's ``spacing``.
    origin : 3 floats, (z, y, x)
        World position of ``volume_zyx[0, 0, 0]`` (scikit-image has none: 0).
    method : str
        ``cubes`` (the default), ``tetra`` or a plugin.
    normals : bool
        Also give unit vertex normals from the volume's gradient
        (``mesh.normals``, like scikit-image's ``normals``).
    flip : bool
        Reverse the orientation.
    **options
        As for :func:`isoconvert.extract` (``ambiguity``, ``nan_as``, ...).

    Returns
    -------
    Mesh
        ``vertices (V, 3) float64`` in **(x, y, z)** world columns
        (``mesh.vertices[:, ::-1]`` is scikit-image's ``verts``),
        ``cells (C, 3) int64`` whose right-hand normals point from values >=
        level to values < level (outward from a bright object, where
        scikit-image's ``gradient_direction="descent"`` points its normals).
    """
    from .attributes import vertex_normals
    from .extract import extract

    volume = volume_from_zyx(volume_zyx, spacing, origin)
    if level is None:
        array = np.asarray(volume_zyx)
        level = 0.5 * (float(np.nanmin(array)) + float(np.nanmax(array)))
    mesh = extract(volume, level, method=method, flip=flip, normals=normals, **options)
    if normals and len(mesh.cells) and mesh.normals is None:  # not from the filling pass
        mesh.normals = vertex_normals(mesh, volume, flip=flip, nan_as=options.get("nan_as"))
    return mesh


__all__ = ["marching_cubes", "volume_from_zyx"]
