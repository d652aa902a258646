"""Ordinary 2D images (PNG, JPEG, BMP, GIF) through Pillow, as gray values."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, one_line
from ..volume import Volume
from .options import ReadOptions, absolute_files


def read_image(path: Path, options: ReadOptions) -> Volume:
    """Read a 2D image; colour images become gray unless ``channel`` picks a band.

    Gray (8/16-bit, integer, float) images keep their values. Colour images are
    converted with Pillow's ``L`` mode (ITU-R 601-2 luma: 0.299 R + 0.587 G +
    0.114 B, rounded to 8 bits); ``channel`` selects one band instead. Rows
    run along y (row 0 first), columns along x.
    """
    from PIL import Image, UnidentifiedImageError

    notes = []
    try:
        with Image.open(path) as img:
            img.load()
            if getattr(img, "n_frames", 1) > 1:
                notes.append(f"{img.n_frames} frames; the first is used")
            if options.channel is not None:
                bands = img.getbands()
                if not 0 <= options.channel < len(bands):
                    raise VolumeError(
                        f"{path}: --channel {options.channel} is out of range 0..{len(bands) - 1} "
                        f"(bands {''.join(bands)})"
                    )
                array = np.asarray(img.getchannel(options.channel))
            elif img.mode in ("L", "I", "F", "I;16", "I;16B", "I;16L"):
                array = np.asarray(img)
            elif img.mode == "1":
                array = np.asarray(img.convert("L"))
            else:
                array = np.asarray(img.convert("L"))
                notes.append(f"{img.mode} image converted to gray (luma); --channel N picks a band")
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise FormatError(f"{path}: not a readable image ({one_line(exc)})") from None
    if array.ndim != 2:
        raise VolumeError(f"{path}: expected a 2D image, got shape {array.shape}")
    return Volume.from_zyx(
        np.ascontiguousarray(array), source=str(path), notes=notes, files=absolute_files([path])
    )
