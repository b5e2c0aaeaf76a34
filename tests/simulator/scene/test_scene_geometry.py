"""Scene geometry against closed forms: ground sampling distance, image shift, horizon, footprint."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.scene import ground_mapping, radiance, resample
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
FOCAL_PX = 0.01467 / 12e-6
CENTRE_PX = 511.5
R0, R1 = 0.0, -0.01          # mer_a.toml radial distortion
ALTITUDE_M = 2000.0
CAMERA_OFFSET_M = 0.5        # camera 0.5 m below the lander origin (mer_a.toml mounting)
SUN = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def undistorted_tangent(distorted: float) -> float:
    """Solve u (1 + R0 + R1 u^2) = u_d (the CAHVOR radial model) with numpy's polynomial roots."""
    roots = np.roots([R1, 0.0, 1.0 + R0, -distorted])
    real = roots[np.abs(roots.imag) < 1e-12].real
    return float(real[np.argmin(np.abs(real - distorted))])


def distorted_column(east_m: float, height_m: float) -> float:
    """Column of a ground point on the centre row of a nadir camera (closed form, forward model)."""
    u = east_m / height_m
    return CENTRE_PX + FOCAL_PX * u * (1.0 + R0 + R1 * u * u)


def uniform_terrain(value=0.2, size=1600, mpp=3.0, incidence_deg=30.0) -> Terrain:
    half = 0.5 * (size - 1) * mpp
    return Terrain(np.full((size, size), value, np.float32), mpp, np.array([-half, half]),
                   np.radians(incidence_deg), 0.0, np.radians(incidence_deg), "uniform")


def textured_terrain(size=1600, mpp=3.0, seed=5) -> Terrain:
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), 2.0)
    half = 0.5 * (size - 1) * mpp
    return Terrain(0.2 + 0.05 * noise / noise.std(), mpp, np.array([-half, half]), np.radians(30), 0.0,
                   np.radians(30), "textured")


def nadir_pose(altitude_m=ALTITUDE_M):
    profile = constant_velocity_profile([0.0, 0.0, altitude_m], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.0])
    return profile.pose(0.0)


@pytest.mark.parametrize("step", [16, 0])
def test_nadir_gsd_at_centre_and_edge_matches_cahvor(step):
    cam = ground_mapping.camera_pose(CAMERA, nadir_pose())
    gmap = ground_mapping.map_to_ground_grid(CAMERA, cam, (0.0, 0.0), 1.0, step)
    height = ALTITUDE_M - CAMERA_OFFSET_M
    rows = slice(511, 513)   # the two rows straddling the optical axis
    centre_gsd = np.mean(gmap.col[rows, 512] - gmap.col[rows, 511])
    assert centre_gsd == pytest.approx(height / FOCAL_PX / (1.0 + R0), rel=2e-4)
    edge_gsd = np.mean(gmap.col[rows, 1] - gmap.col[rows, 0])
    predicted_edge = height * (undistorted_tangent(511.5 / FOCAL_PX) - undistorted_tangent(510.5 / FOCAL_PX))
    assert edge_gsd == pytest.approx(predicted_edge, rel=1e-3)
    assert edge_gsd > 1.003 * centre_gsd   # barrel distortion (1 - 3 R1 u^2): coarser at the edge
    # north is up: rows increase southward
    assert np.mean(gmap.row[600, 500:520] - gmap.row[599, 500:520]) == pytest.approx(centre_gsd, rel=1e-3)


def test_grating_zero_crossings_land_on_predicted_columns():
    """A 30 m east-west sinusoid seen at nadir: every zero crossing on the centre row sits where the
    CAHVOR forward model puts it (mapping + bilinear resampling end to end)."""
    mpp, period, size = 3.0, 30.0, 1600
    half = 0.5 * (size - 1) * mpp
    east = -half + mpp * np.arange(size)
    grating = (0.2 + 0.05 * np.sin(2 * np.pi * east / period)).astype(np.float32)
    terrain = Terrain(np.tile(grating, (size, 1)), mpp, np.array([-half, half]), np.radians(30), 0.0,
                      np.radians(30), "grating")
    config = SceneConfig().with_effects(photometric_correction=False, shadows=False)
    field = radiance.radiance_at_pose(terrain, CAMERA, nadir_pose(), SUN, config).radiance
    profile = field[510:514].mean(axis=0) - field[510:514].mean()
    sign = np.sign(profile)
    index = np.nonzero(sign[:-1] * sign[1:] < 0)[0]
    measured = index + profile[index] / (profile[index] - profile[index + 1])
    height = ALTITUDE_M - CAMERA_OFFSET_M
    crossings_m = 0.5 * period * np.arange(-60, 61)
    predicted = np.array([distorted_column(x, height) for x in crossings_m])
    predicted = predicted[(predicted > 2) & (predicted < 1021)]
    nearest = np.array([measured[np.argmin(np.abs(measured - p))] for p in predicted])
    assert len(predicted) > 100
    assert np.max(np.abs(nearest - predicted)) < 0.1


