"""End-to-end estimator behaviour on synthetic descents with known motion (textured ground plane seen
through the CAHVOR model, DN from the simulator's camera chain)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synthetic_descent import constant_velocity_descent, random_ground

from config_tables.errors import ConfigError
from config_tables.models import parse
from dimes_velocity import REASONS, DimesEstimator, EstimatorConfig, MeasurementError, estimate_velocity
from dimes_velocity.geometry import predicted_positions_m
from flight_interface.frames import quat_from_axis_angle

VELOCITY = np.array([12.0, -7.0, -72.0])


def with_imu_bias(measurements, bias_en):
    images = tuple(dataclasses.replace(m, imu_velocity_mps=m.imu_velocity_mps + np.array([*bias_en, 0.0]))
                   for m in measurements.images)
    return dataclasses.replace(measurements, images=images)


@pytest.fixture(scope="module")
def estimator(mer_a):
    return DimesEstimator(mer_a)


@pytest.fixture(scope="module")
def wide_imu_estimator(mer_a):
    """Told an IMU whose bias is 8 m/s per axis (1 sigma): biases up to ~20 m/s are implied without refusal."""
    return DimesEstimator(mer_a, EstimatorConfig(imu_velocity_bias_sigma_mps=8.0))


@pytest.fixture(scope="module")
def ground():
    return random_ground(np.random.default_rng(11))


@pytest.fixture(scope="module")
def noisy_descent(mer_a, ground):
    return constant_velocity_descent(mer_a, ground, np.random.default_rng(12), velocity_mps=VELOCITY)


def velocity_error(result, truth=VELOCITY):
    return float(np.hypot(result.velocity_east_mps - truth[0], result.velocity_north_mps - truth[1]))


def test_noise_free_images_give_the_velocity_to_a_few_cm_per_s(mer_a, ground, wide_imu_estimator):
    descent = constant_velocity_descent(mer_a, ground, np.random.default_rng(1), velocity_mps=VELOCITY, noise=False)
    result = wide_imu_estimator.estimate(descent.images, with_imu_bias(descent.truth, (9.0, -4.0)))
    assert result.valid and result.reason == "ok"
    assert velocity_error(result) < 0.1
    assert np.hypot(result.imu_bias_east_mps - 9.0, result.imu_bias_north_mps + 4.0) < 0.1


@pytest.mark.parametrize("bias", [(0.0, 0.0), (15.0, 10.0), (-20.0, 5.0)])
def test_imu_bias_is_removed_with_camera_noise(noisy_descent, wide_imu_estimator, bias):
    result = wide_imu_estimator.estimate(noisy_descent.images, with_imu_bias(noisy_descent.truth, bias))
    assert result.valid, result.reason
    assert velocity_error(result) < 0.5
    # each pair's displacement is bias * dt (the IMU over-predicts the motion by that much)
    times = [m.time_s for m in noisy_descent.truth.images]
    for pair in result.pairs:
        dt = times[pair.second_image] - times[pair.first_image]
        assert np.hypot(pair.displacement_east_m - bias[0] * dt, pair.displacement_north_m - bias[1] * dt) < 2.0


def test_result_carries_table3_metrics_and_timings(noisy_descent, estimator):
    result = estimator.estimate(noisy_descent.images, noisy_descent.truth)
    used = [f for f in result.features if f.used]
    assert len(used) >= 2 and {f.pair for f in used} == {0, 1}
    for feature in used:
        assert feature.status == "ok"
        assert 500 < feature.brightness_dn < 20000 and feature.contrast_dn > 0
        assert 0.7 <= feature.correlation <= 1.0
    timings = dataclasses.asdict(result.timings)
    assert all(np.isfinite(v) and v >= 0 for v in timings.values())
    assert result.timings.total_ms >= result.timings.match_ms
    # the JSON form is plain and finite
    data = result.to_dict()
    assert data["reason"] == "ok" and isinstance(data["features"], list) and isinstance(data["pairs"][0], dict)


def test_estimate_velocity_wrapper_matches_the_estimator(mer_a, noisy_descent, estimator):
    direct = estimator.estimate(noisy_descent.images, noisy_descent.truth)
    wrapped = estimate_velocity(noisy_descent.images, noisy_descent.truth, mer_a)
    assert wrapped.velocity_east_mps == direct.velocity_east_mps and wrapped.valid == direct.valid


def test_estimate_velocity_reuses_its_estimator_for_views_of_one_flat_field(mer_a, noisy_descent):
    """A campaign hands every case a fresh read-only view of its flat field: one estimator serves them all, and a
    flat field in other memory (other values) gets its own."""
    from dimes_velocity import estimator as module

    flat = np.ones(mer_a.binned_shape, np.float32)
    answers = []
    for _ in range(3):
        view = flat.view()
        view.setflags(write=False)
        answers.append(estimate_velocity(noisy_descent.images, noisy_descent.truth, mer_a, flat_field=view))
    built = [entry for entry in module._CACHE.values() if entry[0] is mer_a and entry[2] is flat]
    assert len(built) == 1
    assert len({(a.velocity_east_mps, a.velocity_north_mps) for a in answers}) == 1
    brighter = estimate_velocity(noisy_descent.images, noisy_descent.truth, mer_a, flat_field=0.5 * flat)
    ratio = brighter.features[0].brightness_dn / answers[0].features[0].brightness_dn
    assert ratio == pytest.approx(2.0, rel=1e-5)        # its own flattening: signal / 0.5


def test_blank_scene_is_invalid(mer_a, estimator):
    blank = random_ground(np.random.default_rng(2), size_px=512, metres_per_pixel=12.0, contrast=0.0)
    descent = constant_velocity_descent(mer_a, blank, np.random.default_rng(3), velocity_mps=VELOCITY)
    measurements = with_imu_bias(descent.truth, (4.0, 2.0))
    result = estimator.estimate(descent.images, measurements)
    assert not result.valid and result.reason == "low_contrast"
    # invalid: the uncorrected IMU velocity, finite
    assert result.velocity_east_mps == pytest.approx(VELOCITY[0] + 4.0)
    assert result.velocity_north_mps == pytest.approx(VELOCITY[1] + 2.0)


def test_pair_consistency_rejects_a_planted_wrong_match(noisy_descent, estimator):
    """Image 3 moved by 6 binned pixels (~28 m): pair 2 'matches' a wrong displacement (7 m/s)."""
    images = list(noisy_descent.images)
    images[2] = np.roll(images[2], 24, axis=1)
    result = estimator.estimate(images, noisy_descent.truth)
    assert not result.valid and result.reason == "pairs_disagree"
    assert all(p.valid for p in result.pairs)
    assert velocity_error(result) == pytest.approx(0.0, abs=1e-9)        # falls back to the IMU velocity


@pytest.mark.parametrize("fill, reason", [(20, "no_signal"), (4095, "saturated")])
def test_dark_and_saturated_images_are_invalid(noisy_descent, estimator, fill, reason):
    images = [np.full_like(image, fill) for image in noisy_descent.images]
    result = estimator.estimate(images, noisy_descent.truth)
    assert not result.valid and result.reason == reason


def test_attitude_far_from_nadir_is_invalid(noisy_descent, estimator):
    tilted = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(70.0))
    images = tuple(dataclasses.replace(m, attitude_quat=tilted) for m in noisy_descent.truth.images)
    result = estimator.estimate(noisy_descent.images, dataclasses.replace(noisy_descent.truth, images=images))
    assert not result.valid and result.reason == "bad_attitude"


def test_mostly_sky_images_are_invalid(mer_a, ground):
    """Camera tilted 75 deg: the upper part of the frame is sky, the ground is far and foreshortened."""
    tilted = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(75.0))
    descent = constant_velocity_descent(mer_a, ground, np.random.default_rng(4), velocity_mps=VELOCITY,
                                        attitudes=[tilted] * 3)
    result = DimesEstimator(mer_a, EstimatorConfig(max_off_nadir_deg=85.0)).estimate(descent.images, descent.truth)
    assert not result.valid and result.reason in ("sky", "no_signal", "no_overlap")


def test_features_avoid_the_zero_phase_zone(mer_a, ground):
    elevation, azimuth = np.radians(82.0), np.radians(200.0)
    sun = (np.cos(elevation) * np.sin(azimuth), np.cos(elevation) * np.cos(azimuth), np.sin(elevation))
    descent = constant_velocity_descent(mer_a, ground, np.random.default_rng(5), velocity_mps=VELOCITY,
                                        sun_direction=sun)
    config = EstimatorConfig(features_per_pair=16, feature_grid=8, agreeing_features_to_stop=16)   # track all 16
    result = DimesEstimator(mer_a, config).estimate(descent.images, descent.truth)
    positions = predicted_positions_m(descent.truth)
    anti_sun = -np.asarray(sun) / np.linalg.norm(sun)
    half_template_m = (config.template_size_px // 2) * np.sqrt(2) * result.ground_sample_m
    assert len(result.features) > 8
    for feature in result.features:
        image = descent.truth.images[feature.pair]
        camera = np.array([*positions[feature.pair], image.radar_altitude_m - 0.5])
        ray = np.array([feature.east_m, feature.north_m, 0.0]) - camera
        angle = np.arccos(ray @ anti_sun / np.linalg.norm(ray))
        # the whole template (centre +- half diagonal) stays outside the 4.3 deg cone
        assert angle - half_template_m / np.linalg.norm(ray) > np.radians(4.3) - 1e-3


def test_illegal_inputs_raise_naming_the_field(noisy_descent, estimator):
    with pytest.raises(MeasurementError, match="image 1"):
        estimator.estimate([noisy_descent.images[0], noisy_descent.images[1][:, :512], noisy_descent.images[2]],
                           noisy_descent.truth)
    images = list(noisy_descent.truth.images)
    images[2] = dataclasses.replace(images[2], time_s=images[1].time_s)
    with pytest.raises(MeasurementError, match=r"images\[2\]\.time_s"):
        estimator.estimate(noisy_descent.images, dataclasses.replace(noisy_descent.truth, images=tuple(images)))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), tilt_deg=st.floats(0.0, 89.0), level=st.integers(0, 4095),
       spread=st.integers(0, 4095), altitude=st.floats(1.0, 50000.0))
def test_never_nan_never_raises_on_legal_input(noisy_descent, estimator, seed, tilt_deg, level, spread, altitude):
    rng = np.random.default_rng(seed)
    images = [np.clip(level + rng.integers(-spread, spread + 1, image.shape), 0, 4095).astype(np.uint16)
              for image in noisy_descent.images]
    attitude = quat_from_axis_angle(rng.normal(size=3), np.radians(tilt_deg))
    # any constant IMU velocity whose vertical part descends as the radar altitudes do (a physical record)
    times = [m.time_s for m in noisy_descent.truth.images]
    imu = np.array([*rng.normal(0, 50, 2), -0.1 * altitude / (times[1] - times[0])])
    records = tuple(dataclasses.replace(m, attitude_quat=attitude, radar_altitude_m=altitude * (1 - 0.1 * k),
                                        imu_velocity_mps=imu)
                    for k, m in enumerate(noisy_descent.truth.images))
    measurements = dataclasses.replace(noisy_descent.truth, images=records, sun_direction_world=rng.normal(size=3))
    result = estimator.estimate(images, measurements)
    assert result.reason in REASONS and result.valid == (result.reason == "ok")
    values = [result.velocity_east_mps, result.velocity_north_mps, result.imu_bias_east_mps, result.imu_bias_north_mps]
    values += [v for f in result.features for v in dataclasses.astuple(f) if isinstance(v, float)]
    assert np.all(np.isfinite(values))


def test_config_from_toml_table():
    config = parse(EstimatorConfig, {"template_size_px": 21, "min_correlation": 0.8, "require_both_pairs": False},
                   "site.toml", "estimator")
    assert config.template_size_px == 21 and config.min_correlation == 0.8 and not config.require_both_pairs
    assert config.zero_phase_half_angle_deg == 4.3                               # default kept
    with pytest.raises(ConfigError, match=r"site.toml: estimator.min_corelation is not a known field; allowed: remove_dark"):
        parse(EstimatorConfig, {"min_corelation": 0.8}, "site.toml", "estimator")
    with pytest.raises(ConfigError, match=r"site.toml: estimator.min_correlation = 2 is out of range; allowed: >= -1 "
                                          r"and <= 1"):
        parse(EstimatorConfig, {"min_correlation": 2.0}, "site.toml", "estimator")
    with pytest.raises(ConfigError, match=r"site.toml: estimator.template_size_px = 20 must be odd"):
        parse(EstimatorConfig, {"template_size_px": 20}, "site.toml", "estimator")


def test_velocity_uncertainty_closed_forms():
    """Each error term alone, against its closed form (RMS horizontal = sqrt(2) x per-component sigma)."""
    from dimes_velocity.solution import velocity_uncertainty

    heights = np.array([2000.0, 1725.0, 1450.0])
    dt = np.array([3.8, 3.75])
    both = np.array([True, True])
    common = velocity_uncertainty(heights, dt, both, np.zeros(2), 0.0, 0.01, 0.0, 0.0, np.zeros(3))
    per_pair = (heights[:-1] - heights[1:]) / dt
    assert common == pytest.approx(np.sqrt(2) * 0.01 * per_pair.mean())
    relative = velocity_uncertainty(heights, dt, both, np.zeros(2), 0.0, 0.0, 0.001, 0.0, np.zeros(3))
    coefficients = np.array([heights[0] / dt[0], heights[1] / dt[1] - heights[1] / dt[0], -heights[2] / dt[1]]) / 2
    assert relative == pytest.approx(np.sqrt(2) * 0.001 * np.linalg.norm(coefficients))
    matching = velocity_uncertainty(heights, dt, both, np.array([0.5, 0.7]), 0.0, 0.0, 0.0, 0.0, np.zeros(3))
    assert matching == pytest.approx(np.sqrt(2) * np.hypot(0.5 / dt[0], 0.7 / dt[1]) / 2)
    spread = velocity_uncertainty(heights, dt, both, np.zeros(2), 3.0, 0.0, 0.0, 0.0, np.zeros(3))
    assert spread == pytest.approx(np.sqrt(2) * 1.5)
    one_pair = velocity_uncertainty(heights, dt, np.array([False, True]), np.zeros(2), 0.0, 0.01, 0.0, 0.0, np.zeros(3))
    assert one_pair == pytest.approx(np.sqrt(2) * 0.01 * per_pair[1])


def test_a_pair_needs_two_agreeing_features(mer_a, noisy_descent):
    """One good match is not enough by default (the pair answers too_few_features), a config may allow it."""
    images, measurements = noisy_descent.images, noisy_descent.truth
    single = EstimatorConfig(features_per_pair=1)
    result = DimesEstimator(mer_a, single).estimate(images, measurements)
    assert not result.valid and {pair.reason for pair in result.pairs} == {"too_few_features"}
    allowed = DimesEstimator(mer_a, EstimatorConfig(features_per_pair=1, min_features_per_pair=1))
    assert allowed.estimate(images, measurements).valid
