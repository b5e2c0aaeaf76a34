"""Terrain relief (simulator.scene.relief): ray-height intersection, parallax, occlusion, slope shading
and cast shadows against closed-form geometry; relief off renders exactly as a plain terrain."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from config_tables.errors import ConfigError
from config_tables.models import parse
from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.derived_cache import DERIVED
from simulator.scene import ground_mapping, photometry, radiance, relief
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])      # camera boresight down, image columns east, rows south
# exact per-pixel rays and photometry, no pixel-area filter, no lander shadows: point samples of the scene
EXACT = SceneConfig().with_effects(coarse_ray_grid=False, coarse_photometry=False, pixel_area_filter=False,
                                   shadows=False)


def relief_terrain(reflectance, height, mpp, name="relief") -> relief.ReliefTerrain:
    rows, cols = reflectance.shape
    origin = np.array([-0.5 * (cols - 1) * mpp, 0.5 * (rows - 1) * mpp])
    return relief.ReliefTerrain(np.asarray(reflectance, np.float32), mpp, origin, np.radians(30.0), 0.0,
                                np.radians(30.0), name, height_m=np.asarray(height, np.float32))


def pose_at(altitude_m, attitude=LEVEL):
    return constant_velocity_profile([0.0, 0.0, altitude_m], [0.0, 0.0, 0.0], attitude, 1.0, [0.1]).pose(0.0)


def crossing_column(values: np.ndarray, level: float) -> float:
    """First fractional column where ``values`` crosses ``level`` (linear between pixel centres)."""
    above = values > level
    k = int(np.nonzero(above[1:] != above[:-1])[0][0])
    return k + (level - values[k]) / (values[k + 1] - values[k])


def column_where_ray_passes(camera_pose, row: float, east_m: float, height_m: float) -> float:
    """Fractional image column on ``row`` whose ray passes through east = ``east_m`` at z = ``height_m``."""
    columns = np.linspace(0.0, 1023.0, 1023 * 200 + 1)
    pixels = np.stack([columns, np.full_like(columns, row)], axis=-1)
    rays = ground_mapping.camera_frame_rays(CAMERA, pixels) @ camera_pose.camera_to_world.T
    origin = camera_pose.ray_origin_m
    east = origin[0] + (height_m - origin[2]) / rays[:, 2] * rays[:, 0]
    return float(np.interp(east_m, east, columns))


# --- the intersection itself ----------------------------------------------------------------------------

def grid_of(mpp):
    """(east, north) -> (col, row) of a grid whose pixel (0, 0) is at the world origin."""
    def to_grid(east, north):
        return east / mpp, -north / mpp
    return to_grid


def test_a_ray_meets_a_raised_plateau_h_tan_theta_before_the_level_ground():
    mpp, h = 0.5, 7.0
    heights = np.zeros((80, 400))
    heights[:, 100:] = h                                 # plateau from east = 50 m
    origin = np.array([0.0, -20.0, 300.0])
    angles = np.radians([5.0, 15.0, 25.0, 35.0])
    rays = np.stack([np.sin(angles), np.zeros_like(angles), -np.cos(angles)], axis=-1)
    z = relief.intersect_rays(heights, grid_of(mpp), origin, rays, h, 0.0, 0.5 * mpp, 1e-4, metres_per_pixel=mpp)
    east = origin[0] + (z - origin[2]) / rays[:, 2] * rays[:, 0]
    level_east = origin[2] * np.tan(angles)             # where the level ground would be met
    on_plateau = level_east - h * np.tan(angles) > 50.0 + mpp
    assert on_plateau.sum() >= 2
    assert z[on_plateau] == pytest.approx(h, abs=1e-4)
    # the ground offset of the hit is h tan(view angle)
    assert level_east[on_plateau] - east[on_plateau] == pytest.approx(h * np.tan(angles[on_plateau]), abs=1e-3)
    assert z[~on_plateau & (level_east < 50.0)] == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize("skip_px", [0, 8])
def test_a_mesa_hides_the_ground_behind_its_edge_for_h_tan_theta(skip_px):
    mpp, h, edge = 0.25, 6.0, 40.0
    heights = np.zeros((40, 400))
    heights[:, : int(edge / mpp) + 1] = h               # mesa west of east = 40 m, level ground beyond
    origin = np.array([0.0, -5.0, 200.0])
    angles = np.linspace(np.radians(5.0), np.radians(20.0), 3001)
    rays = np.stack([np.sin(angles), np.zeros_like(angles), -np.cos(angles)], axis=-1)
    z = relief.intersect_rays(heights, grid_of(mpp), origin, rays, h, 0.0, 0.5 * mpp, 1e-4, skip_px=skip_px,
                              metres_per_pixel=mpp)
    east = origin[0] + (z - origin[2]) / rays[:, 2] * rays[:, 0]
    ground = east[z < 1e-3]
    theta_edge = np.arctan(edge / (origin[2] - h))      # the ray grazing the mesa's edge
    hidden = h * np.tan(theta_edge)                     # closed form: ground hidden behind the edge
    assert ground.min() > edge + mpp
    first_seen = ground[ground > edge].min() - edge
    assert first_seen == pytest.approx(hidden, abs=0.3 * mpp + 0.01)


# --- rendered: parallax, occlusion and a cast shadow ----------------------------------------------------

@pytest.mark.slow                 # 2-3 s on an idle core, 6 s on the shared machine
def test_plateau_edge_and_its_shadow_seen_from_a_known_pose():
    """A mesa (west of east = 40 m, 8 m high, bright) beside dark level ground, sun from the west at
    zenith 40 deg, nadir camera at 200 m: the bright edge is where the ray passes (40 m, 8 m), the ground
    behind is in shadow up to 40 + 8 tan(40 deg) m (a shadow of h tan(zenith))."""
    mpp, h, edge = 0.25, 8.0, 40.0
    size = 801                                          # grid nodes on multiples of 0.25 m: one at the edge
    east = (np.arange(size) - 0.5 * (size - 1)) * mpp
    top = east <= edge
    height = np.tile(np.where(top, h, 0.0), (size, 1))
    reflectance = np.tile(np.where(top, 0.4, 0.2), (size, 1))
    terrain = relief_terrain(reflectance, height, mpp)
    zenith = np.radians(40.0)
    sun = np.array([-np.sin(zenith), 0.0, np.cos(zenith)])
    diffuse = 0.3
    config = EXACT.with_fields(shadow_diffuse_fraction=diffuse)
    field = radiance.radiance_at_pose(terrain, CAMERA, pose_at(200.0), sun, config)
    cam = ground_mapping.camera_pose(CAMERA, pose_at(200.0))
    row = 511
    profile = field.radiance[row].astype(float)
    flat = radiance.radiance_at_pose(Terrain(np.full((size, size), 0.2, np.float32), mpp, terrain.origin_m,
                                             terrain.moc_incidence_rad, 0.0, terrain.moc_phase_rad),
                                     CAMERA, pose_at(200.0), sun, config).radiance[row].astype(float)
    ratio = profile / flat                              # 2 on the mesa, 0.3 in its shadow, 1 in the sun
    assert ratio[400] == pytest.approx(2.0, rel=1e-3) and ratio[1000] == pytest.approx(1.0, rel=1e-3)
    predicted_edge = column_where_ray_passes(cam, row, edge, h)
    level_edge = column_where_ray_passes(cam, row, edge, 0.0)
    assert predicted_edge - level_edge > 8.0            # parallax of the 8 m mesa: h tan(theta) = 1.6 m, 9.8 px
    assert crossing_column(ratio, 0.5 * (2.0 + diffuse)) == pytest.approx(predicted_edge, abs=0.6)
    shadow_end = column_where_ray_passes(cam, row, edge + h * np.tan(zenith), 0.0)
    in_shadow = ratio[int(predicted_edge) + 2:int(shadow_end) - 1]
    assert in_shadow == pytest.approx(diffuse, rel=1e-3)
    after = ratio[int(predicted_edge) + 2:]
    assert int(predicted_edge) + 2 + crossing_column(after, 0.5 * (1.0 + diffuse)) == pytest.approx(shadow_end, abs=0.6)


@pytest.mark.slow                 # 2-3 s on an idle core, 6 s on the shared machine
def test_tilted_plane_shading_is_the_photometric_function_at_the_tilted_normal():
    mpp, slope = 0.5, np.radians(20.0)
    size = 400
    east = (np.arange(size) - 0.5 * (size - 1)) * mpp
    height = np.tile(np.tan(slope) * east, (size, 1))   # z = tan(slope) east: rises to the east
    terrain = relief_terrain(np.full((size, size), 0.25), height, mpp)
    sun = np.array([np.sin(np.radians(35.0)) * np.sin(np.radians(60.0)),
                    np.sin(np.radians(35.0)) * np.cos(np.radians(60.0)), np.cos(np.radians(35.0))])
    tilt = quat_from_axis_angle([0.0, 1.0, 0.0], np.radians(8.0))
    config = EXACT.with_fields(shadow_diffuse_fraction=0.0)
    field = radiance.radiance_at_pose(terrain, CAMERA, pose_at(100.0, tilt), sun, config)
    cam = ground_mapping.camera_pose(CAMERA, pose_at(100.0, tilt))
    normal = np.array([-np.sin(slope), 0.0, np.cos(slope)])
    pixels = np.array([[100.0, 100.0], [511.0, 511.0], [900.0, 300.0], [300.0, 950.0], [1000.0, 1000.0]])
    rays = ground_mapping.camera_frame_rays(CAMERA, pixels) @ cam.camera_to_world.T
    origin = cam.ray_origin_m
    t = (np.tan(slope) * origin[0] - origin[2]) / (rays[:, 2] - np.tan(slope) * rays[:, 0])   # ray meets the plane
    view = -rays / np.linalg.norm(rays, axis=1, keepdims=True)
    expected_model = photometry.reflectance_model(normal @ sun, view @ normal, view @ sun)
    moc_value = photometry.moc_reflectance_model(terrain.moc_incidence_rad, 0.0, terrain.moc_phase_rad)
    scale = photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au) / np.pi * config.spectral_ratio
    expected = 0.25 * scale * expected_model / moc_value
    got = field.radiance[pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
    assert np.all(t > 0)
    assert got == pytest.approx(expected, rel=2e-4)
    # and it is not the level-ground value (the tilt changes the shading by 2-17 %)
    level_model = photometry.reflectance_model(sun[2], view[:, 2], view @ sun)
    assert np.mean(np.abs(expected_model / level_model - 1.0)) > 0.05


# --- relief off, level relief, configuration ------------------------------------------------------------

def textured(size=1600, mpp=3.0, seed=3):
    rng = np.random.default_rng(seed)
    return (0.2 + 0.03 * rng.standard_normal((size, size))).astype(np.float32), mpp


def test_relief_off_and_plain_terrain_give_the_same_bits_and_level_relief_the_same_image():
    values, mpp = textured()
    plain = Terrain(values, mpp, relief_terrain(values, values, mpp).origin_m, np.radians(30.0), 0.0, np.radians(30.0))
    bumpy = relief_terrain(values, 30.0 * values, mpp)          # heights that would change everything
    level = relief_terrain(values, np.zeros_like(values), mpp)
    sun = np.array([0.5, 0.0, np.sqrt(0.75)])
    pose = pose_at(2000.0, quat_from_axis_angle([1.0, 0.0, 0.0], np.radians(10.0)))
    config = SceneConfig()
    reference = radiance.radiance_at_pose(plain, CAMERA, pose, sun, config).radiance
    owners_before = DERIVED.owners()
    off = radiance.radiance_at_pose(bumpy, CAMERA, pose, sun, config.with_fields(
        relief=relief.ReliefConfig(enabled=False))).radiance
    assert np.array_equal(reference, off)
    assert DERIVED.owners() == owners_before          # relief off did no relief work (no bounds, no horizon)
    on_level = radiance.radiance_at_pose(level, CAMERA, pose, sun, config).radiance
    assert np.max(np.abs(on_level / reference - 1.0)) < 2e-3
    on_bumpy = radiance.radiance_at_pose(bumpy, CAMERA, pose, sun, config).radiance
    assert np.mean(np.abs(on_bumpy / reference - 1.0)) > 0.05


def test_relief_keys_are_validated_in_one_line():
    config = parse(SceneConfig, {"relief": {"march_step_terrain_px": 0.25, "cast_shadows": False}}, "scene.toml",
                   "scene")
    assert config.relief.march_step_terrain_px == 0.25 and not config.relief.cast_shadows
    with pytest.raises(ConfigError) as error:
        parse(SceneConfig, {"relief": {"height_tolerance_m": 5.0}}, "scene.toml", "scene")
    assert "\n" not in str(error.value) and "height_tolerance_m" in str(error.value)


def test_height_field_of_another_shape_is_refused():
    with pytest.raises(ValueError, match="height_m"):
        relief_terrain(np.zeros((10, 10)), np.zeros((10, 9)), 1.0)


# --- the fast (parallax) intersection against a brute-force march and a closed form ------------------------

def brute_force_heights(heights, to_grid, origin, rays, z_top, z_bottom, mpp):
    """First crossing of each ray with the bilinear surface: z stepped down so the ray moves 0.01 px per step,
    then bisection of the first bracket to 1e-7 m (no skip, no early bound: a brute-force reference)."""
    slope = np.hypot(rays[:, 0], rays[:, 1]) / -rays[:, 2]
    dz = np.minimum(0.01 * mpp / np.maximum(slope, 1e-9), 0.01)
    east0 = origin[0] - origin[2] / rays[:, 2] * rays[:, 0]
    north0 = origin[1] - origin[2] / rays[:, 2] * rays[:, 1]

    def residual(z):
        east, north = east0 + z / rays[:, 2] * rays[:, 0], north0 + z / rays[:, 2] * rays[:, 1]
        col, row = to_grid(east, north)
        return z - relief.bilinear(heights, col, row)
    upper = np.full(len(rays), z_top + 1e-3)
    found = np.zeros(len(rays), dtype=bool)
    while not found.all():
        lower = np.maximum(upper - dz, z_bottom - 1e-3)
        crossed = ~found & (residual(lower) <= 0)
        found |= crossed
        upper = np.where(found, upper, lower)
    lower = upper - dz
    for _ in range(60):
        middle = 0.5 * (lower + upper)
        below = residual(middle) <= 0
        lower, upper = np.where(below, middle, lower), np.where(below, upper, middle)
    return 0.5 * (lower + upper)


def cone_terrain():
    """A 300 m x 300 m grid (1 m) with a gentle cone (20 m high, slope 0.3) and a steep knob (20 m, slope 4)."""
    mpp, size = 1.0, 301
    east = (np.arange(size) - 150.0) * mpp
    east_grid, north_grid = np.meshgrid(east, -east)
    gentle = np.maximum(20.0 - 0.3 * np.hypot(east_grid + 40.0, north_grid - 30.0), 0.0)
    knob = np.maximum(20.0 - 4.0 * np.hypot(east_grid - 90.0, north_grid + 20.0), 0.0)
    heights = np.maximum(gentle, knob)
    return relief_terrain(np.full((size, size), 0.2), heights, mpp, name="cones"), heights


def test_parallax_hits_agree_with_a_brute_force_march_and_the_cone_in_closed_form():
    terrain, heights = cone_terrain()
    mpp = terrain.metres_per_pixel
    sun = np.array([0.3, 0.2, np.sqrt(1.0 - 0.13)])
    pose = pose_at(300.0, quat_from_axis_angle([1.0, 0.0, 0.0], np.radians(3.0)))
    cam = ground_mapping.camera_pose(CAMERA, pose)
    level = ground_mapping.map_to_ground_grid(CAMERA, cam, (terrain.origin_m[0], terrain.origin_m[1]), mpp, 0)
    config = EXACT.with_fields(relief=relief.ReliefConfig(method="parallax"))
    ground_map, hits = relief.relief_ground_map(terrain, CAMERA, cam, level, config, sun)
    assert hits.counts["marched"] > 0                    # the knob's hidden side is left to the march

    rng = np.random.default_rng(5)
    pixels = np.vstack([rng.uniform(0, 1023, (3000, 2)),
                        np.stack(np.meshgrid(np.arange(860, 930.0), np.arange(630, 690.0)), -1).reshape(-1, 2)])
    pixels = np.round(pixels)
    cols_px, rows_px = pixels[:, 0].astype(int), pixels[:, 1].astype(int)
    rays = ground_mapping.camera_frame_rays(CAMERA, pixels) @ cam.camera_to_world.T
    origin = cam.ray_origin_m

    def to_grid(east, north):
        row, col = terrain.world_to_pixel(east, north)
        return col, row
    z = brute_force_heights(heights, to_grid, origin, rays, heights.max(), 0.0, mpp)
    brute_col, brute_row = to_grid(origin[0] + (z - origin[2]) / rays[:, 2] * rays[:, 0],
                                   origin[1] + (z - origin[2]) / rays[:, 2] * rays[:, 1])
    fast_col, fast_row = ground_map.col[rows_px, cols_px], ground_map.row[rows_px, cols_px]
    offset_px = np.hypot(fast_col - brute_col, fast_row - brute_row)
    # the fast path reads heights where OpenCV's remap reads (OpenCV 4.x snaps to 1/32 px: within 1/64 px of the ray), plus the
    # 1 mm tolerance. Where a nearer bump may hide the crossing it takes the reference march, which can miss
    # a chord shorter than its 0.5 px step at the knob's silhouette: there it must be the march's point.
    off = offset_px > 0.03
    march_config = EXACT.with_fields(relief=relief.ReliefConfig(method="march"))
    march_map, _ = relief.relief_ground_map(terrain, CAMERA, cam, level, march_config, sun)
    march_offset_px = np.hypot(fast_col - march_map.col[rows_px, cols_px],
                               fast_row - march_map.row[rows_px, cols_px])
    assert off.mean() < 1e-3 and np.all(march_offset_px[off] < 0.03)
    on_knob = (np.hypot(brute_col - 240.0, brute_row - 170.0) * mpp < 5.0) & (z > 1.0)
    assert on_knob.sum() > 100          # the knob is in the sample: rays whose level point lies behind it

    # the gentle cone in closed form (away from its apex and rim, where the bilinear surface is the cone)
    apex = np.array([-40.0, 30.0, 20.0])
    offset = origin - apex
    a = rays[:, 2] ** 2 - 0.09 * (rays[:, 0] ** 2 + rays[:, 1] ** 2)
    b = 2.0 * (offset[2] * rays[:, 2] - 0.09 * (offset[0] * rays[:, 0] + offset[1] * rays[:, 1]))
    c = offset[2] ** 2 - 0.09 * (offset[0] ** 2 + offset[1] ** 2)
    # the camera is inside the upper nappe (z - 20 > 0.3 r): the ray leaves it (the smaller root) before it
    # meets the cone (the larger root, z < 20 m)
    t = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a)
    hit = origin + t[:, None] * rays
    radius = np.hypot(hit[:, 0] - apex[0], hit[:, 1] - apex[1])
    on_side = (hit[:, 2] > 0) & (radius > 3.0) & (radius < 20.0 / 0.3 - 2.0)
    assert on_side.sum() > 100
    exact_col, exact_row = to_grid(hit[on_side, 0], hit[on_side, 1])
    assert np.max(np.hypot(fast_col[on_side] - exact_col, fast_row[on_side] - exact_row)) * mpp < 0.02


def test_half_precision_normals_decode_exactly_in_the_compiled_view_term():
    """The view-term kernel reads the cached float16 normals as raw bits: every finite half value must decode
    to numpy's own float16 -> float32 conversion, signed zeros and subnormals included."""
    from numba import njit

    from simulator.scene import parallax

    @njit
    def decode(bits, scales, out):
        for index in range(bits.size):
            out[index] = parallax._half_to_float32(bits[index], scales)
    bits = np.arange(65536, dtype=np.uint16)
    finite = np.isfinite(bits.view(np.float16))
    decoded = np.empty(bits.size, dtype=np.float32)
    decode(bits, parallax.HALF_SCALES, decoded)
    expected = bits.view(np.float16).astype(np.float32)
    assert np.array_equal(decoded[finite].view(np.uint32), expected[finite].view(np.uint32))


