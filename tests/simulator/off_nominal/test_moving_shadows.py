"""Moving dust-devil and cloud shadows (simulator/off_nominal/moving_shadows.py): motion between images
equal to wind x interval, offset from the caster along the anti-sun azimuth, darkness of the model on
flat ground, off = today's images bit for bit, determinism and the configuration edge."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from config_tables.errors import ConfigError
from config_tables.models import parse
from flight_interface.camera import load_camera
from simulator.descent_image import render_descent_image
from simulator.off_nominal import OffNominalConfig, draw_case_artefacts
from simulator.off_nominal.moving_shadows import place_moving_shadows
from simulator.scene import ground_mapping, photometry
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])            # camera looking straight down
ZENITH = np.radians(40.0)
SUN = np.array([np.sin(ZENITH), 0.0, np.cos(ZENITH)])   # sun in the east, 40 deg from the zenith
ANTI_SUN = np.array([-1.0, 0.0])                   # shadows fall toward the west
IMAGE_TIMES_S = [0.0, 2.0, 4.0]
DIFFUSE = 0.3


def flat_terrain(size=1400, mpp=2.0) -> Terrain:
    half = 0.5 * (size - 1) * mpp
    return Terrain(np.full((size, size), 0.2, dtype=np.float32), mpp, np.array([-half, half]), np.radians(30), 0.0,
                   np.radians(30), "flat")


TERRAIN = flat_terrain()
# the lander drifts north at 8 m/s, 1600 m up: the shadows' motion is measured on the ground, not the image
PROFILE = constant_velocity_profile([0.0, 0.0, 1600.0], [0.0, 8.0, 0.0], LEVEL, 6.0, IMAGE_TIMES_S)


def scene(**off_nominal) -> SceneConfig:
    base = {"shadow_diffuse_fraction": DIFFUSE, "camera_effects": {"shot_noise": False, "read_noise": False}}
    return SceneConfig.model_validate({**base, "off_nominal": off_nominal})


def exposure_ratio(config: SceneConfig, seed: int = 5):
    """Per image: (shadowed / unshadowed exposure radiance (H, W), ground points of the pixels (H, W, 2)),
    and the placed shadows."""
    artefacts = draw_case_artefacts(CAMERA, config.off_nominal, np.random.default_rng(seed))
    plain = scene()
    out = []
    for index in range(len(IMAGE_TIMES_S)):
        shadowed = render_descent_image(TERRAIN, PROFILE, CAMERA, index, SUN, config, None, artefacts)
        lit = render_descent_image(TERRAIN, PROFILE, CAMERA, index, SUN, plain, None, None)
        rows, cols = np.mgrid[0:CAMERA.height_px, 0:CAMERA.width_px]
        points, _ = ground_mapping.ground_points(CAMERA, shadowed.diagnostics.camera_pose,
                                                 np.stack([cols, rows], axis=-1).astype(float))
        out.append((shadowed.radiance.exposure / lit.radiance.exposure, points[..., :2]))
    placed = place_moving_shadows(artefacts.moving_shadows, config.off_nominal, CAMERA, PROFILE, SUN,
                                  photometry.solar_angular_radius_rad(config.sun_distance_au), DIFFUSE)
    return out, placed


def darkening_centroid_m(ratio: np.ndarray, points: np.ndarray) -> np.ndarray:
    weight = np.clip(1.0 - ratio, 0.0, None).astype(float)
    assert weight.sum() > 100.0, "no shadow in view"
    return (weight[..., None] * points).sum(axis=(0, 1)) / weight.sum()


def test_a_dust_devil_shadow_moves_by_wind_times_interval_and_lies_down_sun_of_its_column():
    speed, azimuth = 20.0, 30.0                    # toward north-north-east
    height = 300.0
    config = scene(dust_devil_count=1, dust_devil_diameter_m=40.0, dust_devil_height_m=height,
                   shadow_wind_speed_mps=speed, shadow_wind_toward_azimuth_deg=azimuth)
    images, placed = exposure_ratio(config)
    wind = speed * np.array([np.sin(np.radians(azimuth)), np.cos(np.radians(azimuth))])
    centroids = [darkening_centroid_m(ratio, points) for ratio, points in images]
    for k in (1, 2):
        moved = centroids[k] - centroids[0]
        expected = wind * (IMAGE_TIMES_S[k] - IMAGE_TIMES_S[0])     # 40 m and 80 m
        assert np.linalg.norm(moved - expected) < 0.25, (k, moved, expected)
    # the column's shadow runs from its base H tan(zenith) toward the anti-sun: centre at half that
    for k, centroid in enumerate(centroids):
        mid_s = CAMERA.timing.exposure_mid_time_s(IMAGE_TIMES_S[k])
        base = placed.caster_m[0] + wind * (mid_s - placed.reference_time_s)
        offset = centroid - base
        assert offset @ ANTI_SUN == pytest.approx(0.5 * height * np.tan(ZENITH), abs=0.3)
        assert abs(offset[1]) < 0.3


def test_a_cloud_shadow_is_offset_by_its_height_and_darkened_by_the_model_ratio_on_flat_ground():
    tau, height, diameter = 0.6, 2000.0, 400.0
    config = scene(cloud_shadow_count=1, cloud_diameter_m=diameter, cloud_height_m=height, cloud_optical_depth=tau,
                   shadow_wind_speed_mps=0.0)
    images, placed = exposure_ratio(config, seed=11)
    ratio, points = images[1]
    expected = DIFFUSE + (1.0 - DIFFUSE) * np.exp(-tau / np.cos(ZENITH))       # 0.743
    # the shadow's core: farther than the edge half-width inside the rim
    penumbra = 2 * photometry.solar_angular_radius_rad(photometry.MARS_MEAN_SUN_DISTANCE_AU) * height / np.cos(ZENITH)
    core_radius = 0.5 * diameter - 0.5 * (penumbra + 0.1 * diameter) - 3.0
    centre = placed.caster_m[0] + height * np.tan(ZENITH) * ANTI_SUN
    distance = np.linalg.norm(points - centre, axis=-1)
    core = distance < core_radius
    assert core.sum() > 10_000
    np.testing.assert_allclose(ratio[core], expected, rtol=2e-6)
    assert np.all(ratio[distance > 0.5 * diameter + 0.5 * (penumbra + 0.1 * diameter) + 3.0] == 1.0)
    assert ratio.min() == pytest.approx(expected, rel=2e-6)


def test_overlapping_shadows_multiply_the_direct_beam_only():
    config = scene(cloud_shadow_count=2, cloud_diameter_m=20000.0, cloud_height_m=1000.0, cloud_optical_depth=0.5,
                   shadow_wind_speed_mps=0.0)
    images, _ = exposure_ratio(config, seed=2)     # two clouds wider than the view: every pixel in both cores
    ratio = images[0][0]
    direct = np.exp(-0.5 / np.cos(ZENITH))
    np.testing.assert_allclose(ratio, DIFFUSE + (1 - DIFFUSE) * direct**2, rtol=2e-6)


def test_shadows_off_give_todays_images_bit_for_bit_and_draw_nothing():
    off = scene(dust_devil_count=0, cloud_shadow_count=0, shadow_wind_speed_mps=45.0, cloud_optical_depth=2.0,
                dust_devil_height_m=3000.0)
    assert not off.off_nominal.needs_case_artefacts          # the campaign draws no artefacts: today's path
    rng = np.random.default_rng(9)
    state = rng.bit_generator.state
    assert draw_case_artefacts(CAMERA, off.off_nominal, rng).moving_shadows is None
    assert rng.bit_generator.state == state                # not one number drawn
    today = scene()
    for index in (0, 2):
        a = render_descent_image(TERRAIN, PROFILE, CAMERA, index, SUN, off, np.random.default_rng(3))
        b = render_descent_image(TERRAIN, PROFILE, CAMERA, index, SUN, today, np.random.default_rng(3))
        assert np.array_equal(a.dn, b.dn) and np.array_equal(a.radiance.exposure, b.radiance.exposure)


def test_draws_are_deterministic_and_leave_the_dust_stream_alone():
    shadows = OffNominalConfig(dust_particle_count=20, dust_devil_count=2, cloud_shadow_count=1,
                               shadow_wind_speed_spread_mps=5.0, shadow_wind_direction_spread_deg=40.0)
    one = draw_case_artefacts(CAMERA, shadows, np.random.default_rng(42))
    two = draw_case_artefacts(CAMERA, shadows, np.random.default_rng(42))
    assert np.array_equal(one.moving_shadows.velocity_mps, two.moving_shadows.velocity_mps)
    assert np.array_equal(one.moving_shadows.frame_fraction, two.moving_shadows.frame_fraction)
    assert one.moving_shadows.is_cloud.tolist() == [False, False, True]
    speeds = np.linalg.norm(one.moving_shadows.velocity_mps, axis=1)
    assert np.all((speeds >= 10.0 - 1e-9) & (speeds <= 20.0 + 1e-9))
    assert np.all((one.moving_shadows.frame_fraction >= 0.1) & (one.moving_shadows.frame_fraction <= 0.9))
    dust_only = draw_case_artefacts(CAMERA, OffNominalConfig(dust_particle_count=20), np.random.default_rng(42))
    assert np.array_equal(one.dust_transmission, dust_only.dust_transmission)


def test_keys_have_ranges_in_the_schema_and_bad_values_are_one_line():
    schema = SceneConfig.model_json_schema()
    keys = schema["$defs"]["OffNominalConfig"]["properties"]
    assert keys["dust_devil_count"]["maximum"] == 20 and keys["cloud_height_m"]["minimum"] == 500.0
    assert keys["shadow_wind_speed_mps"]["maximum"] == 60.0
    with pytest.raises(ConfigError) as error:
        parse(SceneConfig, {"off_nominal": {"dust_devil_count": 50}}, "case.toml", "scene")
    text = str(error.value)
    assert "\n" not in text and "scene.off_nominal.dust_devil_count" in text and "20" in text


def numpy_darkened(radiance, col_map, row_map, sky, mpp, shadows, windows, diffuse):
    """The darkening of simulator/off_nominal/shadow_darkening.py written with numpy float32 array passes."""
    out = radiance.copy()
    top, bottom = windows[:, 0].min(), windows[:, 1].max()
    left, right = windows[:, 2].min(), windows[:, 3].max()
    direct = np.ones((bottom - top, right - left), dtype=np.float32)
    for (east_offset, north_offset, anti_east, anti_north, length, slope, intercept, change), window in zip(shadows, windows):
        row0, row1, col0, col1 = window
        east = col_map[row0:row1, col0:col1] * mpp + east_offset
        north = north_offset - row_map[row0:row1, col0:col1] * mpp
        if length > 0:
            along = np.clip(east * anti_east + north * anti_north, np.float32(0), length)
            east = east - along * anti_east
            north = north - along * anti_north
        covered = np.clip(np.sqrt(east * east + north * north) * slope + intercept, np.float32(0), np.float32(1))
        covered[sky[row0:row1, col0:col1]] = 0
        direct[row0 - top:row1 - top, col0 - left:col1 - left] *= covered * change + np.float32(1)
    out[top:bottom, left:right] *= diffuse + (np.float32(1) - diffuse) * direct
    return out


def test_the_compiled_darkening_is_the_distance_ramp_of_every_pixel():
    from simulator.off_nominal import shadow_darkening

    height, width, mpp = 96, 128, 0.5
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float32)
    rng = np.random.default_rng(4)
    col_map = cols + rng.uniform(-0.3, 0.3, cols.shape).astype(np.float32)        # a slightly warped ground grid
    row_map = rows + rng.uniform(-0.3, 0.3, rows.shape).astype(np.float32)
    sky = np.zeros((height, width), bool)
    sky[:6, 100:] = True
    radiance = rng.uniform(5.0, 40.0, (height, width)).astype(np.float32)
    origin = (3.0, 40.0)
    anti_sun = np.array([0.6, -0.8])
    start = np.array([[20.0, 20.0], [40.0, 25.0], [25.0, 10.0]])             # a segment, two discs (m)
    length, radius, edge = np.array([12.0, 0.0, 0.0]), np.array([4.0, 9.0, 30.0]), np.array([1.5, 3.0, 12.0])
    core = np.array([0.2, 0.5, 0.7])
    table = shadow_darkening.shadow_table(start, origin, anti_sun, length, radius, edge, core)
    windows = np.array([[10, 60, 20, 90], [0, 50, 60, 128], [30, 96, 0, 110]], dtype=np.int64)
    darkened = radiance.copy()
    shadow_darkening.darken_windows(darkened, col_map, row_map, sky, True, np.float32(mpp), table, windows,
                                    np.float32(DIFFUSE))
    # the same float32 operations with numpy: the same bits
    assert np.array_equal(darkened, numpy_darkened(radiance, col_map, row_map, sky, np.float32(mpp), table, windows,
                                                   np.float32(DIFFUSE)))
    # closed form in float64: covered = clip(0.5 - (d - r) / w, 0, 1), d the distance to the axis segment
    east = origin[0] + col_map.astype(float) * mpp
    north = origin[1] - row_map.astype(float) * mpp
    direct = np.ones((height, width))
    for index, (row0, row1, col0, col1) in enumerate(windows):
        relative = np.stack([east - start[index, 0], north - start[index, 1]], axis=-1)
        along = np.clip(relative @ anti_sun, 0.0, length[index])
        distance = np.linalg.norm(relative - along[..., None] * anti_sun, axis=-1)
        covered = np.clip(0.5 - (distance - radius[index]) / edge[index], 0.0, 1.0)
        covered[sky] = 0.0
        inside = np.zeros((height, width), bool)
        inside[row0:row1, col0:col1] = True
        direct[inside] *= 1.0 - covered[inside] * (1.0 - core[index])
        seen = covered[inside & ~sky]
        assert (seen == 1).any() and (seen == 0).any() and ((seen > 0.05) & (seen < 0.95)).any()   # core, out, ramp
    ratio = darkened.astype(float) / radiance
    np.testing.assert_allclose(ratio, DIFFUSE + (1 - DIFFUSE) * direct, rtol=0, atol=2e-6)
