"""Calibration products: what ground calibration tells an estimator about its camera's pixels.

An estimator knows the camera as designed (:mod:`flight_interface.camera`) and, besides that, only
what was *measured* on the ground. The one product here is the **flat field**: the relative
response of each read-out pixel (optics falloff x pixel response non-uniformity), as ground
calibration measures it: the mean of N exposures of a uniform source minus the mean of N dark
exposures, normalised. It is never the simulator's truth; the campaign can hand the truth to an
estimator only on request (``[estimator] flat_field = "truth"``), to measure what calibration costs.

Conventions
-----------
* shape: the read-out image, ``camera.binned_shape`` = ``(height / binning_rows, width)`` (256 x 1024
  for MER): rows binned on chip like every descent image, columns not. A full-frame array
  ``(height, width)`` is accepted and averaged over each binned row block;
* values: float32, finite, about 1 on the optical axis (:func:`normalise_flat_field` divides
  by the mean of the central ``1/8 x 1/8`` of the array);
* files: :mod:`file_formats.flat_field_files` reads and writes them (.npy, TIFF, FITS).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CENTRAL_FRACTION = 1.0 / 8.0
#: Smallest accepted relative response: a pixel this dead carries no usable signal.
MIN_RESPONSE = 1e-3


class CalibrationError(ValueError):
    """A calibration product cannot be used; the one-line message names the file (or source) and why."""


@dataclass(frozen=True)
class CalibrationProducts:
    """The calibration products an estimator receives.

    Attributes
    ----------
    flat_field : ndarray, float32, shape ``camera.binned_shape``, or None
        Relative response of each read-out pixel (see the module docstring); None when there is no
        flat-field calibration (an estimator then corrects the design falloff at most).
    flat_field_source : str
        Where the flat field came from: ``"calibrated: N frames"``, ``"truth"``, a file path, ``"none"``.
    """

    flat_field: np.ndarray | None = None
    flat_field_source: str = "none"


def readout_flat_field(array: np.ndarray, binned_shape: tuple[int, int], source: str = "flat field") -> np.ndarray:
    """Check a flat field and return it in read-out shape ``binned_shape`` (rows, columns), float32.

    ``array`` may be of read-out shape or full-frame (``binned_shape[0] * b`` rows): full-frame rows are
    averaged over each block of ``b`` rows (on-chip binning sums charge, so the block's response is
    the mean of its pixels'). Raises :class:`CalibrationError` for another shape, non-finite values
    or a median response below :data:`MIN_RESPONSE` (a dark frame, not a flat). Single dead pixels
    are kept: consumers clip responses at :data:`MIN_RESPONSE`.

    Parameters
    ----------
    array : ndarray, shape (rows, columns) or (rows * b, columns)
        The flat field, read-out or full-frame shape, any numeric dtype (relative response).
    binned_shape : tuple of int
        ``(rows, columns)`` of the read-out image (``camera.binned_shape``).
    source : str, optional
        Name of the file or source, for the error message.

    Returns
    -------
    ndarray, shape ``binned_shape``, float32
        The flat field in read-out shape.

    Raises
    ------
    CalibrationError
        Wrong shape or dtype, non-finite values, or a median response <= :data:`MIN_RESPONSE`.
    """
    array = np.asarray(array)
    rows, columns = binned_shape
    if array.ndim != 2 or array.dtype.kind not in "uif":
        raise CalibrationError(f"{source}: a flat field must be a 2-D numeric array; got shape {array.shape}, "
                               f"dtype {array.dtype}")
    if array.shape[1] != columns or array.shape[0] < rows or array.shape[0] % rows:
        raise CalibrationError(f"{source}: flat field shape {array.shape}; expected {tuple(binned_shape)} "
                               f"(read-out rows, columns) or a full frame with a multiple of {rows} rows")
    values = array.astype(np.float64)
    if array.shape[0] != rows:
        values = values.reshape(rows, array.shape[0] // rows, columns).mean(axis=1)
    if not np.all(np.isfinite(values)):
        raise CalibrationError(f"{source}: flat field contains non-finite values")
    if not float(np.median(values)) > MIN_RESPONSE:
        raise CalibrationError(f"{source}: flat field median response is {float(np.median(values)):.3g}; "
                               f"allowed: > {MIN_RESPONSE:g} (normalised to about 1 on axis)")
    return values.astype(np.float32)


def normalise_flat_field(flat: np.ndarray) -> np.ndarray:
    """Divide by the mean of the central ``1/8 x 1/8`` of the array (about 1 on the optical axis).

    Parameters
    ----------
    flat : ndarray, shape (rows, columns)
        Relative response (any positive scale).

    Returns
    -------
    ndarray, shape (rows, columns), float32
        The response divided by its central mean.

    Raises
    ------
    CalibrationError
        The central mean is not a positive finite number.
    """
    flat = np.asarray(flat, dtype=np.float64)
    rows, columns = flat.shape
    half_rows, half_columns = max(1, int(rows * CENTRAL_FRACTION / 2)), max(1, int(columns * CENTRAL_FRACTION / 2))
    centre = flat[rows // 2 - half_rows: rows // 2 + half_rows, columns // 2 - half_columns: columns // 2 + half_columns]
    scale = float(centre.mean())
    if not (np.isfinite(scale) and scale > 0.0):
        raise CalibrationError(f"flat field: the central mean is {scale!r}; cannot normalise")
    return (flat / scale).astype(np.float32)