def test_relief_hits_off_the_terrain_are_flagged_and_a_window_inside_needs_no_mask():
    """A pose whose window keeps off the terrain's edges has every hit inside the strip (no outside mask is
    needed); a pose over the east edge is not taken as inside, and its pixels beyond the edge are flagged."""
    values, mpp = textured()
    terrain = relief_terrain(values, 10.0 * (values - 0.2) / 0.03, mpp)      # heights of +-30 m
    sun = np.array([0.5, 0.0, np.sqrt(0.75)])
    config = SceneConfig()
    east_edge_m = terrain.origin_m[0] + (values.shape[1] - 0.5) * mpp
    for east_m, inside in ((0.0, True), (east_edge_m - 200.0, False)):
        pose = constant_velocity_profile([east_m, 0.0, 2000.0], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.1]).pose(0.0)
        camera_pose = ground_mapping.camera_pose(CAMERA, pose)
        level_map = ground_mapping.map_to_ground_grid(CAMERA, camera_pose, tuple(terrain.origin_m), mpp, 0)
        ground_map, hits = relief.relief_ground_map(terrain, CAMERA, camera_pose, level_map, config, sun)
        beyond = ground_map.col > values.shape[1] - 0.5          # hit points east of the strip's last pixel edge
        assert relief.hits_inside_terrain(terrain, hits) is inside
        assert beyond.any() is not inside
        field = radiance.radiance_at_pose(terrain, CAMERA, pose, sun, config)
        assert np.array_equal(field.outside, beyond)
