"""Volume: a scalar grid with its physical placement."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import VolumeError
from .grid import LazyGrid, SlabReader

#: dtypes the extractors accept without conversion (the kernels specialize on them).
SUPPORTED_DTYPES = (
    "uint8",
    "int8",
    "uint16",
    "int16",
    "uint32",
    "int32",
    "float32",
    "float64",
)

#: Anatomical frames that world coordinates may be stated in (see :attr:`Volume.frame`).
FRAMES = ("LPS", "RAS")

# Samples per chunk when scanning a volume (about 64 MiB of float64): statistics
# never need a full-size temporary.
_CHUNK_SAMPLES = 8 * 1024 * 1024


@dataclass
class Volume:
    """A 2D or 3D scalar grid in x, y(, z) index order.

    ``data[i, j, k]`` is the sample at grid vertex (i, j, k); x varies fastest in
    memory (a Fortran-ordered view of a C-ordered (z, y, x) array). The world
    position of grid vertex ``idx`` is ``origin + direction @ (idx * spacing)``.

    Attributes
    ----------
    data : (X, Y, Z) or (X, Y) array
        The samples, any of :data:`SUPPORTED_DTYPES` (or convertible to one).
        A volume may be made from a :class:`~isoconvert.grid.LazyGrid` instead
        (then :attr:`grid`): ``data`` reads it whole on first use, while
        block-wise extraction reads it slab by slab and never touches ``data``.
    spacing : (ndim,) float64
        Distance between neighbouring samples along each axis, > 0.
    origin : (ndim,) float64
        World position of grid vertex (0, 0, 0).
    direction : (ndim, ndim) float64
        Unit column vectors of the grid axes in world space (identity if the
        file has none).
    source : str
        Where the volume came from, for messages.
    notes : list of str
        What the reader assumed or derived (e.g. a shape taken from the file
        name), for the user to see.
    unit : str or None
        Unit of spacing and origin when the file states one.
    frame : str or None
        The anatomical frame of world coordinates when the file states one:
        "LPS" (x to the patient's left, y posterior, z superior: NRRD, DICOM,
        ITK's MetaImage) or "RAS" (NIfTI). :meth:`in_frame` converts.
    files : tuple of str
        Every file the header and samples are read from (a detached NRRD
        header and its data files, a MetaImage header and its
        ElementDataFile(s), each slice of a TIFF folder/glob, each DICOM file
        of the series, the .nii, .npy/.npz, raw file, Zarr store folder...),
        as given (absolute, not resolved through symlinks: a consumer that
        must tell whether an output is one of them compares device and
        inode). Empty for a volume made in memory.
    """

    data: np.ndarray
    spacing: np.ndarray = None  # type: ignore[assignment]
    origin: np.ndarray = None  # type: ignore[assignment]
    direction: np.ndarray = None  # type: ignore[assignment]
    source: str = "<array>"
    notes: list[str] = field(default_factory=list)
    unit: str | None = None
    frame: str | None = None
    files: tuple[str, ...] = ()

    # where ``data`` lives (see the property at the end of this module)
    _grid = None
    _array = None

    def __post_init__(self) -> None:
        nd = self.ndim
        if nd not in (2, 3):
            raise VolumeError(
                f"{self.source}: a volume needs 2 or 3 dimensions, got shape {self.shape}"
            )
        self.spacing = _vector(self.spacing, nd, 1.0, "spacing", self.source)
        self.origin = _vector(self.origin, nd, 0.0, "origin", self.source)
        if np.any(self.spacing <= 0):
            raise VolumeError(
                f"{self.source}: spacing {tuple(self.spacing.tolist())} must be positive; "
                "set it with --spacing"
            )
        self.files = tuple(str(f) for f in self.files)
        if self.direction is None:
            self.direction = np.eye(nd)
        self.direction = np.asarray(self.direction, dtype=np.float64)
        if self.direction.shape != (nd, nd) or not np.all(np.isfinite(self.direction)):
            raise VolumeError(
                f"{self.source}: direction must be a finite {nd}x{nd} matrix, "
                f"got shape {self.direction.shape}"
            )
        if abs(np.linalg.det(self.direction)) < 1e-6:
            raise VolumeError(f"{self.source}: the axis directions are degenerate (determinant 0)")

    @classmethod
    def from_zyx(cls, array: np.ndarray, **kwargs) -> Volume:
        """Wrap a C-ordered ``(Z, Y, X)`` (or ``(Y, X)``) array, as numpy/skimage
        store images, without copying."""
        return cls(np.asarray(array).T, **kwargs)

    @property
    def grid(self) -> LazyGrid | None:
        """The lazy grid the samples are read from, or None for an in-memory array."""
        return self._grid

    @property
    def samples(self) -> np.ndarray | LazyGrid:
        """The lazy grid when there is one, else ``data``: what scans that go
        slab by slab (statistics, block-wise extraction) should read."""
        return self._grid if self._grid is not None else self.data

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.samples.shape)

    @property
    def dtype(self) -> np.dtype:
        return self.samples.dtype

    def __repr__(self) -> str:
        kind = repr(self._grid) if self._grid is not None else f"array {self.shape}"
        return f"Volume({kind}, spacing={self.spacing.tolist()}, source={self.source!r})"

    @property
    def affine(self) -> np.ndarray:
        """(ndim, ndim) matrix taking index offsets to world offsets."""
        return self.direction * self.spacing[np.newaxis, :]

    def index_to_world(self, points: np.ndarray) -> np.ndarray:
        """Map index-space points to world space, in place when float64.

        Parameters
        ----------
        points : (N, ndim) float64
            Positions in grid index units (grid vertex (i, j, k) at (i, j, k)).

        Returns
        -------
        (N, ndim) float64
            ``origin + direction @ (points * spacing)``.
        """
        pts = np.asarray(points, dtype=np.float64)
        if np.array_equal(self.direction, np.eye(self.ndim)):
            pts *= self.spacing
        else:
            pts[:] = pts @ self.affine.T
        pts += self.origin
        return pts

    def with_placement(
        self, spacing: tuple[float, ...] | None = None, origin: tuple[float, ...] | None = None
    ) -> Volume:
        """A copy of this volume's description (sharing ``data``) with spacing
        and/or origin replaced, e.g. from the command line."""
        return Volume(
            self.samples,
            spacing=self.spacing if spacing is None else spacing,
            origin=self.origin if origin is None else origin,
            direction=self.direction,
            source=self.source,
            notes=list(self.notes),
            unit=self.unit,
            frame=self.frame,
            files=self.files,
        )

    def in_frame(self, frame: str) -> Volume:
        """This volume with world coordinates in ``frame`` ("lps" or "ras").

        LPS and RAS differ in the sign of x and y: a half turn about z, so
        every placement and every triangle's orientation carry over (the same
        mesh, turned). ``data`` is shared.

        Raises
        ------
        VolumeError
            An unknown frame, or a file that states none.
        """
        target = frame.upper()
        if target not in FRAMES:
            raise VolumeError(f"--space takes lps or ras, got {frame!r}")
        if self.frame is None:
            raise VolumeError(
                f"{self.source}: the file does not say which anatomical frame its coordinates "
                "are in, so --space cannot convert them; drop --space"
            )
        if self.frame == target:
            return self
        turn = np.diag([-1.0, -1.0, 1.0])[: self.ndim, : self.ndim]
        return Volume(
            self.samples,
            spacing=self.spacing,
            origin=turn @ self.origin,
            direction=turn @ self.direction,
            source=self.source,
            notes=[*self.notes, f"coordinates converted from {self.frame} to {target}"],
            unit=self.unit,
            frame=target,
            files=self.files,
        )


def _get_data(self: Volume) -> np.ndarray:
    if self._array is None:
        self._array = np.asarray(self._grid)
    return self._array


def _set_data(self: Volume, value) -> None:
    if isinstance(value, LazyGrid):
        self._grid, self._array = value, None
    else:
        self._grid = None
        self._array = value if isinstance(value, np.ndarray) else np.asarray(value)


# ``data`` reads a lazy grid on first use; the dataclass's __init__ goes through the setter.
Volume.data = property(_get_data, _set_data, doc=Volume.__doc__ and "The samples (X, Y[, Z]).")


def _vector(value, nd: int, default: float, name: str, source: str) -> np.ndarray:
    if value is None:
        return np.full(nd, default, dtype=np.float64)
    arr = np.asarray(value, dtype=np.float64).reshape(-1)
    if arr.shape != (nd,) or not np.all(np.isfinite(arr)):
        raise VolumeError(
            f"{source}: {name} needs {nd} finite numbers for a {nd}D volume, "
            f"got {tuple(arr.tolist())}"
        )
    return arr


def slabs(data: np.ndarray | LazyGrid):
    """Yield contiguous slabs of ``data`` along its last (slowest) axis, each
    about ``_CHUNK_SAMPLES`` samples, so that scans need no full-size temporary
    (and a lazy grid is read one slab at a time)."""
    per_slice = max(1, int(np.prod(data.shape[:-1])))
    step = max(1, _CHUNK_SAMPLES // per_slice)
    reader = SlabReader(data) if isinstance(data, LazyGrid) else None
    for k in range(0, data.shape[-1], step):
        if reader is not None:
            yield reader.read(k, min(k + step, data.shape[2])).T
        else:
            yield data[..., k : k + step]


@dataclass(frozen=True)
class ValueRange:
    """Minimum and maximum of a volume's finite samples, and how many are not finite."""

    min: float
    max: float
    nonfinite: int


