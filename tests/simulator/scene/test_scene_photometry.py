"""Photometry and shadows against closed forms: eq. (1)-(3), ratio 1 at MOC geometry, halo, penumbra."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flight_interface.camera import load_camera
from simulator.scene import ground_mapping, photometry, radiance, shadow
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import REFERENCE_EFFECTS, SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
FOCAL_PX = 0.01467 / 12e-6
R1 = -0.01
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


def sun_vector(incidence_deg: float, azimuth_deg: float) -> np.ndarray:
    """World unit vector toward the sun; azimuth clockwise from north."""
    i, a = np.radians(incidence_deg), np.radians(azimuth_deg)
    return np.array([np.sin(i) * np.sin(a), np.sin(i) * np.cos(a), np.cos(i)])


def uniform_terrain(value=0.2, incidence_deg=30.0, emission_deg=0.0, phase_deg=30.0) -> Terrain:
    size, mpp = 1600, 3.0
    half = 0.5 * (size - 1) * mpp
    return Terrain(np.full((size, size), value, np.float32), mpp, np.array([-half, half]),
                   np.radians(incidence_deg), np.radians(emission_deg), np.radians(phase_deg), "uniform")


def nadir_pose(altitude_m=2000.0):
    return constant_velocity_profile([0.0, 0.0, altitude_m], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.0]).pose(0.0)


def test_phase_function_values_from_the_paper():
    degrees = np.array([0.0, 5.0, 20.0, 30.0, 60.0, 80.0])
    f = photometry.phase_function(np.radians(degrees))
    a = 5.0
    low = 2.05 - 3.93e-2 * a + 2.09e-3 * a**2 - 4.86e-5 * a**3 + 4.93e-7 * a**4 - 1.72e-9 * a**5
    expected = [2.05, low, 1.82 - 0.103, 1.82 - 0.206, 1.82 - 0.515, 1.82 - 0.721]
    assert f == pytest.approx(expected, abs=1e-5)
    # f falls monotonically from the opposition peak; the step at 10 deg is the paper's own 0.12 %
    fine = photometry.phase_function(np.radians(np.linspace(0, 89, 891)))
    assert np.all(np.diff(fine) < 0)
    assert photometry.phase_function(np.radians(9.9999)) - photometry.phase_function(np.radians(10.0)) < 0.003
    assert np.all(photometry.phase_function(np.radians(np.linspace(0, 180, 181))) > 0)


def test_solar_band_irradiance_is_the_documented_planck_number():
    band_mean = photometry.planck_band_fraction(photometry.DIMES_BAND_UM) * 1361.0 / 0.7
    assert photometry.SOLAR_BAND_IRRADIANCE_1AU_W_M2_UM == pytest.approx(band_mean, rel=1e-3)
    assert photometry.solar_band_irradiance_w_m2_um(1.524) == pytest.approx(band_mean / 1.524**2, rel=1e-3)
    # the sun's angular radius at Mars: 696 000 km over 1.524 AU
    assert photometry.solar_angular_radius_rad(1.524) == pytest.approx(np.arcsin(6.957e8 / (1.524 * 1.495978707e11)), rel=1e-9)
    assert SceneConfig().spectral_ratio == pytest.approx(photometry.mars_soil_spectral_ratio(), abs=5e-4)


def test_ratio_is_one_where_dimes_geometry_equals_moc_geometry():
    moc = photometry.moc_reflectance_model(np.radians(30.0), np.radians(20.0), np.radians(45.0))
    sun = sun_vector(30.0, 90.0)
    # a view direction with emission 20 deg and phase 45 deg to this sun
    candidates = [np.array([np.sin(np.radians(20)) * np.sin(az), np.sin(np.radians(20)) * np.cos(az),
                            np.cos(np.radians(20))]) for az in np.radians(np.arange(0, 360, 0.01))]
    phases = np.degrees(np.arccos(np.clip(np.array(candidates) @ sun, -1, 1)))
    view = candidates[int(np.argmin(np.abs(phases - 45.0)))]
    assert photometry.photometric_ratio(view, sun, moc) == pytest.approx(1.0, abs=2e-4)

    # end to end: nadir camera, MOC geometry i = 30, e = 0, g = 30 and a sun 30 deg from zenith: the centre
    # pixels see exactly the MOC geometry, so radiance = I/F * spectral ratio * E / pi
    terrain = uniform_terrain(0.2, 30.0, 0.0, 30.0)
    config = SceneConfig().with_effects(shadows=False, heat_shield=False, **REFERENCE_EFFECTS)
    field = radiance.radiance_at_pose(terrain, CAMERA, nadir_pose(), sun, config).radiance
    expected = 0.2 * config.spectral_ratio * photometry.solar_band_irradiance_w_m2_um(config.sun_distance_au) / np.pi
    assert float(field[511:513, 511:513].mean()) == pytest.approx(expected, rel=1e-4)
    # away from the centre the geometry differs and so does the radiance
    assert abs(float(field[100, 100]) / expected - 1.0) > 0.01


@pytest.mark.parametrize("azimuth_deg", [0.0, 135.0, 250.0])
def test_halo_peak_sits_at_the_anti_sun_point(azimuth_deg):
    sun = sun_vector(15.0, azimuth_deg)
    config = SceneConfig().with_effects(shadows=False, heat_shield=False, **REFERENCE_EFFECTS)
    field = radiance.radiance_at_pose(uniform_terrain(), CAMERA, nadir_pose(), sun, config).radiance
    # closed form: the anti-sun direction -s seen by a level camera (x east, y south, z down)
    x, y, z = -sun[0], sun[1], sun[2]
    u = np.hypot(x, y) / z
    radius_px = FOCAL_PX * u * (1.0 + R1 * u * u)
    predicted = np.array([511.5 + radius_px * x / np.hypot(x, y), 511.5 + radius_px * y / np.hypot(x, y)])
    row, col = np.unravel_index(int(np.argmax(field)), field.shape)
    assert abs(col - predicted[0]) <= 1.0 and abs(row - predicted[1]) <= 1.0
    # the peak is the opposition surge: f(0)/f(15 deg) ~ 2.05/1.77 brighter than the antipodal pixel
    assert field[row, col] > 1.1 * field[1023 - row, 1023 - col]


def test_coarse_photometry_error_is_small_away_from_the_halo_kink():
    sun = sun_vector(15.0, 135.0)
    base = SceneConfig().with_effects(shadows=False, heat_shield=False)
    exact = radiance.radiance_at_pose(uniform_terrain(), CAMERA, nadir_pose(), sun,
                                   base.with_effects(coarse_photometry=False)).radiance
    coarse = radiance.radiance_at_pose(uniform_terrain(), CAMERA, nadir_pose(), sun, base).radiance
    relative = np.abs(coarse / exact - 1.0)
    assert np.max(relative) < 0.01          # worst at the alpha = 0 kink
    assert np.percentile(relative, 99) < 1e-3


def test_circle_overlap_fraction_matches_monte_carlo():
    rng = np.random.default_rng(7)
    points = rng.uniform(-1.0, 1.0, (200_000, 2))
    inside_sun = np.hypot(points[:, 0], points[:, 1]) <= 1.0
    for caster_radius, separation in [(0.4, 0.0), (0.5, 0.9), (1.3, 0.5), (0.8, 1.5), (0.3, 2.0)]:
        covered = np.hypot(points[:, 0] - separation, points[:, 1]) <= caster_radius
        estimate = np.count_nonzero(inside_sun & covered) / np.count_nonzero(inside_sun)
        assert float(shadow.circle_overlap_fraction(1.0, caster_radius, separation)) == pytest.approx(estimate, abs=0.006)


def test_parachute_umbra_at_low_altitude_leaves_only_skylight():
    altitude = 300.0
    sun = sun_vector(15.0, 60.0)
    terrain = uniform_terrain()
    config = SceneConfig().with_effects(heat_shield=False, photometric_correction=False)
    lit = radiance.radiance_at_pose(terrain, CAMERA, nadir_pose(altitude), sun, config.with_effects(shadows=False))
    shaded = radiance.radiance_at_pose(terrain, CAMERA, nadir_pose(altitude), sun, config)
    parachute = np.array([0.0, 0.0, altitude + config.parachute_distance_m])
    centre = parachute - parachute[2] / sun[2] * sun         # sun line through the canopy meets the ground
    pixel, in_front = ground_mapping.world_to_pixels(CAMERA, lit.camera_pose, centre)
    assert in_front
    col, row = np.round(pixel).astype(int)
    # 7.5 m canopy at 342 m subtends 22 mrad >> the sun's 3 mrad: total eclipse, only skylight remains
    assert shaded.radiance[row, col] / lit.radiance[row, col] == pytest.approx(config.shadow_diffuse_fraction, rel=1e-3)
    assert any(np.allclose(c, centre) for c in shaded.shadow_centres_m)
    # far from the shadow nothing changes
    assert shaded.radiance[20, 20] == lit.radiance[20, 20]


def test_lander_shadow_at_2000_m_is_a_partial_eclipse():
    """The 1.9 m lander at ~2200 m from its shadow hides (rho / R_sun)^2 of the sun's disc."""
    sun = sun_vector(25.0, 60.0)
    lander = shadow.Caster("lander", np.array([0.0, 0.0, 2000.0]), 0.95)
    centre = shadow.shadow_centre_m(lander.centre_m, sun)
    sun_radius = photometry.solar_angular_radius_rad(1.524)
    fraction = shadow.occluded_fraction(centre[None, :], lander, sun, sun_radius)[0]
    rho = np.arcsin(0.95 / np.linalg.norm(lander.centre_m - centre))
    assert fraction == pytest.approx((rho / sun_radius) ** 2, rel=1e-4)
    # outside the penumbra: nothing hidden
    far = centre + np.array([50.0, 0.0, 0.0])
    assert shadow.occluded_fraction(far[None, :], lander, sun, sun_radius)[0] == 0.0


