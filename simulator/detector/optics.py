"""Photon collection: spectral radiance at the lens -> photo-electron generation rate per pixel.

Stage 1 of the camera chain. The lens maps a scene radiance ``L`` (W m^-2 sr^-1 um^-1, band
average) onto the focal plane; relative illumination falls off as cos^4 of the field angle.
"""
from __future__ import annotations

import numpy as np

from flight_interface.camera import Camera


def photoelectron_rate(radiance_w_m2_sr_um: np.ndarray, camera: Camera, falloff: bool = True) -> np.ndarray:
    """Photo-electrons per second generated in each pixel (before PRNU).

    Parameters
    ----------
    radiance_w_m2_sr_um : ndarray, shape (height, width)
        Band-average spectral radiance seen by each pixel (0 for sky / no signal).
    camera : Camera
    falloff : bool
        Apply the cos^4 relative illumination of :attr:`Camera.falloff_map`.

    Returns
    -------
    ndarray, shape (height, width), float32, e-/s
    """
    with np.errstate(over="ignore"):   # an overflowing rate becomes inf, which the chain saturates
        rate = np.asarray(radiance_w_m2_sr_um, dtype=np.float32) * np.float32(camera.responsivity_e_per_s)
    if falloff:
        rate *= camera.falloff_map
    return rate
