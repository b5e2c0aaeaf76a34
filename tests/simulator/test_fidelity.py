"""Fidelity shortcuts against exact answers: smear-field warping."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.descent_image import render_descent_image
from simulator.fields import block_means
from simulator.scene import ground_mapping, periods, radiance, smear_warp
from simulator.scene.descent_profile import DescentProfile, constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[2]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
SUN = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
ALTITUDE_M = 2000.0


def smooth_terrain(size=1800, mpp=3.0, seed=5) -> Terrain:
    """Band-limited texture (correlation ~3 terrain px) so bilinear resampling is nearly exact."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal((size, size))
    spectrum = np.fft.rfft2(noise)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    smooth = np.fft.irfft2(spectrum * np.exp(-(fx**2 + fy**2) / (2 * 0.06**2)), s=(size, size))
    values = 0.2 + 0.03 * smooth / smooth.std()
    half = 0.5 * (size - 1) * mpp
    return Terrain(values.astype(np.float32), mpp, np.array([-half, half]), np.radians(30), 0.0, np.radians(30), "smooth")


def turning_profile(rate_deg_s: float = 40.0) -> DescentProfile:
    """Descending at 72 m/s with 25 m/s drift while turning about the lander x axis."""
    time = np.array([0.0, 1.0])
    attitude = np.stack([quat_from_axis_angle([1.0, 0.0, 0.0], np.radians(rate_deg_s) * (t - 0.5)) for t in time])
    velocity = np.array([25.0, -15.0, -72.0])
    position = np.array([0.0, 0.0, ALTITUDE_M]) + (time - 0.5)[:, None] * velocity
    return DescentProfile(time, position, np.tile(velocity, (2, 1)), attitude,
                          np.tile([np.radians(rate_deg_s), 0.0, 0.0], (2, 1)), np.zeros((2, 3)), None,
                          np.array([0.5]), "turning")


def test_flow_of_a_translating_nadir_camera_is_the_ground_shift_over_the_gsd():
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [60.0, 0.0, 0.0], LEVEL, 1.0, [0.5])
    source = ground_mapping.camera_pose(CAMERA, profile.pose(0.5))
    target = ground_mapping.camera_pose(CAMERA, profile.pose(0.51))
    flow = smear_warp.flow_map(CAMERA, source, target)
    assert flow is not None
    grid = np.stack(np.meshgrid(np.arange(CAMERA.width_px), np.arange(CAMERA.height_px)), axis=-1)
    shift = flow - grid
    # at the principal point the camera moved 0.6 m over 2000 m: 0.6/2000 rad = f * 0.6/2000 pixels
    focal_px = 0.01467 / 12e-6
    centre = shift[511:513, 511:513].reshape(-1, 2).mean(axis=0)
    assert abs(np.hypot(*centre) - focal_px * 0.6 / ALTITUDE_M) < 2e-3
    # the ground point seen by a target pixel projects to the flow position in the source image
    pixels = np.array([[100.0, 900.0], [800.0, 200.0], [512.0, 512.0]])
    points, hit = ground_mapping.ground_points(CAMERA, target, pixels)
    expected, _ = ground_mapping.world_to_pixels(CAMERA, source, points)
    got = flow[pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
    assert hit.all() and np.abs(got - expected).max() < 0.01


def test_block_flow_is_the_pixel_flow_at_block_centres_in_block_units():
    profile = turning_profile()
    source = ground_mapping.camera_pose(CAMERA, profile.pose(0.5))
    target = ground_mapping.camera_pose(CAMERA, profile.pose(0.506))
    pixel_flow = smear_warp.flow_map(CAMERA, source, target)
    block_flow = smear_warp.flow_map(CAMERA, source, target, block_rows=4)
    assert block_flow.shape == (256, 1024, 2)
    # block k is centred on pixel row 4k + 1.5: the mean of the pixel flow of rows 4k+1 and 4k+2
    centre = 0.5 * (pixel_flow[1::4] + pixel_flow[2::4])
    assert np.abs(block_flow[..., 0] - centre[..., 0]).max() < 0.02
    assert np.abs(block_flow[..., 1] - (centre[..., 1] - 1.5) / 4).max() < 0.02 / 4


def test_block_mean_smear_fields_give_the_same_charge_as_block_constant_pixel_fields():
    from simulator.detector.camera_chain import CameraEffects, render_image
    from simulator.fields import RadianceFields

    rng = np.random.default_rng(4)
    blocks = {period: (20.0 + 5.0 * rng.random((256, 1024))).astype(np.float32) for period in ("flush", "transfer")}
    exposure = (20.0 + 5.0 * rng.random((1024, 1024))).astype(np.float32)
    quiet = CameraEffects(shot_noise=False, read_noise=False)
    per_pixel = render_image(CAMERA, RadianceFields(np.repeat(blocks["flush"], 4, axis=0), exposure,
                                                    np.repeat(blocks["transfer"], 4, axis=0)),
                             np.random.default_rng(0), quiet)
    per_block = render_image(CAMERA, RadianceFields(blocks["flush"], exposure, blocks["transfer"]),
                             np.random.default_rng(0), quiet)
    assert np.allclose(per_block.expected_charge_e, per_pixel.expected_charge_e, rtol=2e-5)


def test_flow_is_refused_when_the_horizon_is_in_view():
    tilted = np.array([np.cos(np.radians(40.0)), np.sin(np.radians(40.0)), 0.0, 0.0])  # 80 deg off nadir
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], tilted, 1.0, [0.5])
    pose = ground_mapping.camera_pose(CAMERA, profile.pose(0.5))
    assert smear_warp.flow_map(CAMERA, pose, pose) is None