def test_sun_must_be_a_unit_vector_above_the_horizon():
    with pytest.raises(ValueError, match="sun"):
        radiance.sun_unit_vector([0.0, 0.0, -1.0])
    with pytest.raises(ValueError, match="sun"):
        radiance.sun_unit_vector([0.0, 0.5, 0.5])


def test_shadow_windows_hold_the_whole_penumbra():
    """The windowed shadows equal the occlusion evaluated over the whole frame (nothing is cut off)."""
    sun = sun_vector(20.0, 300.0)
    config = SceneConfig().with_effects(heat_shield=False, **REFERENCE_EFFECTS)
    terrain = uniform_terrain()
    pose = nadir_pose(1200.0)
    lit = radiance.radiance_at_pose(terrain, CAMERA, pose, sun, config.with_effects(shadows=False))
    shaded = radiance.radiance_at_pose(terrain, CAMERA, pose, sun, config)
    columns, rows = np.meshgrid(np.arange(1024.0), np.arange(1024.0))
    points, _ = ground_mapping.ground_points(CAMERA, lit.camera_pose, np.stack([columns, rows], axis=-1))
    expected = np.ones((1024, 1024))
    sun_radius = photometry.solar_angular_radius_rad(config.sun_distance_au)
    for caster in radiance.casters(pose, config):
        occluded = shadow.occluded_fraction(points, caster, sun, sun_radius)
        expected *= 1.0 - (1.0 - config.shadow_diffuse_fraction) * occluded
    ratio = shaded.radiance / lit.radiance
    assert np.count_nonzero(expected < 0.999) > 200        # the shadows are in view
    assert np.max(np.abs(ratio - expected)) < 1e-4


