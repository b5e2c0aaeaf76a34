"""EDL generator: pendulum physics against closed forms, attitude kinematics, determinism, sampling."""
from pathlib import Path

import numpy as np
import pytest

from config_tables.errors import ConfigError
from flight_interface.frames import quat_conjugate, quat_multiply, quat_to_rotation_vector, rotate
from sitedata.edl.dynamics import (
    G_MARS_MPS2,
    free_pendulum_swing,
    swing_twist_attitude,
    swing_twist_body_rate,
    tilt_angle_rad,
    twist_angle_rad,
)
from sitedata.edl.generator import generate_profiles, load_edl_parameters, profile_statistics
from sitedata.edl.trajectory_io import compact_frame, frame_to_profiles, profiles_to_frame, read_profiles

SETS = Path(__file__).resolve().parents[3] / "sitedata" / "trajectories"


def _crossing_times(time, angle):
    """Times of downward zero crossings of ``angle`` (linear interpolation)."""
    index = np.nonzero((angle[:-1] > 0) & (angle[1:] <= 0))[0]
    return time[index] + angle[index] / (angle[index] - angle[index + 1]) * (time[index + 1] - time[index])


@pytest.mark.parametrize("length_m", [5.0, 20.0])
def test_small_angle_period_is_two_pi_sqrt_length_over_mars_gravity(length_m):
    period = 2 * np.pi * np.sqrt(length_m / G_MARS_MPS2)
    time, angle = free_pendulum_swing(length_m, 0.0, np.radians(0.5), 2.2 * period, 0.0025)
    measured = np.diff(_crossing_times(time, angle))
    assert len(measured) >= 1
    np.testing.assert_allclose(measured, period, rtol=2e-5)  # finite-amplitude correction is 5e-6


def test_large_swing_period_follows_the_elliptic_series():
    length, amplitude = 5.0, np.radians(30.0)
    period0 = 2 * np.pi * np.sqrt(length / G_MARS_MPS2)
    expected = period0 * (1 + amplitude**2 / 16 + 11 * amplitude**4 / 3072 + 173 * amplitude**6 / 737280)
    time, angle = free_pendulum_swing(length, 0.0, amplitude, 2.2 * period0, 0.0025)
    np.testing.assert_allclose(np.diff(_crossing_times(time, angle)), expected, rtol=2e-5)
    assert abs(expected / period0 - 1) > 0.015  # the test distinguishes the nonlinear pendulum


def test_damping_envelope_is_exponential_with_the_damping_ratio():
    length, zeta = 20.0, 0.05
    omega0 = np.sqrt(G_MARS_MPS2 / length)
    time, angle = free_pendulum_swing(length, zeta, np.radians(2.0), 40.0, 0.0025)
    peaks = np.nonzero((angle[1:-1] > angle[:-2]) & (angle[1:-1] >= angle[2:]))[0] + 1
    assert len(peaks) >= 2
    # log decrement between successive maxima: 2 pi zeta / sqrt(1 - zeta^2)
    decrement = np.log(angle[peaks[:-1]] / angle[peaks[1:]])
    np.testing.assert_allclose(decrement, 2 * np.pi * zeta / np.sqrt(1 - zeta**2), rtol=2e-3)
    # envelope exp(-zeta omega0 t) through the first maximum
    np.testing.assert_allclose(angle[peaks], np.radians(2.0) * np.exp(-zeta * omega0 * time[peaks]), rtol=3e-3)


def test_swing_twist_attitude_points_body_z_up_the_bridle_with_the_given_roll():
    rng = np.random.default_rng(5)
    direction = rng.normal(size=(50, 3)) * [0.3, 0.3, 0.0] + [0, 0, 1]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    twist = rng.uniform(-1.0, 1.0, 50)
    q = swing_twist_attitude(direction, twist)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    body_z = np.stack([rotate(qi, [0.0, 0.0, 1.0]) for qi in q])
    np.testing.assert_allclose(body_z, direction, atol=1e-12)
    np.testing.assert_allclose(tilt_angle_rad(q), np.arccos(direction[:, 2]), atol=1e-7)
    np.testing.assert_allclose(twist_angle_rad(q), twist, atol=1e-12)


def test_body_rate_matches_the_quaternion_derivative():
    def state(t):
        tilt = np.stack([0.3 * np.sin(0.7 * t + 0.2), 0.2 * np.cos(1.3 * t), np.ones_like(t)], axis=-1)
        norm = np.linalg.norm(tilt, axis=-1, keepdims=True)
        return tilt / norm, 0.5 * np.sin(1.9 * t)

    t = np.linspace(0.0, 5.0, 11)
    eps = 1e-5
    d, psi = state(t)
    d_rate = (state(t + eps)[0] - state(t - eps)[0]) / (2 * eps)
    psi_rate = (state(t + eps)[1] - state(t - eps)[1]) / (2 * eps)
    rate = swing_twist_body_rate(d, d_rate, psi, psi_rate)
    q_plus, q_minus = swing_twist_attitude(*state(t + eps)), swing_twist_attitude(*state(t - eps))
    # body rate: rotation vector of q(t-e)^-1 q(t+e) over 2e
    finite = quat_to_rotation_vector(quat_multiply(quat_conjugate(q_minus), q_plus)) / (2 * eps)
    np.testing.assert_allclose(rate, finite, atol=1e-7)


