"""Zarr and OME-Zarr volumes: local stores (a folder), Zarr format 2 and 3, read slab by slab.

A plain array is read as a C-ordered (z, y, x) array, as numpy, scikit-image
and zarr users store volumes; extra leading axes must have size 1. A group
with OME-Zarr ``multiscales`` metadata (NGFF 0.4 in ``.zattrs``, 0.5 under
``attributes.ome`` in ``zarr.json``) gives the axes by name and type, one
array per resolution level (``scale``), and the placement: each level's
``coordinateTransformations`` (scale, then translation), followed by the
multiscale's own, map array indices to physical coordinates.

zarr reads a chunk that is missing from the store as its fill value, so an
incomplete copy would read as a volume with holes of zeros. Every chunk a read
needs must be in the store, unless ``allow_missing_chunks`` (writers such as
zarr-python 3 leave out chunks that hold only the fill value).
"""

from __future__ import annotations

import itertools
import math
import os
from pathlib import Path

import numpy as np

from ..errors import FormatError, VolumeError, extra_hint, one_line
from ..grid import LazyGrid
from ..volume import Volume
from .options import (
    PlacementNote,
    ReadOptions,
    absolute_files,
    check_channel,
    spacing_note,
)
from .stacks import is_zarr_store

# Arrays of at most this many stored chunks (or shards) are checked for missing ones when
# opened, to fail before any work; larger ones as their slabs are read.
_CHECK_AT_OPEN = 10_000
_SPATIAL = "zyx"  # the order of spatial axes in an array (OME-NGFF, and numpy's habit)
_KINDS_BY_NAME = {"x": "space", "y": "space", "z": "space", "c": "channel", "t": "time"}


def _zarr(path: Path):
    """The zarr module, or a one-line error saying how to install it."""
    try:
        import zarr
    except ImportError:
        raise FormatError(
            f"{path}: reading Zarr needs the zarr package: {extra_hint('zarr')}"
        ) from None
    return zarr


def _open(path: Path, array_path: str = ""):
    """The node (array or group) at ``array_path`` in the store at ``path``, read-only."""
    zarr = _zarr(path)
    from zarr.storage import LocalStore

    try:
        return zarr.open(store=LocalStore(path, read_only=True), path=array_path, mode="r")
    except Exception as exc:  # zarr raises many kinds for a broken store
        where = path / array_path if array_path else path
        raise FormatError(f"{where}: not a readable Zarr store ({one_line(exc)})") from None


def read_zarr(path: Path, options: ReadOptions) -> Volume:
    """Read a Zarr array, a group holding one array, or an OME-Zarr image.

    Parameters
    ----------
    path : Path
        The store's folder (the one holding ``zarr.json``, or ``.zarray`` /
        ``.zgroup``).
    options : ReadOptions
        ``scale`` (OME-Zarr resolution level, 0 the finest), ``channel`` (a
        channel axis longer than 1), ``allow_missing_chunks``.

    Returns
    -------
    Volume
        Backed by a :class:`ZarrGrid` for 3D; read whole for 2D.

    Raises
    ------
    FormatError
        Not a Zarr store, no array in it, malformed OME metadata, a missing
        chunk, or zarr not installed.
    VolumeError
        ``scale`` out of range, a non-spatial axis longer than 1, or not 2 or
        3 spatial axes.
    """
    _zarr(path)
    if not path.is_dir():
        raise FormatError(
            f"{path}: not a Zarr store; a Zarr store is a folder holding zarr.json (Zarr 3) "
            "or .zarray / .zgroup (Zarr 2): give that folder"
        )
    if not is_zarr_store(path):
        raise FormatError(
            f"{path}: not a Zarr store (no zarr.json, .zarray or .zgroup in it); give the "
            "store's top folder, the one holding that metadata"
        )
    node = _open(path)
    if not hasattr(node, "array_keys"):  # an array
        return _plain(path, "", node, options)
    multiscales = _multiscales(path, dict(node.attrs))
    if multiscales is not None:
        return _read_ome(path, multiscales, options)
    arrays = sorted(node.array_keys())
    if len(arrays) == 1:
        return _plain(path, arrays[0], node[arrays[0]], options)
    if arrays:
        raise FormatError(
            f"{path}: the Zarr group holds {len(arrays)} arrays ({', '.join(arrays)}) and no "
            f"OME-Zarr metadata; give the path of one, e.g. {path / arrays[0]}"
        )
    groups = sorted(node.group_keys())
    inside = f" (only groups: {', '.join(groups)})" if groups else ""
    hint = f"give the path of an array or image in it, e.g. {path / groups[0]}" if groups else ""
    raise FormatError(
        f"{path}: the Zarr group holds no array{inside}; {hint or 'the store is empty'}"
    )


