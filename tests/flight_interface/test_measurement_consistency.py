"""The measurement record is checked for internal consistency (issue 20): IMU positions against IMU
velocities and times, increasing times, positions for every image or none, unit quaternions. The
numbers are closed-form: a record is built from a known motion and the disagreement is worked out by
hand."""
from __future__ import annotations

import numpy as np
import pytest

from flight_interface.measurements import (
    IMU_CONSISTENCY_MPS,
    QUATERNION_NORM_TOLERANCE,
    DescentMeasurements,
    ImageMeasurement,
    MeasurementError,
    validate_measurements,
)

TIMES = (0.0, 3.75, 7.5)
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def record(velocities, positions=None, times=TIMES, attitude=LEVEL) -> DescentMeasurements:
    images = tuple(ImageMeasurement(time_s=t, attitude_quat=np.asarray(attitude, dtype=float),
                                    angular_rate_radps=np.zeros(3), radar_altitude_m=2000.0 - 72.0 * t,
                                    imu_velocity_mps=np.asarray(v, dtype=float),
                                    imu_position_m=None if positions is None else np.asarray(positions[k], dtype=float))
                   for k, (t, v) in enumerate(zip(times, velocities)))
    return DescentMeasurements(images=images, sun_direction_world=np.array([0.0, -0.5, 0.8]))


def test_tolerance_is_the_documented_five_metres_per_second():
    assert IMU_CONSISTENCY_MPS == 5.0
    assert QUATERNION_NORM_TOLERANCE == 1e-3


def test_positions_for_24_mps_with_zero_velocities_are_refused():
    """Positions move 24 m/s east (90 m per 3.75 s), velocities say 0 (and -72 m/s down, as the
    positions do): 24 m/s of disagreement, allowed 5 + |dv| = 5 m/s."""
    velocities = [(0.0, 0.0, -72.0)] * 3
    positions = [(24.0 * t, 0.0, 2000.0 - 72.0 * t) for t in TIMES]
    with pytest.raises(MeasurementError, match=r"imu_position_m and imu_velocity_mps disagree.*24 m/s.*allowed 5 m/s"):
        validate_measurements(record(velocities, positions))


@pytest.mark.parametrize("excess_mps, accepted", [(4.9, True), (5.1, False)])
def test_tolerance_edge_with_steady_velocity(excess_mps, accepted):
    """Velocity 12 east at both images; positions moving at 12 + excess: disagreement = excess."""
    velocities = [(12.0, -7.0, -72.0)] * 3
    positions = [((12.0 + excess_mps) * t, -7.0 * t, -72.0 * t) for t in TIMES]
    if accepted:
        validate_measurements(record(velocities, positions))
    else:
        with pytest.raises(MeasurementError, match=r"images\[0\.\.1\]: imu_position_m"):
            validate_measurements(record(velocities, positions))


@pytest.mark.parametrize("excess_mps, accepted", [(10.9, True), (11.1, False)])
def test_tolerance_grows_with_the_velocity_change(excess_mps, accepted):
    """Velocities 10 then 16 m/s east (|dv| = 6): allowed 5 + 6 = 11 m/s around the trapezoid's 13."""
    times = (0.0, 4.0)
    velocities = [(10.0, 0.0, -72.0), (16.0, 0.0, -72.0)]        # descending as the radar says
    positions = [(0.0, 0.0, 0.0), ((13.0 + excess_mps) * 4.0, 0.0, -72.0 * 4.0)]
    measurements = record(velocities, positions, times=times)
    if accepted:
        validate_measurements(measurements)
    else:
        with pytest.raises(MeasurementError, match="allowed 11 m/s"):
            validate_measurements(measurements)


def test_swinging_lander_with_bias_and_random_walk_is_accepted():
    """A real IMU: velocity = truth (a 1.5 m/s swing of period 8 s on a steady descent) + a constant
    bias of 6 m/s (3 sigma of the campaign's 2 m/s) + a random walk of 0.1 m/s/sqrt(s), positions
    integrated from that same velocity at 200 Hz. Closed form of the swing's part: the mean of
    1.5 sin(2 pi t / 8) over [0, 3.75] is 1.5 (1 - cos(2 pi 3.75 / 8)) / (2 pi 3.75 / 8) = 0.98 m/s,
    against a trapezoid of 0.75 (sin 0 + sin(2 pi 3.75 / 8)) = 0.15 m/s: 0.83 m/s, the bias cancels."""
    rate = 200.0
    t = np.arange(0.0, 7.5 + 0.5 / rate, 1.0 / rate)
    swing = 1.5 * np.sin(2 * np.pi * t / 8.0)
    walk = np.cumsum(0.1 * np.sqrt(1.0 / rate) * np.random.default_rng(3).standard_normal((t.size, 3)), axis=0)
    velocity = np.column_stack([12.0 + swing, -7.0 + 0 * t, -72.0 + 0 * t]) + np.array([6.0, -6.0, 0.0]) + walk
    position = np.vstack([np.zeros(3), np.cumsum(0.5 * (velocity[1:] + velocity[:-1]) / rate, axis=0)])
    index = [int(round(time * rate)) for time in TIMES]
    measurements = record(velocity[index], position[index])
    validate_measurements(measurements)
    first = measurements.images[:2]
    rate_mps = (first[1].imu_position_m - first[0].imu_position_m) / 3.75
    trapezoid = 0.5 * (first[0].imu_velocity_mps + first[1].imu_velocity_mps)
    omega = 2 * np.pi * 3.75 / 8.0
    assert rate_mps[0] - trapezoid[0] == pytest.approx(1.5 * (1 - np.cos(omega)) / omega - 0.75 * np.sin(omega), abs=0.05)


