"""Numerical stress: CAHVOR projection and its inverse, rotations, and the estimator's ground-plane
warping at the edges (points behind or beside the camera, pixels far outside the frame, rotations of
any size, cameras at the horizon, below the ground, or looking at the sky). Nothing may return NaN or
inf; out-of-domain input raises ValueError naming what is wrong."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dimes_velocity import geometry
from flight_interface import cahvor
from flight_interface.frames import (
    matrix_to_quat,
    off_nadir_angle_rad,
    quat_conjugate,
    quat_from_axis_angle,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    quat_to_rotation_vector,
    rotate,
    slerp,
)

CHEAP = settings(max_examples=300, deadline=None, derandomize=True)
MEDIUM = settings(max_examples=40, deadline=None, derandomize=True)

FOCAL_PX = 0.01467 / 12e-6
R1 = -0.01
# turning point of u (1 + R1 u^2): u* = 1/sqrt(3 |R1|), largest distorted tangent u*(1 + R1 u*^2)
TURNING_U = 1.0 / np.sqrt(3.0 * abs(R1))
MAX_DISTORTED_U = TURNING_U * (1.0 + R1 * TURNING_U**2)

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
unit_interval = st.floats(0.0, 1.0)


def quaternions():
    return st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 1e-3).map(np.array)


def rotation_vectors(max_angle=np.pi):
    return st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0.0, max_angle)).filter(
        lambda t: np.linalg.norm(t[:3]) > 1e-3).map(lambda t: np.array(t[:3]) / np.linalg.norm(t[:3]) * t[3])


# ------------------------------------------------------------------------------------------- CAHVOR
@CHEAP
@given(st.tuples(finite, finite, finite))
def test_projection_of_any_finite_point_is_finite(mer_a, point):
    pixels, in_front = cahvor.project(mer_a.model, np.array(point))
    assert np.all(np.isfinite(pixels))
    if point[2] <= 0:
        assert not in_front          # behind or beside the camera (A = O = +z)


def test_projection_at_the_centre_beside_and_at_extreme_distances_is_finite(mer_a):
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1e-200], [1e300, 0.0, 1e300],
                       [1e-300, 0.0, 1e-300], [0.0, 0.0, -1.0]])
    with np.errstate(all="ignore"):
        pixels, in_front = cahvor.project(mer_a.model, points)
    assert np.all(np.isfinite(pixels))
    assert not in_front[[0, 1, 5]].any()


@pytest.mark.parametrize("tangent", [6.0, 10.05, 31.6, 1e3])
def test_points_beyond_the_distortion_turning_point_are_not_folded_into_the_frame(mer_a, tangent):
    """u (1 + R1 u^2) with R1 = -0.01 peaks at u* = 5.77 (80 deg off axis) and comes back through 0 at
    u = 10: without the turning-point test a ground point 84 deg off axis would land at column 389."""
    _, in_front = cahvor.project(mer_a.model, np.array([tangent, 0.0, 1.0]))
    assert not in_front
    _, inside = cahvor.project(mer_a.model, np.array([0.99 * TURNING_U, 0.0, 1.0]))
    assert inside


@CHEAP
@given(st.floats(-2e6, 2e6), st.floats(-2e6, 2e6))
def test_unprojection_of_any_pixel_is_a_unit_ray_on_the_pixels_side(mer_a, column, row):
    ray = cahvor.unproject(mer_a.model, np.array([column, row]))
    assert np.all(np.isfinite(ray)) and abs(np.linalg.norm(ray) - 1.0) < 1e-12
    assert ray[2] > 0
    offset = np.array([column - 511.5, row - 511.5])
    if np.linalg.norm(offset) > 1e-3:
        # the ray leans the way the pixel lies from the principal point (radial model)
        assert ray[:2] @ offset > 0
        cross = ray[0] * offset[1] - ray[1] * offset[0]
        assert abs(cross) <= 1e-9 * np.linalg.norm(offset) * np.linalg.norm(ray[:2]) + 1e-12


@CHEAP
@given(st.floats(0.0, 0.999), st.floats(0.0, 2 * np.pi))
def test_unproject_inverts_project_out_to_the_distortion_turning_point(mer_a, fraction, azimuth):
    """Inside the model's image circle (distorted tangent below u*(1 + R1 u*^2), 4700 px for MER)
    project(unproject(p)) = p; the frame itself (corners at 724 px) is far inside."""
    radius_px = fraction * MAX_DISTORTED_U * FOCAL_PX
    pixel = np.array([511.5, 511.5]) + radius_px * np.array([np.cos(azimuth), np.sin(azimuth)])
    ray = cahvor.unproject(mer_a.model, pixel)
    back, in_front = cahvor.project(mer_a.model, 1000.0 * ray)
    assert in_front
    assert np.allclose(back, pixel, atol=1e-6 * max(1.0, radius_px / 100.0))


@CHEAP
@given(st.floats(1.0001, 1e6), st.floats(0.0, 2 * np.pi))
def test_pixels_beyond_the_image_circle_get_the_outermost_ray(mer_a, factor, azimuth):
    """No ray reaches a pixel whose distorted tangent exceeds the maximum of u (1 + R1 u^2): unproject
    returns the ray at the turning point u* = 1/sqrt(3 |R1|) (closed form), on the pixel's side."""
    radius_px = factor * MAX_DISTORTED_U * FOCAL_PX
    direction = np.array([np.cos(azimuth), np.sin(azimuth)])
    ray = cahvor.unproject(mer_a.model, np.array([511.5, 511.5]) + radius_px * direction)
    assert np.hypot(ray[0], ray[1]) / ray[2] == pytest.approx(TURNING_U, rel=1e-9)
    assert ray[:2] @ direction > 0


