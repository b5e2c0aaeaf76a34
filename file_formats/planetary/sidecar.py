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
deg and ``|i - e| <= g <= i + e`` (spherical triangle). Unknown fields are refused so typos fail. The file is
declared once, by :class:`Sidecar` (``campaign schema terrain_sidecar``).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import NoReturn

from pydantic import Field, PrivateAttr, model_validator

from config_tables.errors import ConfigError, FieldProblem
from config_tables.models import ConfigModel, load
from file_formats.planetary.image import OrbitalImage, fail

_TRIANGLE_TOLERANCE_DEG = 0.01


class CropWindow(ConfigModel):
    """``[crop]``: a pixel window, rows ``first_row .. first_row + rows - 1``, same for columns."""

    first_row: int = Field(ge=0)
    first_col: int = Field(ge=0)
    rows: int = Field(ge=1)
    cols: int = Field(ge=1)


class Sidecar(ConfigModel):
    """A side-car TOML: what an orbital image file does not state (None = not given; angles in degrees
    here, ``*_rad`` properties in radians)."""

    name: str | None = None
    """Terrain name."""
    metres_per_pixel: float | None = Field(None, gt=0.0)
    """Ground sampling (m)."""
    incidence_deg: float | None = Field(None, ge=0.0, lt=90.0)
    """Solar incidence of the orbital observation (deg)."""
    emission_deg: float | None = Field(None, ge=0.0, lt=90.0)
    """Emission angle of the orbital observation (deg)."""
    phase_deg: float | None = Field(None, ge=0.0, le=180.0)
    """Phase angle of the orbital observation (deg)."""
    dn_to_if_scale: float | None = Field(None, gt=0.0)
    """I/F = dn_to_if_scale * pixel + dn_to_if_offset."""
    dn_to_if_offset: float | None = None
    """See dn_to_if_scale."""
    band_index: int | None = Field(None, ge=0)
    """0-based band of multi-band products."""
    crop: CropWindow | None = None
    """Window applied before everything else."""
    _source: Path = PrivateAttr(Path("."))

    @model_validator(mode="after")
    def _angles_form_a_triangle(self):
        incidence, emission, phase = self.incidence_deg, self.emission_deg, self.phase_deg
        if incidence is not None and emission is not None and phase is not None:
            low, high = abs(incidence - emission), incidence + emission
            if not low - _TRIANGLE_TOLERANCE_DEG <= phase <= high + _TRIANGLE_TOLERANCE_DEG:
                raise FieldProblem("phase_deg", f"= {phase:g} is impossible with incidence {incidence:g} and emission "
                                                f"{emission:g} deg; allowed: {low:g} .. {high:g}")
        return self

    @property
    def source(self) -> Path:
        return self._source

    @property
    def incidence_rad(self) -> float | None:
        return None if self.incidence_deg is None else math.radians(self.incidence_deg)

    @property
    def emission_rad(self) -> float | None:
        return None if self.emission_deg is None else math.radians(self.emission_deg)

    @property
    def phase_rad(self) -> float | None:
        return None if self.phase_deg is None else math.radians(self.phase_deg)


def default_sidecar_path(image_path: str | Path) -> Path:
    """``<stem>.toml`` beside the image."""
    image_path = Path(image_path)
    return image_path.with_suffix(".toml")


def read_sidecar(path: str | Path) -> Sidecar:
    """Parse and validate a side-car TOML (one-line :class:`ConfigError` on any bad field)."""
    sidecar = load(Sidecar, path)
    sidecar._source = Path(path)
    return sidecar


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


def refuse_unknown(image: OrbitalImage, what: str, sidecar_field: str, sidecar_hint: str) -> NoReturn:
    """Raise a ReaderError saying ``what`` is unknown and which side-car field supplies it."""
    raise fail(image.source, f"{what} is unknown: the {image.file_format} file does not state it; give "
                             f"{sidecar_field} in a side-car TOML ({sidecar_hint})")
