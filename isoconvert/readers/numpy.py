"""NumPy arrays: ``.npy`` (memory-mapped) and ``.npz`` (one member, read into memory).

Axis convention. numpy and scikit-image hold a volume as a C-ordered
``(z, y, x)`` array (``(y, x)`` for an image): the last index varies fastest in
memory. A ``.npy`` file stores the array's bytes in its own order and says
which (``fortran_order``). Whatever the order, isoconvert reads the axis that
varies fastest *in the file* as x:

* C order (the default of ``np.save``): ``a[z, y, x]``, i.e. ``a[k, j, i]``.
* Fortran order (``np.save`` of an F-contiguous array, e.g. ``vol.T`` of a
  ``(z, y, x)`` array, or nibabel's ``(x, y, z)`` data): ``a[x, y, z]``, i.e.
  ``a[i, j, k]``.

So ``np.save(f, zyx)`` and ``np.save(f, zyx.T)`` give the same volume, and in
both cases the samples are read with x fastest, without a copy: a 3D ``.npy``
is a lazy :class:`~isoconvert.grid.RawGrid` on the file.
"""

from __future__ import annotations

import math
import zipfile
from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, one_line
from ..grid import RawGrid
from ..memory import check_fits
from ..volume import Volume
from .options import ReadOptions, absolute_files, spacing_note

_SPACING_NOTE = spacing_note("no spacing in a NumPy file; using 1 on every axis; set --spacing")
_SAVE_HINT = "save a (z, y, x) volume or a (y, x) image with np.save"


def read_numpy(path: Path, options: ReadOptions) -> Volume:
    """Read a ``.npy`` (memory-mapped) or one array of a ``.npz`` (``options.key``).

    Parameters
    ----------
    path : Path
        The file.
    options : ReadOptions
        ``key``: the member of a ``.npz`` holding several arrays.
    """
    if path.suffix.lower() == ".npz" or zipfile.is_zipfile(path):
        return _read_npz(path, options.key)
    if options.key is not None:
        raise VolumeError(f"{path}: --key picks an array of a .npz; a .npy holds one array")
    return _read_npy(path)


def array_ndim(path: Path) -> int | None:
    """Dimensions of the array a ``.npy`` holds, or of a ``.npz``'s only array, from the
    header alone (for batch, which skips 2D images); None when unreadable or ambiguous."""
    path = Path(path)
    try:
        if zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as archive:
                members = _members(archive, path)
            return len(next(iter(members.values()))[1]) if len(members) == 1 else None
        with open(path, "rb") as fh:
            return len(_header(fh, path)[0])
    except Exception:  # an unreadable file: reading it says what is wrong
        return None


def _header(fh, path: Path, where: str = "") -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, fortran_order and dtype from an open .npy stream at its start."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(fh)
        else:
            shape, fortran, dtype = fmt.read_array_header_2_0(fh)
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise FormatError(
            f"{path}: not a readable .npy{where} ({one_line(exc)}); {_SAVE_HINT}"
        ) from None
    return tuple(int(n) for n in shape), bool(fortran), np.dtype(dtype)


def _check_dtype(dtype: np.dtype, path: Path, where: str = "") -> np.dtype:
    """The dtype to read as (bool as uint8); complex, object, text refused."""
    if dtype.hasobject or dtype.kind not in "biuf" or dtype.fields is not None:
        kind = "complex numbers" if dtype.kind == "c" else "not real numbers"
        raise VolumeError(
            f"{path}: the array{where} holds {dtype} ({kind}); isoconvert contours real scalar "
            "volumes; save a real array (e.g. np.abs(a) or a.real) instead"
        )
    # bool masks are contoured as 0/1 bytes, as the TIFF and Zarr readers do
    return np.dtype(np.uint8) if dtype == np.bool_ else dtype


def _check_ndim(shape: tuple[int, ...], path: Path, where: str = "") -> None:
    if len(shape) not in (2, 3):
        raise VolumeError(
            f"{path}: the array{where} has shape {shape}, not a 2D or 3D volume; {_SAVE_HINT}"
        )


