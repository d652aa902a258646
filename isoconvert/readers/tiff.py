"""TIFF stacks (tifffile): one multi-page file, a folder of slices, or a glob.

A 3D stack is read lazily, a z-layer being one page of the file or one file of
the folder (:class:`TiffStackGrid`): opening it reads the page headers only (the
checks that every page or slice matches need no pixel), and block-wise
extraction reads the pages of one slab at a time. 2D images, and files whose
layers are not whole pages (a truncated ImageJ file, volumetric tiles), are
read whole.
"""

from __future__ import annotations

import glob as globlib
import math
from collections.abc import Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import FormatError, InputNotFoundError, VolumeError, one_line
from ..grid import LazyGrid
from ..memory import check_fits
from ..volume import Volume
from .options import ReadOptions, absolute_files, check_channel, spacing_note
from .stacks import TIFF_SUFFIXES, natural_key

_CHANNELS = "channels (RGB or multi-channel)"


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


@contextmanager
def _readable(path: Path | str):
    """Turn what tifffile raises on a corrupt file into a one-line FormatError naming it."""
    import tifffile

    try:
        yield
    except (tifffile.TiffFileError, ValueError, OSError, IndexError, KeyError) as exc:
        raise FormatError(f"{path}: not a readable TIFF ({one_line(exc)})") from None


def read_tiff(path: Path, options: ReadOptions) -> Volume:
    """Read a multi-page TIFF file, or a folder / glob of single-page slices.

    Spacing comes from ImageJ metadata (``spacing`` for z, resolution tags for x
    and y, which hold pixels per unit) or OME metadata; without a z spacing it
    is 1 on every axis and a note says so. A 3D stack is a lazy
    :class:`TiffStackGrid`; a 2D image is read whole.
    """
    import tifffile

    spec = str(path)
    if path.is_file():
        files = [path]
    else:
        files = slice_files(spec)
    with _readable(spec):
        if len(files) == 1:
            data, spacing, unit, notes = _read_file(files[0], options.channel, spec)
        else:
            data = _slice_stack(files, options.channel, spec)
            with tifffile.TiffFile(files[0]) as tif:
                spacing, unit, notes = _spacing(tif, 3)
            notes.insert(0, f"{len(files)} slices, {files[0].name} .. {files[-1].name}")
    placement = {
        "spacing": spacing,
        "source": spec,
        "notes": notes,
        "unit": unit,
        "files": absolute_files(files),
    }
    if isinstance(data, LazyGrid):
        return Volume(data, **placement)
    if data.dtype == np.bool_:
        data = data.view(np.uint8)
    return Volume.from_zyx(data, **placement)


