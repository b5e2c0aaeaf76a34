"""Numerical stress of the one-call descent image renderer: attitude from nadir through 89 deg to
beyond the horizon (camera looking at the sky), altitude 10 m to 20 km, angular rates up to 360 deg/s,
zero-texture, black and saturating terrain, a sun near the horizon. Images, masks and diagnostics
must stay finite; the sky mask follows the horizon's closed form."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flight_interface.frames import quat_from_axis_angle, quat_to_matrix
from simulator.descent_image import render_descent_image
from simulator.scene.descent_profile import DescentProfile, constant_velocity_profile
from simulator.scene.terrain import Terrain

SUN = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
HALF_DIAGONAL_FOV = np.radians(31.5)      # MER: corner ray 31.5 deg from the boresight (with distortion)


def flat_terrain(value=0.2, size=400, mpp=60.0, texture=0.0, seed=0) -> Terrain:
    """A terrain strip 24 km square (covers the footprint up to ~20 km altitude at nadir)."""
    rng = np.random.default_rng(seed)
    values = value * (1.0 + texture * rng.standard_normal((size, size)))
    half = 0.5 * (size - 1) * mpp
    return Terrain(np.clip(values, 0.0, None).astype(np.float32), mpp, np.array([-half, half]),
                   np.radians(30.0), 0.0, np.radians(30.0), "stress")


TEXTURED = flat_terrain(texture=0.1)
FINE = flat_terrain(size=1600, mpp=3.0, texture=0.1, seed=1)     # 4.8 km at 3 m: sub-steps per terrain pixel


def check(result, camera):
    """Every output finite, in range, of the documented shape."""
    assert result.dn.shape == camera.binned_shape and result.dn.dtype == np.uint16
    assert result.dn.max() <= camera.electronics.max_dn
    full, blocks = (camera.height_px, camera.width_px), (camera.height_px // camera.binning_rows, camera.width_px)
    for field in (result.radiance.flush, result.radiance.exposure, result.radiance.transfer):
        assert field.shape in (full, blocks)    # smear fields (and a warped blurred exposure) may be per block
        assert np.all(np.isfinite(field)) and field.min() >= 0.0
    assert np.all(np.isfinite(result.image.expected_dn)) and np.all(np.isfinite(result.image.expected_charge_e))
    for mask in (result.sky_mask, result.outside_terrain_mask, result.heat_shield_mask):
        assert mask.dtype == bool and mask.shape == (camera.height_px, camera.width_px)
    d = result.diagnostics
    assert np.all(np.isfinite(d.footprint_m)) and np.all(np.isfinite(d.anti_sun_ground_m))
    assert d.anti_sun_pixel is None or np.all(np.isfinite(d.anti_sun_pixel))
    assert np.all(np.isfinite(d.camera_pose.ray_origin_m)) and np.all(np.isfinite(d.camera_pose.camera_to_world))
    assert all(np.all(np.isfinite(c)) for c in d.shadow_centres_m)
    assert np.isfinite(d.scene_ms) and np.isfinite(d.camera_ms)
    assert all(0 <= count <= 16 for count in d.substeps.values())


def tilted(tilt_rad, azimuth_rad=0.0):
    return quat_from_axis_angle(np.array([np.cos(azimuth_rad), np.sin(azimuth_rad), 0.0]), tilt_rad)


def expected_sky_fraction(camera, attitude):
    """Pixels whose world ray points at or above the horizon (independent of the renderer's grids)."""
    rays = camera.pixel_rays[::16, ::16] @ (quat_to_matrix(attitude) @ camera.camera_to_lander_matrix).T
    return float(np.mean(rays[..., 2] >= 0.0))


@settings(max_examples=12, deadline=None, derandomize=True)
@given(tilt_deg=st.floats(0.0, 180.0), azimuth=st.floats(0.0, 2 * np.pi), altitude_m=st.floats(10.0, 2e4))
def test_any_attitude_and_altitude_renders_finite_images_with_the_right_sky(mer_a, tilt_deg, azimuth, altitude_m):
    attitude = tilted(np.radians(tilt_deg), azimuth)
    profile = constant_velocity_profile([0.0, 0.0, altitude_m], [5.0, -3.0, -min(70.0, altitude_m)], attitude,
                                        0.5, [0.1])
    result = render_descent_image(TEXTURED, profile, mer_a, 0, SUN, None, np.random.default_rng(1))
    check(result, mer_a)
    assert abs(result.sky_mask.mean() - expected_sky_fraction(mer_a, result.diagnostics.pose.attitude_quat)) < 0.02
    if np.radians(tilt_deg) > np.pi / 2 + HALF_DIAGONAL_FOV:
        # looking at the sky: no ground, zero radiance, DN = offset + dark only
        assert result.sky_mask.all() and not result.radiance.exposure.any()
        assert result.dn.max() < 200


@pytest.mark.parametrize("tilt_deg", [60.0, 80.0, 89.0, 89.99, 90.0, 95.0, 121.5, 180.0])
def test_grazing_and_sky_views_are_finite(mer_a, tilt_deg):
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], tilted(np.radians(tilt_deg)), 1.0, [0.1])
    result = render_descent_image(TEXTURED, profile, mer_a, 0, SUN, None, np.random.default_rng(2))
    check(result, mer_a)
    fraction = expected_sky_fraction(mer_a, profile.attitude_quat[0])
    assert abs(result.sky_mask.mean() - fraction) < 0.02
    if tilt_deg >= 121.5:
        assert result.sky_mask.all()