def _plain(path: Path, array_path: str, array, options: ReadOptions) -> Volume:
    """A plain array: (z, y, x), or (y, x); leading axes must have size 1."""
    if options.scale:
        raise VolumeError(
            f"{path}: --scale {options.scale} given, but the store holds one resolution level "
            "(no OME-Zarr multiscales); leave out --scale"
        )
    ndim = len(array.shape)
    if ndim < 2:
        raise VolumeError(
            f"{path}: a Zarr array of shape {tuple(array.shape)} is not a 2D or 3D volume"
        )
    spatial = _SPATIAL[-min(ndim, 3) :]
    axes = [(f"{i}", None, None) for i in range(ndim - len(spatial))]
    axes += [(name, "space", None) for name in spatial]
    notes = [f"axes read as (..., z, y, x), the last three of {ndim}"] if ndim > 3 else []
    return _volume(path, array_path, array, axes, None, None, notes, options)


# --- OME-Zarr -------------------------------------------------------------------------------


def _multiscales(path: Path, attrs: dict) -> dict | None:
    """The first OME-Zarr multiscale image of a group's attributes, or None when not OME-Zarr."""
    ome = attrs.get("ome")
    found = ome.get("multiscales") if isinstance(ome, dict) else attrs.get("multiscales")
    if found is None:
        return None
    first = found[0] if isinstance(found, list) and found else None
    datasets = first.get("datasets") if isinstance(first, dict) else None
    if not (
        isinstance(datasets, list)
        and datasets
        and all(isinstance(d, dict) and isinstance(d.get("path"), str) for d in datasets)
    ):
        raise FormatError(
            f"{path}: the OME-Zarr 'multiscales' metadata is malformed (it needs a list of "
            "images, each with 'datasets' naming one array per level); fix or re-export it"
        )
    return first


def _axes(path: Path, multiscale: dict, ndim: int) -> list[tuple[str, str | None, str | None]]:
    """(name, type, unit) of each array axis; types guessed from names where absent."""
    given = multiscale.get("axes")
    if given is None:  # NGFF 0.1 / 0.2: always (t, c, z, y, x)
        given = list("tczyx"[-ndim:])
    if not isinstance(given, list):
        raise FormatError(f"{path}: the OME-Zarr 'axes' is not a list; fix or re-export it")
    axes = []
    for axis in given:
        if isinstance(axis, str):  # NGFF 0.3: names only
            axis = {"name": axis}
        if not isinstance(axis, dict) or not isinstance(axis.get("name"), str):
            raise FormatError(f"{path}: OME-Zarr axis {axis!r} has no name; fix the 'axes' list")
        name = axis["name"]
        kind = axis.get("type") or _KINDS_BY_NAME.get(name.lower())
        unit = axis.get("unit")
        axes.append((name, kind, unit if isinstance(unit, str) and unit else None))
    if len(axes) != ndim:
        raise FormatError(
            f"{path}: the OME-Zarr metadata names {len(axes)} axes but the array has {ndim}; "
            "fix the 'axes' list"
        )
    return axes