def test_warped_smear_fields_match_rendered_ones_in_column_sums():
    terrain = smooth_terrain()
    profile = turning_profile()
    exact_config = SceneConfig().with_effects(warp_smear_fields=False, share_still_fields=False)
    warped_config = SceneConfig().with_effects(share_still_fields=False)
    exact = periods.period_fields(terrain, CAMERA, profile, 0.5, SUN, exact_config)
    warped = periods.period_fields(terrain, CAMERA, profile, 0.5, SUN, warped_config)
    assert warped.fields.exposure is not warped.fields.flush
    exposure_blocks = block_means(warped.fields.exposure, CAMERA.binning_rows)
    for period in ("flush", "transfer"):
        # the warped smear fields are block means (256, 1024): compare with the exact field's
        reference = block_means(getattr(exact.fields, period), CAMERA.binning_rows)
        fast = getattr(warped.fields, period)
        assert fast.shape == (CAMERA.height_px // CAMERA.binning_rows, CAMERA.width_px)
        interior = (slice(2, -2), slice(8, -8))
        texture = reference[interior].std()
        assert np.abs(fast[interior] - reference[interior]).mean() < 0.05 * texture
        # (the exposure field itself is far off: the scene moved by pixels meanwhile)
        assert np.abs(exposure_blocks[interior] - reference[interior]).mean() > 0.2 * texture
        # smear sees column sums: agree to 1e-3 of the column sum
        sums_exact = reference[interior].sum(axis=0)
        assert np.abs(fast[interior].sum(axis=0) - sums_exact).max() < 1e-3 * sums_exact.mean()


def test_warped_smear_changes_the_expected_image_by_far_less_than_half_a_dn():
    terrain = smooth_terrain()
    profile = turning_profile()
    exact = render_descent_image(terrain, profile, CAMERA, 0, SUN,
                                 SceneConfig().with_effects(warp_smear_fields=False)).image.expected_dn
    fast = render_descent_image(terrain, profile, CAMERA, 0, SUN, SceneConfig()).image.expected_dn
    assert np.sqrt(np.mean((fast - exact) ** 2)) < 0.1


def test_pixel_area_filter_is_the_exact_box_mean_of_a_quadratic():
    rows, cols = np.mgrid[0:64, 0:64].astype(np.float64)
    field = (0.3 * (cols - 20.0) ** 2 + 0.1 * (rows - 40.0) ** 2 + 2.0 * cols).astype(np.float32)
    # mean of a x^2 over [c - 1/2, c + 1/2] is a (c^2 + 1/12): the point value plus a / 12 per axis
    box_mean = field + (0.3 + 0.1) / 12.0
    filtered = radiance.pixel_area_average(field)
    assert np.allclose(filtered[1:-1, 1:-1], box_mean[1:-1, 1:-1], rtol=0, atol=2e-3)


@pytest.mark.slow
def test_supersampled_pixel_on_a_step_edge_reads_its_coverage():
    """A bright/dark step on the ground along a north line: the pixel the edge crosses reads the mean
    weighted by the fraction of its 3 x 3 sub-samples on each side."""
    size, mpp = 1800, 3.0
    values = np.full((size, size), 0.1, dtype=np.float32)
    values[:, size // 2:] = 0.3
    half = 0.5 * (size - 1) * mpp
    terrain = Terrain(values, mpp, np.array([-half, half]), np.radians(30), 0.0, np.radians(30), "step")
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.5])
    base = SceneConfig().with_effects(shadows=False, heat_shield=False, photometric_correction=False,
                                      spectral_ratio=False, coarse_ray_grid=False, pixel_area_filter=False)
    point = radiance.radiance_at_pose(terrain, CAMERA, profile.pose(0.5), SUN, base).radiance
    fine = radiance.radiance_at_pose(terrain, CAMERA, profile.pose(0.5), SUN, base.with_fields(supersample=3)).radiance
    row = point[512]
    low, high = row.min(), row.max()
    # away from the edge (flat on both sides, bilinear ramp is one terrain pixel wide) nothing changes
    flat = (np.abs(row - low) < 1e-6 * high) | (np.abs(row - high) < 1e-6 * high)
    flat &= np.convolve(flat, np.ones(5), mode="same") == 5
    assert np.allclose(fine[512][flat], row[flat], rtol=1e-5)
    # supersampling averages the ramp: the mean across the edge is conserved to the sub-sample error
    edge = slice(int(np.argmax(row > low + 1e-3 * high)) - 3, int(np.argmax(row >= high - 1e-3 * high)) + 4)
    assert abs(fine[512][edge].sum() - row[edge].sum()) < 0.02 * (high - low)


