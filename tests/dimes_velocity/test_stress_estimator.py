"""Numerical stress of the DIMES estimator and the sensor models: blank, black, saturated and
sky-only images, absurd attitudes and altitudes, extreme IMU velocities and image spacings, uint16
against float32 and float64 images. The estimator answers invalid with a reason code instead of a
wrong confident velocity, never returns NaN or inf, and refuses illegal input with MeasurementError."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from synthetic_descent import constant_velocity_descent, random_ground

from config_tables.errors import ConfigError
from config_tables.models import parse
from dimes_velocity import REASONS, DimesEstimator, MeasurementError
from flight_interface.frames import quat_from_axis_angle
from flight_interface.measurements import MAX_SPEED_MPS
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.sensors import SensorConfig, measure

VELOCITY = np.array([12.0, -7.0, -72.0])


@pytest.fixture(scope="module")
def estimator(mer_a):
    return DimesEstimator(mer_a)


@pytest.fixture(scope="module")
def descent(mer_a):
    return constant_velocity_descent(mer_a, random_ground(np.random.default_rng(11)), np.random.default_rng(12),
                                     velocity_mps=VELOCITY)


def replace_all(measurements, **fields):
    return dataclasses.replace(measurements, images=tuple(dataclasses.replace(m, **fields) for m in measurements.images))


def check_result(result):
    """Finite everywhere, a known reason, and the documented fallback when invalid."""
    assert result.reason in REASONS and (result.reason == "ok") == result.valid
    values = [result.velocity_east_mps, result.velocity_north_mps, result.imu_bias_east_mps,
              result.imu_bias_north_mps, result.ground_sample_m]
    values += [v for pair in result.pairs for v in dataclasses.astuple(pair) if isinstance(v, float)]
    values += [v for f in result.features for v in dataclasses.astuple(f) if isinstance(v, float)]
    values += list(dataclasses.astuple(result.timings))
    assert np.all(np.isfinite(values))
    if not result.valid:
        assert result.imu_bias_east_mps == 0.0 and result.imu_bias_north_mps == 0.0


def speed_error(result):
    return float(np.hypot(result.velocity_east_mps - VELOCITY[0], result.velocity_north_mps - VELOCITY[1]))


@pytest.mark.parametrize("images, reason", [
    (lambda d: [np.zeros((256, 1024), np.uint16)] * 3, "no_signal"),               # black
    (lambda d: [np.full((256, 1024), 4095, np.uint16)] * 3, "saturated"),          # saturated
    (lambda d: [np.full((256, 1024), 1e30)] * 3, "saturated"),                     # absurd float DN
    (lambda d: [np.full((256, 1024), -1e30)] * 3, "no_signal"),
    (lambda d: [np.full((256, 1024), 800, np.uint16)] * 3, "low_contrast"),        # perfectly flat
])
def test_unusable_images_are_invalid_with_their_reason(estimator, descent, images, reason):
    result = estimator.estimate(images(descent), descent.truth)
    check_result(result)
    assert not result.valid and result.reason == reason


def test_zero_texture_scene_is_low_contrast(mer_a, estimator):
    blank = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(11), contrast=0.0),
                                      np.random.default_rng(12), velocity_mps=VELOCITY)
    result = estimator.estimate(blank.images, blank.truth)
    check_result(result)
    assert not result.valid and result.reason == "low_contrast"


@pytest.mark.parametrize("tilt_deg", [125.0, 180.0])
def test_sky_only_images_are_invalid(mer_a, estimator, tilt_deg):
    attitude = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(tilt_deg))
    sky = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(11)), np.random.default_rng(12),
                                    velocity_mps=VELOCITY, attitudes=[attitude] * 3)
    truthful = estimator.estimate(sky.images, sky.truth)                       # attitude says "sky"
    check_result(truthful)
    assert not truthful.valid and truthful.reason == "bad_attitude"
    level = replace_all(sky.truth, attitude_quat=np.array([1.0, 0.0, 0.0, 0.0]))  # attitude lies: nadir
    lying = estimator.estimate(sky.images, level)
    check_result(lying)
    assert not lying.valid and lying.reason == "no_signal"


@settings(max_examples=25, deadline=None, derandomize=True)
@given(tilt_deg=st.floats(60.5, 180.0), azimuth=st.floats(0.0, 2 * np.pi))
def test_measured_attitude_beyond_the_off_nadir_limit_is_bad_attitude(estimator, descent, tilt_deg, azimuth):
    attitude = quat_from_axis_angle(np.array([np.cos(azimuth), np.sin(azimuth), 0.0]), np.radians(tilt_deg))
    result = estimator.estimate(descent.images, replace_all(descent.truth, attitude_quat=attitude))
    check_result(result)
    assert not result.valid and result.reason == "bad_attitude"


@settings(max_examples=25, deadline=None, derandomize=True)
@given(tilt_deg=st.floats(0.0, 180.0), azimuth=st.floats(0.0, 2 * np.pi),
       altitude_scale=st.floats(1e-4, 100.0), imu_speed=st.floats(0.0, 9e3), spacing_scale=st.floats(1e-6, 1e3))
def test_any_legal_measurements_give_a_finite_answer(estimator, descent, tilt_deg, azimuth, altitude_scale,
                                                     imu_speed, spacing_scale):
    """Whatever the (legal) measurements claim about the real images (any tilt, altitude x 1e-4 .. 100,
    IMU speed to 9 km/s, image spacing x 1e-6 .. 1e3), the answer is finite with a known reason."""
    attitude = quat_from_axis_angle(np.array([np.cos(azimuth), np.sin(azimuth), 0.0]), np.radians(tilt_deg))
    # the IMU descends as fast as the scaled radar altitudes in the scaled time (a physical record)
    descent_rate = 72.0 * altitude_scale / spacing_scale
    assume(np.hypot(imu_speed, descent_rate) < MAX_SPEED_MPS)
    imu = np.array([imu_speed * np.cos(azimuth), imu_speed * np.sin(azimuth), -descent_rate])
    images = tuple(dataclasses.replace(m, attitude_quat=attitude, radar_altitude_m=m.radar_altitude_m * altitude_scale,
                                       imu_velocity_mps=imu, time_s=m.time_s * spacing_scale)
                   for m in descent.truth.images)
    result = estimator.estimate(descent.images, dataclasses.replace(descent.truth, images=images))
    check_result(result)


def test_uint16_float32_and_float64_images_give_the_same_answer(estimator, descent):
    results = [estimator.estimate([image.astype(dtype) for image in descent.images], descent.truth)
               for dtype in (np.uint16, np.float32, np.float64)]
    for result in results:
        check_result(result)
        assert result.valid and speed_error(result) < 0.5
    assert results[1].velocity_east_mps == pytest.approx(results[0].velocity_east_mps, abs=1e-3)
    assert results[2].velocity_north_mps == pytest.approx(results[0].velocity_north_mps, abs=1e-3)


def test_estimator_refuses_illegal_inputs_with_the_field_named(estimator, descent):
    cases = [
        ([np.full((256, 1024), np.nan)] * 3, descent.truth, "non-finite"),
        (descent.images[:2], descent.truth, "images"),
        ([np.zeros((255, 1024))] * 3, descent.truth, "shape"),
        (descent.images, replace_all(descent.truth, attitude_quat=np.zeros(4)), "attitude_quat"),
        (descent.images, replace_all(descent.truth, radar_altitude_m=0.0), "radar_altitude_m"),
        (descent.images, replace_all(descent.truth, radar_altitude_m=np.inf), "radar_altitude_m"),
        (descent.images, replace_all(descent.truth, imu_velocity_mps=np.array([1e300, 0.0, 0.0])), "imu_velocity_mps"),
        (descent.images, replace_all(descent.truth, imu_velocity_mps=np.array([2e4, 0.0, 0.0])), "allowed: speed"),
        (descent.images, replace_all(descent.truth, time_s=1.0), "time_s"),
        (descent.images, dataclasses.replace(descent.truth, sun_direction_world=np.zeros(3)), "sun_direction_world"),
    ]
    for images, measurements, message in cases:
        with pytest.raises(MeasurementError, match=message):
            estimator.estimate(images, measurements)


# ----------------------------------------------------------------------------------------- sensors
@settings(max_examples=60, deadline=None, derandomize=True)
@given(altitude_m=st.floats(10.0, 2e4), tilt_deg=st.floats(0.0, 180.0), rate_dps=st.floats(0.0, 360.0),
       sigma_scale=st.floats(0.0, 1.0), seed=st.integers(0, 2**32 - 1), start=st.booleans())
def test_sensor_measurements_are_finite_unit_quaternions_at_any_state(mer_a, altitude_m, tilt_deg, rate_dps,
                                                                      sigma_scale, seed, start):
    """Sigmas from perfect to the TOML maxima (30 deg bias, 10 deg random, 60 deg/s rate noise...)."""
    attitude = quat_from_axis_angle(np.array([1.0, 1.0, 0.0]), np.radians(tilt_deg))
    descent_rate = min(75.0, altitude_m)          # stays above the ground over the 0.3 s profile
    profile = constant_velocity_profile([0.0, 0.0, altitude_m], [30.0, -20.0, -descent_rate], attitude, 0.3,
                                        [0.0, 0.1, 0.2])
    profile = dataclasses.replace(profile, angular_rate_radps=np.tile(np.radians([rate_dps, 0.0, 0.0]), (2, 1)))
    config = SensorConfig(attitude_bias_sigma_deg=30.0 * sigma_scale, attitude_random_sigma_deg=10.0 * sigma_scale,
                          alignment_sigma_deg=10.0 * sigma_scale, angular_rate_noise_sigma_dps=60.0 * sigma_scale,
                          radar_altitude_sigma_percent=10.0 * sigma_scale, imu_velocity_bias_sigma_mps=50.0 * sigma_scale,
                          imu_vertical_velocity_bias_sigma_mps=50.0 * sigma_scale,
                          imu_velocity_random_walk_mps_per_sqrt_s=10.0 * sigma_scale,
                          state_time="exposure_start" if start else "mid_exposure", heat_shield_prediction=True,
                          heat_shield_prediction_sigma_m=1000.0 * sigma_scale)
    measurements, truth = measure(profile, None if start else mer_a, np.array([0.0, 0.6, 0.8]), config,
                                  np.random.default_rng(seed))
    assert all(np.isfinite(value) for value in truth.values())
    for image in measurements.images:
        assert np.linalg.norm(image.attitude_quat) == pytest.approx(1.0, abs=1e-12)
        assert np.all(np.isfinite(image.angular_rate_radps)) and np.all(np.isfinite(image.imu_velocity_mps))
        assert image.radar_altitude_m > 0.0
    for k in (1, 2, 3):
        assert 0.0 <= truth[f"attitude_error_image{k}_rad"] <= np.pi + 1e-12


@pytest.mark.parametrize("key, value, message", [
    ("attitude_bias_sigma_deg", -1.0, r"sensors\.attitude_bias_sigma_deg = -1 is out of range; allowed: >= 0 and <= 30"),
    ("radar_altitude_sigma_percent", 50.0, r"radar_altitude_sigma_percent = 50 is out of range"),
    ("imu_velocity_bias_sigma_mps", float("nan"), r"imu_velocity_bias_sigma_mps = nan is not finite"),
    ("state_time", "end", r"state_time = 'end' is not allowed; allowed: mid_exposure, exposure_start"),
    ("perfectly", True, r"sensors\.perfectly is not a known field"),
])
def test_sensor_config_out_of_range_gives_one_line_errors(key, value, message):
    from simulator.sensors import SensorConfig

    with pytest.raises(ConfigError, match=message):
        parse(SensorConfig, {key: value}, "campaign.toml", "sensors")


def test_image_times_outside_the_profile_are_refused_with_the_time_named(mer_a):
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], np.array([1.0, 0.0, 0.0, 0.0]),
                                        1.0, [0.5, 2.0])
    with pytest.raises(ValueError, match=r"time 2\.002\d s outside \[0\.0000, 1\.0000\]"):
        measure(profile, mer_a, np.array([0.0, 0.0, 1.0]), SensorConfig(), np.random.default_rng(0))