def _read_ome(path: Path, multiscale: dict, options: ReadOptions) -> Volume:
    datasets = multiscale["datasets"]
    level = options.scale
    if not 0 <= level < len(datasets):
        levels = range(len(datasets))
        listing = ", ".join(f"{i} ({_level_dims(path, multiscale, i)})" for i in levels)
        raise VolumeError(
            f"{path}: --scale {level} is out of range; choose a resolution level of this "
            f"OME-Zarr: {listing} (samples along x, y, z)"
        )
    array_path, array = _level(path, multiscale, level)
    axes = _axes(path, multiscale, len(array.shape))
    notes: list[str] = []
    transforms = list(datasets[level].get("coordinateTransformations") or [])
    transforms += list(multiscale.get("coordinateTransformations") or [])
    scale = shift = None
    if transforms:
        scale, shift = _transform(transforms, len(axes), notes)
    name = multiscale.get("name")
    named = f" {name!r}" if isinstance(name, str) and name else ""
    notes.insert(0, f"OME-Zarr image{named}, resolution level {level} of 0..{len(datasets) - 1}")
    return _volume(path, array_path, array, axes, scale, shift, notes, options)


def _level(path: Path, multiscale: dict, level: int):
    """The array path and the opened array of a resolution level."""
    array_path = multiscale["datasets"][level]["path"].strip("/")
    array = _open(path, array_path)
    if hasattr(array, "array_keys"):
        raise FormatError(
            f"{path}: OME-Zarr level {level} names {array_path!r}, which is a group, not an "
            "array; fix the 'datasets' list"
        )
    return array_path, array


def _level_dims(path: Path, multiscale: dict, level: int) -> str:
    """``"XxYxZ"``: the samples of a level along its spatial axes, for messages."""
    _, array = _level(path, multiscale, level)
    axes = _axes(path, multiscale, len(array.shape))
    spatial = [n for n, (_, kind, _) in zip(array.shape, axes, strict=True) if kind == "space"]
    return "x".join(map(str, spatial[::-1]))


