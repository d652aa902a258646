"""TIFF stacks (tifffile): one multi-page file, a folder of slices, or a glob."""

from __future__ import annotations

import glob as globlib
import re
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputNotFoundError, VolumeError, one_line
from ..memory import check_fits
from ..volume import Volume
from .options import ReadOptions, select_channel

TIFF_SUFFIXES = (".tif", ".tiff")


def natural_key(path: Path) -> list:
    """Sort key putting slice2 before slice10."""
    return natural_text_key(path.name)


def natural_text_key(text: str) -> list:
    """Sort key comparing runs of digits as numbers ("a2/b" before "a10/b")."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", text)]


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
                declared = int(np.prod(series.shape, dtype=np.float64)) * series.dtype.itemsize
                check_fits(declared, "the declared image series", spec)
                data = _pick_channel(series.asarray(), series.axes, options.channel, files[0])
                spacing, unit, notes = _spacing(tif, data.ndim)
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


def _pick_channel(array: np.ndarray, axes: str, channel: int | None, path: Path) -> np.ndarray:
    """Drop singleton axes; select ``channel`` along a sample/channel axis."""
    keep = [a for a, n in zip(axes, array.shape, strict=True) if n > 1 or a in "XY"]
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
    """Spacing (x, y[, z]) and unit from ImageJ, OME or resolution tags."""
    notes: list[str] = []
    ome = _ome_spacing(tif, ndim)
    if ome is not None:
        notes.append("spacing from OME metadata")
        return ome[0], ome[1], notes
    page = tif.pages[0]
    xy = _resolution_spacing(page)
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
    z = ij.get("spacing")
    if z is not None and float(z) > 0:
        xy = xy if xy is not None else (1.0, 1.0)
        notes.append("spacing from ImageJ metadata")
        return np.array([xy[0], xy[1], float(z)]), unit, notes
    found = f" (resolution tags give x, y spacing {xy[0]:g}, {xy[1]:g})" if xy else ""
    notes.append(f"no z spacing in the TIFF; using 1, 1, 1{found}; set --spacing")
    return None, None, notes


def _resolution_spacing(page) -> tuple[float, float] | None:
    """x, y spacing as the reciprocal of the resolution tags (pixels per unit)."""
    values = []
    for name in ("XResolution", "YResolution"):
        tag = page.tags.get(name)
        if tag is None:
            return None
        num, den = tag.value
        if num <= 0 or den <= 0:
            return None
        values.append(den / num)
    return values[0], values[1]


def _ome_spacing(tif, ndim: int):
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
    return np.array([float(v) for v in values]), pixels.get("PhysicalSizeXUnit", "µm")
