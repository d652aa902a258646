"""TIFF stacks (tifffile): one multi-page file, a folder of slices, or a glob."""

from __future__ import annotations

import glob as globlib
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputNotFoundError, VolumeError, one_line
from ..memory import check_fits
from ..volume import Volume
from .options import ReadOptions, select_channel
from .stacks import TIFF_SUFFIXES, natural_key


def slice_files(spec: str) -> list[Path]:
    """The TIFF files of a folder or glob, in natural order."""
    path = Path(spec)
    if path.is_dir():
        files = [p for p in path.iterdir() if p.suffix.lower() in TIFF_SUFFIXES and p.is_file()]
        where = f"folder {path}"
    else:
        files = [Path(p) for p in globlib.glob(spec) if Path(p).is_file()]
        where = f"pattern {spec!r}"
    if not files:
        raise InputNotFoundError(f"{where} holds no .tif/.tiff files")
    return sorted(files, key=natural_key)


def read_tiff(path: Path, options: ReadOptions) -> Volume:
    """Read a multi-page TIFF file, or a folder / glob of single-page slices.

    Spacing comes from ImageJ metadata (``spacing`` for z, resolution tags for x
    and y, which hold pixels per unit) or OME metadata; without a z spacing it
    is 1 on every axis and a note says so.
    """
    import tifffile

    spec = str(path)
    if path.is_file():
        files = [path]
    else:
        files = slice_files(spec)
    try:
        if len(files) == 1:
            with tifffile.TiffFile(files[0]) as tif:
                series = tif.series[0]
                series_notes = _check_series(tif, files[0])
                declared = int(np.prod(series.shape, dtype=np.float64)) * series.dtype.itemsize
                check_fits(declared, "the declared image series", spec)
                data = _pick_channel(series.asarray(), series.axes, options.channel, files[0])
                spacing, unit, notes = _spacing(tif, data.ndim)
                notes = series_notes + notes
        else:
            data = _stack_slices(files, options.channel)
            with tifffile.TiffFile(files[0]) as tif:
                spacing, unit, notes = _spacing(tif, 3)
            notes.insert(0, f"{len(files)} slices, {files[0].name} .. {files[-1].name}")
    except (tifffile.TiffFileError, ValueError, OSError, IndexError, KeyError) as exc:
        raise FormatError(f"{spec}: not a readable TIFF ({one_line(exc)})") from None
    if data.dtype == np.bool_:
        data = data.view(np.uint8)
    return Volume.from_zyx(data, spacing=spacing, source=spec, notes=notes, unit=unit)


def _check_series(tif, path: Path) -> list[str]:
    """Refuse a file whose pages differ in size (tifffile splits it into series).

    tifffile reads pages of one shape as one series; a plain multi-page file
    with an odd page becomes several series, of which only the first would be
    read. ImageJ hyperstacks and OME files are one series per image and pass.
    Reduced-resolution pages (thumbnails, pyramid levels) and masks are ignored.
    """
    if len(tif.series) < 2:
        return []
    pages = []
    for n in range(len(tif.pages)):
        page = tif.pages.get(n, aspage=True)  # a full page, never a lightweight frame
        if not getattr(page, "is_reduced", False) and not getattr(page, "is_mask", False):
            pages.append((n, page))
    first_n, first = pages[0] if pages else (0, tif.pages[0])
    for n, page in pages[1:]:
        if _page_size(page) != _page_size(first):
            raise VolumeError(
                f"{path}: page {n + 1} of {len(tif.pages)} is {_page_size(page)}, but page "
                f"{first_n + 1} is {_page_size(first)}; all pages of a stack must match (save "
                "the pages at one size, or split the file)"
            )
    shape = "x".join(map(str, tif.series[0].shape[::-1]))
    return [f"the file holds {len(tif.series)} image series; the first ({shape}) is read"]


def _page_size(page) -> str:
    """``"WxH dtype"`` (``"WxHxS dtype"`` with S samples per pixel) of a TIFF page."""
    samples = getattr(page, "samplesperpixel", 1)
    extra = f"x{samples}" if samples > 1 else ""
    return f"{page.imagewidth}x{page.imagelength}{extra} {page.dtype}"


def kept_axes(axes: str, shape: tuple[int, ...]) -> str:
    """The axes of a TIFF series the reader keeps: X, Y and every axis longer than 1.

    Of these, a ``C`` or ``S`` axis is the channel axis; the others are the image's.
    """
    return "".join(a for a, n in zip(axes, shape, strict=True) if n > 1 or a in "XY")


def _pick_channel(array: np.ndarray, axes: str, channel: int | None, path: Path) -> np.ndarray:
    """Drop singleton axes; select ``channel`` along a sample/channel axis."""
    keep = kept_axes(axes, array.shape)
    array = array.reshape([n for a, n in zip(axes, array.shape, strict=True) if a in keep])
    axes = "".join(keep)
    ax = next((i for i, a in enumerate(axes) if a in "CS"), None)
    array = select_channel(array, ax, channel, path, "channels (RGB or multi-channel)")
    if ax is not None:
        axes = axes[:ax] + axes[ax + 1 :]
    if array.ndim not in (2, 3):
        raise VolumeError(
            f"{path}: a TIFF with axes {axes} is not a 2D or 3D scalar image "
            "(time series and multi-series files are not supported)"
        )
    return array