@pytest.fixture(scope="module")
def gusev_params():
    return load_edl_parameters(SETS / "edl_gusev.toml")


@pytest.fixture(scope="module")
def few_profiles(gusev_params):
    return generate_profiles(gusev_params, [3, 7])[0]


def test_profiles_are_deterministic_and_independent_of_the_batch(gusev_params, few_profiles):
    alone = generate_profiles(gusev_params, [7])[0][0]
    batched = few_profiles[1]
    for field in ("time_s", "position_m", "velocity_mps", "attitude_quat", "angular_rate_radps", "heat_shield_position_m"):
        assert np.array_equal(getattr(alone, field), getattr(batched, field)), field
    assert not np.array_equal(few_profiles[0].velocity_mps[:5], batched.velocity_mps[:5])
    other_seed = generate_profiles(gusev_params.with_seed(gusev_params.seed + 1), [7])[0][0]
    assert not np.array_equal(other_seed.velocity_mps[:5], batched.velocity_mps[:5])


def test_stored_set_regenerates_bit_for_bit(gusev_params):
    indices = [0, 1, 2]
    stored = read_profiles(gusev_params.output_path)[:3]
    fresh = generate_profiles(gusev_params, indices)[0]
    regenerated = frame_to_profiles(compact_frame(profiles_to_frame(fresh)), "fresh", "gusev")
    for a, b in zip(stored, regenerated):
        for field in ("time_s", "position_m", "velocity_mps", "attitude_quat", "angular_rate_radps", "wind_mps",
                      "heat_shield_position_m", "image_times_s"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field


def test_images_at_the_paper_altitudes_and_origin_under_image_one(few_profiles):
    for profile in few_profiles:
        t1, t2, t3 = profile.image_times_s
        assert abs(profile.pose(t1).position_m[2] - 2000.0) < 1e-3
        assert abs(profile.pose(t2).position_m[2] - 1725.0) < 1e-3
        assert t3 - t2 == pytest.approx(3.75, abs=1e-12)
        np.testing.assert_allclose(profile.pose(t1).position_m[:2], 0.0, atol=1e-4)
        assert profile.time_s[0] <= t1 - 0.1 and profile.time_s[-1] >= t3 + 0.1
        near = np.abs(profile.time_s - t2) < 0.05
        assert np.all(np.diff(profile.time_s[near]) <= 0.005 + 1e-9)  # dense sampling at the images


def test_velocity_and_rate_columns_are_the_derivatives_of_position_and_attitude(few_profiles):
    for profile in few_profiles:
        dense = np.nonzero(np.diff(profile.time_s) < 0.006)[0]
        dt = np.diff(profile.time_s)[dense][:, None]
        chord = (profile.position_m[dense + 1] - profile.position_m[dense]) / dt
        mean_velocity = 0.5 * (profile.velocity_mps[dense + 1] + profile.velocity_mps[dense])
        np.testing.assert_allclose(chord, mean_velocity, atol=2e-4)
        q0, q1 = profile.attitude_quat[dense], profile.attitude_quat[dense + 1]
        turned = quat_to_rotation_vector(quat_multiply(quat_conjugate(q0), q1)) / dt
        mean_rate = 0.5 * (profile.angular_rate_radps[dense] + profile.angular_rate_radps[dense + 1])
        np.testing.assert_allclose(turned, mean_rate, atol=2e-4)


def test_heat_shield_lies_below_and_beside_the_lander_within_the_drawn_ranges(gusev_params, few_profiles):
    for profile in few_profiles:
        stats = profile_statistics(profile)
        for k in (1, 2, 3):
            assert gusev_params.heat_shield.axial_at_first_image_m[0] <= stats[f"heat_shield_axial_image{k}_m"] <= 200.0
            assert gusev_params.heat_shield.lateral_at_first_image_m[0] <= stats[f"heat_shield_lateral_image{k}_m"] <= 75.0
        assert stats["heat_shield_axial_image3_m"] >= stats["heat_shield_axial_image1_m"]


def test_parameter_file_errors_name_file_and_field(tmp_path):
    text = (SETS / "edl_gusev.toml").read_text().replace("bridle_length_m = 20.0", "bridle_length_m = -3.0")
    bad = tmp_path / "edl_bad.toml"
    bad.write_text(text)
    with pytest.raises(ConfigError, match=r"edl_bad.toml: pendulum.bridle_length_m = -3 is out of range"):
        load_edl_parameters(bad)
    bad.write_text((SETS / "edl_gusev.toml").read_text() + "\n[extra]\nx = 1\n")
    with pytest.raises(ConfigError, match="edl_bad.toml: extra is not a known field; allowed: set, images, "):
        load_edl_parameters(bad)
