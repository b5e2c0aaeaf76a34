"""Flat-field files: a calibration product (:class:`flight_interface.calibration.CalibrationProducts`) on disk.

Formats, by suffix: ``.npy`` (NumPy), ``.tif``/``.tiff`` (one 32-bit float or 16-bit page, read with
Pillow), ``.fits``/``.fit`` (primary HDU, read with astropy: ``pip install moc2dimes[fits]``).
:func:`flat_field_next_to` finds ``<camera stem>.flat.{npy,tif,tiff,fits}`` beside a camera TOML.
Whatever is read is checked and brought to read-out shape by
:func:`flight_interface.calibration.readout_flat_field`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from flight_interface.calibration import CalibrationError, readout_flat_field

FLAT_FIELD_SUFFIXES = (".npy", ".tif", ".tiff", ".fits", ".fit")


def load_flat_field(path: str | Path, binned_shape: tuple[int, int]) -> np.ndarray:
    """Read a flat-field file (.npy, TIFF or FITS) and return it in read-out shape (see module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: flat-field file not found")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            array = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise CalibrationError(f"{path}: not a readable .npy array ({exc})") from None
    elif suffix in (".tif", ".tiff"):
        try:
            with Image.open(path) as image:
                array = np.asarray(image)
        except (UnidentifiedImageError, OSError) as exc:
            raise CalibrationError(f"{path}: not a readable TIFF image ({exc})") from None
    elif suffix in (".fits", ".fit"):
        array = _read_fits(path)
    else:
        raise CalibrationError(f"{path}: unknown flat-field format {suffix!r}; allowed: "
                               f"{', '.join(FLAT_FIELD_SUFFIXES)}")
    return readout_flat_field(array, binned_shape, str(path))


def save_flat_field(path: str | Path, flat: np.ndarray) -> Path:
    """Write a flat field as .npy, 32-bit float TIFF or FITS (by suffix); returns the path."""
    path = Path(path)
    flat = np.asarray(flat, dtype=np.float32)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        np.save(path, flat)
    elif suffix in (".tif", ".tiff"):
        Image.fromarray(flat, mode="F").save(path)
    elif suffix in (".fits", ".fit"):
        fits = _fits_module(path)
        fits.PrimaryHDU(flat).writeto(path, overwrite=True)
    else:
        raise CalibrationError(f"{path}: unknown flat-field format {suffix!r}; allowed: "
                               f"{', '.join(FLAT_FIELD_SUFFIXES)}")
    return path


def flat_field_next_to(camera_path: str | Path) -> Path | None:
    """``<camera stem>.flat.<suffix>`` beside a camera TOML (first suffix of :data:`FLAT_FIELD_SUFFIXES`
    that exists), or None."""
    camera_path = Path(camera_path)
    for suffix in FLAT_FIELD_SUFFIXES:
        candidate = camera_path.with_name(f"{camera_path.stem}.flat{suffix}")
        if candidate.is_file():
            return candidate
    return None


def _fits_module(path: Path):
    # astropy is an optional extra (moc2dimes[fits]): imported only when a FITS file is read or written
    try:
        from astropy.io import fits
    except ImportError:
        raise CalibrationError(f"{path}: reading or writing FITS needs astropy (pip install 'moc2dimes[fits]')") from None
    return fits


def _read_fits(path: Path) -> np.ndarray:
    fits = _fits_module(path)
    try:
        with fits.open(path, memmap=False) as hdus:
            data = next((hdu.data for hdu in hdus if getattr(hdu, "data", None) is not None), None)
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{path}: not a readable FITS file ({exc})") from None
    if data is None:
        raise CalibrationError(f"{path}: FITS file holds no image data")
    return np.asarray(data)