def value_range(data: np.ndarray) -> ValueRange:
    """Scan ``data`` slab by slab for its finite range and count of NaN/Inf."""
    lo, hi, bad = np.inf, -np.inf, 0
    floating = np.issubdtype(data.dtype, np.floating)
    for slab in slabs(data):
        if floating:
            finite = np.isfinite(slab)
            nfin = int(finite.sum())
            bad += slab.size - nfin
            if nfin == 0:
                continue
            if nfin < slab.size:
                slab = slab[finite]
        lo = min(lo, float(slab.min()))
        hi = max(hi, float(slab.max()))
    return ValueRange(lo, hi, bad)


def grid_from_volume(volume: Volume) -> dict:
    """The grid of a volume, as extracted meshes record it in ``info["grid"]``.

    Extractors record it in the meshes they make. Pass it as
    ``isoconvert.check_mesh(mesh, grid=...)`` to judge a mesh file's boundaries
    against the volume it was extracted from (``isoconvert check --grid VOLUME``).

    Parameters
    ----------
    volume : Volume
        Only its shape and placement are used (no samples are read).

    Returns
    -------
    dict
        ``shape`` (ndim,) list of int, ``origin`` (ndim,) list of float and
        ``affine`` (ndim, ndim) nested list of float (index offsets to world
        offsets, :attr:`Volume.affine`): plain lists, ready for JSON or a
        file header.
    """
    return {
        "shape": [int(n) for n in volume.shape],
        "origin": np.asarray(volume.origin, dtype=np.float64).tolist(),
        "affine": np.asarray(volume.affine, dtype=np.float64).tolist(),
    }