def test_positions_for_some_images_only_are_a_count_mismatch():
    measurements = record([(0.0, 0.0, -72.0)] * 3, [(0.0, 0.0, 0.0)] * 3)
    images = (measurements.images[0], measurements.images[1],
              ImageMeasurement(**{**measurements.images[2].__dict__, "imu_position_m": None}))
    with pytest.raises(MeasurementError, match="imu_position_m: given for 2 of 3 images"):
        validate_measurements(DescentMeasurements(images, measurements.sun_direction_world))


def test_image_count_mismatch_is_refused():
    with pytest.raises(MeasurementError, match="expected 3 image measurements; got 2"):
        validate_measurements(record([(0.0, 0.0, -72.0)] * 2, times=TIMES[:2]), image_count=3)


@pytest.mark.parametrize("times", [(0.0, 3.75, 3.75), (0.0, 3.75, 2.0), (5.0, 3.75, 7.5)])
def test_non_increasing_times_are_refused(times):
    with pytest.raises(MeasurementError, match="time_s .* later than the previous image"):
        validate_measurements(record([(0.0, 0.0, -72.0)] * 3, times=times))


@pytest.mark.parametrize("attitude, accepted", [
    ((0.7071, 0.7071, 0.0, 0.0), True),               # 4-decimal rounding: norm 0.99999
    ((1.0005, 0.0, 0.0, 0.0), True),                  # norm 1.0005, within 1e-3
    ((1.002, 0.0, 0.0, 0.0), False),                  # norm 1.002
    ((0.6, 0.6, 0.0, 0.0), False),                    # norm 0.849: not a unit quaternion
    ((0.0, 0.1, 0.2, 0.3), False),                    # a rotation vector, norm 0.374
])
def test_attitude_quaternions_must_have_unit_norm(attitude, accepted):
    measurements = record([(0.0, 0.0, -72.0)] * 3, attitude=attitude)
    if accepted:
        validate_measurements(measurements)
    else:
        with pytest.raises(MeasurementError, match=r"images\[0\]\.attitude_quat .* unit quaternion \(w, x, y, z\); norm"):
            validate_measurements(measurements)


def test_campaign_sensor_models_pass_at_the_site_sigmas_and_the_allowed_extremes():
    """simulator.sensors.measure at the sites' sigmas (defaults) and at every SensorConfig upper bound that
    leaves the record physical: normalized quaternions, increasing times, no IMU positions (so the horizontal
    IMU bias, up to 50 m/s, never meets the position check; a constant bias cancels in the acceleration
    checks). The three sensor errors the plausibility checks bound are refused at their maxima, naming
    the field: radar noise 10 % (200 m at 2000 m), a vertical IMU bias of 50 m/s sigma, a velocity random
    walk of 10 m/s/sqrt(s) (~19 m/s between images, 5 m/s^2)."""
    from simulator.scene.descent_profile import constant_velocity_profile
    from simulator.sensors import SIGMA_FIELDS, SensorConfig, measure

    bounds = {name: SensorConfig.model_fields[name].metadata for name in SIGMA_FIELDS}
    extremes = {name: next(m.le for m in meta if getattr(m, "le", None) is not None) for name, meta in bounds.items()}
    bounded = {"radar_altitude_sigma_percent": "radar_altitude_m and imu_velocity_mps disagree",
               "imu_vertical_velocity_bias_sigma_mps": "radar_altitude_m and imu_velocity_mps disagree",
               "imu_velocity_random_walk_mps_per_sqrt_s": "imu_velocity_mps"}
    physical = {name: value for name, value in extremes.items() if name not in bounded}
    assert len(physical) == len(SIGMA_FIELDS) - 3
    profile = constant_velocity_profile(np.array([0.0, 0.0, 2000.0]), np.array([12.0, -7.0, -72.0]), LEVEL,
                                        8.0, np.array(TIMES))
    for config in (SensorConfig(state_time="exposure_start"), SensorConfig(state_time="exposure_start", **physical)):
        for seed in range(50):
            measurements, _ = measure(profile, None, np.array([0.0, -0.5, 0.8]), config, np.random.default_rng(seed))
            validate_measurements(measurements, image_count=3)
            assert all(m.imu_position_m is None for m in measurements.images)
    for name, words in bounded.items():
        config = SensorConfig(state_time="exposure_start", **{name: extremes[name]})
        refused = 0
        for seed in range(50):
            measurements, _ = measure(profile, None, np.array([0.0, -0.5, 0.8]), config, np.random.default_rng(seed))
            try:
                validate_measurements(measurements, image_count=3)
            except MeasurementError as exc:
                assert words in str(exc), (name, exc)
                refused += 1
        assert refused >= 40, (name, refused)
