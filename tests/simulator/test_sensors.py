"""Sensor models: error statistics over many draws against the configured sigmas, structure of each error."""
import numpy as np
import pytest

from config_tables.errors import ConfigError
from config_tables.models import parse
from flight_interface.camera_file import Timing
from flight_interface.frames import quat_conjugate, quat_from_axis_angle, quat_multiply, quat_to_rotation_vector, rotate
from simulator.scene.descent_profile import DescentProfile
from simulator.sensors import SIGMA_FIELDS, SensorConfig, measure

EXPOSURE_S = 0.0051
DRAWS = 2000


class _Camera:
    """The only camera property the sensors use (its timing); a real Camera works the same."""
    timing = Timing(fast_flush_s=0.0051, exposure_s=EXPOSURE_S, frame_transfer_s=0.0051, readout_s=0.2)


def _swinging_profile() -> DescentProfile:
    """Lander descending at 72 m/s, drifting east at 12 m/s and swinging about north by 0.3 rad/s."""
    time = np.linspace(0.0, 8.0, 801)
    angle = 0.25 * np.sin(1.2 * time)
    attitude = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), angle)
    rate = np.column_stack([np.zeros_like(time), 0.3 * np.cos(1.2 * time), np.zeros_like(time)])
    velocity = np.tile([12.0, -2.0, -72.0], (len(time), 1)) + np.column_stack([np.sin(time), np.zeros((len(time), 2))])
    position = np.column_stack([12.0 * time - np.cos(time) + 1.0, -2.0 * time, 2000.0 - 72.0 * time])
    return DescentProfile(time, position, velocity, attitude, rate, np.tile([10.0, -1.0, 0.0], (len(time), 1)),
                          position + [40.0, 30.0, -160.0], np.array([0.3, 4.0, 7.75]))


PROFILE = _swinging_profile()
CAMERA = _Camera()
SUN = np.array([0.3, -0.2, 0.9])


def _draw(config: SensorConfig, count: int = DRAWS, seed: int = 11):
    rng = np.random.default_rng(seed)
    return [measure(PROFILE, CAMERA, SUN, config, rng) for _ in range(count)]


def _true_poses(config: SensorConfig):
    offset = 0.5 * EXPOSURE_S if config.state_time == "mid_exposure" else 0.0
    return [PROFILE.pose(float(t) + offset) for t in PROFILE.image_times_s]


def _world_errors(results, config):
    """(draws, images, 3) rotation vectors of q_meas * q_true^-1 (world-frame attitude error)."""
    poses = _true_poses(config)
    return np.array([[quat_to_rotation_vector(quat_multiply(m.attitude_quat, quat_conjugate(p.attitude_quat)))
                      for m, p in zip(measurement.images, poses)] for measurement, _ in results])


ZERO = {name: 0.0 for name in SIGMA_FIELDS}
ONLY = {name: SensorConfig(**{**ZERO, field: value}) for name, field, value in [
    ("attitude_bias_sigma_rad", "attitude_bias_sigma_deg", 1.0),
    ("attitude_random_sigma_rad", "attitude_random_sigma_deg", 0.05),
    ("alignment_sigma_rad", "alignment_sigma_deg", 0.1), ("angular_rate_noise_sigma_radps", "angular_rate_noise_sigma_dps", 0.1),
    ("radar_altitude_sigma_fraction", "radar_altitude_sigma_percent", 0.03),
    ("imu_velocity_bias_sigma_mps", "imu_velocity_bias_sigma_mps", 2.0)]}


def test_attitude_bias_is_constant_over_the_images_with_a_total_tilt_of_one_degree_rms():
    errors = _world_errors(_draw(ONLY["attitude_bias_sigma_rad"]), ONLY["attitude_bias_sigma_rad"])
    np.testing.assert_allclose(errors[:, 1:], errors[:, :1].repeat(2, axis=1), atol=1e-12)
    # default reading: 1 deg is the RMS of the tilt angle, so each axis has 1/sqrt(2) deg
    tilt = np.hypot(errors[:, 0, 0], errors[:, 0, 1])
    assert np.sqrt(np.mean(tilt ** 2)) == pytest.approx(np.radians(1.0), rel=0.05)
    np.testing.assert_allclose(errors[:, 0].std(axis=0), np.radians(1.0) / np.sqrt(2.0), rtol=0.06)
    np.testing.assert_allclose(errors[:, 0].mean(axis=0), 0.0, atol=4 * np.radians(1.0) / np.sqrt(DRAWS))