def test_ten_metres_per_second_shifts_image_by_predicted_pixels():
    """10 m/s east for the time that closed form says moves the image 6 px: the fields agree after a
    6-column shift, and a sub-pixel scan finds its best match at 6.00 px."""
    terrain = textured_terrain()
    gsd_m = (ALTITUDE_M - CAMERA_OFFSET_M) / (FOCAL_PX * (1.0 + R0))
    elapsed_s = 6.0 * gsd_m / 10.0
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [10.0, 0.0, 0.0], LEVEL, 2.0, [0.0, 1.0])
    config = SceneConfig().with_effects(photometric_correction=False, shadows=False)
    first = radiance.radiance_at_pose(terrain, CAMERA, profile.pose(0.0), SUN, config).radiance
    second = radiance.radiance_at_pose(terrain, CAMERA, profile.pose(elapsed_s), SUN, config).radiance
    centre = first[384:640, 390:646]
    candidates = np.arange(5.80, 6.2001, 0.01)
    misfit = [np.std(cv2.warpAffine(second, np.float32([[1, 0, s], [0, 1, 0]]), (1024, 1024),
                                    flags=cv2.INTER_CUBIC)[384:640, 390:646] - centre) for s in candidates]
    assert candidates[int(np.argmin(misfit))] == pytest.approx(6.0, abs=0.015)  # moving east: scene slides left
    residual = {shift: np.std(second[384:640, 390 - shift:646 - shift] - centre) for shift in (5, 6, 7)}
    assert residual[6] < 0.05 * np.std(centre)
    assert residual[6] < 0.3 * min(residual[5], residual[7])


def test_pose_past_horizon_gives_masked_sky_and_no_nan():
    tilt = np.radians(80.0)   # boresight 80 deg from nadir toward north: the top rows see the sky
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0],
                                        quat_from_axis_angle([1.0, 0.0, 0.0], tilt), 1.0, [0.0])
    terrain = textured_terrain()
    field = radiance.radiance_at_pose(terrain, CAMERA, profile.pose(0.0), SUN, SceneConfig())
    assert np.all(np.isfinite(field.radiance))
    assert field.sky.any() and not field.sky.all()
    assert np.all(field.radiance[field.sky] == 0.0)
    assert not np.any(field.outside & field.sky)
    # horizon on the centre column: the ray 10 deg above the boresight (closed form with distortion)
    u = np.tan(np.pi / 2 - tilt)
    horizon_row = CENTRE_PX - FOCAL_PX * u * (1.0 + R0 + R1 * u * u)
    first_ground_row = int(np.argmax(~field.sky[:, 512]))
    assert abs(first_ground_row - horizon_row) <= 1.0
    # the ground near the horizon is kilometres away, beyond the 4.8 km strip: flagged, not garbage
    assert field.outside.any()
    assert np.all(field.radiance[field.outside] > 0)


def test_outside_strip_is_flagged_exactly():
    terrain = uniform_terrain(size=300)   # 900 m strip, smaller than the 1.7 km footprint
    field = radiance.radiance_at_pose(terrain, CAMERA, nadir_pose(), SUN,
                                   SceneConfig().with_effects(photometric_correction=False, shadows=False))
    pixels = np.stack(np.meshgrid(np.arange(0, 1024, 37.0), np.arange(0, 1024, 41.0)), axis=-1).reshape(-1, 2)
    points, hit = ground_mapping.ground_points(CAMERA, field.camera_pose, pixels)
    west, east, south, north = terrain.extent_m
    outside = (points[:, 0] < west) | (points[:, 0] > east) | (points[:, 1] < south) | (points[:, 1] > north)
    near_edge = (np.abs(points[:, 0] - west) < 2) | (np.abs(points[:, 0] - east) < 2) | \
                (np.abs(points[:, 1] - south) < 2) | (np.abs(points[:, 1] - north) < 2)
    flagged = field.outside[pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
    assert np.array_equal(flagged[~near_edge], outside[~near_edge])
    assert outside.any() and (~outside).any()
    assert np.all(np.isfinite(field.radiance))


def test_coarse_ray_grid_matches_exact_rays_to_hundredth_of_terrain_pixel():
    tilt = quat_from_axis_angle([0.6, 0.8, 0.0], np.radians(30.0))
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], tilt, 1.0, [0.0])
    cam = ground_mapping.camera_pose(CAMERA, profile.pose(0.0))
    coarse = ground_mapping.map_to_ground_grid(CAMERA, cam, (-2400.0, 2400.0), 3.0, 16)
    exact = ground_mapping.map_to_ground_grid(CAMERA, cam, (-2400.0, 2400.0), 3.0, 0)
    error = np.hypot(coarse.col - exact.col, coarse.row - exact.row)
    assert np.max(error) < 0.02


