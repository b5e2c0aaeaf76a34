"""Estimator geometry: poses, IMU-predicted positions, rectification maps and exclusion zones."""
from __future__ import annotations

import numpy as np
import pytest

from dimes_velocity import geometry
from flight_interface import cahvor
from flight_interface.frames import quat_from_axis_angle
from flight_interface.measurements import DescentMeasurements, ImageMeasurement


def test_predicted_positions_integrate_linear_velocity_exactly():
    """Trapezoidal integration is exact for a velocity linear in time: x = v0 t + a t^2 / 2."""
    v0, acceleration = np.array([3.0, -2.0, -70.0]), np.array([0.5, 0.25, -1.0])
    times = [0.0, 3.7, 7.5]
    images = tuple(ImageMeasurement(t, np.array([1.0, 0, 0, 0]), np.zeros(3), 2000.0 - 72 * t, v0 + acceleration * t)
                   for t in times)
    positions = geometry.predicted_positions_m(DescentMeasurements(images, np.array([0, 0, 1.0])))
    expected = np.array([(v0 * t + 0.5 * acceleration * t * t)[:2] for t in times])
    assert np.allclose(positions, expected, atol=1e-12)


def test_camera_pose_level_lander_looks_down(mer_a):
    pose = geometry.camera_pose(mer_a, np.array([1.0, 0, 0, 0]), 2000.0, np.array([10.0, -5.0]))
    assert np.allclose(pose.centre_m, [10.0, -5.0, 1999.5])          # camera 0.5 m below the lander origin
    assert np.allclose(pose.boresight, [0, 0, -1])
    assert pose.off_nadir_rad == pytest.approx(0.0, abs=1e-12)
    # nadir ground point projects to the principal point
    pixel, _ = cahvor.project(pose.model, np.array([10.0, -5.0, 0.0]))
    assert np.allclose(pixel, [511.5, 511.5], atol=1e-9)


@pytest.mark.parametrize("altitude, tilt_deg", [(2000.0, 0.0), (1450.0, 20.0), (1725.0, 40.0)])
def test_rectification_map_matches_exact_projection(mer_a, altitude, tilt_deg):
    attitude = quat_from_axis_angle(np.array([1.0, 0.4, 0.0]), np.radians(tilt_deg))
    pose = geometry.camera_pose(mer_a, attitude, altitude, np.zeros(2))
    sample = 2000.0 / geometry.binned_focal_px(mer_a)
    rect = geometry.rectify_map(pose, mer_a, 256, sample, geometry.ground_centre_m(pose, np.radians(60)), 17,
                                None, 0.0)
    columns, rows = np.meshgrid(np.arange(256.0), np.arange(256.0))
    ground = np.stack([rect.origin_m[0] + sample * columns, rect.origin_m[1] - sample * rows, 0 * rows], axis=-1)
    pixels, in_front = cahvor.project(pose.model, ground)
    binned = (pixels - 1.5) / 4.0                      # full-frame -> 4x4 binned pixel coordinates
    inside = in_front & np.all((binned >= 0) & (binned <= 255), axis=-1)
    nearly_inside = in_front & np.all((binned >= -0.01) & (binned <= 255.01), axis=-1)
    visible = rect.visible.astype(bool)
    assert visible.mean() > 0.4
    assert not (visible & ~nearly_inside).any()        # never claims an invisible ground point
    assert (inside & ~visible).mean() < 0.02           # and loses little at the footprint edge
    error = np.hypot(binned[..., 0] - rect.map_x, binned[..., 1] - rect.map_y)[visible]
    assert error.max() < 0.01
    # ground_of / pixel_of are inverse
    assert np.allclose(rect.pixel_of(rect.ground_of(12.25, 200.5)), [12.25, 200.5])


def test_zero_phase_zone_is_a_4_3_degree_cone_around_the_anti_sun_ray(mer_a):
    pose = geometry.camera_pose(mer_a, np.array([1.0, 0, 0, 0]), 2000.0, np.zeros(2))
    elevation, azimuth = np.radians(80.0), np.radians(40.0)
    sun = np.array([np.cos(elevation) * np.sin(azimuth), np.cos(elevation) * np.cos(azimuth), np.sin(elevation)])
    sample = 2000.0 / geometry.binned_focal_px(mer_a)
    half_angle = np.radians(4.3)
    rect = geometry.rectify_map(pose, mer_a, 256, sample, np.zeros(2), 17, -sun, half_angle)
    centre = pose.centre_m
    anti_sun_ground = centre - sun * centre[2] / sun[2]          # where the anti-sun ray meets z = 0
    zone = rect.excluded_zone.astype(bool)
    column, row = np.rint(rect.pixel_of(anti_sun_ground[:2])).astype(int)
    assert zone[row, column]
    # along a ground line through the anti-sun point, the zone ends where the ray angle is 4.3 deg
    angles = []
    for step in np.arange(0, 80):
        point = anti_sun_ground[:2] + step * sample * np.array([1.0, 0.0])
        c, r = np.rint(rect.pixel_of(point)).astype(int)
        if not zone[r, c]:
            ray = np.append(point, 0.0) - centre
            angles.append(np.degrees(np.arccos(ray @ -sun / np.linalg.norm(ray))))
            break
    assert angles and 4.2 < angles[0] < 4.5
    assert 0.005 < zone.mean() < 0.1