@pytest.mark.parametrize("reading, axis_sigma_deg", [("per_axis", 1.0), ("total_angle", 1.0 / np.sqrt(3.0))])
def test_attitude_bias_other_readings_of_its_sigma(reading, axis_sigma_deg):
    config = SensorConfig(**{**ZERO, "attitude_bias_sigma_deg": 1.0, "attitude_bias_sigma_is": reading})
    errors = _world_errors(_draw(config, count=1000), config)[:, 0]
    np.testing.assert_allclose(errors.std(axis=0), np.radians(axis_sigma_deg), rtol=0.08)
    if reading == "total_angle":
        assert np.sqrt(np.mean(np.sum(errors ** 2, axis=1))) == pytest.approx(np.radians(1.0), rel=0.05)


def test_between_image_random_error_is_independent_per_image_with_sigma_005_degree():
    errors = _world_errors(_draw(ONLY["attitude_random_sigma_rad"]), ONLY["attitude_random_sigma_rad"])
    np.testing.assert_allclose(errors.reshape(-1, 3).std(axis=0), np.radians(0.05), rtol=0.05)
    correlation = np.corrcoef(errors[:, 0, 0], errors[:, 1, 0])[0, 1]
    assert abs(correlation) < 4 / np.sqrt(DRAWS)


def test_alignment_error_is_fixed_to_the_lander_body():
    config = ONLY["alignment_sigma_rad"]
    results = _draw(config)
    poses = _true_poses(config)
    body = np.array([[quat_to_rotation_vector(quat_multiply(quat_conjugate(p.attitude_quat), m.attitude_quat))
                      for m, p in zip(measurement.images, poses)] for measurement, _ in results])
    # constant in the body frame although the lander swings between images ...
    np.testing.assert_allclose(body[:, 1:], body[:, :1].repeat(2, axis=1), atol=1e-12)
    np.testing.assert_allclose(body[:, 0].std(axis=0), np.radians(0.1), rtol=0.06)
    # ... hence not constant in the world frame
    world = _world_errors(results, config)
    assert np.abs(world[:, 0] - world[:, 2]).max() > 1e-5


def test_radar_altitude_error_is_003_percent_of_altitude():
    config = ONLY["radar_altitude_sigma_fraction"]
    results = _draw(config)
    poses = _true_poses(config)
    relative = np.array([[m.radar_altitude_m / p.position_m[2] - 1.0 for m, p in zip(r.images, poses)] for r, _ in results])
    np.testing.assert_allclose(relative.std(axis=0), 0.0003, rtol=0.06)
    assert abs(np.corrcoef(relative[:, 0], relative[:, 2])[0, 1]) < 4 / np.sqrt(DRAWS)
    truth = np.array([[t[f"radar_altitude_error_image{k}_m"] for k in (1, 2, 3)] for _, t in results])
    measured = np.array([[m.radar_altitude_m - p.position_m[2] for m, p in zip(r.images, poses)] for r, _ in results])
    np.testing.assert_allclose(truth, measured, atol=1e-9)


def test_imu_velocity_bias_is_constant_so_velocity_changes_are_true():
    config = ONLY["imu_velocity_bias_sigma_mps"]
    results = _draw(config)
    poses = _true_poses(config)
    error = np.array([[m.imu_velocity_mps - p.velocity_mps for m, p in zip(r.images, poses)] for r, _ in results])
    np.testing.assert_allclose(error[:, 1:], error[:, :1].repeat(2, axis=1), atol=1e-12)
    np.testing.assert_allclose(error[:, 0, :2].std(axis=0), 2.0, rtol=0.06)
    np.testing.assert_array_equal(error[:, :, 2], 0.0)  # default: no vertical bias
    truth = np.array([[t["imu_velocity_bias_east_mps"], t["imu_velocity_bias_north_mps"]] for _, t in results])
    np.testing.assert_allclose(truth, error[:, 0, :2], atol=1e-12)


