"""DICOM via pydicom: a series of single-frame slices, or one enhanced multi-frame file.

Opening a series reads the headers only (``stop_before_pixels``); the slices
are sorted by their position along the slice normal (not by file name or
InstanceNumber), and the pixel data is decoded slab by slab by
:class:`DicomSeriesGrid`, which applies RescaleSlope/RescaleIntercept so the
samples are in the modality's units (Hounsfield units for CT). World
coordinates are DICOM patient coordinates, LPS, in millimetres.

An enhanced multi-frame file (Enhanced CT/MR/PET Image Storage, or any file
with per-frame functional groups) is one volume: each frame's position,
orientation, pixel spacing and rescale come from its functional groups
(PerFrameFunctionalGroupsSequence, else SharedFunctionalGroupsSequence), the
frames are sorted by position along the normal exactly as slices are, and
:class:`DicomFramesGrid` decodes only the frames of the slab asked for.
"""

from __future__ import annotations

import glob
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, extra_hint, one_line
from ..grid import LazyGrid
from ..volume import Volume
from .options import ReadOptions, absolute_files, spacing_note

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
        raise FormatError(f"reading DICOM needs pydicom: {extra_hint('dicom')}") from None
    return pydicom


def _header(path: Path):
    """The dataset of ``path`` without pixel data, or None when it is not DICOM."""
    pydicom = _pydicom()
    try:
        return pydicom.dcmread(path, stop_before_pixels=True)
    except Exception:  # not DICOM, or a header pydicom cannot parse: not a slice
        return None


def _numbers(ds, keyword: str, n: int) -> np.ndarray | None:
    """``n`` finite numbers from ``ds``'s ``keyword``, or None when missing or malformed."""
    value = None if ds is None else ds.get(keyword)
    try:
        out = np.array([float(v) for v in value], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if out.shape != (n,) or not np.all(np.isfinite(out)):
        return None
    return out


def _floats(ds, keyword: str, n: int, path: Path) -> np.ndarray:
    out = _numbers(ds, keyword, n)
    if out is None:
        value = ds.get(keyword)
        raise FormatError(
            f"{path}: {keyword} is missing or not {n} numbers ({value!r}); the slice cannot be "
            "placed (is this a localizer or a non-image object? remove it from the folder)"
        )
    return out


def _shown(value) -> str:
    """A DICOM value for a note: "missing", or what it holds."""
    if value is None:
        return "missing"
    if isinstance(value, (str, bytes, int, float)):
        return str(value)
    try:
        return "[" + ", ".join(str(v) for v in value) + "]"
    except TypeError:
        return repr(value)


def _pixel_spacing(ds, name: str, notes: list[str]) -> np.ndarray:
    """PixelSpacing [row spacing (y), column spacing (x)] of ``ds``; 1, 1 and a note
    (that ``--spacing`` removes) when it is missing or not two positive numbers, so
    that ``--spacing`` can always set it."""
    spacing = _numbers(ds, "PixelSpacing", 2)
    if spacing is not None and np.all(spacing > 0):
        return spacing
    notes.append(
        spacing_note(
            f"PixelSpacing {_shown(ds.get('PixelSpacing'))} in {name} is not two positive "
            "numbers; using 1 for x and y; set --spacing"
        )
    )
    return np.ones(2)


def _thickness(ds, what: str, notes: list[str]) -> float:
    """The z spacing of a volume of one slice: its SliceThickness, or 1 when that is
    missing or not a positive number (with a note either way, which ``--spacing``
    removes)."""
    value = ds.get("SliceThickness")
    try:
        dz = float(value)
    except (TypeError, ValueError):
        dz = float("nan")
    if np.isfinite(dz) and dz > 0:
        notes.append(spacing_note(f"{what}; z spacing {dz:g} from SliceThickness"))
        return dz
    notes.append(
        spacing_note(
            f"{what}; SliceThickness {_shown(value)} is not a positive number, so z "
            "spacing 1; set --spacing"
        )
    )
    return 1.0


def _is_multiframe(ds) -> bool:
    """True for an enhanced multi-frame image (or any file of several frames)."""
    return int(ds.get("NumberOfFrames", 1) or 1) > 1 or "PerFrameFunctionalGroupsSequence" in ds


def _count(items: list) -> str:
    """What a series holds, for the listing of several series."""
    frames = [int(ds.get("NumberOfFrames", 1) or 1) for _, ds in items if _is_multiframe(ds)]
    if not frames:
        return "1 slice" if len(items) == 1 else f"{len(items)} slices"
    if len(items) == 1:
        return f"one multi-frame file of {frames[0]} frames"
    return f"{len(items)} files, {len(frames)} of them multi-frame"


@dataclass(frozen=True)
class DicomSeries:
    """One image series among the DICOM files of a folder (see :func:`folder_series`)."""

    uid: str  # SeriesInstanceUID ("" when the files have none)
    number: int | None  # SeriesNumber, when the files give one
    description: str  # SeriesDescription, or ""
    files: int  # DICOM image files
    frames: int  # images: the files' frames (a slice each for single-frame files)


def _image_headers(files: list[Path]) -> tuple[list[tuple[Path, object]], list[str]]:
    """The (file, dataset) pairs of the DICOM images among ``files``, and the names
    of the others."""
    headers, skipped = [], []
    for f in files:
        ds = _header(f)
        if ds is None or "Rows" not in ds:
            skipped.append(f.name)
            continue
        headers.append((f, ds))
    return headers, skipped


def _by_series(headers: list[tuple[Path, object]]) -> dict[str, list]:
    """``headers`` grouped by SeriesInstanceUID, in the order of their first files."""
    series: dict[str, list] = {}
    for f, ds in headers:
        series.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))
    return series


