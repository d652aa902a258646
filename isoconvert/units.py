"""Length units of volumes, by the names their formats use.

Readers keep a volume's unit as the file names it (``Volume.unit``: "mm" from
DICOM and NIfTI, "µm" or "micron" from ImageJ TIFF, "micrometer" from OME-Zarr,
NRRD's ``space units``); writers whose format fixes or states a unit (GLB in
meters, 3MF's ``unit`` attribute, SVG's sizes) look it up here.
"""

from __future__ import annotations

#: Meters per unit, by lower-case name.
METERS_PER_UNIT = {
    "nm": 1e-9,
    "nanometer": 1e-9,
    "nanometre": 1e-9,
    "um": 1e-6,
    "µm": 1e-6,  # micro sign
    "μm": 1e-6,  # Greek mu
    "micron": 1e-6,
    "microns": 1e-6,
    "micrometer": 1e-6,
    "micrometre": 1e-6,
    "mm": 1e-3,
    "millimeter": 1e-3,
    "millimetre": 1e-3,
    "cm": 1e-2,
    "centimeter": 1e-2,
    "centimetre": 1e-2,
    "m": 1.0,
    "meter": 1.0,
    "metre": 1.0,
    "in": 0.0254,
    "inch": 0.0254,
    "ft": 0.3048,
    "foot": 0.3048,
}


def meters_per_unit(unit: str | None) -> float | None:
    """Meters in one ``unit``, or None when the unit is missing or not a length
    this table knows."""
    if not isinstance(unit, str):
        return None
    return METERS_PER_UNIT.get(unit.strip().lower())


#: The usual symbol of each length, by meters per unit.
SYMBOLS = {1e-9: "nm", 1e-6: "µm", 1e-3: "mm", 1e-2: "cm", 0.0254: "in", 0.3048: "ft", 1.0: "m"}


def unit_symbol(unit: str | None) -> str | None:
    """The usual symbol of a length unit ("micron" -> "µm"), or None when unknown."""
    return SYMBOLS.get(meters_per_unit(unit))
