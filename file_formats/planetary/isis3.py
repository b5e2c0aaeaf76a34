"""ISIS3 cube reader (attached label; ``Tile`` and ``BandSequential`` cores).

Pixel types UnsignedByte, SignedWord, UnsignedWord and Real, LSB or MSB. ISIS special pixels
(NULL, LRS, LIS, HIS, HRS) are masked with the values of ISIS ``SpecialPixel.h``:

=============  ==========================  ==========================
type           special raw values          valid raw range
=============  ==========================  ==========================
UnsignedByte   0 (NULL/LRS/LIS), 255 (HIS/HRS)   1..254
SignedWord     -32768..-32764              >= -32752
UnsignedWord   0, 1, 2, 65534, 65535       3..65522
Real           0xFF7FFFFB..0xFF7FFFFF      >= VALID_MIN4 (0xFF7FFFFA)
=============  ==========================  ==========================

Integer types are scaled by ``Base + Multiplier * raw``; ISIS ignores Base/Multiplier for Real and
so does this reader. ``Mapping.PixelResolution`` (metres/pixel) gives the scale; a cube with a
``Radiometry`` group and Real pixels is calibrated I/F (MOC ``moccal``), so its DN-to-I/F is 1, 0.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from file_formats.planetary.image import OrbitalImage, fail, file_size, read_attached_label, read_raw
from file_formats.planetary.layout import RasterLayout, apply_scaling, check_dimensions, decode_band, describe_dtype
from file_formats.planetary.pvl import Quantity, lookup, to_plain

_VALID_MIN4 = float(np.array([0xFF7FFFFA], dtype="<u4").view("<f4")[0])
# type -> (numpy kind+size, valid raw min, valid raw max)
PIXEL_TYPES = {
    "UNSIGNEDBYTE": ("u1", 1, 254),
    "SIGNEDWORD": ("i2", -32752, 32767),
    "UNSIGNEDWORD": ("u2", 3, 65522),
    "REAL": ("f4", _VALID_MIN4, None),
}
_BYTE_ORDERS = {"LSB": "<", "MSB": ">"}


def looks_like_isis3(head: bytes) -> bool:
    """True when the file starts with an ISIS3 ``Object = IsisCube`` label."""
    return head.lstrip()[:40].replace(b" ", b"").lower().startswith(b"object=isiscube")


def read_isis3(path: str | Path, band_index: int = 0) -> OrbitalImage:
    """Read one band of an ISIS3 cube with an attached label.

    Parameters
    ----------
    path : path-like
    band_index : int
        0-based band.

    Returns
    -------
    OrbitalImage
    """
    path = Path(path)
    parsed, _ = read_attached_label(path, "ISIS3")
    cube = lookup(parsed.tree, "IsisCube")
    core = lookup(cube, "Core") if isinstance(cube, dict) else None
    if not isinstance(core, dict):
        raise fail(path, "ISIS3 label has no IsisCube/Core object")
    if lookup(core, "^Core") is not None:
        raise fail(path, "detached ISIS3 core (^Core pointer) is not supported; use the attached cube")
    dimensions = lookup(core, "Dimensions", default={})
    pixels_group = lookup(core, "Pixels", default={})
    samples, lines, bands = (lookup(dimensions, key) for key in ("Samples", "Lines", "Bands"))
    check_dimensions(path, lines, samples, bands, ("Core.Dimensions.Lines", "Core.Dimensions.Samples",
                                                   "Core.Dimensions.Bands"))
    type_name = str(lookup(pixels_group, "Type", default="<missing>"))
    pixel_type = PIXEL_TYPES.get(type_name.upper())
    if pixel_type is None:
        raise fail(path, f"Core.Pixels.Type = {type_name} is not supported; allowed: UnsignedByte, SignedWord, "
                         f"UnsignedWord, Real")
    order_name = str(lookup(pixels_group, "ByteOrder", default="<missing>"))
    order = _BYTE_ORDERS.get(order_name.upper())
    if order is None:
        raise fail(path, f"Core.Pixels.ByteOrder = {order_name} is not allowed; allowed: Lsb, Msb")
    kind_size, valid_min, valid_max = pixel_type
    dtype = np.dtype(order + kind_size)
    base, multiplier = (_finite(path, pixels_group, key, default) for key, default in
                        (("Base", 0.0), ("Multiplier", 1.0)))
    if dtype.kind == "f":
        base, multiplier = 0.0, 1.0
    start_byte = lookup(core, "StartByte")
    if isinstance(start_byte, bool) or not isinstance(start_byte, int) or start_byte < 1:
        raise fail(path, f"Core.StartByte = {start_byte!r} is not a positive integer")
    if start_byte - 1 < parsed.end_offset:
        raise fail(path, f"Core.StartByte = {start_byte} points inside the label (which ends at byte "
                         f"{parsed.end_offset})")
    layout = RasterLayout(lines, samples, bands, dtype, "BSQ", base=base, multiplier=multiplier,
                          valid_raw_min=valid_min, valid_raw_max=valid_max)
    core_format = str(lookup(core, "Format", default="<missing>"))
    if core_format.upper() == "TILE":
        pixels, valid = _read_tiled(path, core, start_byte - 1, layout, band_index)
    elif core_format.upper() == "BANDSEQUENTIAL":
        pixels, valid = decode_band(path, start_byte - 1, layout, band_index, "ISIS3 core")
    else:
        raise fail(path, f"Core.Format = {core_format} is not supported; allowed: Tile, BandSequential")
    calibrated = dtype.kind == "f" and isinstance(lookup(cube, "Radiometry"), dict)
    return OrbitalImage(
        pixels=pixels, valid=valid, source=path, file_format="ISIS3", label=to_plain(parsed.tree),
        metres_per_pixel=_pixel_resolution_m(path, cube), dn_to_if_scale=1.0 if calibrated else None,
        dn_to_if_offset=0.0 if calibrated else None, band_index=band_index, band_count=bands)


def _finite(path: Path, scope: dict, key: str, default: float) -> float:
    value = lookup(scope, key, default=default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise fail(path, f"Core.Pixels.{key} = {value!r} is not a finite number")
    return float(value)


def _read_tiled(path: Path, core: dict, offset: int, layout: RasterLayout, band_index: int
                ) -> tuple[np.ndarray, np.ndarray]:
    tile_samples, tile_lines = lookup(core, "TileSamples"), lookup(core, "TileLines")
    for name, value in (("TileSamples", tile_samples), ("TileLines", tile_lines)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise fail(path, f"Core.{name} = {value!r} is not a positive integer")
    tiles_across = -(-layout.samples // tile_samples)
    tiles_down = -(-layout.lines // tile_lines)
    band_items = tiles_across * tiles_down * tile_samples * tile_lines
    total = offset + layout.bands * band_items * layout.dtype.itemsize
    size = file_size(path)
    if total > size:
        raise fail(path, f"truncated or inconsistent: tiled ISIS3 core ({layout.lines} x {layout.samples} x "
                         f"{layout.bands} of {describe_dtype(layout.dtype)}, {tile_samples}x{tile_lines} tiles) needs bytes "
                         f"{offset}..{total} but the file has {size} bytes")
    if not 0 <= band_index < layout.bands:
        raise fail(path, f"band_index {band_index} is out of range; the file has {layout.bands} band(s)")
    raw = read_raw(path, offset + band_index * band_items * layout.dtype.itemsize, band_items, layout.dtype,
                   "ISIS3 tiled core")
    mosaic = (raw.reshape(tiles_down, tiles_across, tile_lines, tile_samples)
              .transpose(0, 2, 1, 3).reshape(tiles_down * tile_lines, tiles_across * tile_samples))
    return apply_scaling(mosaic[:layout.lines, :layout.samples], layout)


def _pixel_resolution_m(path: Path, cube: dict) -> float | None:
    mapping = lookup(cube, "Mapping")
    if not isinstance(mapping, dict):
        return None
    resolution = lookup(mapping, "PixelResolution")
    if isinstance(resolution, Quantity):
        unit = resolution.unit.lower().replace(" ", "")
        if unit not in ("meters/pixel", "metres/pixel", "m/pixel", "m"):
            raise fail(path, f"Mapping.PixelResolution unit <{resolution.unit}> is not understood; "
                             f"allowed: meters/pixel")
        resolution = resolution.value
    if isinstance(resolution, (int, float)) and not isinstance(resolution, bool) and resolution > 0:
        return float(resolution)
    return None