def test_presets_order_cost_and_unknown_names_are_refused():
    import pytest

    from simulator.fidelity import PRESETS
    from simulator.scene_config import preset_config

    assert PRESETS == ("reference", "high", "default", "fast")
    reference, default = preset_config("reference"), preset_config("default")
    assert reference.supersample == 3 and reference.camera_effects.exact_poisson
    assert not reference.effects.coarse_ray_grid and not reference.effects.warp_smear_fields
    assert default == SceneConfig()                    # the default preset is the nominal configuration
    with pytest.raises(ValueError, match="allowed: reference, high, default, fast"):
        preset_config("ultra")


def test_heat_shield_edges_read_their_pixel_area_mean():
    """Antialiased silhouette (3 x 3 edge samples) against the 3 x 3 supersampled render: edge pixels
    agree to a small fraction of the shield/ground contrast (a hard edge errs by up to the whole of it;
    the reference's own samples must be points, not antialiased again)."""

    terrain = smooth_terrain()
    base = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.1])
    shield = np.tile([20.0, 10.0, ALTITUDE_M - 150.0], (2, 1))
    profile = DescentProfile(base.time_s, base.position_m, base.velocity_mps, base.attitude_quat,
                             base.angular_rate_radps, base.wind_mps, shield, base.image_times_s, "shield")
    config = SceneConfig().with_effects(shadows=False, coarse_ray_grid=False, pixel_area_filter=False)
    pose = profile.pose(0.1)
    once = radiance.radiance_at_pose(terrain, CAMERA, pose, SUN, config)
    fine = radiance.radiance_at_pose(terrain, CAMERA, pose, SUN, config.with_fields(supersample=3))
    from scipy.ndimage import binary_dilation, binary_erosion
    edge = binary_dilation(once.heat_shield) & ~binary_erosion(once.heat_shield)
    contrast = np.median(once.radiance[~once.heat_shield]) - np.median(once.radiance[binary_erosion(once.heat_shield)])
    error = np.abs(once.radiance[edge] - fine.radiance[edge])
    assert edge.sum() > 100 and contrast > 0
    assert np.sqrt(np.mean(error ** 2)) < 0.01 * contrast     # (5 % if the reference's samples were blurred)


def test_fidelity_preset_from_toml_with_explicit_overrides(tmp_path):
    import pytest

    from config_tables.errors import ConfigError
    from config_tables.models import parse
    from config_tables.toml_file import load_toml
    from simulator.scene_config import SceneConfig

    path = tmp_path / "scene.toml"
    path.write_text('[scene]\nfidelity = "reference"\nsupersample = 2\n')
    config = parse(SceneConfig, load_toml(path)["scene"], path, "scene")
    assert config.supersample == 2 and config.camera_effects.exact_poisson
    assert not config.effects.warp_smear_fields
    path.write_text('[scene]\nfidelity = "ultra"\n')
    with pytest.raises(ConfigError, match=r"scene\.fidelity.*allowed: reference, high, default, fast"):
        parse(SceneConfig, load_toml(path)["scene"], path, "scene")


def test_binned_render_camera_row_k_sees_the_centre_of_block_k():
    """CAHVOR V' = (V - 1.5 A) / 4: a world point on row r of the camera is on row (r - 1.5) / 4 of the
    block-centre camera, on the same column (fast preset's binned_render)."""
    from flight_interface import cahvor
    from simulator.descent_image import binned_render_camera

    binned = binned_render_camera(CAMERA)
    assert (binned.height_px, binned.width_px, binned.binning_rows) == (256, 1024, 1)
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), np.ones(50)])
    full, _ = cahvor.project(CAMERA.model, points)
    block, _ = cahvor.project(binned.model, points)
    np.testing.assert_allclose(block[:, 0], full[:, 0], atol=1e-9)
    np.testing.assert_allclose(block[:, 1], (full[:, 1] - 1.5) / 4.0, atol=1e-9)