@pytest.mark.parametrize("sun_z", [0.87, 0.2, 0.0])
def test_ratio_from_cosines_is_equation_1_over_the_moc_value(sun_z):
    # the in-place fast form against equation (1) written out here in float64: mu0/(mu+mu0) f(alpha) / MOC,
    # with phase angles over the whole range (below 10 deg: eq. (2); up to the anti-sun point: eq. (3))
    rng = np.random.default_rng(11)
    phase_deg = np.concatenate([np.linspace(0.0, 180.0, 721), rng.uniform(0.0, 12.0, 300)])
    emission_deg = rng.uniform(0.0, 89.0, phase_deg.size)
    alpha = phase_deg
    f_low = 2.05 - 3.93e-2 * alpha + 2.09e-3 * alpha**2 - 4.86e-5 * alpha**3 + 4.93e-7 * alpha**4 - 1.72e-9 * alpha**5
    f = np.where(alpha < 10.0, f_low, 1.82 - 1.03e-2 * (alpha - 10.0))
    mu = np.cos(np.radians(emission_deg))
    expected = (sun_z / (mu + sun_z) if sun_z > 0 else 0.0) * f / 0.61
    cos_emission = mu.astype(np.float32).reshape(1, -1)
    cos_phase = np.cos(np.radians(phase_deg)).astype(np.float32).reshape(1, -1)
    got = photometry.photometric_ratio_from_cosines(cos_emission, cos_phase, sun_z, 0.61)
    assert got.dtype == np.float32 and got.shape == (1, phase_deg.size)
    # float32 arccos near 0 and 180 deg is coarse (1e-3 deg): compare at float32 resolution of the angle
    assert np.allclose(got.ravel(), expected, rtol=2e-4, atol=2e-4)