def folder_series(folder: Path) -> list[DicomSeries]:
    """The image series of the DICOM files directly in ``folder``, read from their
    headers only, by series number (then UID).

    Raises
    ------
    FormatError
        pydicom is not installed.
    """
    files = sorted(p for p in Path(folder).iterdir() if p.is_file())
    found = []
    for uid, items in _by_series(_image_headers(files)[0]).items():
        ds = items[0][1]
        try:
            number = int(ds.get("SeriesNumber"))
        except (TypeError, ValueError):
            number = None
        frames = sum(int(d.get("NumberOfFrames", 1) or 1) for _, d in items)
        description = str(ds.get("SeriesDescription", "") or "")
        found.append(DicomSeries(uid, number, description, len(items), frames))
    return sorted(found, key=lambda s: (s.number is None, s.number or 0, s.uid))


def read_dicom(path: Path, options: ReadOptions) -> Volume:
    """Read a DICOM series (a folder of slices, or one file of it) or a multi-frame file.

    Parameters
    ----------
    path : Path
        A folder of DICOM files, one DICOM file (its folder's series; an
        enhanced multi-frame file alone) or a glob of DICOM files. A series
        that is one multi-frame file reads as that file.
    options : ReadOptions
        ``series``: the SeriesInstanceUID to read when the folder holds several.

    Returns
    -------
    Volume
        Lazy (:class:`DicomSeriesGrid`, or :class:`DicomFramesGrid` for a
        multi-frame file), placed in LPS millimetres, values rescaled.

    Raises
    ------
    FormatError
        No DICOM image, several series and no ``series``, uneven or duplicate
        slice positions, a multi-frame file holding several volumes (repeated
        positions, mixed orientations) or frames that cannot be placed, a
        compressed transfer syntax pydicom cannot decode here.
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
        if _is_multiframe(ds) and options.series in (None, str(ds.get("SeriesInstanceUID", ""))):
            # a multi-frame file is a volume by itself: its folder need not be scanned
            return _multiframe_volume(path, path, ds, [])
        files = sorted(p for p in path.parent.iterdir() if p.is_file())
        where = f"in {path.parent}"
    notes: list[str] = []
    headers, skipped = _image_headers(files)
    if skipped:
        more = f" and {len(skipped) - 3} more" if len(skipped) > 3 else ""
        shown = ", ".join(skipped[:3]) + more
        notes.append(f"ignored {len(skipped)} file(s) that are not DICOM images: {shown}")
    if not headers:
        raise FormatError(
            f"{path}: no DICOM image files {where}; check the input, or name its format with "
            "--input-format"
        )

    series = _by_series(headers)
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
                f"{_count(items)})"
                for uid, items in series.items()
            )
            raise FormatError(
                f"{path}: {len(series)} DICOM series{'' if path.is_dir() else ' ' + where}: "
                f"{listing}; choose one with --series UID"
            )
        wanted = next(iter(series))
    elif wanted not in series:
        raise FormatError(
            f"{path}: no series {wanted}{'' if path.is_dir() else ' ' + where}; there are "
            f"{', '.join(series)}; "
            "give one of these to --series"
        )
    items = series[wanted]
    if len(series) > 1:
        notes.append(f"series {wanted}, one of {len(series)} {where}")
    multi = [f.name for f, ds in items if _is_multiframe(ds)]
    if multi and len(items) == 1:
        return _named(_multiframe_volume(path, items[0][0], items[0][1], notes), series, wanted)
    if len(items) == 1:
        raise FormatError(
            f"{path}: series {wanted or '(no UID)'}{'' if path.is_dir() else ' ' + where} is "
            "one slice, an image rather than a volume (a localizer?); a surface needs a "
            "series of two or more slices"
        )
    if multi:
        shown = ", ".join(multi[:3]) + (f" and {len(multi) - 3} more" if len(multi) > 3 else "")
        raise FormatError(
            f"{path}: series {wanted} {where} is {len(items)} files, {len(multi)} of them "
            f"multi-frame ({shown}); a multi-frame file is a volume by itself: give one file "
            "as the input"
        )
    return _named(_series_volume(path, items, notes), series, wanted)


def _named(volume: Volume, series: dict, wanted: str) -> Volume:
    """``volume``, its source naming the series when its folder holds several (the
    mesh headers and messages then say which)."""
    if len(series) > 1:
        volume.source = f"{volume.source} (series {wanted})"
    return volume


def _series_volume(path: Path, items: list, notes: list[str]) -> Volume:
    f0, ds0 = items[0]
    for f, ds in items:
        _check_grayscale(f, ds)
    rows, cols = int(ds0.Rows), int(ds0.Columns)
    iop = _floats(ds0, "ImageOrientationPatient", 6, f0)
    row_cos, col_cos = iop[:3], iop[3:]
    normal = np.cross(row_cos, col_cos)
    if abs(np.linalg.norm(normal) - 1) > 1e-3:
        raise FormatError(
            f"{f0}: ImageOrientationPatient {iop.tolist()} is not two orthogonal unit vectors"
        )
    # [row spacing (y), column spacing (x)]; 1, 1 and a note when missing or not positive
    spacing_yx = _pixel_spacing(ds0, f0.name, notes)
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
        dz = _thickness(items[0][1], "one slice", notes)
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
        dz = _even_gap(path, gaps, names, "slice", "series")
    direction = np.column_stack([row_cos, col_cos, normal])
    dtype, slopes = _value_type(items)
    grid = DicomSeriesGrid(path, [f for f, _ in items], (cols, rows, len(items)), dtype, slopes)
    if any(s != (1.0, 0.0) for s in slopes):
        notes.append(_rescale_note(*slopes[0]))
    return Volume(
        grid,
        spacing=(float(spacing_yx[1]), float(spacing_yx[0]), dz),
        origin=origin,
        direction=direction,
        source=str(path),
        notes=notes,
        unit="mm",
        frame="LPS",
        files=absolute_files(f for f, _ in items),
    )


#: Functional groups whose differing values tell why frames repeat a position:
#: (sequence, attribute, what the distinct values are), for the refusal message.
_FRAME_KINDS = (
    ("FrameContentSequence", "TemporalPositionIndex", "temporal positions"),
    ("FrameContentSequence", "StackID", "stacks"),
    ("MREchoSequence", "EffectiveEchoTime", "echo times"),
    ("MRDiffusionSequence", "DiffusionBValue", "b-values"),
)


def _group_item(frame, shared, sequence: str):
    """The item of functional-group ``sequence`` that applies to a frame: from the frame's
    own group, else from the shared group (DICOM puts each macro in one of the two), else
    None."""
    for group in (frame, shared):
        seq = None if group is None else group.get(sequence)
        if seq:
            return seq[0]
    return None


def _vector_text(values: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"


def _multiframe_volume(path: Path, f: Path, ds, notes: list[str]) -> Volume:
    """The volume of one enhanced multi-frame file ``f`` (header ``ds``, without pixels).

    Each frame is placed from its functional groups: PlanePositionSequence,
    PlaneOrientationSequence, PixelMeasuresSequence and
    PixelValueTransformationSequence, per frame or shared (the top-level
    attributes where a file has them instead). The frames are sorted by
    position along the slice normal, as the slices of a series are.
    """
    _check_grayscale(f, ds)
    n = int(ds.get("NumberOfFrames", 1) or 1)
    per_frame = ds.get("PerFrameFunctionalGroupsSequence")
    if not per_frame:
        sop = ds.get("SOPClassUID")
        kind = getattr(sop, "name", None) or str(sop or "unknown SOP class")
        raise FormatError(
            f"{f}: a multi-frame DICOM file ({n} frames, {kind}) without per-frame functional "
            "groups (PerFrameFunctionalGroupsSequence), so its frames cannot be placed; "
            "isoconvert reads enhanced multi-frame images and series of single-frame slices: "
            "convert it (e.g. with dcm2niix) to NIfTI"
        )
    if len(per_frame) != n:
        raise FormatError(
            f"{f}: NumberOfFrames is {n} but PerFrameFunctionalGroupsSequence has "
            f"{len(per_frame)} items; the file is inconsistent: re-export it"
        )
    shared_seq = ds.get("SharedFunctionalGroupsSequence")
    shared = shared_seq[0] if shared_seq else None

    def missing(i: int, keyword: str, sequence: str) -> FormatError:
        return FormatError(
            f"{f}: frame {i + 1} of {n} has no valid {keyword} ({sequence} in its per-frame or "
            "shared functional groups), so it cannot be placed; re-export the file, or convert "
            "it (e.g. with dcm2niix) to NIfTI"
        )

    positions = np.empty((n, 3))
    orientations = np.empty((n, 6))
    spacings = np.empty((n, 2))  # [row spacing (y), column spacing (x)] as in PixelSpacing
    rescale = []
    # a top-level RescaleSlope/Intercept applies to frames whose groups state none
    top = _rescale_of(ds)
    for i, frame in enumerate(per_frame):
        item = _group_item(frame, shared, "PlanePositionSequence")
        ipp = _numbers(item, "ImagePositionPatient", 3)
        if ipp is None:
            raise missing(i, "ImagePositionPatient", "PlanePositionSequence")
        item = _group_item(frame, shared, "PlaneOrientationSequence")
        iop = _numbers(item if item is not None else ds, "ImageOrientationPatient", 6)
        if iop is None:
            raise missing(i, "ImageOrientationPatient", "PlaneOrientationSequence")
        item = _group_item(frame, shared, "PixelMeasuresSequence")
        spacing = _numbers(item if item is not None else ds, "PixelSpacing", 2)
        if spacing is None or not np.all(spacing > 0):
            spacing = np.full(2, np.nan)  # said once for all frames, below
        positions[i], orientations[i], spacings[i] = ipp, iop, spacing
        item = _group_item(frame, shared, "PixelValueTransformationSequence")
        rescale.append(_rescale_of(item, top))

    iop = orientations[0]
    odd = np.flatnonzero(np.max(np.abs(orientations - iop), axis=1) > _IOP_TOL)
    if odd.size:
        kinds = len(np.unique(np.round(orientations, 4), axis=0))
        j = int(odd[0])
        raise FormatError(
            f"{f}: the frames have {kinds} different orientations (ImageOrientationPatient), "
            f"e.g. frame 1 {_vector_text(iop)} and frame {j + 1} {_vector_text(orientations[j])}; "
            "frames that are not parallel (several stacks, a localizer) are not one volume: split "
            "the file (e.g. with dcm2niix) and read one stack"
        )
    row_cos, col_cos = iop[:3], iop[3:]
    normal = np.cross(row_cos, col_cos)
    if abs(np.linalg.norm(normal) - 1) > 1e-3:
        raise FormatError(
            f"{f}: ImageOrientationPatient {iop.tolist()} is not two orthogonal unit vectors"
        )
    unplaced = np.flatnonzero(np.isnan(spacings[:, 0]))
    if unplaced.size:
        j = int(unplaced[0])
        item = _group_item(per_frame[j], shared, "PixelMeasuresSequence")
        value = (item if item is not None else ds).get("PixelSpacing")
        notes.append(
            spacing_note(
                f"PixelSpacing {_shown(value)} of frame {j + 1} ({unplaced.size} of {n} frames) "
                "is not two positive numbers; using 1 for x and y; set --spacing"
            )
        )
        spacings[:] = 1.0
    odd = np.flatnonzero(np.any(np.abs(spacings - spacings[0]) > 1e-6 * spacings[0], axis=1))
    if odd.size:
        j = int(odd[0])
        raise FormatError(
            f"{f}: the frames have different PixelSpacing, e.g. frame 1 "
            f"{_vector_text(spacings[0])} and frame {j + 1} {_vector_text(spacings[j])}; "
            "resample the file to one pixel size (e.g. with 3D Slicer)"
        )

    along = positions @ normal
    order = np.argsort(along, kind="stable")
    pos = along[order]
    if n == 1:
        item = _group_item(per_frame[0], shared, "PixelMeasuresSequence")
        dz = _thickness(item if item is not None else ds, "one frame", notes)
    else:
        gaps = np.diff(pos)
        same = int(np.count_nonzero(gaps <= _GAP_ATOL))
        if same:
            raise FormatError(_repeated_positions(f, per_frame, n, n - same))
        dz = _even_gap(path, gaps, [f"frame {k + 1}" for k in order], "frame", "file")

    per_z = [rescale[k] for k in order]
    dtype = _rescaled_type(f, [(ds, sb) for sb in dict.fromkeys(per_z)])
    grid = DicomFramesGrid(path, f, (int(ds.Columns), int(ds.Rows), n), dtype, order, per_z)
    notes.append(f"enhanced multi-frame file of {n} frames, sorted by position along the normal")
    if len(set(per_z)) > 1:
        notes.append("values rescaled frame by frame (RescaleSlope/RescaleIntercept)")
    elif per_z[0] != (1.0, 0.0):
        notes.append(_rescale_note(*per_z[0]))
    return Volume(
        grid,
        spacing=(float(spacings[0, 1]), float(spacings[0, 0]), dz),
        origin=positions[order[0]],
        direction=np.column_stack([row_cos, col_cos, normal]),
        source=str(path),
        notes=notes,
        unit="mm",
        frame="LPS",
        files=absolute_files([f]),
    )


def _repeated_positions(f: Path, per_frame, n: int, distinct: int) -> str:
    """The message refusing a file whose frames repeat positions: what repeats, and why
    when the functional groups say (temporal positions, stacks, echoes, b-values)."""
    found = []
    for sequence, keyword, what in _FRAME_KINDS:
        values = set()
        for frame in per_frame:
            item = _group_item(frame, None, sequence)
            if item is not None and item.get(keyword) is not None:
                values.add(str(item.get(keyword)))
        if len(values) > 1:
            found.append(f"{len(values)} {what}")
    why = f" ({', '.join(found)})" if found else ""
    return (
        f"{f}: {n} frames at only {distinct} distinct positions along the slice normal{why}: "
        "the file holds several volumes and isoconvert reads one; convert it to NIfTI (e.g. "
        "with dcm2niix) and pick one volume with --volume-index"
    )


def _check_grayscale(f: Path, ds) -> None:
    if int(ds.get("SamplesPerPixel", 1)) != 1:
        raise FormatError(
            f"{f}: colour DICOM ({ds.get('PhotometricInterpretation')}) is not a scalar "
            "volume; isoconvert reads grayscale series"
        )


def _even_gap(path: Path, gaps: np.ndarray, names: list[str], unit: str, whole: str) -> float:
    """The spacing along the normal: the median of ``gaps`` (positive, between the sorted
    slices or frames called ``names``), refused when any gap is off it.

    The spacing comes from the positions, never from SliceThickness, which is the
    thickness of the slab a slice integrates and may overlap or leave gaps.
    """
    dz = float(np.median(gaps))
    bad = np.flatnonzero(np.abs(gaps - dz) > max(_GAP_RTOL * dz, _GAP_ATOL))
    if bad.size:
        lo, hi = int(np.argmin(gaps)), int(np.argmax(gaps))
        raise FormatError(
            f"{path}: uneven {unit} spacing: median gap {dz:.4g} mm, min {gaps[lo]:.4g} mm "
            f"(between {names[lo]} and {names[lo + 1]}), max {gaps[hi]:.4g} mm (between "
            f"{names[hi]} and {names[hi + 1]}), {bad.size} of {gaps.size} gaps off; a {unit} "
            f"is missing or the {whole} has varying spacing: resample it (e.g. with 3D Slicer)"
        )
    return dz


def _stored_range(ds) -> tuple[int, int]:
    bits = int(ds.get("BitsStored", ds.get("BitsAllocated", 16)))
    if int(ds.get("PixelRepresentation", 0)) == 1:
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def _rescale_of(ds, fallback: tuple[float, float] = (1.0, 0.0)) -> tuple[float, float]:
    """(RescaleSlope, RescaleIntercept) of ``ds`` (a dataset or a functional-group item),
    ``fallback`` where it has none."""
    if ds is None or (ds.get("RescaleSlope") is None and ds.get("RescaleIntercept") is None):
        return fallback
    return float(ds.get("RescaleSlope", 1) or 1), float(ds.get("RescaleIntercept", 0) or 0)


def _value_type(items: list) -> tuple[np.dtype, list[tuple[float, float]]]:
    """The sample type after rescaling, and each slice's (slope, intercept)."""
    slopes = [_rescale_of(ds) for _, ds in items]
    pairs = [(ds, s) for (_, ds), s in zip(items, slopes, strict=True)]
    return _rescaled_type(items[0][0], pairs), slopes