def test_distortion_turning_point_closed_forms():
    assert cahvor.distortion_turning_point(np.array([0.0, -0.01, 0.0])) == pytest.approx(1 / np.sqrt(0.03))
    assert cahvor.distortion_turning_point(np.array([0.0, 0.0, 0.0])) == np.inf
    assert cahvor.distortion_turning_point(np.array([0.1, 0.05, 0.01])) == np.inf
    # 1 + 5 R2 s^2 = 0 with R2 = -0.002: s = 10, u* = sqrt(10)
    assert cahvor.distortion_turning_point(np.array([0.0, 0.0, -0.002])) == pytest.approx(np.sqrt(10.0))


# ---------------------------------------------------------------------------------------- rotations
@CHEAP
@given(quaternions(), st.tuples(finite, finite, finite))
def test_rotations_preserve_length_and_are_finite(quaternion, vector):
    vector = np.array(vector)
    matrix = quat_to_matrix(quaternion)
    assert np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(matrix) == pytest.approx(1.0, abs=1e-12)
    rotated = rotate(quaternion, vector)
    assert np.linalg.norm(rotated) == pytest.approx(np.linalg.norm(vector), rel=1e-12, abs=1e-9)
    back = matrix_to_quat(matrix)
    assert abs(abs(back @ quat_normalize(quaternion)) - 1.0) < 1e-9        # same rotation (q ~ -q)
    angle = off_nadir_angle_rad(quaternion)
    assert 0.0 <= angle <= np.pi


@CHEAP
@given(rotation_vectors())
def test_rotation_vector_round_trip_up_to_half_a_turn(vector):
    back = quat_to_rotation_vector(quat_from_rotation_vector(vector))
    if np.linalg.norm(vector) < np.pi - 1e-6:
        assert np.allclose(back, vector, atol=1e-9)
    else:   # at pi, v and -v are the same rotation
        assert min(np.linalg.norm(back - vector), np.linalg.norm(back + vector)) < 1e-6


