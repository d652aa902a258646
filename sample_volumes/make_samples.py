"""Make the small sample volumes in this folder.

Run from anywhere: ``python sample_volumes/make_samples.py``. Each volume is
written as raw (``name_XxYxZ_dtype.raw``), NRRD (gzip) and ImageJ TIFF, all with
the same samples, so they must give identical meshes.

- torus: the book's Figure 1.1 (Wenger, *Isosurfaces*): a 20x20x20 grid of
  distances to a circle of radius 6 centred at (9.5, 9.5, 9.5) in the plane
  z = 9.5; the isovalue 3 gives a torus. It is a *distance* field: the torus
  is the negative region, so use --flip for outward normals.
- sphere: a bright ball, as a CT scan shows one: uint8 values
  128 + 8 * (14 - distance to the centre), clipped to 0..255; level 127.5 gives
  a sphere of radius about 14 voxels.
- two_spheres: book section 1.3: two balls of radius 5 touching at grid vertex
  (14, 10, 10); values 5 - distance to the nearer centre (float32), level 0. The
  touching point has exactly the isovalue.
- figure_2_4: the 5x5 grid of the book's Figure 2.4 (isovalue 5; one sample
  equals 5), a 2D image written as raw and NRRD only. The figure's rows are
  printed top row first with y pointing up, so printed row r is y = 4 - r and
  column c is x = c. (A TIFF or PNG would show it upside down, since image rows
  run downward.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def torus() -> np.ndarray:
    """(20, 20, 20) float32 in x, y, z order: distance to the circle of Figure 1.1."""
    x, y, z = np.meshgrid(*(np.arange(20.0),) * 3, indexing="ij")
    c = 9.5
    ring = np.hypot(x - c, y - c) - 6.0
    return np.sqrt(ring**2 + (z - c) ** 2).astype(np.float32)


def sphere() -> np.ndarray:
    """(40, 40, 40) uint8: a bright ball of radius 14 around (19.5, 19.5, 19.5)."""
    x, y, z = np.meshgrid(*(np.arange(40.0),) * 3, indexing="ij")
    d = np.sqrt((x - 19.5) ** 2 + (y - 19.5) ** 2 + (z - 19.5) ** 2)
    return np.clip(np.rint(128 + 8 * (14 - d)), 0, 255).astype(np.uint8)


def two_spheres() -> np.ndarray:
    """(29, 21, 21) float32: 5 - distance to the nearer of (9, 10, 10) and (19, 10, 10)."""
    x, y, z = np.meshgrid(np.arange(29.0), np.arange(21.0), np.arange(21.0), indexing="ij")
    d1 = np.sqrt((x - 9) ** 2 + (y - 10) ** 2 + (z - 10) ** 2)
    d2 = np.sqrt((x - 19) ** 2 + (y - 10) ** 2 + (z - 10) ** 2)
    return (5.0 - np.minimum(d1, d2)).astype(np.float32)


#: Figure 2.4's values as the book prints them, top row first.
FIGURE_2_4_ROWS = (
    (8, 9, 7, 6, 3),
    (7, 3, 5, 3, 2),
    (8, 1, 7, 8, 4),
    (8, 6, 4, 2, 6),
    (9, 8, 3, 7, 6),
)


def figure_2_4() -> np.ndarray:
    """(5, 5) uint8 in x, y order: printed row r is y = 4 - r, column c is x = c."""
    return np.array(FIGURE_2_4_ROWS, dtype=np.uint8)[::-1].T.copy()


SAMPLES = {"torus": torus, "sphere": sphere, "two_spheres": two_spheres}
#: 2D samples: written as raw and NRRD only (see figure_2_4 above).
IMAGES = {"figure_2_4": figure_2_4}


def write_all(folder: Path = HERE) -> list[Path]:
    """Write every sample in every format to ``folder``; return the paths."""
    import nrrd
    import tifffile

    written = []
    for name, make in SAMPLES.items():
        data = make()  # (X, Y, Z)
        dims = "x".join(map(str, data.shape))
        raw = folder / f"{name}_{dims}_{data.dtype.name}.raw"
        # x fastest in the file: the (Z, Y, X) C-order bytes are data.T
        np.ascontiguousarray(data.T).tofile(raw)
        nrrd_path = folder / f"{name}.nrrd"
        header = {"spacings": [1.0, 1.0, 1.0], "encoding": "gzip", "endian": "little"}
        nrrd.write(str(nrrd_path), data, header, index_order="F")
        tif = folder / f"{name}.tif"
        tifffile.imwrite(
            tif,
            np.ascontiguousarray(data.T),
            imagej=True,
            resolution=(1.0, 1.0),
            metadata={"spacing": 1.0, "axes": "ZYX"},
        )
        written += [raw, nrrd_path, tif]
    for name, make in IMAGES.items():
        data = make()  # (X, Y)
        dims = "x".join(map(str, data.shape))
        raw = folder / f"{name}_{dims}_{data.dtype.name}.raw"
        np.ascontiguousarray(data.T).tofile(raw)
        nrrd_path = folder / f"{name}.nrrd"
        nrrd.write(str(nrrd_path), data, {"spacings": [1.0, 1.0]}, index_order="F")
        written += [raw, nrrd_path]
    return written


if __name__ == "__main__":
    for path in write_all():
        print(path.relative_to(HERE.parent))