def _transform(transforms: list, ndim: int, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis scale and translation of a list of OME-NGFF coordinate transformations.

    Applied in order, as the spec says: index -> index * scale, + translation;
    so a later scale also scales the translation before it.
    """
    scale, shift = np.ones(ndim), np.zeros(ndim)
    for t in transforms:
        kind = t.get("type") if isinstance(t, dict) else None
        if kind == "identity":
            continue
        if kind not in ("scale", "translation"):
            notes.append(f"OME-Zarr coordinate transformation {kind!r} ignored")
            continue
        try:
            values = np.asarray(t[kind], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            values = None  # a transformation stored in a binary "path" is not read
        if values is None or values.shape != (ndim,) or not np.all(np.isfinite(values)):
            about, flag = ("spacing", "--spacing") if kind == "scale" else ("origin", "--origin")
            notes.append(
                PlacementNote(
                    f"OME-Zarr {kind} {t.get(kind, t.get('path'))!r} ignored (not one "
                    f"finite number per axis); set {flag}",
                    about,
                )
            )
            continue
        if kind == "scale":
            scale, shift = scale * values, shift * values
        else:
            shift = shift + values
    return scale, shift


# --- the volume -----------------------------------------------------------------------------


def _volume(path, array_path, array, axes, scale, shift, notes, options) -> Volume:
    """Pick the spatial axes, index the others, and make the Volume (lazy when 3D).

    ``axes`` gives (name, type, unit) per array axis; ``scale`` and ``shift``
    the placement per array axis (None: the store has none).
    """
    where = path / array_path if array_path else path
    shape = tuple(int(n) for n in array.shape)
    spatial = [i for i, (_, kind, _) in enumerate(axes) if kind == "space"]
    if len(spatial) not in (2, 3):
        names = ", ".join(name for name, _, _ in axes)
        raise VolumeError(
            f"{where}: the array has {len(spatial)} spatial axes (axes {names}); a volume "
            "needs 2 or 3"
        )
    roles = _roles(where, axes, shape, spatial, options.channel)
    grid = ZarrGrid(path, array_path, roles, array.dtype, options.allow_missing_chunks, array)
    xyz = spatial[::-1]  # arrays hold (z,) y, x; a Volume's vectors are (x, y(, z))
    spacing = origin = None
    if scale is None:
        notes.append(spacing_note("no spacing in the store; using 1 (set --spacing)"))
    else:
        spacing, origin = _placement(scale[xyz], shift[xyz], [axes[i][0] for i in xyz], notes)
        notes.append(
            PlacementNote(
                "spacing and origin from the OME-Zarr coordinateTransformations", "spacing origin"
            )
        )
    units = [axes[i][2] for i in xyz]
    unit = units[0] if len(set(units)) == 1 else None
    if len(set(units)) > 1:
        listed = ", ".join(f"{axes[i][0]} {u or '(none)'}" for i, u in zip(xyz, units, strict=True))
        notes.append(f"the spatial axes have different units ({listed}); no unit is given")
    # the store's folder stands for all its files (metadata and chunks)
    placement = {
        "spacing": spacing,
        "origin": origin,
        "source": str(path),
        "notes": notes,
        "unit": unit,
        "files": absolute_files([path]),
    }
    if len(spatial) == 2:
        return Volume.from_zyx(grid.read_all(), **placement)
    if grid.stored_chunks() <= _CHECK_AT_OPEN:
        grid.check_chunks(0, grid.shape[2])
    return Volume(grid, **placement)


def _roles(where: Path, axes, shape, spatial: list[int], channel: int | None) -> tuple:
    """Per array axis: "z", "y" or "x" for the spatial ones, else the index read along it."""
    roles: list[str | int] = list(_SPATIAL[-len(spatial) :])
    out: list[str | int] = []
    channels = [i for i, (_, kind, _) in enumerate(axes) if kind == "channel" and shape[i] > 1]
    for i, (name, _, _) in enumerate(axes):
        if i in spatial:
            out.append(roles[spatial.index(i)])
        elif i in channels[:1]:
            what = f"channels (axis {name} of size {shape[i]})"
            out.append(check_channel(shape[i], channel, where, what))
        elif shape[i] != 1:
            raise VolumeError(
                f"{where}: axis {name} has size {shape[i]}; isoconvert reads one scalar volume, "
                "so every axis but z, y, x (and a channel axis, with --channel) must have size 1 "
                "(save the part you want as its own array)"
            )
        else:
            out.append(0)
    if not channels:
        check_channel(None, channel, where, "")
    return tuple(out)


def _placement(scale, shift, names, notes) -> tuple[np.ndarray, np.ndarray]:
    """Spacing and origin (x, y(, z)); a scale that is not positive is ignored with a note."""
    spacing = np.array(scale, dtype=np.float64)
    for axis, value in enumerate(scale):
        if not value > 0:
            notes.append(
                spacing_note(
                    f"OME-Zarr scale {value:g} for axis {names[axis]} ignored; using 1; "
                    "set --spacing"
                )
            )
            spacing[axis] = 1.0
    return spacing, np.asarray(shift, dtype=np.float64)


class ZarrGrid(LazyGrid):
    """A 3D volume in a local Zarr array (Zarr 2 or 3), read a slab of z-layers at a time.

    A read asks zarr for ``array[k0:k1]`` along the z axis (the other spatial
    axes whole, any other axis at one index), so zarr decodes only the chunks
    the slab touches; slabs need not be aligned with chunks. Before reading,
    every chunk (or shard) of those layers must be in the store, unless
    ``allow_missing``. The grid holds the store's path and the array's path in
    it; the opened array is a per-process cache, dropped when pickled.

    A 2D array (roles "y", "x") makes a grid of one z-layer, which the reader
    reads whole (:meth:`read_all`) into a 2D volume.

    Parameters
    ----------
    store : Path
        The store's folder.
    array_path : str
        The array's path in the store ("" when the store is the array).
    roles : tuple of str or int
        One entry per array axis: "z", "y", "x", or the index read along a
        non-spatial axis. ``shape`` follows from it.
    dtype : numpy dtype
        The array's (bool is read as uint8).
    allow_missing : bool
        Read missing chunks as the fill value, as zarr does.
    array : zarr.Array or None
        The array, when the caller has it open already (kept as the cache).
    """

    def __init__(
        self,
        store: Path,
        array_path: str,
        roles: tuple,
        dtype: np.dtype,
        allow_missing: bool = False,
        array=None,
    ):
        self.store = Path(store)
        self.array_path = array_path
        self.path = self.store / array_path if array_path else self.store
        self.roles = tuple(roles)
        # bool volumes are contoured as 0/1 bytes, as the TIFF reader does
        self.dtype = np.dtype(np.uint8) if np.dtype(dtype) == np.bool_ else np.dtype(dtype)
        self.allow_missing = allow_missing
        if array is not None:
            self._opened = array
        sizes = dict(zip(self.roles, self._array().shape, strict=True))
        self.shape = tuple(int(sizes.get(a, 1)) for a in "xyz")
        self._checked: set[int] = set()  # z rows of chunks found complete

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state.pop("_opened", None)
        return state

    def _array(self):
        """The zarr array, opened once per process."""
        opened = self.__dict__.get("_opened")
        if opened is None:
            opened = self._opened = _open(self.store, self.array_path)
        return opened

    @property
    def z_chunk(self) -> int:
        """z-layers per stored chunk (shard): slabs that start and end at multiples of
        it decode each chunk once; others decode the chunks they share twice."""
        array = self._array()
        return (array.shards or array.chunks)[self.roles.index("z")] if "z" in self.roles else 1

    def stored_chunks(self) -> int:
        """How many chunks (shards, when sharded) the array is stored in."""
        array = self._array()
        grid = array.shards or array.chunks
        return math.prod(-(-n // c) for n, c in zip(array.shape, grid, strict=True))

    def check_chunks(self, k0: int, k1: int) -> None:
        """Check that every stored chunk of z-layers ``k0..k1 - 1`` is in the store.

        Raises
        ------
        FormatError
            ``"PATH: chunk Z/Y/X is missing (the store is incomplete); ..."``,
            the chunk's grid coordinates in array axis order.
        """
        if self.allow_missing or k1 <= k0:
            return
        array = self._array()
        grid = array.shards or array.chunks
        depth = self.z_chunk
        rows = [r for r in range(k0 // depth, (k1 - 1) // depth + 1) if r not in self._checked]
        for row in rows:
            ranges = []
            for role, n, c in zip(self.roles, array.shape, grid, strict=True):
                if role == "z":
                    ranges.append(range(row, row + 1))
                elif isinstance(role, str):
                    ranges.append(range(-(-n // c)))
                else:
                    ranges.append(range(role // c, role // c + 1))
            for coords in itertools.product(*ranges):
                key = array.metadata.encode_chunk_key(coords)
                if not os.path.exists(os.path.join(self.path, key)):
                    raise FormatError(
                        f"{self.path}: chunk {'/'.join(map(str, coords))} is missing; if its "
                        "writer leaves out chunks that hold only the fill value (zarr-python 3 "
                        "does by default), pass --allow-missing-chunks, else the store is "
                        "incomplete: copy it again"
                    )
            self._checked.add(row)

    def _read(self, selection: tuple, what: str) -> np.ndarray:
        """``array[selection]`` with its spatial axes in (z,) y, x order, C-contiguous."""
        try:
            data = np.asarray(self._array()[selection])
        except Exception as exc:  # a corrupt chunk: the codec's own exception
            raise FormatError(
                f"{self.path}: {what} cannot be read (a chunk is corrupt? {one_line(exc)})"
            ) from None
        order = [r for r in self.roles if isinstance(r, str)]
        data = np.transpose(data, [order.index(a) for a in _SPATIAL if a in order])
        if data.dtype == np.bool_:
            data = data.view(np.uint8)
        return np.ascontiguousarray(data, dtype=self.dtype)

    def read_all(self) -> np.ndarray:
        """The whole array, spatial axes only, in C order ((Z, Y, X) or (Y, X))."""
        self.check_chunks(0, self.shape[2])
        return self._read(
            tuple(slice(None) if isinstance(r, str) else r for r in self.roles), "the array"
        )

    def read_zyx(self, k0: int, k1: int) -> np.ndarray:
        self._check_slab(k0, k1)
        self.check_chunks(k0, k1)
        selection = tuple(
            slice(k0, k1) if r == "z" else slice(None) if isinstance(r, str) else r
            for r in self.roles
        )
        return self._read(selection, f"z-layers {k0}..{k1 - 1}")
