"""The camera chain's binned path (simulator.detector.camera_chain.BINNED_STAGES): the PSF folded into the
4-row binning against the full-resolution stages, which blur every pixel and bin afterwards."""
from __future__ import annotations

import numpy as np
import pytest

from simulator.detector import psf
from simulator.detector.camera_chain import CameraEffects, expected_charge_e, render_image
from simulator.fields import RadianceFields


def smooth_scene(seed: int = 3) -> np.ndarray:
    """A terrain-like field: a few pixels' correlation length, 20 .. 40 W m^-2 sr^-1 um^-1."""
    rng = np.random.default_rng(seed)
    coarse = rng.standard_normal((130, 130))
    rows = np.linspace(0, 127, 1024)
    fine = np.array([np.interp(rows, np.arange(130), column) for column in coarse.T]).T
    fine = np.array([np.interp(rows, np.arange(130), row) for row in fine])
    return (30.0 + 5.0 * fine).astype(np.float32)


def test_folded_block_sums_equal_the_block_sums_of_the_full_blur(mer_a):
    """Sampling every 4th row of the box-filtered blur is the fold of its spectrum: exact to float32."""
    field = np.random.default_rng(1).random((1024, 1024), dtype=np.float32) * 50.0
    blurred, plain = psf.binned_blur_sums(field, mer_a, 4)
    full = psf.blur_field(field, mer_a).astype(np.float64)
    np.testing.assert_allclose(blurred, full.reshape(256, 4, 1024).sum(axis=1), rtol=0, atol=2e-3)
    np.testing.assert_allclose(plain, field.astype(np.float64).reshape(256, 4, 1024).sum(axis=1), rtol=1e-6)


def test_a_sinusoid_along_the_columns_keeps_the_box_times_mtf(mer_a):
    """A row-direction cosine of period P px, 4-row block sums: amplitude x MTF(f) x |sin(4 pi/P) / sin(pi/P)|."""
    period_px = 16.0
    rows = np.arange(1024)[:, None]
    field = (10.0 + np.cos(2 * np.pi * rows / period_px) * np.ones((1, 1024))).astype(np.float32)
    blurred, _ = psf.binned_blur_sums(field, mer_a, 4)
    frequency = 1.0 / (period_px * mer_a.pixel_pitch_m)
    mtf = float(psf.optics_mtf(np.array([frequency]), mer_a)[0])
    box = abs(np.sin(4 * np.pi / period_px) / np.sin(np.pi / period_px))
    centre = blurred[64:192, 512].astype(np.float64)      # away from the mirrored edges; 4 phases a period
    amplitude = np.sqrt(2.0 * np.mean((centre - centre.mean()) ** 2))
    assert amplitude == pytest.approx(mtf * box, rel=0.02)


@pytest.mark.parametrize("moving", [False, True])
def test_binned_path_matches_the_full_resolution_stages(mer_a, moving):
    """Same charge to the in-block covariance of blur and PRNU: << 0.02 DN RMS on a terrain-like scene."""
    scene = smooth_scene()
    fields = (RadianceFields(scene, np.roll(scene, 1, axis=1), np.roll(scene, 2, axis=1)) if moving
              else RadianceFields(scene, scene, scene))
    binned = expected_charge_e(mer_a, fields).astype(np.float64)
    full = expected_charge_e(mer_a, fields, full_resolution=True).astype(np.float64)
    error_dn = (binned - full) / mer_a.electronics.adc_gain_e_per_dn
    assert np.sqrt(np.mean(error_dn ** 2)) < 0.02


def test_without_psf_and_prnu_the_binned_path_is_the_full_resolution_one(mer_a):
    """No blur, no in-block gain structure: nothing is approximated, only the summation order differs."""
    field = np.random.default_rng(2).random((1024, 1024), dtype=np.float32) * 40.0
    effects = CameraEffects(optics_psf=False)
    binned = expected_charge_e(mer_a, RadianceFields(field, np.roll(field, 3, 0), field), effects)
    full = expected_charge_e(mer_a, RadianceFields(field, np.roll(field, 3, 0), field), effects,
                             full_resolution=True)
    np.testing.assert_allclose(binned, full, rtol=2e-6)


def test_a_saturating_scene_goes_to_the_full_resolution_stages(mer_a):
    """A pixel that may reach full well blooms per pixel: the binned path hands the image on."""
    bright = np.full((1024, 1024), 400.0, dtype=np.float32)
    image = render_image(mer_a, RadianceFields(bright, bright, bright), np.random.default_rng(0))
    full = expected_charge_e(mer_a, RadianceFields(bright, bright, bright), full_resolution=True)
    np.testing.assert_array_equal(image.expected_charge_e, full)
