"""The camera chain stage by stage against analytic answers."""
from dataclasses import replace

import numpy as np
import pytest

from flight_interface.camera_file import PLANCK_J_S, SPEED_OF_LIGHT_M_S
from simulator.detector.camera_chain import CameraEffects, render_image
from simulator.fields import RadianceFields

N_ROWS = 1024
BIN = 4


def _uniform(camera, radiance):
    field = np.full((camera.height_px, camera.width_px), radiance, dtype=np.float32)
    return RadianceFields(field, field, field)


def _responsivity(camera):
    """Independent evaluation of pi T A dlambda QE lambda / (4 N^2 h c)."""
    rad = camera.radiometry
    photons_per_joule = rad.effective_wavelength_um * 1e-6 / (PLANCK_J_S * SPEED_OF_LIGHT_M_S)
    return (np.pi / (4 * rad.f_number**2) * rad.optics_transmission * camera.pixel_pitch_m**2
            * (rad.band_max_um - rad.band_min_um) * rad.mean_quantum_efficiency * photons_per_joule)


def test_documented_responsivity_number(mer_a):
    assert mer_a.responsivity_e_per_s == pytest.approx(_responsivity(mer_a), rel=1e-12)
    # the number documented in flight_interface/camera_file.py
    assert mer_a.responsivity_e_per_s == pytest.approx(1.86e5, rel=0.01)


def test_flat_field_mean_dn_within_half_percent(mer_a):
    radiance = 30.0
    image = render_image(mer_a, _uniform(mer_a, radiance), np.random.default_rng(1),
                         CameraEffects(falloff=False))
    timing, ele = mer_a.timing, mer_a.electronics
    # every pixel: exposure + on average (N+1)/(2N) of the flush and of the transfer period
    smear_fraction = (N_ROWS + 1) / (2 * N_ROWS)
    active_time = timing.exposure_s + smear_fraction * (timing.fast_flush_s + timing.frame_transfer_s)
    rate = _responsivity(mer_a) * radiance + ele.dark_current_e_per_s()
    storage_dark = BIN * ele.dark_current_e_per_s() * timing.readout_s * (256 + 1) / (2 * 256)
    mean_charge = BIN * rate * active_time + storage_dark
    expected = mean_charge / ele.adc_gain_e_per_dn + ele.adc_offset_dn
    assert image.dn.mean() == pytest.approx(expected, rel=0.005)
    assert image.expected_dn.mean() == pytest.approx(expected, rel=0.005)


def test_variance_is_poisson_plus_read_noise(mer_a):
    radiance = 25.0
    image = render_image(mer_a, _uniform(mer_a, radiance), np.random.default_rng(2),
                         CameraEffects(falloff=False, prnu=False, smear=False, dark_current=False))
    ele = mer_a.electronics
    mean_e = BIN * _responsivity(mer_a) * radiance * mer_a.timing.exposure_s
    expected_var_dn = (mean_e + ele.read_noise_e**2) / ele.adc_gain_e_per_dn**2 + 1.0 / 12.0
    assert image.dn.astype(float).var() == pytest.approx(expected_var_dn, rel=0.05)


def test_cos4_falloff_at_the_corner(mer_a):
    undistorted = replace(mer_a, model=replace(mer_a.model, r=np.zeros(3)))
    image = render_image(undistorted, _uniform(undistorted, 20.0), np.random.default_rng(3),
                         CameraEffects(prnu=False, smear=False, dark_current=False, shot_noise=False,
                                       read_noise=False))
    focal_px = 0.01467 / 12e-6
    rows = np.arange(4)  # binned row 0 holds full rows 0..3; column 0
    radius = np.hypot(511.5, 511.5 - rows)
    cos4 = np.cos(np.arctan(radius / focal_px)) ** 4
    centre_rows = np.array([508, 509, 510, 511])
    centre_cos4 = np.cos(np.arctan(np.hypot(0.5, 511.5 - centre_rows) / focal_px)) ** 4
    ratio = image.expected_charge_e[0, 0] / image.expected_charge_e[127, 511]
    assert ratio == pytest.approx(cos4.sum() / centre_cos4.sum(), rel=1e-5)
    assert ratio < 0.72  # ~0.69 at the corner of a 45 deg camera