def _rescaled_type(name: Path, pairs: list) -> np.dtype:
    """The sample type that holds every stored value of each (header, (slope, intercept))
    pair rescaled: the whole stored range (BitsStored), not only the values present."""
    lo = hi = None
    integral = True
    for ds, (s, b) in pairs:
        if ds.get("FloatPixelData") is not None or int(ds.get("BitsAllocated", 16)) > 32:
            integral = False
        integral = integral and s.is_integer() and b.is_integer()
        smin, smax = _stored_range(ds)
        ends = (smin * s + b, smax * s + b)
        lo = min(ends) if lo is None else min(lo, *ends)
        hi = max(ends) if hi is None else max(hi, *ends)
    if not integral:
        return np.dtype(np.float32)
    eight = all(int(ds.get("BitsAllocated", 16)) == 8 for ds, _ in pairs)
    types = (np.uint8, np.int16, np.uint16, np.int32) if eight else (np.int16, np.uint16, np.int32)
    for t in types:
        info = np.iinfo(t)
        if info.min <= lo and hi <= info.max:
            return np.dtype(t)
    # beyond int32: float64 holds every integer up to 2**53 exactly
    if max(abs(lo), abs(hi)) <= 2**53:
        return np.dtype(np.float64)
    raise VolumeError(f"{name}: rescaled values {lo:g}..{hi:g} overflow every sample type")


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
            raise _decode_error(f, ds, exc) from None
        nx, ny, _ = self.shape
        if image.shape != (ny, nx):
            raise FormatError(
                f"{f}: the image is {'x'.join(map(str, image.shape[::-1]))}, not {nx}x{ny} as "
                "its header said when the series was opened; read it again"
            )
        return _apply_rescale(image, self.rescale[z], self.dtype)