@pytest.mark.parametrize("sun_z", [0.87, 0.2, 0.0])
def test_ratio_from_ray_dz_is_the_ratio_of_minus_dz_bit_for_bit(sun_z):
    # the exact map's form (cos e = -d_z, computed as mu0 / (mu0 - min(d_z, 0))) against equation (1) in
    # float64 on unit rays, and bit for bit against the cosine form given cos e = -d_z, with rays beyond
    # the horizon (d_z >= 0, signed zeros) whose mu clips to 0
    rng = np.random.default_rng(12)
    dz = np.concatenate([-rng.uniform(0.0, 1.0, 2000), rng.uniform(0.0, 0.3, 50), [0.0, -0.0, -1.0]])
    phase_deg = rng.uniform(0.0, 150.0, dz.size)
    alpha = phase_deg
    f_low = 2.05 - 3.93e-2 * alpha + 2.09e-3 * alpha**2 - 4.86e-5 * alpha**3 + 4.93e-7 * alpha**4 - 1.72e-9 * alpha**5
    f = np.where(alpha < 10.0, f_low, 1.82 - 1.03e-2 * (alpha - 10.0))
    mu = np.maximum(-dz, 0.0)
    expected = (sun_z / (mu + sun_z) if sun_z > 0 else 0.0) * f / 0.61
    ray_dz = dz.astype(np.float32).reshape(1, -1)
    cos_phase = np.cos(np.radians(phase_deg)).astype(np.float32).reshape(1, -1)
    got = photometry.photometric_ratio_from_ray_dz(ray_dz, cos_phase.copy(), sun_z, 0.61, out=np.empty_like(ray_dz))
    assert np.allclose(got.ravel(), expected, rtol=2e-4, atol=2e-4)
    from_cosines = photometry.photometric_ratio_from_cosines(-ray_dz, cos_phase.copy(), sun_z, 0.61)
    assert np.array_equal(got, from_cosines)
    assert np.array_equal(ray_dz.ravel(), dz.astype(np.float32))       # the rays are left as they were