def test_smear_of_a_single_bright_row(mer_a):
    bright_row, radiance = 601, 50.0
    field = np.zeros((1024, 1024), dtype=np.float32)
    field[bright_row] = radiance
    image = render_image(mer_a, RadianceFields(field, field, field), np.random.default_rng(4),
                         CameraEffects(optics_psf=False, falloff=False, prnu=False, dark_current=False,
                                       shot_noise=False, read_noise=False))   # one row: no lens blur
    timing = mer_a.timing
    rate = _responsivity(mer_a) * radiance
    per_row = np.zeros(N_ROWS)
    rows = np.arange(N_ROWS)
    per_row[rows >= bright_row] += timing.fast_flush_s / N_ROWS * rate   # crossed it while flushing
    per_row[rows <= bright_row] += timing.frame_transfer_s / N_ROWS * rate  # crosses it in transfer
    per_row[bright_row] += timing.exposure_s * rate
    expected = per_row.reshape(256, 4).sum(axis=1)
    np.testing.assert_allclose(image.expected_charge_e[:, 100], expected, rtol=1e-5)


def test_smear_uses_each_period_field(mer_a):
    zero = np.zeros((1024, 1024), dtype=np.float32)
    flush_only = zero.copy()
    flush_only[:, :] = 10.0
    image = render_image(mer_a, RadianceFields(flush_only, zero, zero), np.random.default_rng(5),
                         CameraEffects(falloff=False, prnu=False, dark_current=False, shot_noise=False,
                                       read_noise=False))
    rate = _responsivity(mer_a) * 10.0
    rows = np.arange(N_ROWS)
    per_row = mer_a.timing.fast_flush_s / N_ROWS * rate * (rows + 1)   # crossed rows 0..r
    np.testing.assert_allclose(image.expected_charge_e[:, 7], per_row.reshape(256, 4).sum(axis=1), rtol=1e-5)


def test_dark_signal_follows_doubling_model(mer_a):
    cold = replace(mer_a, electronics=mer_a.electronics.model_copy(update={"ccd_temperature_c": -20.0}))
    effects = CameraEffects(shot_noise=False, read_noise=False)
    dark = _uniform(mer_a, 0.0)
    warm_charge = render_image(mer_a, dark, np.random.default_rng(6), effects).expected_charge_e
    cold_charge = render_image(cold, dark, np.random.default_rng(6), effects).expected_charge_e
    assert warm_charge.mean() / cold_charge.mean() == pytest.approx(2.0 ** (20.0 / 6.5), rel=1e-5)
    assert mer_a.electronics.dark_current_e_per_s() == pytest.approx(1500.0)


def test_saturation_clips_at_4095_and_never_wraps(mer_a):
    image = render_image(mer_a, _uniform(mer_a, 1e6), np.random.default_rng(7))
    assert image.dn.dtype == np.uint16
    assert image.dn.min() == 4095 and image.dn.max() == 4095
    assert image.expected_dn.max() == 4095.0
    dark = render_image(mer_a, _uniform(mer_a, 0.0), np.random.default_rng(7))
    assert dark.dn.max() < 200  # offset + dark + read noise; no wrap-around from negatives
    assert np.all(np.isfinite(dark.expected_dn))


def test_nan_and_inf_radiance_never_reach_the_image(mer_a):
    field = np.full((1024, 1024), 10.0, dtype=np.float32)
    field[5, 5] = np.nan
    field[6, 6] = np.inf
    image = render_image(mer_a, [field, field, field], np.random.default_rng(8))
    assert np.all(np.isfinite(image.expected_dn))