@pytest.mark.parametrize("altitude_m", [10.0, 100.0, 2000.0, 20000.0])
def test_altitudes_from_10_m_to_20_km(mer_a, altitude_m):
    profile = constant_velocity_profile([0.0, 0.0, altitude_m], [20.0, 10.0, -min(75.0, 7.0 * altitude_m)],
                                        np.array([1.0, 0.0, 0.0, 0.0]), 0.2, [0.05])
    result = render_descent_image(TEXTURED, profile, mer_a, 0, SUN, None, np.random.default_rng(3))
    check(result, mer_a)
    assert not result.sky_mask.any()
    # 20 km: the nadir footprint (2 x 20 km x tan 22.7 deg = 16.7 km) still fits on the 24 km strip
    assert not result.outside_terrain_mask.any()
    assert 200 < result.dn.mean() < 4000


def rotating_profile(rate_deg_s, altitude_m=2000.0, axis=(1.0, 0.0, 0.0)) -> DescentProfile:
    time = np.array([0.45, 0.55])               # 36 deg at most between the samples (slerp's short arc)
    angle = np.radians(rate_deg_s) * (time - 0.5)
    attitude = np.stack([quat_from_axis_angle(np.array(axis), a) for a in angle])
    rate = np.radians(rate_deg_s) * np.array(axis)
    return DescentProfile(time, np.tile([0.0, 0.0, altitude_m], (2, 1)), np.zeros((2, 3)), attitude,
                          np.tile(rate, (2, 1)), np.zeros((2, 3)), None, np.array([0.5]), "rotating")


@settings(max_examples=6, deadline=None, derandomize=True)
@given(rate_deg_s=st.floats(0.0, 360.0), axis=st.sampled_from([(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]))
def test_angular_rates_up_to_360_deg_per_s(mer_a, rate_deg_s, axis):
    """At 360 deg/s the view turns 1.8 deg per 5.1 ms exposure (~40 image pixels): sub-steps stay
    capped at max_substeps and the blurred fields stay finite and bounded by the sharp ones."""
    profile = rotating_profile(rate_deg_s, axis=axis)
    result = render_descent_image(FINE, profile, mer_a, 0, SUN, None, np.random.default_rng(4))
    check(result, mer_a)
    assert not result.sky_mask.any()
    if axis != (0.0, 0.0, 1.0):
        # ground shift during the exposure (terrain pixels): between the nadir sweep h d and the
        # sweep at the 31.5 deg corner ray h (tan(c + d/2) - tan(c - d/2)); sub-steps = ceil, capped
        sweep = np.radians(rate_deg_s) * mer_a.timing.exposure_s
        height = 2000.0 - 0.5
        low = height * sweep / FINE.metres_per_pixel
        high = height * (np.tan(HALF_DIAGONAL_FOV + sweep / 2) - np.tan(HALF_DIAGONAL_FOV - sweep / 2)) / FINE.metres_per_pixel
        count = result.diagnostics.substeps["exposure"]
        lowest, highest = min(16, max(1, int(np.floor(low)))), min(16, int(np.ceil(high)) + 1)
        if result.radiance.exposure.shape == mer_a.binned_shape:   # warp-and-accumulate: 2^k >= the count
            assert count & (count - 1) == 0 and lowest <= count and count // 2 < highest
        else:
            assert lowest <= count <= highest


@pytest.mark.parametrize("value, texture", [(0.0, 0.0), (0.2, 0.0), (50.0, 0.0), (1e6, 0.0)])
def test_black_zero_texture_and_saturating_terrain(mer_a, value, texture):
    terrain = flat_terrain(value=value, texture=texture)
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], np.array([1.0, 0.0, 0.0, 0.0]), 1.0, [0.1])
    result = render_descent_image(terrain, profile, mer_a, 0, SUN, None, None)
    check(result, mer_a)
    if value == 0.0:
        assert not result.radiance.exposure.any() and result.dn.max() < 200
    if value >= 50.0:                           # I/F 50 and 1e6: every pixel saturates
        assert np.all(result.dn == mer_a.electronics.max_dn)


def test_sun_grazing_the_horizon_keeps_shadows_and_diagnostics_finite(mer_a):
    elevation = np.radians(0.01)
    sun = np.array([np.cos(elevation), 0.0, np.sin(elevation)])
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], np.array([1.0, 0.0, 0.0, 0.0]), 1.0, [0.1])
    result = render_descent_image(TEXTURED, profile, mer_a, 0, sun, None, np.random.default_rng(5))
    check(result, mer_a)
    assert result.diagnostics.anti_sun_pixel is None      # 11.5 km ... 23 000 km away along the ground


@pytest.mark.parametrize("sun", [np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 2.0]),
                                 np.array([np.nan, 0.0, 1.0])])
def test_sun_below_the_horizon_or_not_a_unit_vector_is_refused(mer_a, sun):
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], np.array([1.0, 0.0, 0.0, 0.0]), 1.0, [0.1])
    with pytest.raises(ValueError, match="sun"):
        render_descent_image(TEXTURED, profile, mer_a, 0, sun, None, None)


def test_zero_attitude_quaternion_is_refused(mer_a):
    with pytest.raises(ValueError, match="quaternion"):
        constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, -70.0], np.zeros(4), 1.0, [0.1])


def test_camera_below_the_ground_is_refused(mer_a):
    profile = constant_velocity_profile([0.0, 0.0, 0.2], [0.0, 0.0, 0.0], np.array([1.0, 0.0, 0.0, 0.0]), 1.0, [0.1])
    with pytest.raises(ValueError, match="altitude|ground"):
        render_descent_image(TEXTURED, profile, mer_a, 0, SUN, None, None)