@CHEAP
@given(st.floats(1e-3, 2 * np.pi), st.floats(1e-4, 0.2), st.sampled_from([0, 1, 2]))
@pytest.mark.slow
def test_angular_rates_up_to_360_deg_per_s_integrate_to_the_closed_form_angle(rate_fraction, duration_s, axis):
    """Rate w (up to 2 pi rad/s) for t seconds about a body axis: the composed per-step rotations
    (1000 steps) equal one rotation by w t, and slerp between the ends is the rotation by w t / 2."""
    rate = rate_fraction                       # rad/s, up to 360 deg/s
    axis_vector = np.eye(3)[axis]
    step = quat_from_rotation_vector(axis_vector * rate * duration_s / 1000)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for _ in range(1000):
        q = quat_multiply(q, step)
    expected = quat_from_axis_angle(axis_vector, rate * duration_s)
    assert abs(abs(quat_normalize(q) @ expected) - 1.0) < 1e-10
    middle = slerp(np.array([1.0, 0.0, 0.0, 0.0]), expected, 0.5)
    half = quat_from_axis_angle(axis_vector, 0.5 * rate * duration_s)
    assert abs(abs(middle @ half) - 1.0) < 1e-12


@CHEAP
@given(quaternions(), quaternions(), unit_interval)
def test_slerp_is_a_finite_unit_quaternion_even_between_opposite_rotations(q0, q1, fraction):
    result = slerp(q0, q1, fraction)
    assert np.all(np.isfinite(result)) and np.linalg.norm(result) == pytest.approx(1.0, abs=1e-12)
    result = slerp(q0, -q0, fraction)             # the same rotation: no motion
    assert abs(abs(result @ quat_normalize(q0)) - 1.0) < 1e-12
    half_turn = quat_multiply(quat_from_axis_angle([1.0, 0.0, 0.0], np.pi), quat_normalize(q0))
    assert np.all(np.isfinite(slerp(q0, half_turn, fraction)))


@pytest.mark.parametrize("call, match", [
    (lambda: quat_normalize(np.zeros(4)), "non-zero norm"),
    (lambda: quat_normalize(np.array([np.nan, 0.0, 0.0, 1.0])), "finite"),
    (lambda: quat_to_matrix(np.zeros(4)), "non-zero norm"),
    (lambda: quat_from_axis_angle(np.zeros(3), 1.0), "axis"),
    (lambda: quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.inf), "angle"),
    (lambda: quat_from_rotation_vector(np.array([np.inf, 0.0, 0.0])), "rotation vector"),
])
def test_degenerate_rotations_raise_a_clear_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_tiny_and_half_turn_rotations_keep_full_precision():
    tiny = quat_from_rotation_vector(np.array([1e-12, 0.0, 0.0]))
    assert quat_to_rotation_vector(tiny)[0] == pytest.approx(1e-12, rel=1e-9)
    assert np.allclose(quat_conjugate(tiny) @ tiny, 1.0)
    half_turn = matrix_to_quat(np.diag([1.0, -1.0, -1.0]))
    assert np.allclose(np.abs(half_turn), [0.0, 1.0, 0.0, 0.0])


# ----------------------------------------------------- estimator ground-plane warping (homographies)
def _rectification(camera, tilt_rad, height_m, sample_m, centre=None, max_off_nadir=np.radians(89.9)):
    attitude = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), tilt_rad)
    # the lander sits 0.5 m above the camera (mounting offset): lander altitude = camera height + 0.5
    pose = geometry.camera_pose(camera, attitude, height_m + 0.5 * np.cos(tilt_rad), np.zeros(2))
    centre = geometry.ground_centre_m(pose, max_off_nadir) if centre is None else np.asarray(centre, float)
    with np.errstate(all="ignore"):   # nothing may leak even when numpy complains on the way
        return pose, geometry.rectify_map(pose, camera, 64, sample_m, centre, 9, np.array([0.0, 0.0, -1.0]),
                                          np.radians(4.3), np.array([0.0, 0.0, 0.0]), np.radians(3.0))