def test_fast_preset_renders_block_fields_with_full_frame_masks():
    """The fast preset's fields come per binning block; its masks stay full frame; a flat ground (exact ray
    map and photometry, whose node grids differ between the presets) reads the default render's block
    means to second order in the block (the photometric ratio is smooth)."""
    flat = Terrain(np.full((1800, 1800), 0.2, np.float32), 3.0, np.array([-2698.5, 2698.5]), np.radians(30), 0.0,
                   np.radians(30), "flat")
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, -1.0], LEVEL, 2.0, np.array([0.5]))
    exact = dict(shadows=False, coarse_ray_grid=False, coarse_photometry=False)
    fast = render_descent_image(flat, profile, CAMERA, 0, SUN, SceneConfig(fidelity="fast").with_effects(**exact))
    default = render_descent_image(flat, profile, CAMERA, 0, SUN, SceneConfig().with_effects(**exact))
    assert fast.radiance.exposure.shape == (256, 1024) and fast.sky_mask.shape == (1024, 1024)
    np.testing.assert_allclose(fast.radiance.exposure, block_means(default.radiance.exposure, 4), rtol=1e-3)


def test_fast_takes_a_window_moving_less_than_3_terrain_px_as_still():
    """Level flight at 2000 m, 490 m/s east: the ground moves 490 x 15.3 ms / 3 m = 2.5 terrain px over the
    fast flush + exposure + frame transfer (0.83 px in the exposure: one sub-pose either way). Fast (< 3 px)
    gives the exposure field to all three periods; default (< 1 px) gives the smear periods their own poses'
    fields; high and reference never share. What fast drops is the smear periods' pose offset (~0.8 px,
    across the columns here: the worst direction). Smear reads column means: each pixel collects
    (T_flush + T_transfer) x its column's mean radiance, so the expected image moves by at most that
    much of the column means' change, which the offset hardly makes (the column averages it out)."""
    from simulator.descent_image import binned_render_camera
    from simulator.fidelity import PRESETS
    from simulator.scene_config import preset_config

    timing = CAMERA.timing
    window_s = timing.fast_flush_s + timing.exposure_s + timing.frame_transfer_s
    terrain = smooth_terrain()
    speed_mps = 2.5 * terrain.metres_per_pixel / window_s
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [speed_mps, 0.0, 0.0], LEVEL, 1.0, [0.5])
    shares = {}
    for preset in PRESETS:
        config = preset_config(preset)
        shares[preset] = config.effects.share_still_fields and config.still_shift_terrain_px > 2.5
    assert shares == {"reference": False, "high": False, "default": False, "fast": True}
    fast = preset_config("fast").with_effects(shadows=False)
    exact = fast.with_fields(still_shift_terrain_px=1.0)
    blocks = binned_render_camera(CAMERA)                     # the fast render's camera: one ray per block
    still = periods.period_fields(terrain, blocks, profile, 0.5, SUN, fast)
    moving = periods.period_fields(terrain, blocks, profile, 0.5, SUN, exact)
    default = periods.period_fields(terrain, CAMERA, profile, 0.5, SUN,
                                    preset_config("default").with_effects(shadows=False))
    assert still.shared and still.fields.flush is still.fields.exposure is still.fields.transfer
    assert not moving.shared and not default.shared
    assert moving.substeps["exposure"] == 1                    # the exposure field is the same either way
    np.testing.assert_array_equal(moving.fields.exposure, still.fields.exposure)
    exposure = still.fields.exposure
    column_changes = []
    for period in ("flush", "transfer"):
        own = getattr(moving.fields, period)
        pixel_change = np.abs(own[2:-2, 8:-8] - exposure[2:-2, 8:-8]).mean()
        column_change = own.mean(axis=0) - exposure.mean(axis=0)
        assert pixel_change > 0.05 * exposure[2:-2, 8:-8].std()                # the poses differ
        assert np.abs(column_change[8:-8]).mean() < 0.2 * pixel_change          # the column means hardly
        column_changes.append(column_change)
    images = [render_descent_image(terrain, profile, CAMERA, 0, SUN, config).image.expected_dn
              for config in (fast, exact)]
    change_dn = np.sqrt(np.mean((images[0] - images[1]) ** 2))
    # bound: T_f |dF| + T_t |dT| of the column means, in DN: a uniform scene's image collects its radiance
    # over the whole window (exposure + smear), so DN per (radiance x second) is about mean DN / (mean F x window)
    dn_per_radiance_s = images[1].mean() / (exposure.mean() * window_s)
    worst = timing.fast_flush_s * np.abs(column_changes[0]) + timing.frame_transfer_s * np.abs(column_changes[1])
    bound_dn = np.sqrt(np.mean(worst ** 2)) * dn_per_radiance_s
    assert 0.0 < change_dn < bound_dn