def _read_npy(path: Path) -> Volume:
    with open(path, "rb") as fh:
        shape, fortran, dtype = _header(fh, path)
        offset = fh.tell()
    _check_ndim(shape, path)
    dtype = _check_dtype(dtype, path)
    # Python integers: a header may declare a shape whose product overflows 64 bits
    nbytes = math.prod(shape) * dtype.itemsize
    size = path.stat().st_size
    if size - offset < nbytes:
        raise FormatError(
            f"{path}: the .npy holds {size - offset} bytes of samples, but its header declares "
            f"shape {shape} of {dtype} ({nbytes} bytes); the file is truncated, save it again"
        )
    notes = [_SPACING_NOTE]
    files = absolute_files([path])
    if fortran:
        notes.append("Fortran-ordered array read as (x, y[, z])")
    # the axis fastest in the file is x: reversed for C order, as is for Fortran order
    xyz = shape if fortran else shape[::-1]
    if len(shape) == 3:
        grid = RawGrid(path, dtype, xyz, offset)
        return Volume(grid, source=str(path), notes=notes, files=files)
    if 0 in shape:
        return Volume(np.zeros(xyz, dtype), source=str(path), notes=notes, files=files)
    mapped = np.memmap(path, dtype=dtype, mode="c", offset=offset, shape=xyz[::-1])
    return Volume.from_zyx(np.asarray(mapped), source=str(path), notes=notes, files=files)


def _members(archive: zipfile.ZipFile, path: Path) -> dict[str, tuple]:
    """Array name: (member name, shape, dtype) of every .npy member, from headers only."""
    found = {}
    for info in archive.infolist():
        if not info.filename.endswith(".npy"):
            continue
        name = info.filename[: -len(".npy")]
        with archive.open(info) as fh:
            shape, fortran, dtype = _header(fh, path, f" member {name!r}")
        found[name] = (info, shape, fortran, dtype)
    return found


def _listing(members: dict) -> str:
    return ", ".join(f"{k} {v[1]} {v[3]}" for k, v in members.items())


def _read_npz(path: Path, key: str | None) -> Volume:
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise FormatError(
            f"{path}: not a readable .npz (a zip archive of .npy files) ({one_line(exc)}); "
            "save it again with np.savez"
        ) from None
    with archive:
        members = _members(archive, path)
        if not members:
            raise FormatError(f"{path}: the .npz holds no arrays; save one with np.savez")
        if key is None:
            if len(members) > 1:
                raise VolumeError(
                    f"{path}: the .npz holds {len(members)} arrays ({_listing(members)}); "
                    "choose one with --key NAME"
                )
            key = next(iter(members))
        elif key not in members:
            raise VolumeError(
                f"{path}: the .npz has no array {key!r}; it holds {_listing(members)}; "
                "choose one with --key NAME"
            )
        info, shape, fortran, dtype = members[key]
        where = f" {key!r}"
        _check_ndim(shape, path, where)
        read_as = _check_dtype(dtype, path, where)
        nbytes = math.prod(shape) * dtype.itemsize
        check_fits(nbytes, f"the array {key!r}", str(path))
        with archive.open(info) as fh:
            _header(fh, path, where)
            out = np.empty(math.prod(shape), dtype=dtype)
            view = memoryview(out.view(np.uint8))
            got = 0
            # reads stop at the declared size: a member cannot inflate past it
            while got < nbytes:
                n = fh.readinto(view[got:])
                if not n:
                    break
                got += n
        if got != nbytes:
            raise FormatError(
                f"{path}: the array {key!r} holds {got} bytes, but its header declares shape "
                f"{shape} of {dtype} ({nbytes} bytes); the file is truncated, save it again"
            )
    notes = [_SPACING_NOTE]
    if len(members) > 1:
        notes.insert(0, f"array {key!r} of {len(members)} in the .npz")
    if fortran:
        notes.append("Fortran-ordered array read as (x, y[, z])")
    xyz = shape if fortran else shape[::-1]
    data = out.view(read_as).reshape(xyz[::-1])
    return Volume.from_zyx(data, source=str(path), notes=notes, files=absolute_files([path]))
