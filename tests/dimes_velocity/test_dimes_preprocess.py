"""Flattening: binning, dark, smear, falloff removal checked against the camera's closed-form response
(given the detector's true flat field, so that the closed form is exact; the calibrated flat field is
tested in test_flat_field.py)."""
from __future__ import annotations

import numpy as np
import pytest

from dimes_velocity.config import EstimatorConfig
from dimes_velocity.preprocess import bin_columns, flatten, make_flattening
from simulator.calibration import true_flat_field
from simulator.detector.camera_chain import CameraEffects, render_image

NOISE_FREE = CameraEffects(shot_noise=False, read_noise=False, optics_psf=False)   # truth: the unblurred blocks


def block_radiance(rng, low=20.0, high=60.0, blocks=256, size=4):
    """Radiance constant over each 4 x 4 block (so the binned truth is exact)."""
    per_block = rng.uniform(low, high, (blocks, blocks))
    return per_block, np.kron(per_block, np.ones((size, size))).astype(np.float32)


def expected_signal_dn(camera, per_block):
    """Exposure-only DN of a 4 x 4 block of uniform radiance, no falloff: 16 k T_e L / gain."""
    k = camera.responsivity_e_per_s
    return 16.0 * k * camera.timing.exposure_s * per_block / camera.electronics.adc_gain_e_per_dn


@pytest.fixture(scope="module")
def flattening(mer_a):
    return make_flattening(mer_a, EstimatorConfig(), true_flat_field(mer_a))


def test_bin_columns_sums_adjacent_columns():
    raw = np.arange(2 * 8, dtype=np.uint16).reshape(2, 8)
    assert np.array_equal(bin_columns(raw, 4), np.array([[6, 22], [38, 54]], dtype=np.float32))


def test_flatten_recovers_radiance_through_full_camera_chain(mer_a, flattening):
    rng = np.random.default_rng(1)
    per_block, radiance = block_radiance(rng)
    rendered = render_image(mer_a, (radiance, radiance, radiance), rng, NOISE_FREE)
    flat = flatten(rendered.expected_dn, flattening, EstimatorConfig())
    truth = expected_signal_dn(mer_a, per_block)
    relative = np.abs(flat.signal_dn / truth - 1.0)
    assert relative.max() < 2e-3
    assert not flat.excluded.any()
    # without smear removal the same image is far off (smear ~ one extra exposure of the column mean)
    raw_config = EstimatorConfig(remove_smear=False)
    unsmeared = flatten(rendered.expected_dn, make_flattening(mer_a, raw_config, true_flat_field(mer_a)), raw_config)
    assert np.median(unsmeared.signal_dn / truth - 1.0) > 0.3


def test_flatten_removes_falloff(mer_a, flattening):
    """A uniform scene is vignetted by cos^4 (about 0.55 in the corners) and flat after flattening."""
    radiance = np.full((1024, 1024), 40.0, np.float32)
    rendered = render_image(mer_a, (radiance, radiance, radiance), np.random.default_rng(0), NOISE_FREE)
    raw_binned = bin_columns(rendered.expected_dn, 4)
    assert raw_binned[0, 0] / raw_binned[128, 128] < 0.8
    flat = flatten(rendered.expected_dn, flattening, EstimatorConfig())
    assert np.ptp(flat.signal_dn) / flat.signal_dn.mean() < 2e-3


def test_smear_inversion_with_bright_stripe(mer_a, flattening):
    """A bright band smears along its columns; the inversion puts the charge back."""
    per_block = np.full((256, 256), 20.0)
    per_block[100:110, 50:200] = 100.0
    radiance = np.kron(per_block, np.ones((4, 4))).astype(np.float32)
    rendered = render_image(mer_a, (radiance, radiance, radiance), np.random.default_rng(0), NOISE_FREE)
    flat = flatten(rendered.expected_dn, flattening, EstimatorConfig())
    truth = expected_signal_dn(mer_a, per_block)
    assert np.abs(flat.signal_dn / truth - 1.0).max() < 5e-3


def test_saturated_and_dark_pixels_are_excluded(mer_a, flattening):
    radiance = np.full((1024, 1024), 40.0, np.float32)
    radiance[400:480, 400:480] = 4000.0          # far beyond full well
    radiance[:, :200] = 0.0                      # "sky"
    rendered = render_image(mer_a, (radiance, radiance, radiance), np.random.default_rng(0), CameraEffects())
    flat = flatten(rendered.dn, flattening, EstimatorConfig())
    assert flat.excluded[100:120, 100:120].all()          # saturated blocks
    assert flat.excluded[:, :45].all()                     # no signal
    assert not flat.excluded[:, 60:95].any()
    assert flat.saturated_fraction > 0 and flat.dark_fraction > 0.15


def test_noise_model_matches_noise_realisations(mer_a, flattening):
    """The predicted noise of the flattened image equals the scatter of two noise draws / sqrt(2)."""
    rng = np.random.default_rng(5)
    _, radiance = block_radiance(rng)
    first = render_image(mer_a, (radiance, radiance, radiance), rng, CameraEffects())
    second = render_image(mer_a, (radiance, radiance, radiance), rng, CameraEffects())
    config = EstimatorConfig()
    flat_a, flat_b = flatten(first.dn, flattening, config), flatten(second.dn, flattening, config)
    measured = np.std(flat_a.signal_dn - flat_b.signal_dn) / np.sqrt(2.0)
    predicted = np.sqrt(np.mean(flat_a.noise_dn ** 2))
    assert 0.85 < measured / predicted < 1.15