def _read_file(path: Path, channel: int | None, spec: str):
    """A single TIFF file: (grid or (Z, Y, X) / (Y, X) array, spacing, unit, notes)."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        check_complete(tif, path)
        series = tif.series[0]
        series_notes = _check_series(tif, path)
        index, axes = _selection(series.axes, series.shape, channel, path)
        data = _page_grid(tif, series, index, spec) if len(axes) == 3 else None
        if data is None:
            declared = math.prod(series.shape) * series.dtype.itemsize
            check_fits(declared, "the declared image series", spec)
            data = _pick_channel(series.asarray(), series.axes, channel, path)
        spacing, unit, notes = _spacing(tif, data.ndim)
    return data, spacing, unit, series_notes + notes


_TRUNCATED = "(truncated?); copy or save the file again"


def check_complete(tif, path: Path) -> None:
    """Refuse a TIFF that holds less than its own structure and metadata declare.

    A copy cut short keeps its first pages, and often its metadata: tifffile
    then reads the pages that are left (an ImageJ stack of 27 images becomes one
    2D image) or invents the rest. From the headers alone, without reading a
    pixel, a file is corrupt when

    * a page's strips or tiles run past the end of the file;
    * its last page points to a next page past the end of the file;
    * its ImageJ metadata declares more images than the file holds (ImageJ
      may store the images of a large stack after one page header: those count);
    * its OME metadata declares more planes than the file has pages (unless
      the OME metadata spreads the image over several files).

    Raises
    ------
    FormatError
        ``"PATH: corrupt TIFF: ... (truncated?)"``.
    """
    size = tif.filehandle.size
    pages = tif.pages
    count = len(pages)  # indexes the whole chain of page headers
    if count == 0:
        return  # not a TIFF at all: tifffile says so when the series is read
    ij = tif.imagej_metadata if tif.is_imagej else None
    declared = ij.get("images") if isinstance(ij, dict) else None
    if isinstance(declared, int) and declared > count:
        held = count
        if len(tif.series):
            series = tif.series[0]
            per_page = math.prod(series.keyframe.shape) or 1
            held = max(count, math.prod(series.shape) // per_page)
        if declared > held:
            raise FormatError(
                f"{path}: corrupt TIFF: its ImageJ metadata declares {declared} images but the "
                f"file holds {held} {_TRUNCATED}"
            )
    planes = _ome_planes(tif)
    if planes is not None and planes > count:
        raise FormatError(
            f"{path}: corrupt TIFF: its OME metadata declares {planes} planes but the file "
            f"holds {count} {_TRUNCATED}"
        )
    for n in range(count):
        page = pages[n]
        ends = [
            int(o) + int(c)
            for o, c in zip(page.dataoffsets, page.databytecounts, strict=False)
            if c
        ]
        if ends and max(ends) > size:
            raise FormatError(
                f"{path}: corrupt TIFF: the image data of page {n + 1} of {count} runs to byte "
                f"{max(ends)}, past the end of the file ({size} bytes) {_TRUNCATED}"
            )
    _check_next_page(tif, path, size, count)


def _check_next_page(tif, path: Path, size: int, count: int) -> None:
    """The last page's pointer to a next page must be 0 (none) or inside the file."""
    import struct

    where = getattr(tif.pages, "next_page_offset", None)
    if where is None or tif.tiff.is_ndpi:
        return
    fmt = tif.tiff.offsetformat
    fh = tif.filehandle
    fh.seek(where)
    raw = fh.read(struct.calcsize(fmt))
    following = struct.unpack(fmt, raw)[0] if len(raw) == struct.calcsize(fmt) else size
    if following >= size:
        raise FormatError(
            f"{path}: corrupt TIFF: page {count} points to a next page at byte {following}, "
            f"past the end of the file ({size} bytes) {_TRUNCATED}"
        )


def _ome_root(tif):
    """The parsed OME-XML of ``tif`` (an ElementTree element), or None when it has
    none or it does not parse."""
    if not tif.is_ome or not tif.ome_metadata:
        return None
    import xml.etree.ElementTree as ET

    try:
        return ET.fromstring(tif.ome_metadata)
    except ET.ParseError:
        return None


