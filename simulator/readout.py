"""Measurement and readout: shot noise, read noise, full well, ADC gain, quantisation and clipping.

Stage 4 of the camera chain, at binned resolution. On-chip binning sums the charge of independent
pixels before the output amplifier, and a sum of independent Poisson variables is Poisson with the
summed mean, so drawing shot noise on the binned mean is exact in distribution (as long as no single
pixel is clipped at full well, which :func:`simulator.render.render_image` handles before binning).
"""
from __future__ import annotations

import numpy as np

from .camera_config import Electronics


def shot_noise_e(rng: np.random.Generator, mean_e: np.ndarray) -> np.ndarray:
    """Poisson draw of the photo + thermal electrons, float64 (exact for means up to ~1e18)."""
    return rng.poisson(np.maximum(mean_e, 0.0)).astype(np.float64)


def read_noise_e(rng: np.random.Generator, shape: tuple[int, ...], sigma_e: float) -> np.ndarray:
    """Gaussian read noise of the output amplifier (e-)."""
    return sigma_e * rng.standard_normal(shape)


def expected_dn(mean_e: np.ndarray, electronics: Electronics) -> np.ndarray:
    """Noise-free DN (float32): charge clipped at the binned full well, gain, offset, clipped to the ADC range."""
    charge = np.minimum(mean_e, electronics.binned_full_well_e)
    dn = charge / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn
    return np.clip(dn, 0.0, electronics.max_dn).astype(np.float32)


def digitize(charge_e: np.ndarray, electronics: Electronics) -> np.ndarray:
    """ADC: charge (e-, with noise) -> uint16 DN, clipped to ``0 .. 2**bits - 1`` (never wraps)."""
    charge = np.minimum(charge_e, electronics.binned_full_well_e)
    dn = np.rint(charge / electronics.adc_gain_e_per_dn + electronics.adc_offset_dn)
    return np.clip(dn, 0.0, electronics.max_dn).astype(np.uint16)