def test_footprint_crop_holds_every_ground_point():
    terrain = uniform_terrain()
    cam = ground_mapping.camera_pose(CAMERA, nadir_pose())
    footprint, hit = ground_mapping.footprint_m(CAMERA, cam)
    rows, cols = terrain.world_to_pixel(footprint[:, 0], footprint[:, 1])
    crop = resample.footprint_crop(terrain, cols, rows, bool(hit.all()))
    gmap = ground_mapping.map_to_ground_grid(CAMERA, cam, tuple(terrain.origin_m), terrain.metres_per_pixel, 16)
    assert crop.col0 <= gmap.col.min() - 1 and gmap.col.max() + 1 <= crop.col1 - 1
    assert crop.row0 <= gmap.row.min() - 1 and gmap.row.max() + 1 <= crop.row1 - 1
    # the crop is the footprint, not the whole strip (1.7 km of a 4.8 km terrain)
    assert (crop.col1 - crop.col0) < 0.4 * terrain.shape[1]


def test_exact_map_with_phase_cosines_matches_the_world_rays():
    # the exact map runs strip by strip and hands over the phase cosines it computed with the map: each
    # must be the per-pixel value of the world ray (float64 closed form), and asking for the cosines must
    # leave the map itself unchanged (also with the sky in view: the horizon at the top rows)
    for tilt_deg in (30.0, 80.0):
        tilt = quat_from_axis_angle([0.6, 0.8, 0.0] if tilt_deg < 45 else [1.0, 0.0, 0.0], np.radians(tilt_deg))
        profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], tilt, 1.0, [0.0])
        cam = ground_mapping.camera_pose(CAMERA, profile.pose(0.0))
        plain = ground_mapping.map_to_ground_grid(CAMERA, cam, (-2400.0, 2400.0), 3.0, 0)
        plain_col, plain_row, plain_sky = plain.col.copy(), plain.row.copy(), plain.sky.copy()
        with_phase = ground_mapping.map_to_ground_grid(CAMERA, cam, (-2400.0, 2400.0), 3.0, 0, phase_sun_world=SUN)
        assert np.array_equal(with_phase.col, plain_col) and np.array_equal(with_phase.row, plain_row)
        assert np.array_equal(with_phase.sky, plain_sky) and with_phase.any_sky == (tilt_deg > 45)
        world_rays = CAMERA.pixel_rays @ cam.camera_to_world.T
        cos_emission, cos_phase = ground_mapping.view_cosines(CAMERA, cam, with_phase, SUN)
        assert np.max(np.abs(cos_phase - (-world_rays @ SUN))) < 1e-6
        assert np.max(np.abs(cos_emission + world_rays[..., 2])) < 1e-6
        assert with_phase.cos_phase is None       # handed over once: a second call recomputes
        _, again = ground_mapping.view_cosines(CAMERA, cam, with_phase, SUN)
        assert np.max(np.abs(again - (-world_rays @ SUN))) < 1e-6


@pytest.mark.parametrize("window", [(0, 1024, 0, 1024), (300, 345, 500, 546), (1000, 1024, 0, 7), (5, 6, 7, 8)])
def test_node_window_interpolation_reproduces_an_affine_field_and_the_full_upsample(window):
    """Bilinear interpolation reproduces an affine field exactly: every window of it reads the field's values at
    its pixels, and agrees with the full-frame upsample (cv2.resize) on the window; channels stay separate."""
    from simulator.scene.node_grid import interpolate_nodes_window, node_positions, upsample_nodes

    step = 16
    cols, rows = np.meshgrid(node_positions(1024, step), node_positions(1024, step))
    nodes = np.stack([3.0 + 0.25 * cols - 0.5 * rows, -1.0 + 0.125 * rows], axis=-1)
    row0, row1, col0, col1 = window
    got = interpolate_nodes_window(nodes, step, row0, row1, col0, col1)
    pixel_cols, pixel_rows = np.meshgrid(np.arange(col0, col1), np.arange(row0, row1))
    want = np.stack([3.0 + 0.25 * pixel_cols - 0.5 * pixel_rows, -1.0 + 0.125 * pixel_rows], axis=-1)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-4)
    full = upsample_nodes(nodes, step, 1024, 1024)[row0:row1, col0:col1]
    np.testing.assert_allclose(got, full, rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(interpolate_nodes_window(nodes[..., 1], step, row0, row1, col0, col1), got[..., 1])
    assert interpolate_nodes_window(nodes, step, row0, row0, col0, col1).shape == (0, col1 - col0, 2)