def _stack_slices(files: list[Path], channel: int | None) -> np.ndarray:
    """Read single-image files into one (Z, Y, X) array, checking they match."""
    import tifffile

    first = None
    out = None
    for z, f in enumerate(files):
        with tifffile.TiffFile(f) as tif:
            series = tif.series[0]
            img = _pick_channel(series.asarray(), series.axes, channel, f)
        if img.ndim != 2:
            raise VolumeError(
                f"{f}: a slice of a stack must be one 2D image, got shape {img.shape}"
            )
        if first is None:
            first = (f, img.shape, img.dtype)
            check_fits(len(files) * img.nbytes, f"{len(files)} slices like {f.name}", str(f))
            out = np.empty((len(files),) + img.shape, dtype=img.dtype)
        elif (img.shape, img.dtype) != first[1:]:
            raise VolumeError(
                f"{f}: slice is {img.shape[1]}x{img.shape[0]} {img.dtype}, but {first[0].name} "
                f"is {first[1][1]}x{first[1][0]} {first[2]}; all slices must match"
            )
        out[z] = img
    return out


def _spacing(tif, ndim: int) -> tuple[np.ndarray | None, str | None, list[str]]:
    """Spacing (x, y[, z]) and unit from ImageJ, OME or resolution tags.

    A value that is not a positive finite number (0, negative, NaN, inf) is
    ignored with a note and 1 is used for its axis, so that ``--spacing`` can
    still override it.
    """
    notes: list[str] = []
    ome = _ome_spacing(tif, ndim, notes)
    if ome is not None:
        notes.append("spacing from OME metadata")
        return ome[0], ome[1], notes
    page = tif.pages[0]
    xy = _resolution_spacing(page, notes)
    ij = tif.imagej_metadata or {}
    unit = ij.get("unit")
    if isinstance(unit, str):
        unit = unit.encode().decode("unicode_escape") if "\\u" in unit else unit
        if unit == "pixel":
            unit = None
    if ndim == 2:
        if xy is not None:
            notes.append("spacing from the TIFF resolution tags")
            return np.array(xy), unit, notes
        return None, None, notes
    raw_z = ij.get("spacing")
    if raw_z is not None:
        z = _positive(raw_z)
        if z is None:
            notes.append(
                f"spacing {_show(raw_z)} in the ImageJ metadata ignored; using 1; set --spacing"
            )
            z = 1.0
        else:
            notes.append("spacing from ImageJ metadata")
        xy = xy if xy is not None else (1.0, 1.0)
        return np.array([xy[0], xy[1], z]), unit, notes
    found = f" (resolution tags give x, y spacing {xy[0]:g}, {xy[1]:g})" if xy else ""
    notes.append(f"no z spacing in the TIFF; using 1, 1, 1{found}; set --spacing")
    return None, None, notes


def _show(value) -> str:
    """A metadata value for a note: numbers as ``%g`` ("0", "nan"), the rest quoted."""
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError, OverflowError):
        return repr(value)


def _positive(value) -> float | None:
    """``value`` as a float when it is a positive finite number, else None."""
    try:
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        return None
    return number if np.isfinite(number) and number > 0 else None


def _resolution_spacing(page, notes: list[str]) -> tuple[float, float] | None:
    """x, y spacing as the reciprocal of the resolution tags (pixels per unit).

    None when a tag is absent; an unusable tag (0 or negative) gives 1 and a note.
    """
    values = []
    for name in ("XResolution", "YResolution"):
        tag = page.tags.get(name)
        if tag is None:
            return None
        try:
            num, den = tag.value
            spacing = _positive(den / num) if num > 0 and den > 0 else None
        except (TypeError, ValueError, ZeroDivisionError, OverflowError):
            num, den, spacing = tag.value, 1, None
        if spacing is None:
            notes.append(f"{name} {num}/{den} in the TIFF tags ignored; using 1; set --spacing")
            spacing = 1.0
        values.append(spacing)
    return values[0], values[1]


def _ome_spacing(tif, ndim: int, notes: list[str]):
    """Spacing and unit from the OME Pixels element; None when it lacks an axis."""
    if not tif.is_ome or not tif.ome_metadata:
        return None
    import xml.etree.ElementTree as ET

    try:
        root = ET.fromstring(tif.ome_metadata)
    except ET.ParseError:
        return None
    pixels = next((el for el in root.iter() if el.tag.endswith("Pixels")), None)
    if pixels is None:
        return None
    names = ("PhysicalSizeX", "PhysicalSizeY", "PhysicalSizeZ")[:ndim]
    values = [pixels.get(n) for n in names]
    if any(v is None for v in values):
        return None
    spacing = []
    for name, value in zip(names, values, strict=True):
        number = _positive(value)
        if number is None:
            notes.append(
                f"{name} {_show(value)} in the OME metadata ignored; using 1; set --spacing"
            )
            number = 1.0
        spacing.append(number)
    return np.array(spacing), pixels.get("PhysicalSizeXUnit", "µm")
