"""Charge generation: pixel response non-uniformity and thermal (dark) electrons.

Stage 2 of the camera chain, acting on generation *rates* (e-/s) of the image area, so that the
frame-transfer integration in :mod:`simulator.detector.charge_transfer` treats photo and thermal charge alike.
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera import Camera
from simulator.derived_cache import DERIVED


def prnu_map(camera: Camera) -> np.ndarray:
    """The simulated detector's relative pixel response (mean 1, rms ``radiometry.prnu_sigma``).

    The realisation is fixed by ``radiometry.prnu_seed`` and cached per camera. This is simulator truth:
    an estimator never sees it, only a flat field measured from simulated calibration exposures
    (:mod:`simulator.calibration`).

    Parameters
    ----------
    camera : Camera
        The camera.

    Returns
    -------
    ndarray, shape (height, width), float32
        Relative response per pixel.
    """
    cache = DERIVED.of(camera, "render")
    if "prnu_map" not in cache:
        rng = np.random.default_rng(camera.radiometry.prnu_seed)
        gains = 1.0 + camera.radiometry.prnu_sigma * rng.standard_normal((camera.height_px, camera.width_px))
        cache["prnu_map"] = np.clip(gains, 0.0, None).astype(np.float32)
        cache["prnu_map"].setflags(write=False)
    return cache["prnu_map"]


def apply_prnu(rate_e_per_s: np.ndarray, prnu_map: np.ndarray) -> np.ndarray:
    """Multiply a photo-electron rate by the relative pixel response (in place when float32).

    Parameters
    ----------
    rate_e_per_s : ndarray, shape (H, W)
        Photo-electron rate (e-/s).
    prnu_map : ndarray, shape (H, W), float32
        Relative pixel response (:func:`prnu_map`).

    Returns
    -------
    ndarray, shape (H, W), float32
        The rate times the response (e-/s).
    """
    rate_e_per_s *= prnu_map
    return rate_e_per_s


def dark_rate_e_per_s(camera: Camera, scale: float = 1.0) -> float:
    """Uniform dark generation rate per pixel at the camera's CCD temperature.

    Uses the documented doubling rule of :meth:`Electronics.dark_current_e_per_s`.

    Parameters
    ----------
    camera : Camera
        The camera (its electronics).
    scale : float, optional
        Multiplies the rate (off-nominal "excessive dark current").

    Returns
    -------
    float
        Dark rate (e-/s per pixel).
    """
    return scale * camera.electronics.dark_current_e_per_s()


def storage_dark_e(camera: Camera, dark_rate: float) -> np.ndarray:
    """Dark electrons each binned row gathers in the storage area while it waits to be read out.

    The row nearest the serial register is read first. With charge moving toward the last image row,
    image row ``height-1`` arrives first and is read first; binned row ``k`` of ``n`` waits
    ``readout_s * (n - k) / n`` (reversed for the other direction). Binning sums ``binning_rows``
    pixels, each holding its own dark charge.

    Parameters
    ----------
    camera : Camera
        The camera (timing, binning, transfer direction).
    dark_rate : float
        Dark rate per pixel (e-/s).

    Returns
    -------
    ndarray, shape (binned_rows, 1), float32
        Electrons per binned pixel.
    """
    rows, _ = camera.binned_shape
    order = np.arange(rows, dtype=np.float64)
    waits = (rows - order) / rows if camera.timing.transfer_toward_last_row else (order + 1.0) / rows
    dark = camera.binning_rows * dark_rate * camera.timing.readout_s * waits
    return dark.astype(np.float32)[:, None]
