"""PNG, TIFF and GeoTIFF reader (Pillow), single-band grayscale images.

Accepted modes: 8-bit (L), 16-bit (I;16*), 32-bit integer (I), 32-bit float (F), and gray+alpha
(LA: alpha 0 marks invalid pixels). Colour, palette and bilevel images are refused: terrain is one
band of reflectance. Before decoding, PNG chunk CRCs are verified and TIFF strip/tile extents are
checked against the file size, so a truncated or corrupted file raises rather than returning
partial pixels.

GeoTIFF: ``ModelPixelScaleTag`` gives the ground sampling when ``GTModelTypeGeoKey`` says the CRS
is projected and ``ProjLinearUnitsGeoKey`` is metres (9001; absent is taken as metres, noted).
Geographic (degree) CRSs leave ``metres_per_pixel`` unknown; non-square pixels are refused.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PIL import Image, ImageFile, UnidentifiedImageError

from file_formats.planetary.image import OrbitalImage, ReaderError, fail, file_size, finish

_MODE_DTYPES = {"L": np.uint8, "I;16": np.uint16, "I;16L": np.uint16, "I;16B": np.uint16, "I;16N": np.uint16,
                "I": np.int32, "F": np.float32, "LA": np.uint8}
_TAG_STRIP_OFFSETS, _TAG_STRIP_COUNTS, _TAG_TILE_OFFSETS, _TAG_TILE_COUNTS = 273, 279, 324, 325
_TAG_PIXEL_SCALE, _TAG_TIEPOINT, _TAG_TRANSFORM, _TAG_GEOKEYS = 33550, 33922, 34264, 34735
_GEOKEY_MODEL_TYPE, _GEOKEY_LINEAR_UNITS = 1024, 3076
_METRE = 9001


def looks_like_raster(head: bytes) -> bool:
    return head.startswith((b"\x89PNG\r\n\x1a\n", b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"))


def read_raster(path: str | Path, band_index: int = 0) -> OrbitalImage:
    """Read a grayscale PNG/TIFF/GeoTIFF. ``band_index`` selects a page of a multi-page TIFF."""
    path = Path(path)
    size = file_size(path)
    previous_setting = ImageFile.LOAD_TRUNCATED_IMAGES
    ImageFile.LOAD_TRUNCATED_IMAGES = False      # a truncated file must raise, never pad with zeros
    try:
        array, mode, file_format, pages, metres, notes, tags, info = _decode(path, size, band_index)
    except ReaderError:
        raise
    except UnidentifiedImageError:
        raise fail(path, "not a readable PNG/TIFF image (unrecognised format)") from None
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
        raise fail(path, f"image data are corrupt or truncated (Pillow: {exc})") from None
    finally:
        ImageFile.LOAD_TRUNCATED_IMAGES = previous_setting
    if mode == "LA":
        valid = array[..., 1] > 0
        array = array[..., 0]
    else:
        valid = np.ones(array.shape[:2], dtype=bool)
    if array.ndim != 2:
        raise fail(path, f"decoded array has shape {array.shape}; expected one band")
    pixels, valid = finish(array.astype(np.float32), valid)
    label = {"format": file_format, "mode": mode, "pages": pages, "tags": tags, "info": info}
    kind = "GeoTIFF" if _TAG_GEOKEYS in tags or _TAG_PIXEL_SCALE in tags else file_format
    return OrbitalImage(pixels=pixels, valid=valid, source=path, file_format=kind, label=label,
                        metres_per_pixel=metres, band_index=band_index, band_count=pages, notes=tuple(notes))


def _decode(path: Path, size: int, band_index: int):
    """Verify and decode one page: (array, mode, format, pages, metres/pixel, notes, tags, info)."""
    with Image.open(path) as probe:
        file_format = probe.format
        if file_format == "PNG":
            probe.verify()                       # chunk CRCs
    with Image.open(path) as image:
        pages = getattr(image, "n_frames", 1)
        if not 0 <= band_index < pages:
            raise fail(path, f"band_index {band_index} is out of range; the file has {pages} page(s)")
        image.seek(band_index)
        notes: list[str] = []
        metres = None
        if file_format == "TIFF":
            _check_tiff_extents(path, image, size)
            metres = _geotiff_metres_per_pixel(path, image, notes)
        mode = image.mode
        if mode not in _MODE_DTYPES:
            raise fail(path, f"{file_format} mode {mode!r} is not supported (terrain must be one grayscale "
                             f"band); allowed modes: {', '.join(_MODE_DTYPES)}")
        image.load()
        array = np.asarray(image)
        tags = {int(k): _plain(v) for k, v in image.tag_v2.items()} if file_format == "TIFF" else {}  # type: ignore[attr-defined]  # TiffImageFile only
        info = {k: _plain(v) for k, v in image.info.items() if isinstance(v, (int, float, str, tuple))}
    return array, mode, file_format, pages, metres, notes, tags, info


def _plain(value):
    if isinstance(value, bytes):
        return value[:64].hex()
    if isinstance(value, tuple):
        return tuple(_plain(v) for v in value[:64])
    try:
        return float(value) if not isinstance(value, (int, str)) else value
    except (TypeError, ValueError):
        return str(value)


def _check_tiff_extents(path: Path, image: Image.Image, size: int) -> None:
    tags = image.tag_v2  # type: ignore[attr-defined]  # a TiffImageFile here (callers check the format)
    for offsets_tag, counts_tag, name in ((_TAG_STRIP_OFFSETS, _TAG_STRIP_COUNTS, "StripOffsets/StripByteCounts"),
                                          (_TAG_TILE_OFFSETS, _TAG_TILE_COUNTS, "TileOffsets/TileByteCounts")):
        if offsets_tag in tags:
            offsets = np.atleast_1d(np.asarray(tags[offsets_tag], dtype=np.int64))
            if counts_tag not in tags:
                raise fail(path, f"TIFF has {name.split('/')[0]} but no {name.split('/')[1]}")
            counts = np.atleast_1d(np.asarray(tags[counts_tag], dtype=np.int64))
            if offsets.shape != counts.shape:
                raise fail(path, f"TIFF {name} have different lengths ({offsets.size} vs {counts.size})")
            end = int((offsets + counts).max()) if offsets.size else 0
            if end > size:
                raise fail(path, f"truncated TIFF: {name} reach byte {end} but the file has {size} bytes")


def _geotiff_metres_per_pixel(path: Path, image: Image.Image, notes: list[str]) -> float | None:
    tags = image.tag_v2  # type: ignore[attr-defined]  # a TiffImageFile here (callers check the format)
    if _TAG_PIXEL_SCALE not in tags and _TAG_TRANSFORM not in tags:
        return None
    keys = {}
    directory = tags.get(_TAG_GEOKEYS)
    if directory is not None:
        entries = list(directory)
        for start in range(4, len(entries) - 3, 4):
            key_id, location, _count, value = entries[start:start + 4]
            if location == 0:
                keys[int(key_id)] = int(value)
    model_type = keys.get(_GEOKEY_MODEL_TYPE)
    if model_type != 1:
        notes.append(f"GeoTIFF GTModelTypeGeoKey = {model_type} (not a projected CRS): metres_per_pixel unknown")
        return None
    units = keys.get(_GEOKEY_LINEAR_UNITS)
    if units is None:
        notes.append("GeoTIFF has no ProjLinearUnitsGeoKey; pixel scale taken as metres")
    elif units != _METRE:
        notes.append(f"GeoTIFF ProjLinearUnitsGeoKey = {units} (not metres, 9001): metres_per_pixel unknown")
        return None
    if _TAG_PIXEL_SCALE in tags:
        scale_x, scale_y = (float(v) for v in list(tags[_TAG_PIXEL_SCALE])[:2])
        source = "ModelPixelScaleTag"
    else:
        matrix = [float(v) for v in tags[_TAG_TRANSFORM]]
        if len(matrix) != 16 or matrix[1] != 0.0 or matrix[4] != 0.0:
            raise fail(path, "GeoTIFF ModelTransformationTag is rotated or sheared; a north-up grid is required")
        scale_x, scale_y = abs(matrix[0]), abs(matrix[5])
        source = "ModelTransformationTag"
    if not (scale_x > 0 and math.isfinite(scale_x) and scale_y > 0 and math.isfinite(scale_y)):
        raise fail(path, f"GeoTIFF {source} scale ({scale_x}, {scale_y}) is not positive and finite")
    if abs(scale_x - scale_y) > 1e-6 * scale_x:
        raise fail(path, f"GeoTIFF {source} has non-square pixels ({scale_x} x {scale_y} m); square pixels are "
                         f"required")
    return scale_x