def _apply_rescale(image: np.ndarray, rescale: tuple[float, float], dtype: np.dtype) -> np.ndarray:
    """Stored values to the modality's units; the caller stores the result as ``dtype``
    (which :func:`_rescaled_type` chose to hold every rescaled value)."""
    s, b = rescale
    if (s, b) == (1.0, 0.0):
        return image
    if dtype.kind == "f":
        return image.astype(dtype) * dtype.type(s) + dtype.type(b)
    return image.astype(np.int64) * int(s) + int(b)


def _decode_error(f: Path, ds, exc: Exception) -> FormatError:
    """The error for pixel data of ``f`` (header ``ds``, or None to read it) that pydicom
    failed to decode: the decoder package to install when it is compressed."""
    if ds is None:
        ds = _header(f)
    syntax = getattr(getattr(ds, "file_meta", None), "TransferSyntaxUID", None)
    if syntax is not None and syntax.is_compressed:
        return FormatError(
            f"{f}: pixel data compressed as {syntax.name}, which pydicom cannot decode here; "
            f"{_PLUGINS}"
        )
    return FormatError(f"{f}: cannot decode the pixel data ({one_line(exc)})")


class DicomFramesGrid(LazyGrid):
    """An enhanced multi-frame DICOM file read a few frames at a time, rescaled.

    With pydicom 3 a slab decodes only its own frames (``pydicom.pixels.iter_pixels``
    reads their bytes from the file; an uncompressed file is not read whole).
    pydicom 2 can only decode every frame at once, so there the frames are decoded
    once, on the first read, and kept for later slabs (not pickled): one copy of the
    stored samples, the practical route for one file.

    Holds the file's name and numbers only: it pickles, and threads may read slabs
    at once.

    Parameters
    ----------
    path : str or Path
        The input as given, for messages.
    file : Path
        The multi-frame file.
    shape : (3,) tuple of int
        (X, Y, Z) = (Columns, Rows, frames).
    dtype : numpy dtype
        Of the rescaled samples.
    frames : sequence of int
        The frame (0-based, in file order) of each z-layer, in increasing position
        along the slice normal.
    rescale : sequence of (slope, intercept)
        Per z-layer.
    """

    def __init__(
        self,
        path: str | Path,
        file: Path,
        shape: tuple[int, int, int],
        dtype: np.dtype,
        frames: Sequence[int],
        rescale: Sequence[tuple[float, float]],
    ):
        self.path = Path(path)
        self.file = Path(file)
        self.shape = tuple(int(n) for n in shape)
        self.dtype = np.dtype(dtype)
        self.frames = [int(k) for k in frames]
        self.rescale = [(float(s), float(b)) for s, b in rescale]
        self._decoded: np.ndarray | None = None  # pydicom 2 only: every frame, decoded

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_decoded"] = None  # a worker decodes its own frames
        return state

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        out = self._empty_slab(k0, k1)
        nx, ny, _ = self.shape
        frames = self._decode(self.frames[k0:k1])
        for z, image in zip(range(k0, k1), frames, strict=True):
            if image.shape != (ny, nx):
                raise FormatError(
                    f"{self.file}: frame {self.frames[z] + 1} is "
                    f"{'x'.join(map(str, image.shape[::-1]))}, not {nx}x{ny} as the header said "
                    "when the file was opened; read it again"
                )
            out[z - k0] = _apply_rescale(image, self.rescale[z], self.dtype)
        return out

    def _decode(self, indices: list[int]) -> list[np.ndarray]:
        """The stored values of frames ``indices`` (0-based), in that order."""
        pydicom = _pydicom()
        try:
            try:
                from pydicom.pixels import iter_pixels
            except ImportError:  # pydicom 2
                if self._decoded is None:
                    nx, ny, _ = self.shape
                    whole = pydicom.dcmread(self.file).pixel_array
                    self._decoded = whole.reshape(-1, ny, nx)
                return [self._decoded[k] for k in indices]
            return list(iter_pixels(self.file, indices=indices))
        except Exception as exc:
            raise _decode_error(self.file, None, exc) from None


def _rescale_note(slope: float, intercept: float) -> str:
    """The note saying how stored values became the volume's (HU for CT)."""
    sign = "-" if intercept < 0 else "+"
    return (
        f"values rescaled: stored * {slope:g} {sign} {abs(intercept):g} "
        "(RescaleSlope/RescaleIntercept)"
    )
