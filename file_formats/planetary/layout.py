"""Decode one band of a raw raster (lines of samples, optional per-line prefix/suffix bytes, BSQ/BIL/BIP).

Shared by the PDS3, VICAR, DDD and ISIS3 (band-sequential) readers. The size check is exact:
the file must hold every byte the layout describes, or :class:`~.image.ReaderError` is raised.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from file_formats.planetary.image import fail, file_size, finish, read_raw

STORAGE_ORDERS = ("BSQ", "BIL", "BIP")


@dataclass(frozen=True)
class RasterLayout:
    """Geometry and encoding of a raw raster.

    Attributes
    ----------
    lines, samples, bands : int
        Image dimensions.
    dtype : numpy dtype
        Stored item type with explicit byte order (e.g. ``>i2``).
    storage : str
        "BSQ" (band sequential), "BIL" (line interleaved) or "BIP" (pixel interleaved).
    prefix_bytes, suffix_bytes : int
        Bytes before/after the samples of each stored line (BSQ only).
    base, multiplier : float
        ``value = raw * multiplier + base`` for valid pixels.
    invalid_raw : tuple of float
        Raw values that mark missing/special pixels.
    valid_raw_min, valid_raw_max : float or None
        Raw values outside [min, max] are special (ISIS / QUBE conventions).
    """

    lines: int
    samples: int
    bands: int
    dtype: np.dtype
    storage: str = "BSQ"
    prefix_bytes: int = 0
    suffix_bytes: int = 0
    base: float = 0.0
    multiplier: float = 1.0
    invalid_raw: tuple[float, ...] = ()
    valid_raw_min: float | None = None
    valid_raw_max: float | None = None

    @property
    def line_bytes(self) -> int:
        """Bytes of one stored line record (one band in BSQ, all bands in BIL/BIP)."""
        per_line_bands = 1 if self.storage == "BSQ" else self.bands
        return self.prefix_bytes + per_line_bands * self.samples * self.dtype.itemsize + self.suffix_bytes

    @property
    def total_bytes(self) -> int:
        records = self.lines * (self.bands if self.storage == "BSQ" else 1)
        return records * self.line_bytes


def describe_dtype(dtype: np.dtype) -> str:
    """'uint8', 'MSB int16', 'LSB float32' ... for error messages."""
    dtype = np.dtype(dtype)
    name = {"u": "uint", "i": "int", "f": "float"}.get(dtype.kind, dtype.kind) + str(8 * dtype.itemsize)
    if dtype.itemsize == 1:
        return name
    big = dtype.byteorder == ">" or (dtype.byteorder == "=" and np.little_endian is False)
    return f"{'MSB' if big else 'LSB'} {name}"


def check_dimensions(path: Path, lines, samples, bands, names: tuple[str, str, str]) -> None:
    """Refuse non-integer or non-positive dimensions, naming the keyword."""
    for value, name in zip((lines, samples, bands), names):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise fail(path, f"{name} = {value!r} is not a positive integer")


def decode_band(path: Path, offset: int, layout: RasterLayout, band_index: int, what: str
                ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (float32) and validity mask of one band, shape (lines, samples).

    Raises
    ------
    ReaderError
        When the file is shorter than ``offset + layout.total_bytes`` or the band index is invalid.
    """
    if layout.storage not in STORAGE_ORDERS:
        raise fail(path, f"{what}: band storage {layout.storage!r} is not supported; allowed: BSQ, BIL, BIP")
    if not 0 <= band_index < layout.bands:
        raise fail(path, f"band_index {band_index} is out of range; the file has {layout.bands} band(s)")
    if layout.storage != "BSQ" and (layout.prefix_bytes or layout.suffix_bytes):
        raise fail(path, f"{what}: line prefix/suffix bytes with {layout.storage} storage are not supported")
    size = file_size(path)
    end = offset + layout.total_bytes
    if offset < 0 or end > size:
        raise fail(path, f"truncated or inconsistent: {what} ({layout.lines} lines x {layout.samples} samples x "
                         f"{layout.bands} bands of {describe_dtype(layout.dtype)}, {layout.prefix_bytes}+{layout.suffix_bytes} "
                         f"line prefix+suffix bytes) needs bytes {offset}..{end} but the file has {size} bytes")
    item = layout.dtype.itemsize
    if layout.storage == "BSQ":
        band_bytes = layout.lines * layout.line_bytes
        raw = read_raw(path, offset + band_index * band_bytes, band_bytes, np.dtype(np.uint8), what)
        records = raw.reshape(layout.lines, layout.line_bytes)
        body = records[:, layout.prefix_bytes:layout.prefix_bytes + layout.samples * item]
        band = np.ascontiguousarray(body).view(layout.dtype).reshape(layout.lines, layout.samples)
    else:
        count = layout.lines * layout.samples * layout.bands
        flat = read_raw(path, offset, count, layout.dtype, what)
        if layout.storage == "BIL":
            band = flat.reshape(layout.lines, layout.bands, layout.samples)[:, band_index, :]
        else:
            band = flat.reshape(layout.lines, layout.samples, layout.bands)[:, :, band_index]
    return apply_scaling(band, layout)


def apply_scaling(raw: np.ndarray, layout: RasterLayout) -> tuple[np.ndarray, np.ndarray]:
    """Mask special raw values, apply base/multiplier, return (float32 pixels, valid)."""
    valid = np.ones(raw.shape, dtype=bool)
    if raw.dtype.kind == "f":
        valid &= np.isfinite(raw)
    for value in layout.invalid_raw:
        valid &= raw != value
    if layout.valid_raw_min is not None:
        valid &= raw >= layout.valid_raw_min
    if layout.valid_raw_max is not None:
        valid &= raw <= layout.valid_raw_max
    with np.errstate(invalid="ignore", over="ignore"):
        values = raw.astype(np.float64) * layout.multiplier + layout.base
    return finish(values, valid)
