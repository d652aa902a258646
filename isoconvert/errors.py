"""Errors the library raises for user mistakes.

Every message names what is wrong (the file, the parameter) and how to fix it,
in one line. The library never prints or exits; the CLI turns these into one
line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import functools
import re

#: The fix a file parser's error points to, for a file of the right kind.
DAMAGED_FILE = "it may be damaged or cut short: compare its size with the original's"


class IsoconvertError(Exception):
    """Base class of every error caused by input the user can fix."""


class InputNotFoundError(IsoconvertError):
    """An input file, folder or glob does not exist or matches nothing."""


class FormatError(IsoconvertError):
    """A file is not in the format it claims, or a format name is unknown."""


class VolumeError(IsoconvertError):
    """A volume's shape, dtype or values cannot be used for extraction."""


class LevelError(IsoconvertError):
    """The isovalue is unusable for this volume (outside its range, no surface)."""


class OutputError(IsoconvertError):
    """The output cannot be written (exists, folder missing or unwritable)."""


def one_line(text: object, limit: int = 300) -> str:
    """Text from elsewhere (a parser's exception) made fit for a one-line message."""
    flat = " ".join(str(text).split())
    flat = "".join(c if c.isprintable() else "?" for c in flat)
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


#: The extra of isoconvert that installs each optional package a format needs.
EXTRAS = {"h5py": "hdf5", "netCDF4": "netcdf"}


def install_hint(package: str) -> str:
    """How to install an optional package: :func:`extra_hint` of its extra (h5py:
    hdf5, and so on); ``pip install PACKAGE`` for one without an extra."""
    extra = EXTRAS.get(package)
    return extra_hint(extra) if extra else f"pip install {package}"


@functools.cache
def extra_hint(extra: str) -> str:
    """How to install one of isoconvert's extras, as this installation can:
    ``pip install "isoconvert[dicom]"``, or, where isoconvert was installed from a
    folder (a clone), the extra's own requirements (``pip install "pydicom>=2.4"``):
    the package index may not hold isoconvert then, and installing the folder again
    would rebuild its kernels."""
    import importlib.metadata
    import json

    try:
        dist = importlib.metadata.distribution("isoconvert")
        origin = json.loads(dist.read_text("direct_url.json") or "{}")
        requires = dist.requires or []
    except Exception:  # not installed (run from the source tree), or odd metadata
        origin, requires = {}, []
    if str(origin.get("url", "")).startswith("file:"):
        needs = [
            req.split(";")[0].strip()
            for req in requires
            if re.search(r"""extra\s*==\s*["']""" + re.escape(extra) + """["']""", req)
        ]
        if needs:
            return "pip install " + " ".join(f'"{need}"' for need in needs)
    return f'pip install "isoconvert[{extra}]"'


def utf8_text(text: str) -> bytes:
    """``text`` as UTF-8 bytes, whatever file names it holds: a name that is not
    valid UTF-8 (Python keeps its bytes as lone surrogates) shows U+FFFD where
    those bytes were, as file managers show it, instead of failing to encode."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace").encode("utf-8")