def test_angular_rate_noise_sigma():
    config = ONLY["angular_rate_noise_sigma_radps"]
    results = _draw(config)
    poses = _true_poses(config)
    noise = np.array([[m.angular_rate_radps - p.angular_rate_radps for m, p in zip(r.images, poses)] for r, _ in results])
    np.testing.assert_allclose(noise.reshape(-1, 3).std(axis=0), np.radians(0.1), rtol=0.05)


def test_perfect_sensors_measure_the_truth_at_mid_exposure():
    measurements, truth = measure(PROFILE, CAMERA, SUN, SensorConfig.exact(), np.random.default_rng(0))
    for image, t in zip(measurements.images, PROFILE.image_times_s):
        assert image.time_s == t
        mid = t + 0.5 * EXPOSURE_S
        # closed form of the profile: altitude 2000 - 72 t, east velocity 12 + sin t
        assert image.radar_altitude_m == pytest.approx(2000.0 - 72.0 * mid, abs=1e-9)
        assert image.imu_velocity_mps[0] == pytest.approx(12.0 + np.sin(mid), abs=2e-5)
        np.testing.assert_allclose(rotate(image.attitude_quat, [0, 0, 1.0]),
                                   [np.sin(0.25 * np.sin(1.2 * mid)), 0.0, np.cos(0.25 * np.sin(1.2 * mid))], atol=1e-5)
        np.testing.assert_allclose(image.heat_shield_offset_m, [40.0, 30.0, -160.0], atol=1e-4)  # lerp vs Hermite
    np.testing.assert_allclose(measurements.sun_direction_world, SUN / np.linalg.norm(SUN))
    assert all(value == 0.0 for value in truth.values())


def test_switching_one_sensor_to_perfect_leaves_the_other_errors_unchanged_and_seeds_repeat():
    full = measure(PROFILE, CAMERA, SUN, SensorConfig(), np.random.default_rng(42))
    again = measure(PROFILE, CAMERA, SUN, SensorConfig(), np.random.default_rng(42))
    no_attitude = measure(PROFILE, CAMERA, SUN, SensorConfig(attitude_bias_sigma_deg=0.0),
                          np.random.default_rng(42))
    assert full[1] == again[1]
    assert no_attitude[1]["radar_altitude_error_image2_m"] == full[1]["radar_altitude_error_image2_m"]
    assert no_attitude[1]["attitude_bias_east_rad"] == 0.0 != full[1]["attitude_bias_east_rad"]
    other = measure(PROFILE, CAMERA, SUN, SensorConfig(), np.random.default_rng(43))
    assert other[1]["radar_altitude_error_image2_m"] != full[1]["radar_altitude_error_image2_m"]


def test_config_from_table_defaults_are_the_paper_numbers_and_errors_name_the_field():
    default = parse(SensorConfig, {}, "c.toml", "sensors")
    assert default == SensorConfig()
    assert default.attitude_bias_sigma_rad == pytest.approx(np.radians(1.0))
    assert default.attitude_random_sigma_rad == pytest.approx(np.radians(0.05))
    assert default.alignment_sigma_rad == pytest.approx(np.radians(0.1))
    assert default.radar_altitude_sigma_fraction == pytest.approx(0.0003)
    custom = parse(SensorConfig, {"attitude_bias_sigma_deg": 2.0, "imu_velocity_bias_sigma_mps": 0.0},
                   "c.toml", "sensors")
    assert custom.attitude_bias_sigma_rad == pytest.approx(np.radians(2.0)) and custom.imu_velocity_bias_sigma_mps == 0.0
    perfect = parse(SensorConfig, {"perfect": True}, "c.toml", "sensors")
    assert perfect == SensorConfig.exact() and perfect.attitude_bias_sigma_rad == 0.0 == perfect.imu_velocity_bias_sigma_mps
    with pytest.raises(ConfigError, match=r"c.toml: sensors.radar_altitude_sigma_percent = -1 is out of range"):
        parse(SensorConfig, {"radar_altitude_sigma_percent": -1}, "c.toml", "sensors")
    with pytest.raises(ConfigError, match=r"sensors.state_time = 'late' is not allowed; allowed: mid_exposure"):
        parse(SensorConfig, {"state_time": "late"}, "c.toml", "sensors")
    with pytest.raises(ConfigError, match=r"sensors.attitude_sigma_deg is not a known field; allowed: perfect, "):
        parse(SensorConfig, {"attitude_sigma_deg": 1.0}, "c.toml", "sensors")
