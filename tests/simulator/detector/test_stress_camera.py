"""Numerical stress of the camera: configuration at the edges of every allowed range (camera TOML
written to a temporary directory), the camera chain with zero, saturating and absurd radiance,
exposures and CCD temperatures at their limits, Poisson means up to 1e9 electrons, float32 against
float64 input. DN stay in 0 .. 2**bits - 1, the expected image is finite; bad configuration gives a
one-line ConfigError naming the file, the field and the allowed range."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from config_tables.errors import ConfigError
from flight_interface.camera import load_camera
from simulator.detector import readout
from simulator.detector.camera_chain import CameraEffects, render_image

MER_A = (Path(__file__).resolve().parents[3] / "sitedata" / "cameras" / "mer_a.toml").read_text()
SMALL = dict(width_px="64", height_px="64", principal_point_px="[31.5, 31.5]")   # 3 deg FOV, same optics
NO_NOISE = CameraEffects(shot_noise=False, read_noise=False)


def camera_text(**fields) -> str:
    text = MER_A
    for key, value in fields.items():
        text, count = re.subn(rf"(?m)^{key} = [^#\n]*", f"{key} = {value}", text)
        assert count == 1, key
    return text


_COUNTER = iter(range(10**9))


@pytest.fixture(scope="module")
def make_camera(tmp_path_factory):
    directory = tmp_path_factory.mktemp("cameras")

    def make(**fields):
        path = directory / f"camera_{next(_COUNTER)}.toml"
        path.write_text(camera_text(**{**SMALL, **fields}))
        return load_camera(path)
    return make


def uniform(camera, value, dtype=np.float32):
    field = np.full((camera.height_px, camera.width_px), value, dtype=dtype)
    return field, field, field


def check_image(camera, image):
    max_dn = camera.electronics.max_dn
    assert image.dn.dtype == np.uint16 and image.dn.shape == camera.binned_shape
    assert image.dn.max() <= max_dn
    assert np.all(np.isfinite(image.expected_dn)) and np.all(np.isfinite(image.expected_charge_e))
    assert image.expected_dn.min() >= 0.0 and image.expected_dn.max() <= max_dn


# ------------------------------------------------------------------------------ configuration edges
@settings(max_examples=25, deadline=None, derandomize=True)
@given(exposure_s=st.sampled_from([1e-9, 1e-6, 5.1e-3, 1.0, 10.0]),
       temperature_c=st.sampled_from([-273.15, -120.0, -20.0, 0.0, 60.0, 150.0, 200.0]),
       bits=st.sampled_from([1, 8, 12, 16]),
       radiance=st.sampled_from([0.0, 1e-6, 40.0, 1e4, 1e7]))
def test_any_allowed_exposure_temperature_and_adc_gives_a_sane_image(make_camera, exposure_s, temperature_c,
                                                                      bits, radiance):
    camera = make_camera(exposure_s=exposure_s, ccd_temperature_c=temperature_c, adc_bits=bits)
    image = render_image(camera, uniform(camera, radiance), np.random.default_rng(1))
    check_image(camera, image)
    # closed form bound: offset + (photo charge in exposure + smear + all dark) / gain, clipped
    electronics = camera.electronics
    dark = electronics.dark_current_e_per_s()
    total_time = exposure_s + camera.timing.fast_flush_s + camera.timing.frame_transfer_s + camera.timing.readout_s
    rate = radiance * camera.responsivity_e_per_s * 1.1        # PRNU within 10 %
    bound = camera.binning_rows * (rate * (exposure_s + 0.0102) + dark * total_time)
    expected = min(electronics.adc_offset_dn + bound / electronics.adc_gain_e_per_dn, electronics.max_dn)
    assert image.expected_dn.max() <= expected * (1 + 1e-5) + 1e-3


def test_ccd_at_absolute_zero_has_no_dark_and_hot_ccd_saturates(make_camera):
    cold = make_camera(ccd_temperature_c=-273.15)
    assert 0.0 <= cold.electronics.dark_current_e_per_s() < 1e-9       # 1500 * 2**(-42)
    image = render_image(cold, uniform(cold, 0.0), np.random.default_rng(2), NO_NOISE)
    assert np.all(image.expected_dn == np.float32(cold.electronics.adc_offset_dn))
    hot = make_camera(ccd_temperature_c=200.0)      # 1500 * 2**(200 / 6.5) = 2.7e12 e-/s: full in 70 ns
    assert hot.electronics.dark_current_e_per_s() == pytest.approx(1500.0 * 2 ** (200 / 6.5))
    image = render_image(hot, uniform(hot, 0.0), np.random.default_rng(2))
    assert np.all(image.dn == hot.electronics.max_dn) and np.all(image.expected_dn == hot.electronics.max_dn)


@pytest.mark.parametrize("fields, message", [
    (dict(exposure_s="0.0"), r"timing\.exposure_s = 0 is out of range; allowed: > 0 and <= 10"),
    (dict(exposure_s="10.5"), r"timing\.exposure_s = 10\.5 is out of range"),
    (dict(exposure_s="nan"), r"timing\.exposure_s = nan is not finite"),
    (dict(exposure_s="-inf"), r"timing\.exposure_s = -inf is not finite"),
    (dict(ccd_temperature_c="-274.0"), r"electronics\.ccd_temperature_c = -274 is out of range; allowed: >= -273\.15"),
    (dict(ccd_temperature_c="201.0"), r"electronics\.ccd_temperature_c = 201 is out of range"),
    (dict(adc_bits="0"), r"electronics\.adc_bits = 0 is out of range; allowed: >= 1 and <= 16"),
    (dict(adc_bits="17"), r"electronics\.adc_bits = 17 is out of range"),
    (dict(full_well_e="1e300"), r"electronics\.full_well_e = 1e\+300 is out of range; allowed: > 0 and <= 1e\+10"),
    (dict(binned_full_well_e="0.0"), r"electronics\.binned_full_well_e = 0 is out of range"),
    (dict(f_number="0.1"), r"radiometry\.f_number = 0\.1 is out of range; allowed: >= 0\.5"),
    (dict(dark_doubling_temperature_k="0.001", ccd_temperature_c="200.0"),
     r"electronics\.ccd_temperature_c = 200 gives a dark current of inf e-/s .*allowed: <= 1e\+13"),
    (dict(dark_current_ref_e_per_s="1e9", dark_reference_temperature_c="-273.15", ccd_temperature_c="100.0"),
     r"electronics\.ccd_temperature_c = 100 gives a dark current .* allowed: <= 1e\+13"),
    (dict(radial_distortion="[0.0, -1.0, 0.0]", width_px="1024", height_px="1024", principal_point_px="[511.5, 511.5]"),
     r"geometry\.radial_distortion = \[0, -1, 0\] stops increasing 471 px .*corner at 724 px"),
    (dict(focal_length_m="1.0"), r"geometry gives a field of view of 0\.0 x 0\.0 deg; allowed: 1 to 170 deg"),
])
def test_out_of_range_camera_fields_give_one_line_errors(make_camera, fields, message):
    with pytest.raises(ConfigError, match=message) as error:
        make_camera(**fields)
    assert "\n" not in str(error.value) and ".toml" in str(error.value)


def test_strongest_distortion_that_still_increases_to_the_corners_loads(make_camera):
    """R1 = -0.3: turning point u* = 1/sqrt(0.9) at 0.703 x 1222.5 = 859 px > the 724 px corner."""
    camera = make_camera(radial_distortion="[0.0, -0.3, 0.0]", width_px="1024", height_px="1024",
                         principal_point_px="[511.5, 511.5]")
    assert np.all(np.isfinite(camera.pixel_rays)) and np.all(camera.falloff_map > 0)


# -------------------------------------------------------------------------------------- camera chain
@settings(max_examples=60, deadline=None, derandomize=True)
@given(level=st.floats(0.0, 1e7), contrast=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1),
       float64=st.booleans())
def test_camera_chain_dn_in_range_and_expected_image_finite(make_camera, level, contrast, seed, float64):
    camera = small_camera(make_camera)
    rng = np.random.default_rng(seed)
    field = level * (1.0 + contrast * (rng.random((64, 64)) - 0.5))
    field = field.astype(np.float64 if float64 else np.float32)
    image = render_image(camera, (field, field, field), rng)
    check_image(camera, image)


_SMALL_CAMERA = []


def small_camera(make_camera):
    if not _SMALL_CAMERA:
        _SMALL_CAMERA.append(make_camera())
    return _SMALL_CAMERA[0]


def test_zero_radiance_without_dark_is_the_adc_offset_and_saturation_is_max_dn(make_camera):
    camera = small_camera(make_camera)
    effects = CameraEffects(dark_current=False, shot_noise=False, read_noise=False)
    black = render_image(camera, uniform(camera, 0.0), np.random.default_rng(0), effects)
    assert np.all(black.expected_charge_e == 0.0)
    assert np.all(black.expected_dn == np.float32(camera.electronics.adc_offset_dn))
    for radiance in (1e4, 1e7, 1e30):
        bright = render_image(camera, uniform(camera, radiance), np.random.default_rng(0))
        assert np.all(bright.dn == 4095) and np.all(bright.expected_dn == 4095.0)


def test_expected_dn_is_monotonic_in_radiance(make_camera):
    camera = small_camera(make_camera)
    pattern = np.random.default_rng(4).random((64, 64))
    previous = None
    for level in np.geomspace(1e-3, 1e4, 40):
        field = (level * pattern).astype(np.float32)
        image = render_image(camera, (field, field, field), np.random.default_rng(0), NO_NOISE)
        if previous is not None:
            assert np.all(image.expected_dn >= previous)
        previous = image.expected_dn


@settings(max_examples=30, deadline=None, derandomize=True)
@given(level=st.floats(1e-3, 3e3), seed=st.integers(0, 1000))
def test_float32_and_float64_radiance_give_the_same_expected_image(make_camera, level, seed):
    camera = small_camera(make_camera)
    field64 = level * np.random.default_rng(seed).random((64, 64))
    single = render_image(camera, uniform(camera, 0.0) if level == 0 else (field64.astype(np.float32),) * 3,
                          np.random.default_rng(0), NO_NOISE)
    double = render_image(camera, (field64,) * 3, np.random.default_rng(0), NO_NOISE)
    assert np.allclose(single.expected_dn, double.expected_dn, rtol=1e-5, atol=1e-3)


def test_radiance_as_float16_and_integers_is_accepted(make_camera):
    camera = small_camera(make_camera)
    reference = render_image(camera, uniform(camera, 40.0, np.float64), np.random.default_rng(0), NO_NOISE)
    for dtype in (np.float16, np.int32, np.uint16):
        image = render_image(camera, uniform(camera, 40, dtype), np.random.default_rng(0), NO_NOISE)
        assert np.allclose(image.expected_dn, reference.expected_dn, rtol=1e-5)


# ----------------------------------------------------------------------------------------- Poisson
@settings(max_examples=30, deadline=None, derandomize=True)
@given(exponent=st.floats(-3.0, 9.0), seed=st.integers(0, 2**32 - 1), float32=st.booleans(),
       exact=st.booleans())
def test_shot_noise_up_to_1e9_electrons_has_poisson_mean_and_variance(exponent, seed, float32, exact):
    """Both the exact Poisson draw and the Gaussian shortcut above 1000 e- (read noise off)."""
    mean = 10.0**exponent
    count = 20000
    means = np.full(count, mean, dtype=np.float32 if float32 else np.float64)
    draws = readout.noisy_charge_e(np.random.default_rng(seed), means, 0.0, read_noise=False, exact_poisson=exact)
    assert draws.dtype == np.float64 and np.all(np.isfinite(draws))
    true_mean = float(means[0])
    # sample mean within 5 standard errors; sample variance within 5 of its standard errors
    # (+ float32 resolution of the Gaussian shortcut: 2**-24 of the mean)
    resolution = true_mean * 2.0**-23
    assert abs(draws.mean() - true_mean) < 5 * np.sqrt(true_mean / count) + resolution + 1e-12
    variance_error = np.sqrt((2 * true_mean**2 + true_mean) / count)
    assert abs(draws.var() - true_mean) < 5 * variance_error + resolution**2 + 1e-9
    if exact or true_mean < readout.GAUSSIAN_MIN_MEAN_E:
        assert draws.min() >= 0 and np.all(draws == np.round(draws))


def test_zero_negative_and_tiny_poisson_means_give_zero_charge():
    for exact in (False, True):
        draws = readout.noisy_charge_e(np.random.default_rng(0), np.array([0.0, -5.0, 1e-300, -np.inf]), 0.0,
                                       read_noise=False, exact_poisson=exact)
        assert np.array_equal(draws, np.zeros(4))


def test_one_billion_electrons_through_the_whole_chain(make_camera):
    """Full well 1e10, gain 1e6 e-/DN, no smear: a binned pixel of ~1e9 e- reads ~1000 DN with a
    Poisson spread of sqrt(1e9) / 1e6 = 0.03 DN, so DN = round(expected) +- 1 (read noise off)."""
    camera = make_camera(full_well_e="1e10", binned_full_well_e="1e10", adc_gain_e_per_dn="1e6", read_noise_e="0.0",
                         adc_bits="16")
    per_pixel_e = 2.5e8     # 4 binned rows -> 1e9 e-
    radiance = per_pixel_e / (camera.responsivity_e_per_s * camera.timing.exposure_s)
    for exact in (False, True):
        effects = CameraEffects(smear=False, read_noise=False, exact_poisson=exact)
        image = render_image(camera, uniform(camera, radiance), np.random.default_rng(5), effects)
        check_image(camera, image)
        assert 0.9e9 < float(image.expected_charge_e.min()) and float(image.expected_charge_e.max()) < 1.1e9
        assert np.all(np.abs(image.dn.astype(float) - image.expected_dn) <= 1.0)


def test_dark_current_scale_at_its_toml_limit_on_the_hottest_camera(make_camera):
    """2.7e12 e-/s x 1e6 (the scene TOML's limit) x 100 s readout: storage dark ~1e21 e- per binned
    pixel, far above the binned full well: the image is saturated, the Gaussian shortcut finite."""
    camera = make_camera(ccd_temperature_c=200.0, readout_s=100.0)
    image = render_image(camera, uniform(camera, 40.0), np.random.default_rng(0),
                         CameraEffects(dark_current_scale=1e6))
    check_image(camera, image)
    assert np.all(image.dn == camera.electronics.max_dn)


def test_exact_poisson_survives_means_beyond_numpys_limit(make_camera):
    camera = make_camera(ccd_temperature_c=200.0, readout_s=100.0)
    image = render_image(camera, uniform(camera, 40.0), np.random.default_rng(0),
                         CameraEffects(dark_current_scale=1e6, exact_poisson=True))
    assert np.all(image.dn == camera.electronics.max_dn)


# ------------------------------------------------------------------------ absurd radiance (for lead)
@pytest.mark.parametrize("radiance", [1e34, np.inf])
def test_overflowing_radiance_saturates_instead_of_reading_black(make_camera, radiance):
    camera = small_camera(make_camera)
    image = render_image(camera, uniform(camera, radiance, np.float64), np.random.default_rng(0))
    assert np.all(image.dn == 4095)


def test_negative_radiance_is_refused_or_read_as_zero(make_camera):
    camera = small_camera(make_camera)
    zero = render_image(camera, uniform(camera, 0.0), np.random.default_rng(0), NO_NOISE)
    try:
        negative = render_image(camera, uniform(camera, -5.0), np.random.default_rng(0), NO_NOISE)
    except ValueError as error:
        assert "radiance" in str(error)
        return
    assert np.array_equal(negative.expected_dn, zero.expected_dn)