def test_heat_shield_cone_is_excluded(mer_a):
    pose = geometry.camera_pose(mer_a, np.array([1.0, 0, 0, 0]), 2000.0, np.zeros(2))
    shield = np.array([60.0, -40.0, 2000.0 - 170.0])             # 170 m below, 72 m to the side
    sample = 2000.0 / geometry.binned_focal_px(mer_a)
    half_angle = np.arctan2(2.65, np.linalg.norm(shield - pose.centre_m)) + np.radians(1.0)
    rect = geometry.rectify_map(pose, mer_a, 256, sample, np.zeros(2), 17, None, 0.0, shield, half_angle)
    zone = rect.excluded_zone.astype(bool)
    direction = (shield - pose.centre_m) / np.linalg.norm(shield - pose.centre_m)
    behind = pose.centre_m - direction * pose.centre_m[2] / direction[2]     # ground point hidden by the shield
    column, row = np.rint(rect.pixel_of(behind[:2])).astype(int)
    assert zone[row, column]
    # a narrow cone at angle theta from the vertical cuts the ground in an ellipse of area
    # pi (H tan a)^2 / cos^3(theta)
    cos_theta = -direction[2]
    expected_area_px = np.pi * (pose.centre_m[2] * np.tan(half_angle) / sample) ** 2 / cos_theta ** 3
    assert zone.sum() == pytest.approx(expected_area_px, rel=0.05)


def test_predicted_positions_prefer_imu_positions():
    """With IMU-propagated positions the displacement is theirs (a swinging lander is not linear)."""
    times = [0.0, 3.8, 7.6]
    positions = [np.array([100.0, 50.0, 2000.0]), np.array([131.0, 40.0, 1725.0]), np.array([170.0, 35.0, 1450.0])]
    images = tuple(ImageMeasurement(t, np.array([1.0, 0, 0, 0]), np.zeros(3), p[2], np.array([9.0, -2.0, -72.0]),
                                    imu_position_m=p) for t, p in zip(times, positions))
    predicted = geometry.predicted_positions_m(DescentMeasurements(images, np.array([0, 0, 1.0])))
    assert np.allclose(predicted, [[0, 0], [31, -10], [70, -15]])
    partial = (images[0], images[1], ImageMeasurement(7.6, np.array([1.0, 0, 0, 0]), np.zeros(3), 1450.0,
                                                      np.array([9.0, -2.0, -72.0])))
    fallback = geometry.predicted_positions_m(DescentMeasurements(partial, np.array([0, 0, 1.0])))
    assert np.allclose(fallback, [[0, 0], [34.2, -7.6], [68.4, -15.2]])


def test_rectifying_images_together_gives_each_image_its_own_maps(mer_a):
    """rectify_maps interpolates the images' knot maps in one call: each image's maps and masks are bit for bit the
    ones it gets alone (its zero-phase zone and heat shield cone included)."""
    sun = np.array([0.3, -0.2, 0.93])
    sun /= np.linalg.norm(sun)
    sample = 2000.0 / geometry.binned_focal_px(mer_a)
    requests = []
    for altitude, tilt_deg, shield in ((2000.0, 3.0, None), (1725.0, 12.0, np.array([40.0, -30.0, 1600.0])),
                                       (1450.0, 25.0, None)):
        attitude = quat_from_axis_angle(np.array([1.0, 0.4, 0.0]), np.radians(tilt_deg))
        pose = geometry.camera_pose(mer_a, attitude, altitude, np.array([5.0, -8.0]))
        requests.append(geometry.RectificationRequest(pose, geometry.ground_centre_m(pose, np.radians(60)), shield,
                                                      0.05 if shield is not None else 0.0))
    together = geometry.rectify_maps(requests, mer_a, 256, sample, 17, -sun, np.radians(4.3))
    for request, rect in zip(requests, together):
        alone = geometry.rectify_map(request.pose, mer_a, 256, sample, request.centre_m, 17, -sun, np.radians(4.3),
                                     request.heat_shield_m, request.heat_shield_half_angle_rad)
        for name in ("origin_m", "map_x", "map_y", "visible", "excluded_zone"):
            assert np.array_equal(getattr(rect, name), getattr(alone, name)), name
    assert any(rect.excluded_zone.any() for rect in together)          # a cone is in view: the test covers it


