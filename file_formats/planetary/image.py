"""The common result of every terrain reader, the reader error, and checked raw-array decoding.

Every reader returns an :class:`OrbitalImage`: one band of an orbital image as float32 pixel
values (after the file's own base/multiplier, so DN or I/F as the file says), a validity mask
(special, missing and non-finite pixels are False and set to 0 in ``pixels``), and whatever the
file knows about scale, photometric geometry and the DN-to-I/F calibration.

Every failure is a :class:`ReaderError` whose one-line message names the file and the keyword or
format that defeated the reader. Readers never return pixels they could not account for: a file
shorter than its label promises, a pointer outside the file, an unknown sample type all raise.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from config_tables.errors import ConfigError
from file_formats.planetary.pvl import LabelSyntaxError, ParsedLabel, parse_label


class ReaderError(ConfigError):
    """An image file cannot be read faithfully (one line: file, keyword/format, what is wrong)."""


def fail(path: Path | str, message: str) -> ReaderError:
    """A :class:`ReaderError` whose message starts with the file name."""
    return ReaderError(f"{path}: {message}")


@dataclass(frozen=True)
class OrbitalImage:
    """One band of an orbital image and what is known about it.

    Attributes
    ----------
    pixels : ndarray, float32, shape (rows, cols)
        Pixel values after the file's base/multiplier (DN, or I/F when the file is calibrated).
        Invalid pixels hold 0.
    valid : ndarray, bool, shape (rows, cols)
        False where the file marks the pixel special/missing (ISIS NULL/LRS/LIS/HIS/HRS, PDS
        MISSING_CONSTANT, QUBE CORE_NULL, non-finite floats).
    source : Path
        The file the pixels came from.
    file_format : str
        "PDS3", "ISIS3", "VICAR", "DDD", "GeoTIFF", "TIFF" or "PNG".
    label : dict
        The parsed label / header keywords (nested dicts; PVL quantities as ``Quantity``).
    metres_per_pixel : float or None
        Ground sampling (m) when the file states it in metres (map-projected products).
    incidence_rad, emission_rad, phase_rad : float or None
        Photometric angles of the orbital observation (rad) when the file states them.
    dn_to_if_scale, dn_to_if_offset : float or None
        ``I/F = dn_to_if_scale * pixels + dn_to_if_offset`` when known (1 and 0 for I/F products).
    band_index, band_count : int
        Which band (0-based) of how many the pixels are.
    notes : tuple of str
        Anything the reader had to decide (e.g. a pointer repaired), for provenance.
    """

    pixels: np.ndarray
    valid: np.ndarray
    source: Path
    file_format: str
    label: dict[str, Any] = field(default_factory=dict)
    metres_per_pixel: float | None = None
    incidence_rad: float | None = None
    emission_rad: float | None = None
    phase_rad: float | None = None
    dn_to_if_scale: float | None = None
    dn_to_if_offset: float | None = None
    band_index: int = 0
    band_count: int = 1
    notes: tuple[str, ...] = ()

    def __post_init__(self):
        if self.pixels.ndim != 2 or self.pixels.dtype != np.float32:
            raise ValueError(f"{self.source}: pixels must be 2-D float32; got {self.pixels.dtype} {self.pixels.shape}")
        if self.valid.shape != self.pixels.shape or self.valid.dtype != bool:
            raise ValueError(f"{self.source}: valid mask must be bool of shape {self.pixels.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape

    def replace(self, **changes: Any) -> OrbitalImage:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)


def finish(pixels: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float32 pixels with non-finite values invalidated and every invalid pixel set to 0."""
    pixels = np.asarray(pixels, dtype=np.float32)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(pixels)
    return np.where(valid, pixels, np.float32(0.0)).astype(np.float32, copy=False), valid


def file_size(path: Path) -> int:
    try:
        status = path.stat()
    except FileNotFoundError:
        raise fail(path, "file not found") from None
    except OSError as exc:
        raise fail(path, f"cannot be read ({exc.strerror})") from None
    if not path.is_file():
        raise fail(path, "is not a regular file (a directory?); allowed: an image file")
    return status.st_size


def read_attached_label(path: Path, what: str, max_bytes: int = 8 << 20) -> tuple[ParsedLabel, str]:
    """Parse the PVL label at the start of ``path``.

    Returns the parsed label and the text it was parsed from. Raises :class:`ReaderError` naming the
    file when no complete label (up to ``END``) is found in the first ``max_bytes`` bytes.
    """
    size = file_size(path)
    chunk = 64 << 10
    while True:
        with path.open("rb") as handle:
            text = handle.read(min(chunk, size)).decode("latin-1")
        try:
            return parse_label(text), text
        except LabelSyntaxError as exc:
            truncated_text = len(text) < size and "ended without" in str(exc)
            if truncated_text and chunk < max_bytes:
                chunk *= 4
                continue
            raise fail(path, f"{what} label is not valid: {exc}") from None


def read_raw(path: Path, offset: int, count: int, dtype: np.dtype, what: str) -> np.ndarray:
    """``count`` items of ``dtype`` from byte ``offset`` of ``path``, refusing short files."""
    needed = offset + count * np.dtype(dtype).itemsize
    size = file_size(path)
    if offset < 0 or needed > size:
        raise fail(path, f"truncated or inconsistent: {what} needs bytes {offset}..{needed} "
                         f"but the file has {size} bytes")
    with path.open("rb") as handle:
        handle.seek(offset)
        return np.fromfile(handle, dtype=dtype, count=count)

