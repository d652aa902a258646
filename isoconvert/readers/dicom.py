"""DICOM series (a folder of single-frame slices) via pydicom.

Opening a series reads the headers only (``stop_before_pixels``); the slices
are sorted by their position along the slice normal (not by file name or
InstanceNumber), and the pixel data is decoded slab by slab by
:class:`DicomSeriesGrid`, which applies RescaleSlope/RescaleIntercept so the
samples are in the modality's units (Hounsfield units for CT). World
coordinates are DICOM patient coordinates, LPS, in millimetres.
"""

from __future__ import annotations

import glob
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, one_line
from ..grid import LazyGrid
from ..volume import Volume
from .options import ReadOptions

#: relative and absolute (mm) tolerance of a slice gap against the median gap
_GAP_RTOL = 0.01
_GAP_ATOL = 0.01
#: tolerance on the orientation cosines of the slices of one series
_IOP_TOL = 1e-4

_PLUGINS = (
    "install pylibjpeg with pylibjpeg-libjpeg (or pylibjpeg-openjpeg, pylibjpeg-rle), or gdcm"
)


def _pydicom():
    try:
        import pydicom
    except ImportError:
        raise FormatError(
            "reading DICOM needs pydicom: pip install 'isoconvert[dicom]' (or pip install pydicom)"
        ) from None
    return pydicom


def _header(path: Path):
    """The dataset of ``path`` without pixel data, or None when it is not DICOM."""
    pydicom = _pydicom()
    try:
        return pydicom.dcmread(path, stop_before_pixels=True)
    except Exception:  # not DICOM, or a header pydicom cannot parse: not a slice
        return None


def _floats(ds, keyword: str, n: int, path: Path) -> np.ndarray:
    value = ds.get(keyword)
    try:
        out = np.array([float(v) for v in value], dtype=np.float64)
    except (TypeError, ValueError):
        out = np.empty(0)
    if out.shape != (n,) or not np.all(np.isfinite(out)):
        raise FormatError(
            f"{path}: {keyword} is missing or not {n} numbers ({value!r}); the slice cannot be "
            "placed (is this a localizer or a non-image object? remove it from the folder)"
        )
    return out


def read_dicom(path: Path, options: ReadOptions) -> Volume:
    """Read a DICOM series: a folder of slices, or one file of it (its folder's series).

    Parameters
    ----------
    path : Path
        A folder of DICOM files, one DICOM file (its folder's series) or a
        glob of DICOM files.
    options : ReadOptions
        ``series``: the SeriesInstanceUID to read when the folder holds several.

    Returns
    -------
    Volume
        Lazy (:class:`DicomSeriesGrid`), placed in LPS millimetres, values rescaled.

    Raises
    ------
    FormatError
        No DICOM image, several series and no ``series``, uneven or duplicate
        slice positions, a compressed transfer syntax pydicom cannot decode here.
    """
    path = Path(path)
    spec = str(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.is_file())
        where = f"in {path}"
    elif not path.exists() and glob.has_magic(spec):
        # a glob: the series among the files it matches
        files = sorted(Path(p) for p in glob.glob(spec) if Path(p).is_file())
        where = f"among the files {spec} matches"
    else:
        ds = _header(path)
        if ds is None or "Rows" not in ds:
            raise FormatError(
                f"{path}: not a readable DICOM image (no DICOM header with image rows); "
                "check the file, or name its format with --input-format"
            )
        files = sorted(p for p in path.parent.iterdir() if p.is_file())
        where = f"in {path.parent}"
    notes: list[str] = []
    headers = []
    skipped = []
    for f in files:
        ds = _header(f)
        if ds is None or "Rows" not in ds:
            skipped.append(f.name)
            continue
        headers.append((f, ds))
    if skipped:
        more = f" and {len(skipped) - 3} more" if len(skipped) > 3 else ""
        shown = ", ".join(skipped[:3]) + more
        notes.append(f"ignored {len(skipped)} file(s) that are not DICOM images: {shown}")
    if not headers:
        raise FormatError(
            f"{path}: no DICOM image files {where}; check the input, or name its format with "
            "--input-format"
        )

    series: dict[str, list] = {}
    for f, ds in headers:
        series.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))
    wanted = options.series
    if wanted is None and path.is_file():
        # one file given: its series
        mine = [str(ds.get("SeriesInstanceUID", "")) for f, ds in headers if f == path]
        if not mine:
            raise FormatError(f"{path}: not a DICOM image file")
        wanted = mine[0]
    if wanted is None:
        if len(series) > 1:
            listing = "; ".join(
                f"{uid} ({str(items[0][1].get('SeriesDescription', '') or 'no description')}, "
                f"{len(items)} slices)"
                for uid, items in series.items()
            )
            raise FormatError(
                f"{path}: {len(series)} DICOM series {where}: {listing}; choose one with "
                "--series UID"
            )
        wanted = next(iter(series))
    elif wanted not in series:
        raise FormatError(
            f"{path}: no series {wanted} {where}; there are {', '.join(series)}; "
            "give one of these to --series"
        )
    items = series[wanted]
    if len(series) > 1:
        notes.append(f"series {wanted}, one of {len(series)} {where}")
    return _series_volume(path, items, notes)