def test_upsample_reproduces_a_bilinear_field_exactly_across_column_chunks():
    """Catmull-Rom reproduces any linear function (its weights sum to 1 and have the right first moment).

    Eight channels make 8 x 256 = 2048 lines: the column pass runs over several chunks, and every pixel of every
    chunk must come out as the plane through the knots.
    """
    size, knots = 256, 17
    positions = geometry.knot_operator(size, knots)[0]
    channels = 8
    slopes = np.linspace(-0.3, 0.4, channels)
    values = (slopes[None, None, :] * positions[None, :, None] - 0.2 * positions[:, None, None]
              + np.arange(channels)[None, None, :])
    upsampled = geometry._upsample(size, knots, values)
    pixel = np.arange(size, dtype=float)
    expected = (slopes[:, None, None] * pixel[None, None, :] - 0.2 * pixel[None, :, None]
                + np.arange(channels)[:, None, None])
    assert upsampled.shape == (channels, size, size) and upsampled.dtype == np.float32
    assert np.abs(upsampled - expected).max() < 1e-3 * np.abs(expected).max()


def test_compiled_cone_cells_is_the_dilate_erode_definition():
    """``compiled.cone_cells`` gives the block of the numpy definition (a 4 x 4 max and min of each cell's knots)."""
    import cv2

    from dimes_velocity import compiled

    rng = np.random.default_rng(5)
    support = np.ones((4, 4), np.uint8)
    for trial in range(200):
        cosines = np.cos(rng.uniform(0.0, 0.3, (19, 19)) + (0.0 if trial % 2 else rng.uniform(0, 0.2)))
        level = float(np.cos(rng.uniform(0.0, 0.2)))
        cells = len(cosines) - 3
        highest = cv2.dilate(cosines, support, anchor=(0, 0))[:cells, :cells]
        lowest = cv2.erode(cosines, support, anchor=(0, 0))[:cells, :cells]
        possible = highest + 0.28125 * (highest - lowest) > level
        found, first_row, end_row, first_column, end_column = compiled.cone_cells(cosines, level, 0.28125)
        assert found == bool(possible.any())
        if found:
            rows, columns = np.flatnonzero(possible.any(axis=1)), np.flatnonzero(possible.any(axis=0))
            assert (first_row, end_row, first_column, end_column) == (rows[0], rows[-1] + 1, columns[0], columns[-1] + 1)


def test_compiled_inside_frame_is_the_four_comparisons():
    from dimes_velocity import compiled

    rng = np.random.default_rng(6)
    map_x = rng.uniform(-2.0, 258.0, (64, 64)).astype(np.float32)
    map_y = rng.uniform(-2.0, 258.0, (64, 64)).astype(np.float32)
    map_x[0, :4] = [0.0, 255.0, np.nextafter(np.float32(255.0), np.float32(300.0)), np.nan]
    inside = compiled.inside_frame(map_x, map_y, np.float32(255.0), np.float32(255.0))
    expected = (map_x >= 0) & (map_x <= 255) & (map_y >= 0) & (map_y <= 255)
    assert inside.dtype == np.uint8 and np.array_equal(inside.view(bool), expected)


def test_predicted_positions_are_the_numpy_trapezoid_bit_for_bit():
    """The Python-float trapezoid gives the bits of ``cumsum(0.5 (v[1:] + v[:-1]) diff(t))`` (its definition)."""
    rng = np.random.default_rng(14)
    for _ in range(2000):
        count = int(rng.integers(2, 6))
        times = np.cumsum(rng.uniform(0.1, 5.0, count)) + rng.uniform(-10.0, 10.0)
        velocities = rng.normal(size=(count, 3)) * 30.0
        images = tuple(ImageMeasurement(float(t), np.array([1.0, 0, 0, 0]), np.zeros(3), 2000.0, velocity)
                       for t, velocity in zip(times, velocities))
        steps = 0.5 * (velocities[1:, :2] + velocities[:-1, :2]) * np.diff(times)[:, None]
        expected = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        positions = geometry.predicted_positions_m(DescentMeasurements(images, np.array([0, 0, 1.0])))
        assert positions.shape == expected.shape and np.array_equal(positions.view(np.uint64), expected.view(np.uint64))
