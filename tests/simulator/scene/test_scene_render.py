"""Heat shield, motion blur, and the one-call descent image renderer with its TOML config."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from config_tables.errors import ConfigError
from config_tables.models import parse
from config_tables.toml_file import load_toml
from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.descent_image import DescentImage, render_descent_image
from simulator.scene import blur_warp, heat_shield, motion_blur, periods, photometry, radiance
from simulator.scene.descent_profile import DescentProfile, constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
FOCAL_PX = 0.01467 / 12e-6
R1 = -0.01
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
SUN = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])


def textured_terrain(size=1600, mpp=3.0, seed=3) -> Terrain:
    rng = np.random.default_rng(seed)
    values = 0.2 + 0.03 * rng.standard_normal((size, size))
    half = 0.5 * (size - 1) * mpp
    return Terrain(values.astype(np.float32), mpp, np.array([-half, half]), np.radians(30), 0.0, np.radians(30), "tex")


def profile_with_heat_shield(offset_m) -> DescentProfile:
    base = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.1])
    shield = np.tile(np.array([0.0, 0.0, 2000.0]) + np.asarray(offset_m, dtype=float), (2, 1))
    return DescentProfile(base.time_s, base.position_m, base.velocity_mps, base.attitude_quat,
                          base.angular_rate_radps, base.wind_mps, shield, base.image_times_s, "with shield")


def test_heat_shield_on_axis_covers_the_predicted_pixel_count():
    config = SceneConfig().with_effects(shadows=False)
    axial = 150.0
    profile = profile_with_heat_shield([0.0, 0.0, -axial])
    field = radiance.radiance_at_pose(textured_terrain(), CAMERA, profile.pose(0.0), SUN, config)
    depth = heat_shield.cone_depth_m(5.3, np.radians(140.0))
    assert depth == pytest.approx(2.65 / np.tan(np.radians(70.0)))
    # the rim circle (radius 2.65 m) at (axial + camera offset 0.5 m - depth / 2) below the camera
    u = 2.65 / (axial - 0.5 - 0.5 * depth)
    radius_px = FOCAL_PX * u * (1.0 + R1 * u * u)
    predicted = np.pi * radius_px**2                       # ~1500 pixels
    count = np.count_nonzero(field.heat_shield)
    assert count == pytest.approx(predicted, rel=0.02)
    rows, cols = np.nonzero(field.heat_shield)
    assert rows.mean() == pytest.approx(511.5, abs=0.3) and cols.mean() == pytest.approx(511.5, abs=0.3)
    # black Kapton, Lambert-shaded: I/F = 0.07 cos(i) with i within 30 +- 20 deg of the facet normals
    # (inside the silhouette; its edge pixels are antialiased, a coverage-weighted mix with the ground)
    from scipy.ndimage import binary_erosion
    interior = binary_erosion(field.heat_shield)
    irradiance = photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au)
    values = field.radiance[interior] / (irradiance / np.pi)
    assert values.min() >= 0.07 * np.cos(np.radians(50.0)) - 1e-6
    assert values.max() <= 0.07 * np.cos(np.radians(10.0)) + 1e-6
    assert values.max() - values.min() > 0.02            # its own shading, not a flat disc
    assert np.all(field.radiance[interior] < 0.5 * np.median(field.radiance))
    # edge pixels lie between the shield and the ground they partly cover
    edge = field.heat_shield & ~interior
    assert np.all(field.radiance[edge] >= 0.07 * np.cos(np.radians(50.0)) * irradiance / np.pi - 1e-6)
    assert np.all(field.radiance[edge] <= field.radiance[~field.heat_shield].max())


def test_heat_shield_outside_the_view_is_not_drawn():
    profile = profile_with_heat_shield([75.0, 0.0, -140.0])    # 28 deg off axis: outside the 22.7 deg half FOV
    field = radiance.radiance_at_pose(textured_terrain(), CAMERA, profile.pose(0.0), SUN, SceneConfig())
    assert field.heat_shield is None
    inside = profile_with_heat_shield([50.0, 0.0, -200.0])     # 14 deg off axis: in view
    field = radiance.radiance_at_pose(textured_terrain(), CAMERA, inside.pose(0.0), SUN, SceneConfig())
    assert field.heat_shield is not None and field.heat_shield.any()
    cols = np.nonzero(field.heat_shield)[1]
    assert cols.mean() > 511.5 + 0.9 * FOCAL_PX * 50.0 / 200.0   # east of centre, where it should be


def rotating_profile(rate_deg_s: float) -> DescentProfile:
    """Level lander turning about its x axis at a constant rate (slerp between two samples)."""
    time = np.array([0.0, 1.0])
    angle = np.radians(rate_deg_s) * (time - 0.5)
    attitude = np.stack([quat_from_axis_angle([1.0, 0.0, 0.0], a) for a in angle])
    return DescentProfile(time, np.tile([0.0, 0.0, 2000.0], (2, 1)), np.zeros((2, 3)), attitude,
                          np.tile([np.radians(rate_deg_s), 0.0, 0.0], (2, 1)), np.zeros((2, 3)), None,
                          np.array([0.5]), "rotating")


def test_substep_count_follows_the_actual_image_shift():
    terrain = textured_terrain()
    config = SceneConfig().with_effects(warp_motion_blur=False)     # one rendered field per sub-pose
    still = periods.period_fields(terrain, CAMERA, rotating_profile(0.0), 0.5, SUN, config)
    assert still.shared and still.fields.flush is still.fields.exposure is still.fields.transfer

    rate = 60.0
    blurred = periods.period_fields(terrain, CAMERA, rotating_profile(rate), 0.5, SUN, config)
    # closed form: during the 5.1 ms exposure the sight line of the edge row (field angle theta_e, with
    # distortion) sweeps by rate * T; its ground point moves h (tan(theta_e + d) - tan(theta_e))
    height = 2000.0 - 0.5
    u_d = 511.5 / FOCAL_PX
    roots = np.roots([R1, 0.0, 1.0, -u_d])
    real = roots[np.abs(roots.imag) < 1e-12].real
    theta_edge = np.arctan(real[np.argmin(np.abs(real - u_d))])
    sweep = np.radians(rate) * CAMERA.timing.exposure_s
    ground_shift_px = height * (np.tan(theta_edge + sweep / 2) - np.tan(theta_edge - sweep / 2)) / terrain.metres_per_pixel
    assert blurred.substeps["exposure"] == int(np.ceil(ground_shift_px))
    assert blurred.substeps["flush"] == blurred.substeps["exposure"] == blurred.substeps["transfer"]
    assert not blurred.shared
    # the blurred exposure field is the mean of the sub-pose fields
    times = motion_blur.substep_times(0.5, 0.5 + CAMERA.timing.exposure_s, blurred.substeps["exposure"])
    profile = rotating_profile(rate)
    mean = np.mean([radiance.radiance_at_pose(terrain, CAMERA, profile.pose(t), SUN, config).radiance for t in times], axis=0)
    assert np.allclose(blurred.fields.exposure, mean, rtol=1e-5, atol=1e-4)
    # blur lowers the pixel-to-pixel contrast of a white-noise terrain
    assert np.std(np.diff(blurred.fields.exposure[400:600, 512])) < np.std(np.diff(still.fields.exposure[400:600, 512]))


@pytest.mark.parametrize("rate_deg_s", [60.0, 150.0])
def test_warped_blur_matches_the_sub_pose_integration(rate_deg_s):
    """Warp-and-accumulate (scene.blur_warp) against rendering every one of the same N sub-poses: the
    block means of the three period fields agree to 1.5 % RMS of the mean field (2 % for flush and
    transfer) on this white-noise terrain (every terrain pixel independent, the worst case for
    resampling: its pixel-to-pixel contrast is ~10 %); campaign terrain is ~0.1 % (docs/simulator.md)."""
    terrain = textured_terrain()
    profile = rotating_profile(rate_deg_s)
    warped = periods.period_fields(terrain, CAMERA, profile, 0.5, SUN, SceneConfig())
    count = warped.substeps["exposure"]
    assert count >= 4 and count & (count - 1) == 0                   # a power of two: recursive doubling
    assert warped.fields.exposure.shape == (256, 1024)               # warped at binned resolution
    exact_config = SceneConfig().with_effects(warp_motion_blur=False, warp_smear_fields=False)
    timing = CAMERA.timing
    windows = {"flush": (0.5 - timing.fast_flush_s, 0.5), "exposure": (0.5, 0.5 + timing.exposure_s),
               "transfer": (0.5 + timing.exposure_s, 0.5 + timing.exposure_s + timing.frame_transfer_s)}
    for period, (start, end) in windows.items():
        fields = [radiance.radiance_at_pose(terrain, CAMERA, profile.pose(t), SUN, exact_config).radiance
                  for t in motion_blur.substep_times(start, end, count)]
        exact = np.mean(fields, axis=0).reshape(256, 4, 1024).mean(axis=1)
        error = getattr(warped.fields, period) - exact
        rms = float(np.sqrt(np.mean(error[8:-8, 8:-8] ** 2)) / np.mean(exact))
        assert rms < (0.015 if period == "exposure" else 0.02), (period, rms)
        if period == "exposure":
            # the warps' resampling must not smooth away the texture the blur leaves (high-pass RMS against
            # the exact sub-poses; bilinear warps on block rows kept 82-85 % here, bicubic ones 94-98 %)
            def high_pass(field):
                return (field - cv2.blur(field.astype(np.float32), (9, 3)))[8:-8, 8:-8]
            kept = float(np.std(high_pass(warped.fields.exposure)) / np.std(high_pass(exact)))
            assert 0.9 < kept < 1.05, kept
    assert not warped.sky.any() and warped.exposure_centre.radiance.shape == (1024, 1024)
    again = periods.period_fields(terrain, CAMERA, profile, 0.5, SUN, SceneConfig())   # cached enlarged camera
    assert all(np.array_equal(getattr(again.fields, p), getattr(warped.fields, p)) for p in windows)


@pytest.mark.parametrize("count", [4, 8, 16, 64])
def test_warped_blur_leaves_are_the_exposure_sub_poses(count):
    """The doubling scheme's leaves (the rendered sub-pose N/2 moved by the steps of the bits of j XOR N/2,
    the last step backward) are the exposure's N sub-poses, each once, so their average is the exposure
    with no last warp; its time centre is the exposure mid-time."""
    windows = periods.period_windows(CAMERA, 0.5)
    plan = blur_warp._Plan(CAMERA, lambda time_s: None, windows, count)
    leaves = np.arange(plan.count)
    offsets = sum(((leaves ^ plan.base_index) >> level & 1) * plan.step_sub_poses(level) for level in range(plan.levels))
    assert np.array_equal(np.sort(plan.base_index + offsets), leaves)
    assert np.array_equal(plan.base_index + offsets, leaves)            # leaf j reads sub-pose j
    times = motion_blur.substep_times(*windows["exposure"], count)
    assert plan.base_s == times[count // 2]
    assert plan.average_centre_s == pytest.approx(np.mean(times), abs=1e-12)
    assert plan.average_centre_s == pytest.approx(CAMERA.timing.exposure_mid_time_s(0.5), abs=1e-12)


def test_render_descent_image_end_to_end_and_deterministic():
    terrain = textured_terrain()
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [10.0, 5.0, -72.0], LEVEL, 10.0, [1.0, 4.0, 7.75])
    first = render_descent_image(terrain, profile, CAMERA, 1, SUN, SceneConfig(), np.random.default_rng(11))
    again = render_descent_image(terrain, profile, CAMERA, 4.0, SUN, SceneConfig(), np.random.default_rng(11))
    assert isinstance(first, DescentImage)
    assert first.dn.shape == (256, 1024) and first.dn.dtype == np.uint16
    assert np.array_equal(first.dn, again.dn)                       # index 1 == time 4.0 s, same seed
    assert first.sky_mask.shape == (1024, 1024) and not first.sky_mask.any()
    assert not first.heat_shield_mask.any() and not first.diagnostics.heat_shield_visible
    assert first.diagnostics.exposure_start_s == 4.0
    assert first.diagnostics.pose.position_m[2] == pytest.approx(2000.0 - 72.0 * 4.0)
    assert 100 < first.dn.mean() < 4000
    noise_free = render_descent_image(terrain, profile, CAMERA, 1, SUN, SceneConfig(), None)
    assert np.array_equal(noise_free.dn, np.round(noise_free.image.expected_dn).astype(np.uint16))
    binned = first.binned_mask(first.sky_mask, CAMERA.binning_rows)
    assert binned.shape == (256, 1024)
    with pytest.raises(IndexError, match="image index"):
        render_descent_image(terrain, profile, CAMERA, 3, SUN)


def test_scene_effects_switch_off_cleanly():
    half = 0.5 * 1599 * 3.0
    terrain = Terrain(np.full((1600, 1600), 0.2, np.float32), 3.0, np.array([-half, half]), np.radians(30), 0.0,
                      np.radians(30), "uniform")
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.5])
    full = render_descent_image(terrain, profile, CAMERA, 0, SUN, SceneConfig(), None)
    plain = SceneConfig().with_effects(photometric_correction=False, spectral_ratio=False)
    flat = render_descent_image(terrain, profile, CAMERA, 0, SUN, plain, None)
    # without photometry and spectral ratio the radiance is the MOC I/F times E / pi everywhere
    # (the shadows fall 1.2 km away, outside the field of view, for a sun 30 deg from the zenith)
    irradiance = photometry.solar_band_irradiance_w_m2_um(1.524)
    assert np.allclose(flat.radiance.exposure, 0.2 * irradiance / np.pi, rtol=1e-5)
    assert full.diagnostics.anti_sun_pixel is None
    # with them, the centre sees the MOC geometry (ratio 1) times the spectral ratio, the rest varies
    assert full.radiance.exposure[511:513, 511:513].mean() == pytest.approx(
        0.2 * irradiance / np.pi * SceneConfig().spectral_ratio, rel=2e-3)
    assert np.ptp(full.radiance.exposure) > 0.05 * full.radiance.exposure.mean()


def test_scene_config_from_toml(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text("[scene]\nparachute_distance_m = 25.0\nheat_shield_cone_angle_deg = 120.0\n"
                    "[scene.effects]\nshadows = false\n[scene.camera_effects]\ndark_current_scale = 2.0\n")
    config = parse(SceneConfig, load_toml(path)["scene"], path, "scene")
    assert config.parachute_distance_m == 25.0
    assert config.heat_shield_cone_angle_rad == pytest.approx(np.radians(120.0))
    assert config.effects.shadows is False and config.effects.heat_shield is True
    assert config.camera_effects.dark_current_scale == 2.0
    assert config.heat_shield_diameter_m == 5.3

    path.write_text("[scene]\nshadow_diffuse_fraction = 1.5\n")
    with pytest.raises(ConfigError, match=r"scene.toml: scene.shadow_diffuse_fraction = 1.5 is out of range"):
        parse(SceneConfig, load_toml(path)["scene"], path, "scene")
    path.write_text("[scene.effects]\nshadow = false\n")
    with pytest.raises(ConfigError, match="scene.effects.shadow is not a known field"):
        parse(SceneConfig, load_toml(path)["scene"], path, "scene")


def test_batched_image_shifts_equal_one_projection_per_pair():
    """The shifts of several pose pairs, projected together, are those of one pair at a time through
    ground_mapping.world_to_pixels (bit for bit); a level translation by d metres moves every pixel's
    ground point by d, the whole shift for a terrain pixel so coarse that the ground unit is the smaller."""
    from simulator.scene import ground_mapping
    drifting = constant_velocity_profile([0.0, 0.0, 1500.0], [12.0, -5.0, 0.0], LEVEL, 1.0, [0.5])
    descending = constant_velocity_profile([0.0, 0.0, 1500.0], [12.0, -5.0, -60.0], LEVEL, 1.0, [0.5])
    turning = rotating_profile(90.0)
    poses = [ground_mapping.camera_pose(CAMERA, profile.pose(t)) for profile in (drifting, turning, descending)
             for t in (0.40, 0.45, 0.50, 0.55)]
    pairs = [(poses[0], poses[3]), (poses[0], poses[1]), (poses[1], poses[2]), (poses[4], poses[7]),
             (poses[5], poses[6]), (poses[8], poses[11]), (poses[2], poses[2])]
    pixels = motion_blur.sample_pixels(CAMERA)
    terrain_mpp = 0.3
    batched = motion_blur.image_shifts(CAMERA, pairs, terrain_mpp, pixels)
    for (start, end), shift in zip(pairs, batched):
        ground_start, hit_start = ground_mapping.ground_points(CAMERA, start, pixels)
        ground_end, hit_end = ground_mapping.ground_points(CAMERA, end, pixels)
        reprojected, in_front = ground_mapping.world_to_pixels(CAMERA, end, ground_start)
        image_px = np.where(in_front, np.linalg.norm(reprojected - pixels, axis=-1), np.inf)
        expected = np.minimum(np.linalg.norm(ground_end - ground_start, axis=-1) / terrain_mpp, image_px)
        assert shift == float(np.max(expected[hit_start & hit_end]))
        assert shift == motion_blur.image_shift(CAMERA, start, end, terrain_mpp, pixels)
    assert batched[-1] == 0.0          # no motion, no shift
    metres = (0.55 - 0.40) * np.hypot(12.0, -5.0)
    coarse = motion_blur.image_shifts(CAMERA, pairs[:1], 1e3, pixels)[0]
    assert coarse == pytest.approx(metres / 1e3, rel=1e-9)