def _ome_planes(tif) -> int | None:
    """The planes (pages) the OME metadata of ``tif`` declares, or None when it has none
    or spreads its images over several files (TiffData naming a file)."""
    root = _ome_root(tif)
    if root is None:
        return None
    if any(el.tag.endswith("UUID") and el.get("FileName") for el in root.iter()):
        return None
    planes = 0
    for pixels in (el for el in root.iter() if el.tag.endswith("Pixels")):
        try:
            z, c, t = (int(pixels.get(f"Size{a}", 1)) for a in "ZCT")
            samples = max(
                [int(ch.get("SamplesPerPixel", 1)) for ch in pixels if ch.tag.endswith("Channel")]
                or [1]
            )
        except ValueError:
            return None
        # an RGB channel of 3 samples is one plane of 3 samples per pixel
        planes += z * t * max(1, c // max(samples, 1))
    return planes or None


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
    return "".join(axes[i] for i in _kept(axes, shape))


def _kept(axes: str, shape: tuple[int, ...]) -> list[int]:
    """Positions of the axes :func:`kept_axes` keeps."""
    return [i for i, (a, n) in enumerate(zip(axes, shape, strict=True)) if n > 1 or a in "XY"]


def _selection(
    axes: str, shape: tuple[int, ...], channel: int | None, path: Path
) -> tuple[tuple[int | slice, ...], str]:
    """How to take the scalar image out of a TIFF series, from its axes alone.

    Singleton axes are dropped (index 0), and ``channel`` is taken along the
    first kept ``C`` or ``S`` axis (:func:`kept_axes`).

    Returns
    -------
    index : tuple of int or slice
        One entry per series axis: ``series_array[index]`` is the image.
    axes : str
        The image's axes, 2 or 3 of them (e.g. ``"ZYX"``).

    Raises
    ------
    VolumeError
        ``channel`` missing, out of range or given without a channel axis, or
        an image that is not 2D or 3D once the channel is taken.
    """
    kept = _kept(axes, shape)
    chan = next((i for i in kept if axes[i] in "CS"), None)
    picked = check_channel(None if chan is None else shape[chan], channel, path, _CHANNELS)
    index = tuple(
        picked if i == chan else slice(None) if i in kept else 0 for i in range(len(axes))
    )
    left = "".join(axes[i] for i in kept if i != chan)
    if len(left) not in (2, 3):
        raise VolumeError(
            f"{path}: a TIFF with axes {left} is not a 2D or 3D scalar image "
            "(time series and multi-series files are not supported)"
        )
    return index, left


def _sliced(shape: tuple[int, ...], index: tuple) -> tuple[int, ...]:
    """The shape of ``array[index]`` for an array of ``shape`` (index: ints and full slices)."""
    return tuple(n for n, i in zip(shape, index, strict=True) if isinstance(i, slice))


def _pick_channel(array: np.ndarray, axes: str, channel: int | None, path: Path) -> np.ndarray:
    """Drop singleton axes; select ``channel`` along a sample/channel axis (a C-ordered copy
    only when that selection leaves the samples strided)."""
    index, _ = _selection(axes, array.shape, channel, path)
    return np.ascontiguousarray(array[index])


def _page_grid(tif, series, index: tuple, spec: str) -> TiffStackGrid | None:
    """A grid reading one page per z-layer of ``series``, or None when its layers are not pages.

    tifffile's series array is its pages stacked in order, reshaped to
    ``series.shape``: the leading axes number the pages (C order), the
    trailing ones are one page's. The z axis must be one of the leading ones
    (always, but for volumetric tiles); a channel axis may be either.
    """
    shape = tuple(series.shape)
    per_page = math.prod(series.keyframe.shape)
    split = next((q for q in range(len(shape), -1, -1) if math.prod(shape[q:]) == per_page), None)
    if split is None or series.transform is not None:
        return None
    if math.prod(shape[:split]) != len(series):
        return None  # e.g. a truncated ImageJ file: one page header for many images
    lead, inpage = index[:split], index[split:]
    if sum(isinstance(i, slice) for i in lead) != 1:
        return None  # z inside a page (volumetric tiles)
    positions = np.arange(len(series)).reshape(shape[:split])[lead]
    pages = [series[int(j)].index for j in positions]
    if not all(isinstance(p, int) for p in pages):
        return None  # pages in SubIFDs
    ny, nx = _sliced(shape[split:], inpage)
    return TiffStackGrid(
        spec,
        [tif.filehandle.path],
        (nx, ny, len(pages)),
        series.dtype,
        pages=pages,
        page_shape=shape[split:],
        inpage=inpage,
    )


def _slice_stack(files: list[Path], channel: int | None, spec: str) -> TiffStackGrid:
    """A grid of single-image files, one z-layer each, after checking from their headers
    that they are 2D images of one shape and type."""
    import tifffile

    first = None
    for f in files:
        with tifffile.TiffFile(f) as tif:
            check_complete(tif, f)
            series = tif.series[0]
            index, _ = _selection(series.axes, series.shape, channel, f)
            shape = _sliced(series.shape, index)
            dtype = series.dtype
        if len(shape) != 2:
            raise VolumeError(f"{f}: a slice of a stack must be one 2D image, got shape {shape}")
        if first is None:
            first = (f, shape, dtype)
        elif (shape, dtype) != first[1:]:
            raise VolumeError(
                f"{f}: slice is {shape[1]}x{shape[0]} {dtype}, but {first[0].name} "
                f"is {first[1][1]}x{first[1][0]} {first[2]}; all slices must match"
            )
    ny, nx = first[1]
    return TiffStackGrid(spec, files, (nx, ny, len(files)), first[2], channel=channel)


class TiffStackGrid(LazyGrid):
    """A 3D stack of TIFF images read a z-layer (a page, or a file) at a time.

    Either one file per layer (a folder or glob of single-image slices: each
    file's first series, ``channel`` taken), or one page per layer of a
    multi-page file (``pages``: the page of each layer, the image taken from
    it by ``inpage``). Holds names and numbers only, and opens the files on
    each read: it pickles, and threads may read slabs at once.

    Parameters
    ----------
    path : str or Path
        The input as given (a file, folder or glob), for messages.
    files : sequence of Path
        The slice files, one per layer; or the one multi-page file.
    shape : (3,) tuple of int
        (X, Y, Z).
    dtype : numpy dtype
        Of the images (bool is read as uint8).
    channel : int or None
        Slice files: the channel to take, as the user chose it.
    pages : sequence of int or None
        A multi-page file: index in the file of each layer's page.
    page_shape : tuple of int
        A multi-page file: the shape a page's image is reshaped to (the
        trailing axes of the series).
    inpage : tuple of int or slice
        A multi-page file: the index taking the (Y, X) image out of the
        reshaped page (its singleton and channel axes).
    """

    def __init__(
        self,
        path: str | Path,
        files: Sequence[Path],
        shape: tuple[int, int, int],
        dtype: np.dtype,
        *,
        channel: int | None = None,
        pages: Sequence[int] | None = None,
        page_shape: tuple[int, ...] = (),
        inpage: tuple = (),
    ):
        self.path = Path(path)
        self.files = [Path(f) for f in files]
        self.shape = tuple(int(n) for n in shape)
        # bool images are contoured as 0/1 bytes, as the whole-file path does
        self.dtype = np.dtype(np.uint8) if np.dtype(dtype) == np.bool_ else np.dtype(dtype)
        self.channel = channel
        self.pages = None if pages is None else [int(p) for p in pages]
        self.page_shape = tuple(page_shape)
        self.inpage = tuple(inpage)

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        import tifffile

        out = self._empty_slab(k0, k1)
        if self.pages is not None:
            with _readable(self.files[0]), tifffile.TiffFile(self.files[0]) as tif:
                for z, page in enumerate(self.pages[k0:k1]):
                    image = tif.pages[page].asarray().reshape(self.page_shape)[self.inpage]
                    self._put(out, z, image, self.files[0], f"page {page + 1}")
        else:
            for z, f in enumerate(self.files[k0:k1]):
                with _readable(f), tifffile.TiffFile(f) as tif:
                    series = tif.series[0]
                    image = _pick_channel(series.asarray(), series.axes, self.channel, f)
                self._put(out, z, image, f, "the slice")
        return out

    def _put(self, out: np.ndarray, z: int, image: np.ndarray, path: Path, what: str) -> None:
        if image.dtype == np.bool_:
            image = image.view(np.uint8)
        if image.shape != out.shape[1:] or image.dtype != out.dtype:
            raise FormatError(
                f"{path}: {what} is now {image.shape[-1]}x{image.shape[0]} {image.dtype}, not "
                f"{out.shape[2]}x{out.shape[1]} {out.dtype} as when the stack was opened; read it "
                "again"
            )
        out[z] = image


def _spacing(tif, ndim: int) -> tuple[np.ndarray | None, str | None, list[str]]:
    """Spacing (x, y[, z]) and unit from ImageJ, OME or resolution tags.

    A value that is not a positive finite number (0, negative, NaN, inf) is
    ignored with a note and 1 is used for its axis, so that ``--spacing`` can
    still override it.
    """
    notes: list[str] = []
    ome = _ome_spacing(tif, ndim, notes)
    if ome is not None:
        notes.append(spacing_note("spacing from OME metadata"))
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
            notes.append(spacing_note("spacing from the TIFF resolution tags"))
            return np.array(xy), unit, notes
        return None, None, notes
    raw_z = ij.get("spacing")
    if raw_z is not None:
        z = _positive(raw_z)
        if z is None:
            notes.append(
                spacing_note(
                    f"spacing {_show(raw_z)} in the ImageJ metadata ignored; using 1; set --spacing"
                )
            )
            z = 1.0
        else:
            notes.append(spacing_note("spacing from ImageJ metadata"))
        xy = xy if xy is not None else (1.0, 1.0)
        return np.array([xy[0], xy[1], z]), unit, notes
    found = f" (resolution tags give x, y spacing {xy[0]:g}, {xy[1]:g})" if xy else ""
    notes.append(spacing_note(f"no z spacing in the TIFF; using 1, 1, 1{found}; set --spacing"))
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
            notes.append(
                spacing_note(f"{name} {num}/{den} in the TIFF tags ignored; using 1; set --spacing")
            )
            spacing = 1.0
        values.append(spacing)
    return values[0], values[1]


def _ome_spacing(tif, ndim: int, notes: list[str]):
    """Spacing and unit from the OME Pixels element; None when it lacks an axis."""
    root = _ome_root(tif)
    if root is None:
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
                spacing_note(
                    f"{name} {_show(value)} in the OME metadata ignored; using 1; set --spacing"
                )
            )
            number = 1.0
        spacing.append(number)
    return np.array(spacing), pixels.get("PhysicalSizeXUnit", "µm")
