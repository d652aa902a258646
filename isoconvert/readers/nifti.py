"""NIfTI-1 and NIfTI-2 volumes (``.nii``, ``.nii.gz``), through nibabel.

Axes. NIfTI stores samples with the first index (i, x) varying fastest, as
isoconvert holds them; nibabel's arrays are ``(X, Y, Z[, T])``.

Placement. The voxel-to-world affine is the sform when ``sform_code > 0``,
else the qform when ``qform_code > 0``, else nibabel's fallback (the voxel
sizes, centred, x flipped as in Analyze); a note says which. Its 3x3 part's
column lengths are the spacing, the normalised columns the direction, its
translation the origin. World coordinates are NIfTI's RAS+ (x towards the
patient's right, y anterior, z superior), not the LPS of DICOM and most NRRD
files (there x and y are negated): a note says so.

Samples. ``scl_slope`` / ``scl_inter`` (slope set, not 0 or NaN, and not the
identity) are applied, making the samples float; such images are read into
memory. Uncompressed, unscaled 3D images (and one volume of a 4D image) are a
lazy :class:`~isoconvert.grid.RawGrid` on the file from ``vox_offset``.
A 4D image needs ``volume_index``; 5D and more are refused. A 2D image (or a
3D image of one slice) is read as a 2D image.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import DAMAGED_FILE, FormatError, VolumeError, extra_hint, one_line
from ..grid import RawGrid
from ..memory import check_fits
from ..volume import Volume
from .options import ReadOptions, absolute_files

_RAS_NOTE = "coordinates in RAS (NIfTI's frame)"
_UNITS = {"mm": "mm", "micron": "µm", "meter": "m"}
_GZIP_MAGIC = b"\x1f\x8b"


def _nibabel():
    try:
        import nibabel
    except ImportError:
        raise FormatError(f"reading NIfTI needs nibabel: {extra_hint('nifti')}") from None
    return nibabel


def _load(path: Path):
    nib = _nibabel()
    try:
        img = nib.load(str(path))
    except Exception as exc:  # nibabel raises many kinds on a corrupt header
        raise FormatError(
            f"{path}: not a readable NIfTI file ({type(exc).__name__}: {one_line(exc)}); "
            f"{DAMAGED_FILE}"
        ) from None
    if not isinstance(img, nib.Nifti1Image):  # Nifti2Image is a subclass
        raise FormatError(
            f"{path}: not a NIfTI file (nibabel reads it as {type(img).__name__}); "
            "convert it to NIfTI or NRRD first"
        )
    return img


def nifti_ndim(path: Path) -> int | None:
    """Spatial dimensions (2 or 3) of a NIfTI file from its header (for batch, which
    skips 2D images); None when unreadable."""
    try:
        shape = _spatial_shape(_load(Path(path)).header.get_data_shape())
    except Exception:  # an unreadable header: reading it says what is wrong
        return None
    return 2 if len(shape) == 2 or shape[2] == 1 else 3


def _spatial_shape(shape: tuple[int, ...]) -> tuple[int, ...]:
    """The shape without trailing axes of length 1 beyond the third."""
    shape = tuple(int(n) for n in shape)
    while len(shape) > 3 and shape[-1] == 1:
        shape = shape[:-1]
    return shape


def read_nifti(path: Path, options: ReadOptions) -> Volume:
    """Read a NIfTI-1/NIfTI-2 ``.nii`` or ``.nii.gz`` with its affine.

    Parameters
    ----------
    path : Path
        The file.
    options : ReadOptions
        ``volume_index``: the volume of a 4D image to read.

    Raises
    ------
    FormatError
        nibabel missing, not a NIfTI file, truncated data.
    VolumeError
        A 4D image without ``volume_index`` (or with one out of range), 5D or more.
    """
    img = _load(path)
    header = img.header
    shape = _spatial_shape(header.get_data_shape())
    index = _volume_index(shape, options.volume_index, path)
    xyz = shape[:3]
    notes: list[str] = []
    if index is not None and shape[3] > 1:
        notes.append(f"volume {index} of {shape[3]}")
    dtype = header.get_data_dtype()
    # nibabel moves scl_slope/scl_inter into the proxy on loading (1 and 0 when the
    # slope is 0 or NaN, i.e. not set) and clears them in the header
    slope = float(getattr(img.dataobj, "slope", 1.0))
    inter = float(getattr(img.dataobj, "inter", 0.0))
    scaled = (slope, inter) != (1.0, 0.0)
    if scaled:
        notes.append(f"samples scaled by scl_slope {slope:g}, scl_inter {inter:g}")
    affine, which = _affine(header)
    notes.append(which)
    if not which.startswith("placement from the sform"):  # placed by pixdim's voxel sizes
        notes.extend(_voxel_size_notes(_raw_pixdim(path, header), min(len(xyz), 3)))
    notes.append(_RAS_NOTE)
    unit = _UNITS.get(header.get_xyzt_units()[0])
    flat = len(xyz) == 2 or xyz[2] == 1
    # the proxy's offset: nibabel reads vox_offset 0 in a single file as 352 (the minimum)
    offset = int(getattr(img.dataobj, "offset", header.get_data_offset()))
    per_volume = math.prod(xyz) * dtype.itemsize  # Python integers: never wraps
    if not scaled and not flat and not _gzipped(path) and dtype.kind in "biuf":
        start = offset + (index or 0) * per_volume
        have = os.path.getsize(path) - start
        if have < per_volume:
            raise FormatError(
                f"{path}: the NIfTI file holds {max(have, 0)} bytes of samples"
                f"{'' if index is None else f' for volume {index}'}, but its header declares "
                f"{'x'.join(map(str, xyz))} of {dtype.name} ({per_volume} bytes); the file is "
                "truncated"
            )
        data = RawGrid(path, dtype, xyz, start)
    else:
        check_fits(per_volume * (8 // dtype.itemsize if scaled else 1), "the volume", str(path))
        proxy = img.dataobj
        part = proxy[:, :, :, index] if index is not None else proxy
        data = np.asanyarray(part)
        data = data.reshape(xyz)
        if data.dtype.byteorder not in "=|":
            data = data.astype(data.dtype.newbyteorder("="))
    spacing, direction, origin = _placement(affine, notes)
    if flat:
        notes.append("one slice: read as a 2D image")
        if not np.allclose(affine[:2, 2], 0) or not np.allclose(affine[2, :2], 0):
            notes.append("the slice's tilt out of the x-y plane is dropped")
        data = data.reshape(xyz[:2])
        spacing, origin = spacing[:2], origin[:2]
        sub = direction[:2, :2]
        lengths = np.linalg.norm(sub, axis=0)
        if np.all(lengths > 1e-6) and abs(np.linalg.det(sub / lengths)) > 1e-6:
            direction = sub / lengths
        else:
            direction = None
    return Volume(
        data,
        spacing=spacing,
        origin=origin,
        direction=direction,
        source=str(path),
        notes=notes,
        unit=unit,
        frame="RAS",
        files=absolute_files([path]),
    )


def _volume_index(shape: tuple[int, ...], index: int | None, path: Path) -> int | None:
    if len(shape) > 4:
        raise VolumeError(
            f"{path}: the NIfTI image has {len(shape)} dimensions {shape}; only 2D, 3D and 4D "
            "(one volume picked with --volume-index) are read"
        )
    if len(shape) < 4:
        if index is not None and index != 0:
            raise VolumeError(
                f"{path}: --volume-index {index} given, but the NIfTI file holds one volume"
            )
        return None
    count = shape[3]
    if count == 1:
        return 0
    if index is None:
        raise VolumeError(
            f"{path}: the NIfTI file holds {count} volumes; choose one with --volume-index "
            f"0..{count - 1}"
        )
    if not 0 <= index < count:
        raise VolumeError(f"{path}: --volume-index {index} is out of range 0..{count - 1}")
    return index


def _affine(header) -> tuple[np.ndarray, str]:
    """The voxel-to-world affine and the note saying which it is: the sform when its code
    is set and it is usable, else the qform when its code is set and it is usable, else
    nibabel's fallback from the voxel sizes."""
    sform_code = int(header["sform_code"])
    qform_code = int(header["qform_code"])
    passed = []  # why a form whose code is set was not used
    if sform_code > 0:
        sform = header.get_sform()
        why = _unusable(sform)
        if why is None:
            return sform, f"placement from the sform (sform_code {sform_code})"
        passed.append(f"sform unusable ({why})")
    if qform_code > 0:
        qform = header.get_qform()
        why = _unusable(qform)
        if why is None:
            if passed:
                return qform, f"{passed[0]}; placed by the qform (qform_code {qform_code})"
            return qform, f"placement from the qform (qform_code {qform_code}; no sform)"
        passed.append(f"qform unusable ({why})")
    why = "; ".join(passed) if passed else "no sform or qform"
    base = header.get_base_affine()
    if _unusable(base) is not None:  # a voxel size is not finite: 1 there, the others kept
        header = header.copy()
        sizes = np.asarray(header["pixdim"][1:4], dtype=np.float64)
        header["pixdim"][1:4] = np.where(np.isfinite(sizes) & (sizes > 0), sizes, 1.0)
        base = header.get_base_affine()
    return base, (
        f"placement from the voxel sizes only ({why}; nibabel's fallback, centred, x flipped)"
    )


