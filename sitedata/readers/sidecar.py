"""Side-car TOML: what an orbital image file does not say about itself.

Next to ``image.img`` a file ``image.toml`` (or any file given explicitly) may hold::

    name = "M01/00115"              # optional terrain name
    metres_per_pixel = 4.5          # ground sampling, m (> 0)
    incidence_deg = 31.0            # photometric angles of the ORBITAL observation, degrees
    emission_deg = 0.0
    phase_deg = 31.0
    dn_to_if_scale = 0.0012         # I/F = dn_to_if_scale * pixel + dn_to_if_offset
    dn_to_if_offset = 0.0
    band_index = 0                  # 0-based band of multi-band products

    [crop]                          # optional window, pixels (applied before everything else)
    first_row = 0
    first_col = 0
    rows = 2000
    cols = 672

Every field is optional; a field given here overrides what the file states (a note records it).
Angles must describe a real geometry: incidence and emission in [0, 90) deg, phase in [0, 180]
deg and ``|i - e| <= g <= i + e`` (spherical triangle). Unknown fields are refused so typos fail.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from flight_interface.tomlfields import ConfigError, Table, load_toml

from .image import OrbitalImage, fail

ALLOWED_FIELDS = ("name", "metres_per_pixel", "incidence_deg", "emission_deg", "phase_deg", "dn_to_if_scale",
                  "dn_to_if_offset", "band_index", "crop")
CROP_FIELDS = ("first_row", "first_col", "rows", "cols")
_TRIANGLE_TOLERANCE_DEG = 0.01


@dataclass(frozen=True)
class CropWindow:
    """A pixel window: rows ``first_row .. first_row + rows - 1``, same for columns."""

    first_row: int
    first_col: int
    rows: int
    cols: int


@dataclass(frozen=True)
class Sidecar:
    """Parsed side-car values (None = not given). Angles in radians."""

    source: Path
    name: str | None = None
    metres_per_pixel: float | None = None
    incidence_rad: float | None = None
    emission_rad: float | None = None
    phase_rad: float | None = None
    dn_to_if_scale: float | None = None
    dn_to_if_offset: float | None = None
    band_index: int | None = None
    crop: CropWindow | None = None


def default_sidecar_path(image_path: str | Path) -> Path:
    """``<stem>.toml`` beside the image."""
    image_path = Path(image_path)
    return image_path.with_suffix(".toml")


def read_sidecar(path: str | Path) -> Sidecar:
    """Parse and validate a side-car TOML (one-line :class:`ConfigError` on any bad field)."""
    path = Path(path)
    table = Table(load_toml(path), str(path))
    for key in table.data:
        if key not in ALLOWED_FIELDS:
            raise table.fail(key, f"is not a side-car field; allowed: {', '.join(ALLOWED_FIELDS)}")

    def optional_number(key: str, **limits) -> float | None:
        return table.number(key, **limits) if table.has(key) else None

    def optional_angle(key: str, maximum: float, exclusive: bool) -> float | None:
        if not table.has(key):
            return None
        return table.number(key, minimum=0.0, maximum=maximum, exclusive_maximum=exclusive)

    incidence = optional_angle("incidence_deg", 90.0, True)
    emission = optional_angle("emission_deg", 90.0, True)
    phase = optional_angle("phase_deg", 180.0, False)
    if incidence is not None and emission is not None and phase is not None:
        low, high = abs(incidence - emission), incidence + emission
        if not low - _TRIANGLE_TOLERANCE_DEG <= phase <= high + _TRIANGLE_TOLERANCE_DEG:
            raise table.fail("phase_deg", f"= {phase:g} is impossible with incidence {incidence:g} and emission "
                                          f"{emission:g} deg; allowed: {low:g} .. {high:g}")
    crop = None
    if table.has("crop"):
        crop_table = table.table("crop")
        for key in crop_table.data:
            if key not in CROP_FIELDS:
                raise crop_table.fail(key, f"is not a crop field; allowed: {', '.join(CROP_FIELDS)}")
        crop = CropWindow(crop_table.integer("first_row", minimum=0), crop_table.integer("first_col", minimum=0),
                          crop_table.integer("rows", minimum=1), crop_table.integer("cols", minimum=1))
    return Sidecar(
        source=path,
        name=table.string("name") if table.has("name") else None,
        metres_per_pixel=optional_number("metres_per_pixel", minimum=0.0, exclusive_minimum=True),
        incidence_rad=None if incidence is None else math.radians(incidence),
        emission_rad=None if emission is None else math.radians(emission),
        phase_rad=None if phase is None else math.radians(phase),
        dn_to_if_scale=optional_number("dn_to_if_scale", minimum=0.0, exclusive_minimum=True),
        dn_to_if_offset=optional_number("dn_to_if_offset"),
        band_index=table.integer("band_index", minimum=0) if table.has("band_index") else None,
        crop=crop)


def apply_sidecar(image: OrbitalImage, sidecar: Sidecar | None) -> OrbitalImage:
    """The image with the side-car's crop applied and its values filling in (or overriding) the file's."""
    if sidecar is None:
        return image
    notes = list(image.notes)
    pixels, valid = image.pixels, image.valid
    if sidecar.crop is not None:
        crop = sidecar.crop
        rows, cols = image.shape
        if crop.first_row + crop.rows > rows or crop.first_col + crop.cols > cols:
            raise ConfigError(f"{sidecar.source}: crop rows {crop.first_row}+{crop.rows}, cols {crop.first_col}+"
                              f"{crop.cols} exceeds the image ({rows} rows x {cols} cols of {image.source})")
        window = (slice(crop.first_row, crop.first_row + crop.rows), slice(crop.first_col, crop.first_col + crop.cols))
        pixels, valid = pixels[window].copy(), valid[window].copy()
        notes.append(f"cropped to rows {crop.first_row}..{crop.first_row + crop.rows - 1}, cols "
                     f"{crop.first_col}..{crop.first_col + crop.cols - 1} by {sidecar.source}")
    changes = {}
    for field in ("metres_per_pixel", "dn_to_if_scale", "dn_to_if_offset"):
        changes[field] = _merge(image, sidecar, field, field, notes)
    for field in ("incidence", "emission", "phase"):
        changes[f"{field}_rad"] = _merge(image, sidecar, f"{field}_rad", f"{field}_deg", notes)
    if sidecar.dn_to_if_scale is not None and sidecar.dn_to_if_offset is None and image.dn_to_if_offset is None:
        changes["dn_to_if_offset"] = 0.0
    return image.replace(pixels=pixels, valid=valid, notes=tuple(notes), **changes)


def _merge(image: OrbitalImage, sidecar: Sidecar, field: str, toml_key: str, notes: list[str]):
    from_file, from_sidecar = getattr(image, field), getattr(sidecar, field)
    if from_sidecar is None:
        return from_file
    if from_file is not None and not math.isclose(from_file, from_sidecar, rel_tol=1e-9, abs_tol=1e-12):
        notes.append(f"{sidecar.source}: {toml_key} overrides the file's value ({from_file:g} -> {from_sidecar:g}"
                     f"{' rad' if field.endswith('_rad') else ''})")
    return from_sidecar


def refuse_unknown(image: OrbitalImage, what: str, sidecar_field: str, sidecar_hint: str) -> None:
    """Raise a ReaderError saying ``what`` is unknown and which side-car field supplies it."""
    raise fail(image.source, f"{what} is unknown: the {image.file_format} file does not state it; give "
                             f"{sidecar_field} in a side-car TOML ({sidecar_hint})")