def _check_rectification(camera, pose, rect):
    assert np.all(np.isfinite(rect.map_x)) and np.all(np.isfinite(rect.map_y))
    assert rect.visible.dtype == np.uint8 and set(np.unique(rect.visible)) <= {0, 1}
    image = np.random.default_rng(0).random((256, 256)).astype(np.float32)
    warped = geometry.warp(image, rect)
    assert np.all(np.isfinite(warped)) and warped.min() >= 0.0 and warped.max() <= 1.0
    # every visible pixel's ground point is in front of the camera and inside the binned frame
    rows, columns = np.nonzero(rect.visible)
    if len(rows):
        pick = np.linspace(0, len(rows) - 1, min(len(rows), 50)).astype(int)
        ground = np.array([[*rect.ground_of(c, r), 0.0] for c, r in zip(columns[pick], rows[pick])])
        pixels, in_front = cahvor.project(pose.model, ground)
        assert in_front.all()
        binned = (pixels - 1.5) / 4.0
        assert np.all(binned > -1.5) and np.all(binned < 256.5)


@MEDIUM
@given(st.floats(0.0, np.pi), st.floats(1e-6, 2e4), st.floats(1e-9, 1e9))
def test_ground_plane_warping_is_finite_for_any_tilt_height_and_sampling(mer_a, tilt_rad, height_m, sample_m):
    """Tilts from nadir through the horizon to zenith (the homography degenerates at the horizon and
    flips behind the camera), camera heights down to a micrometre, ground samples from nm to Gm."""
    pose, rect = _rectification(mer_a, tilt_rad, height_m, sample_m)
    _check_rectification(mer_a, pose, rect)
    if tilt_rad > np.pi / 2 + np.radians(23.0):
        assert not rect.visible.any()      # the whole frame looks at the sky: no ground is seen


@pytest.mark.parametrize("tilt_deg, height_m, sample_m, centre", [
    (90.0, 2000.0, 6.5, None),             # boresight exactly on the horizon
    (0.0, 1e-9, 1e-3, None),               # camera on the ground plane
    (0.0, 2000.0, 6.5, (1e12, 0.0)),       # grid far beyond the horizon
    (45.0, 2000.0, 6.5, (0.0, -1e7)),      # grid behind the camera
    (180.0, 2000.0, 6.5, None),            # looking straight up
])
def test_degenerate_homographies_give_finite_maps_and_no_visible_ground(mer_a, tilt_deg, height_m, sample_m, centre):
    pose, rect = _rectification(mer_a, np.radians(tilt_deg), height_m, sample_m, centre)
    _check_rectification(mer_a, pose, rect)
    if tilt_deg != 90.0:
        assert not rect.visible.any()


def test_one_quaternion_matrix_is_the_batched_matrix_bit_for_bit():
    """A single quaternion takes a Python-float path: the same bits as the same quaternion in a batch (the numpy
    path), for any norm and sign of w, and a rotation (orthonormal, det +1)."""
    rng = np.random.default_rng(21)
    quaternions = rng.normal(size=(4000, 4)) * rng.uniform(0.01, 100.0, (4000, 1))
    quaternions[::7, 2] = 0.0
    quaternions[::5, 0] *= -1.0
    batched = quat_to_matrix(quaternions)
    for quaternion, expected in zip(quaternions, batched):
        single = quat_to_matrix(quaternion)
        assert single.shape == (3, 3) and np.array_equal(single.view(np.uint64), expected.view(np.uint64))
    assert np.allclose(single @ single.T, np.eye(3), atol=1e-12) and np.linalg.det(single) == pytest.approx(1.0)
    for degenerate in ([0.0, 0.0, 0.0, 0.0], [np.nan, 1.0, 0.0, 0.0], [np.inf, 0.0, 0.0, 0.0]):
        with pytest.raises(ValueError, match="finite with a non-zero norm"):
            quat_to_matrix(np.array(degenerate))