def test_interpolated_edge_rays_are_the_camera_models_rays_and_only_fast_takes_them():
    """The heat shield's silhouette sub-pixel rays moved to first order from the pixel rays of an exact ground
    map agree with CAHVOR's unprojection of the sub-pixel positions to ~1e-7 rad (the camera model's
    second-order change over a third of a pixel); the edge pixels then read the same pixel-area mean. Only
    the fast preset takes them."""
    from flight_interface import cahvor
    from simulator.scene import heat_shield
    from simulator.scene_config import preset_config

    assert {preset: preset_config(preset).effects.interpolated_edge_rays
            for preset in ("reference", "high", "default", "fast")} == \
        {"reference": False, "high": False, "default": False, "fast": True}
    profile = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.1])
    cam = ground_mapping.camera_pose(CAMERA, profile.pose(0.1))
    exact_map = ground_mapping.map_to_ground_grid(CAMERA, cam, (0.0, 0.0), 3.0, 0)
    rng = np.random.default_rng(3)
    rows = np.concatenate([[0, 1023, 0, 1023], rng.integers(0, 1024, 40)])     # corners: one-sided differences
    cols = np.concatenate([[0, 0, 1023, 1023], rng.integers(0, 1024, 40)])
    offsets = (np.arange(3) + 0.5) / 3 - 0.5
    d_col, d_row = (axis.ravel() for axis in np.meshgrid(offsets, offsets))
    moved = heat_shield.edge_rays(exact_map, rows, cols, d_row, d_col)
    pixels = np.stack([cols[:, None] + d_col, rows[:, None] + d_row], axis=-1).reshape(-1, 2)
    unprojected = (cahvor.unproject(CAMERA.model, pixels) @ cam.camera_to_world.T).reshape(moved.shape)
    moved_unit = moved / np.linalg.norm(moved, axis=-1, keepdims=True)
    angle = np.linalg.norm(np.cross(moved_unit, unprojected), axis=-1)
    assert angle.max() < 1e-6
    # the silhouette's pixel-area mean: the same as with the unprojected rays, to a small fraction of the contrast
    terrain = smooth_terrain()
    base = constant_velocity_profile([0.0, 0.0, ALTITUDE_M], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.1])
    shield = np.tile([20.0, 10.0, ALTITUDE_M - 150.0], (2, 1))
    with_shield = DescentProfile(base.time_s, base.position_m, base.velocity_mps, base.attitude_quat,
                                 base.angular_rate_radps, base.wind_mps, shield, base.image_times_s, "shield")
    config = SceneConfig().with_effects(shadows=False, coarse_ray_grid=False)
    pose = with_shield.pose(0.1)
    unproject = radiance.radiance_at_pose(terrain, CAMERA, pose, SUN, config)
    moved_field = radiance.radiance_at_pose(terrain, CAMERA, pose, SUN, config.with_effects(interpolated_edge_rays=True))
    assert unproject.heat_shield.sum() > 100
    np.testing.assert_array_equal(moved_field.heat_shield, unproject.heat_shield)
    contrast = np.median(unproject.radiance[~unproject.heat_shield]) - np.median(unproject.radiance[unproject.heat_shield])
    assert np.abs(moved_field.radiance - unproject.radiance).max() < 0.02 * contrast


def test_block_masks_become_full_frame_masks_block_row_by_block_row():
    """The binned render's masks: block k's value on rows 4k .. 4k + 3 of its column, empty or not."""
    from simulator.descent_image import _full_frame_mask

    empty = np.zeros((256, 1024), dtype=bool)
    some = empty.copy()
    some[3, 7] = some[255, 1023] = True
    for block_mask in (empty, some):
        full = _full_frame_mask(block_mask, 4)
        assert full.shape == (1024, 1024) and full.dtype == bool and full.flags.writeable
        rows, cols = np.nonzero(full)
        expected_rows = (4 * np.nonzero(block_mask)[0][:, None] + np.arange(4)).ravel()
        np.testing.assert_array_equal(np.sort(rows), np.sort(expected_rows))
        assert set(cols) == set(np.nonzero(block_mask)[1])