def _series_volume(path: Path, items: list, notes: list[str]) -> Volume:
    f0, ds0 = items[0]
    for f, ds in items:
        frames = int(ds.get("NumberOfFrames", 1) or 1)
        if frames > 1:
            raise FormatError(
                f"{f}: a multi-frame DICOM file ({frames} frames) is not read yet; give a folder "
                "of single-frame slices, or convert it (e.g. with dcm2niix) to NIfTI"
            )
        if int(ds.get("SamplesPerPixel", 1)) != 1:
            raise FormatError(
                f"{f}: colour DICOM ({ds.get('PhotometricInterpretation')}) is not a scalar "
                "volume; isoconvert reads grayscale series"
            )
    rows, cols = int(ds0.Rows), int(ds0.Columns)
    iop = _floats(ds0, "ImageOrientationPatient", 6, f0)
    row_cos, col_cos = iop[:3], iop[3:]
    normal = np.cross(row_cos, col_cos)
    if abs(np.linalg.norm(normal) - 1) > 1e-3:
        raise FormatError(
            f"{f0}: ImageOrientationPatient {iop.tolist()} is not two orthogonal unit vectors"
        )
    spacing_yx = _floats(ds0, "PixelSpacing", 2, f0)  # [row spacing (y), column spacing (x)]
    positions = []
    for f, ds in items:
        if (int(ds.Rows), int(ds.Columns)) != (rows, cols):
            raise FormatError(
                f"{f}: {int(ds.Columns)}x{int(ds.Rows)} pixels, but {f0.name} has {cols}x{rows}; "
                "a series must have slices of one size"
            )
        other = _floats(ds, "ImageOrientationPatient", 6, f)
        if np.max(np.abs(other - iop)) > _IOP_TOL:
            raise FormatError(
                f"{f}: ImageOrientationPatient differs from {f0.name}'s; the slices are not "
                "parallel (a localizer or a tilted series?): remove the odd files"
            )
        positions.append(float(_floats(ds, "ImagePositionPatient", 3, f) @ normal))
    order = np.argsort(positions, kind="stable")
    items = [items[i] for i in order]
    pos = np.asarray(positions)[order]
    names = [f.name for f, _ in items]
    origin = _floats(items[0][1], "ImagePositionPatient", 3, items[0][0])
    if len(items) == 1:
        dz = float(items[0][1].get("SliceThickness", 1) or 1)
        notes.append(f"one slice; z spacing {dz:g} from SliceThickness")
    else:
        gaps = np.diff(pos)
        dup = np.flatnonzero(gaps <= _GAP_ATOL)
        if dup.size:
            i = int(dup[0])
            raise FormatError(
                f"{path}: {dup.size} duplicate slice position(s), e.g. {names[i]} and "
                f"{names[i + 1]} both at {pos[i]:.3f} mm along the normal; remove the duplicates "
                "(or pick one series with --series)"
            )
        dz = float(np.median(gaps))
        bad = np.flatnonzero(np.abs(gaps - dz) > max(_GAP_RTOL * dz, _GAP_ATOL))
        if bad.size:
            lo, hi = int(np.argmin(gaps)), int(np.argmax(gaps))
            raise FormatError(
                f"{path}: uneven slice spacing: median gap {dz:.4g} mm, min {gaps[lo]:.4g} mm "
                f"(between {names[lo]} and {names[lo + 1]}), max {gaps[hi]:.4g} mm (between "
                f"{names[hi]} and {names[hi + 1]}), {bad.size} of {gaps.size} gaps off; a slice "
                "is missing or the series has varying spacing: resample it (e.g. with 3D Slicer)"
            )
    direction = np.column_stack([row_cos, col_cos, normal])
    dtype, slopes = _value_type(items)
    grid = DicomSeriesGrid(path, [f for f, _ in items], (cols, rows, len(items)), dtype, slopes)
    if any(s != (1.0, 0.0) for s in slopes):
        s, b = slopes[0]
        sign = "-" if b < 0 else "+"
        notes.append(
            f"values rescaled: stored * {s:g} {sign} {abs(b):g} (RescaleSlope/RescaleIntercept)"
        )
    return Volume(
        grid,
        spacing=(float(spacing_yx[1]), float(spacing_yx[0]), dz),
        origin=origin,
        direction=direction,
        source=str(path),
        notes=notes,
        unit="mm",
        frame="LPS",
    )