def _raw_pixdim(path: Path, header) -> np.ndarray:
    """pixdim as the file holds it: nibabel's loading replaces a 0 by 1 and a
    negative value by its size (with a logged warning), so the header it gives
    has lost them."""
    from nibabel.openers import ImageOpener

    try:
        with ImageOpener(str(path)) as fh:
            return np.asarray(type(header).from_fileobj(fh, check=False)["pixdim"])
    except Exception:  # unreadable twice is unreadable once: the loaded header will do
        return np.asarray(header["pixdim"])


def _voxel_size_notes(pixdim: np.ndarray, dims: int) -> list[str]:
    """Notes on pixdim values that are no voxel size (0, negative, not finite), which
    nibabel's qform and fallback replace (0 by 1, a negative one by its size)."""
    notes = []
    for axis, value in zip("xyz"[:dims], pixdim[1 : dims + 1], strict=True):
        value = float(value)
        if not np.isfinite(value):
            notes.append(f"pixdim {axis} {value} is not a voxel size; using 1 (set --spacing)")
        elif value == 0:
            notes.append(f"pixdim {axis} 0 is not a voxel size; using 1 (set --spacing)")
        elif value < 0:
            notes.append(f"pixdim {axis} {value:g} is negative; using {-value:g} (set --spacing)")
    return notes


