"""Descent profile interpolation and placement."""
import numpy as np
import pytest

from flight_interface.frames import quat_from_axis_angle, rotate
from simulator.scene.descent_profile import DescentProfile, constant_velocity_profile


def _swinging_profile():
    time = np.linspace(0.0, 2.0, 21)
    rate = 0.5  # rad/s about body x
    attitude = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), rate * time)
    position = np.stack([10.0 * time, -3.0 * time, 2000.0 - 72.0 * time], axis=-1)
    velocity = np.tile([10.0, -3.0, -72.0], (21, 1))
    return DescentProfile(time, position, velocity, attitude, np.tile([rate, 0.0, 0.0], (21, 1)),
                          np.tile([4.0, 1.0, 0.0], (21, 1)), position + [0.0, 60.0, -150.0],
                          np.array([0.1, 1.0, 1.9]))


def test_pose_interpolates_position_and_slerps_attitude():
    profile = _swinging_profile()
    pose = profile.pose(0.537)
    np.testing.assert_allclose(pose.position_m, [5.37, -1.611, 2000 - 72 * 0.537], atol=1e-9)
    expected = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), 0.5 * 0.537)
    np.testing.assert_allclose(pose.attitude_quat, expected, atol=1e-12)
    with pytest.raises(ValueError, match="outside"):
        profile.pose(2.5)


def test_placed_profile_turns_the_whole_flight():
    profile = _swinging_profile()
    heading = np.radians(90.0)
    placed = profile.placed(heading, np.array([100.0, 200.0]))
    pose, original = placed.pose(1.0), profile.pose(1.0)
    # east velocity becomes north velocity after a 90 deg counter-clockwise turn
    np.testing.assert_allclose(pose.velocity_mps, [3.0, 10.0, -72.0], atol=1e-9)
    np.testing.assert_allclose(pose.position_m, [100.0 + 3.0, 200.0 + 10.0, 2000 - 72.0], atol=1e-9)
    # body axes turn with it: lander x axis in world turns by 90 deg about z
    np.testing.assert_allclose(rotate(pose.attitude_quat, [1.0, 0, 0]),
                               rotate(quat_from_axis_angle(np.array([0, 0, 1.0]), heading),
                                      rotate(original.attitude_quat, [1.0, 0, 0])), atol=1e-12)
    np.testing.assert_allclose(placed.wind_at(1.0), [-1.0, 4.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose.heat_shield_position_m - pose.position_m, [-60.0, 0.0, -150.0], atol=1e-9)


def test_profile_rejects_bad_shapes_and_time():
    with pytest.raises(ValueError, match="strictly increasing"):
        constant_velocity_profile([0, 0, 2000], [0, 0, -72], [1, 0, 0, 0], 0.0, [0.0], samples=2)