def test_same_seed_same_bits_different_seed_different_noise(mer_a):
    fields = _uniform(mer_a, 30.0)
    first = render_image(mer_a, fields, np.random.default_rng(123)).dn
    second = render_image(mer_a, fields, np.random.default_rng(123)).dn
    third = render_image(mer_a, fields, np.random.default_rng(124)).dn
    assert np.array_equal(first, second)
    assert not np.array_equal(first, third)
    assert first.shape == (256, 1024)


def test_callable_and_sequence_inputs_match(mer_a):
    field = np.full((1024, 1024), 12.0, dtype=np.float32)
    by_list = render_image(mer_a, [field, field, field], np.random.default_rng(9)).dn
    by_callable = render_image(mer_a, lambda period: field, np.random.default_rng(9)).dn
    assert np.array_equal(by_list, by_callable)
    with pytest.raises(ValueError, match="shape"):
        render_image(mer_a, [field[:10], field, field], np.random.default_rng(9))


@pytest.mark.parametrize("exact_poisson", [False, True])
def test_noise_modes_match_poisson_moments_and_stay_exact_when_dim(exact_poisson):
    from simulator.detector.readout import GAUSSIAN_MIN_MEAN_E, noisy_charge_e

    rng = np.random.default_rng(11)
    bright_mean, dim_mean, read_sigma = 5.0e4, 3.0, 0.0
    mean = np.concatenate([np.full(200_000, bright_mean), np.full(200_000, dim_mean)])
    assert dim_mean < GAUSSIAN_MIN_MEAN_E < bright_mean
    noisy = noisy_charge_e(rng, mean, read_sigma, exact_poisson=exact_poisson)
    bright, dim = noisy[:200_000], noisy[200_000:]
    # moments of Poisson(mean): standard errors sqrt(m / n) and ~m sqrt(2 / n)
    assert abs(bright.mean() - bright_mean) < 4 * np.sqrt(bright_mean / bright.size)
    assert bright.var() == pytest.approx(bright_mean, rel=4 * np.sqrt(2 / bright.size))
    # dim pixels are exact Poisson in both modes: integers with P(0) = exp(-m)
    assert np.all(dim == np.round(dim))
    p_zero = np.exp(-dim_mean)
    assert abs((dim == 0).mean() - p_zero) < 4 * np.sqrt(p_zero * (1 - p_zero) / dim.size)


def test_noise_with_read_noise_only_adds_its_variance():
    from simulator.detector.readout import noisy_charge_e

    mean = np.full(400_000, 2.0e4)
    noisy = noisy_charge_e(np.random.default_rng(12), mean, 30.0)
    assert noisy.var() == pytest.approx(2.0e4 + 30.0**2, rel=4 * np.sqrt(2 / mean.size))
    quiet = noisy_charge_e(np.random.default_rng(12), mean, 30.0, shot_noise=False)
    assert quiet.var() == pytest.approx(30.0**2, rel=4 * np.sqrt(2 / mean.size))


def test_fast_normal_draws_are_standard_and_reproducible_whatever_the_thread_count():
    import cv2

    from simulator.detector.readout import standard_normal_f32

    threads = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = standard_normal_f32(np.random.default_rng(5), (512, 1024))
        cv2.setNumThreads(2)
        two = standard_normal_f32(np.random.default_rng(5), (512, 1024))
    finally:
        cv2.setNumThreads(threads)
    assert np.array_equal(one, two)
    other = standard_normal_f32(np.random.default_rng(6), (512, 1024))
    assert not np.array_equal(one, other)
    n = one.size
    assert abs(one.mean()) < 4 / np.sqrt(n) and abs(one.var() - 1) < 4 * np.sqrt(2 / n)
    assert abs(np.mean(one ** 3)) < 4 * np.sqrt(15 / n)               # symmetric
    assert abs(np.mean(one ** 4) - 3) < 4 * np.sqrt(96 / n)          # Gaussian kurtosis
    assert abs(np.corrcoef(one.ravel()[:-1], one.ravel()[1:])[0, 1]) < 4 / np.sqrt(n)