def _unusable(affine: np.ndarray) -> str | None:
    """Why a 4x4 affine cannot place a grid (None when it can): not finite, zero, or singular
    (an axis of zero length, or axes in one plane)."""
    affine = np.asarray(affine, dtype=np.float64)
    if not np.all(np.isfinite(affine)):
        return "not finite"
    linear = affine[:3, :3]
    if not np.any(linear):
        return "zero"
    lengths = np.linalg.norm(linear, axis=0)
    if not np.all(lengths > 0) or abs(np.linalg.det(linear / lengths)) <= 1e-6:
        return "singular"
    return None


def _placement(affine: np.ndarray, notes: list[str]):
    """(spacing, direction, origin) of a 4x4 voxel-to-world affine."""
    linear = np.asarray(affine[:3, :3], dtype=np.float64)
    origin = np.asarray(affine[:3, 3], dtype=np.float64)
    spacing = np.linalg.norm(linear, axis=0)
    good = np.all(np.isfinite(linear)) and np.all(spacing > 0) and np.all(np.isfinite(origin))
    if good:
        direction = linear / spacing
        good = abs(np.linalg.det(direction)) > 1e-6
    if not good:
        notes.append("the NIfTI affine is degenerate; using spacing 1 and no direction")
        return np.ones(3), np.eye(3), np.zeros(3)
    return spacing, direction, origin


def _gzipped(path: Path) -> bool:
    with open(path, "rb") as fh:
        return fh.read(2) == _GZIP_MAGIC