def _stored_range(ds) -> tuple[int, int]:
    bits = int(ds.get("BitsStored", ds.get("BitsAllocated", 16)))
    if int(ds.get("PixelRepresentation", 0)) == 1:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def _value_type(items: list) -> tuple[np.dtype, list[tuple[float, float]]]:
    """The sample type after rescaling, and each slice's (slope, intercept)."""
    slopes = []
    lo = hi = None
    integral = True
    for _, ds in items:
        s = float(ds.get("RescaleSlope", 1) or 1)
        b = float(ds.get("RescaleIntercept", 0) or 0)
        slopes.append((s, b))
        if ds.get("FloatPixelData") is not None or int(ds.get("BitsAllocated", 16)) > 32:
            integral = False
        integral = integral and s.is_integer() and b.is_integer()
        smin, smax = _stored_range(ds)
        ends = (smin * s + b, smax * s + b)
        lo = min(ends) if lo is None else min(lo, *ends)
        hi = max(ends) if hi is None else max(hi, *ends)
    if not integral:
        return np.dtype(np.float32), slopes
    eight = all(int(ds.get("BitsAllocated", 16)) == 8 for _, ds in items)
    types = (np.uint8, np.int16, np.uint16, np.int32) if eight else (np.int16, np.uint16, np.int32)
    for t in types:
        info = np.iinfo(t)
        if info.min <= lo and hi <= info.max:
            return np.dtype(t), slopes
    # beyond int32: float64 holds every integer up to 2**53 exactly
    if max(abs(lo), abs(hi)) <= 2**53:
        return np.dtype(np.float64), slopes
    raise VolumeError(f"{items[0][0]}: rescaled values {lo:g}..{hi:g} overflow every sample type")


class DicomSeriesGrid(LazyGrid):
    """A DICOM series read a slice (a file) at a time, rescaled.

    Holds paths and numbers only, decoding the files of a slab on each read:
    it pickles, and threads may read slabs at once.

    Parameters
    ----------
    path : str or Path
        The input as given, for messages.
    files : sequence of Path
        One file per z-layer, in increasing position along the slice normal.
    shape : (3,) tuple of int
        (X, Y, Z) = (Columns, Rows, slices).
    dtype : numpy dtype
        Of the rescaled samples.
    rescale : sequence of (slope, intercept)
        Per file.
    """

    def __init__(
        self,
        path: str | Path,
        files: Sequence[Path],
        shape: tuple[int, int, int],
        dtype: np.dtype,
        rescale: Sequence[tuple[float, float]],
    ):
        self.path = Path(path)
        self.files = [Path(f) for f in files]
        self.shape = tuple(int(n) for n in shape)
        self.dtype = np.dtype(dtype)
        self.rescale = [(float(s), float(b)) for s, b in rescale]

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        out = self._empty_slab(k0, k1)
        for z in range(k0, k1):
            out[z - k0] = self._slice(z)
        return out

    def _slice(self, z: int) -> np.ndarray:
        pydicom = _pydicom()
        f = self.files[z]
        ds = pydicom.dcmread(f)
        try:
            image = ds.pixel_array
        except Exception as exc:
            syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
            if syntax is not None and syntax.is_compressed:
                raise FormatError(
                    f"{f}: pixel data compressed as {syntax.name}, which pydicom cannot decode "
                    f"here; {_PLUGINS}"
                ) from None
            raise FormatError(f"{f}: cannot decode the pixel data ({one_line(exc)})") from None
        nx, ny, _ = self.shape
        if image.shape != (ny, nx):
            raise FormatError(
                f"{f}: the image is {'x'.join(map(str, image.shape[::-1]))}, not {nx}x{ny} as "
                "its header said when the series was opened; read it again"
            )
        s, b = self.rescale[z]
        if (s, b) == (1.0, 0.0):
            return image
        if self.dtype.kind == "f":
            return image.astype(self.dtype) * self.dtype.type(s) + self.dtype.type(b)
        return image.astype(np.int64) * int(s) + int(b)
