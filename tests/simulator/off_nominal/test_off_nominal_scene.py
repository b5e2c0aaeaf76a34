"""Off-nominal scene effects: heat-shield glint, angular rate multiplier, [scene.off_nominal] config,
per-case artefacts through render_descent_image."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from config_tables.errors import ConfigError
from config_tables.models import parse
from flight_interface.camera import load_camera
from flight_interface.frames import quat_conjugate, quat_from_axis_angle, quat_multiply, quat_to_rotation_vector
from simulator.descent_image import render_descent_image
from simulator.off_nominal import OffNominalArtefacts, OffNominalConfig, draw_case_artefacts, with_particle_hits
from simulator.scene import ground_mapping, motion_blur, photometry
from simulator.scene.descent_profile import DescentProfile, constant_velocity_profile, scale_angular_rates
from simulator.scene.glint import specular_radiance
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
SUN_40 = np.array([np.sin(np.radians(40.0)), 0.0, np.cos(np.radians(40.0))])   # sun 40 deg from zenith, east


def flat_terrain(size=1600, mpp=3.0) -> Terrain:
    rng = np.random.default_rng(3)
    values = (0.2 + 0.02 * rng.standard_normal((size, size))).astype(np.float32)
    half = 0.5 * (size - 1) * mpp
    return Terrain(values, mpp, np.array([-half, half]), np.radians(30), 0.0, np.radians(30), "flat")


def shield_below(axial_m=150.0) -> DescentProfile:
    base = constant_velocity_profile([0.0, 0.0, 2000.0], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.5])
    shield = np.tile([0.0, 0.0, 2000.0 - axial_m], (2, 1))
    return replace(base, heat_shield_position_m=shield)


def with_off_nominal(**values) -> SceneConfig:
    return SceneConfig().with_effects(shadows=False).with_fields(off_nominal=OffNominalConfig(**values))


# ---------------------------------------------------------------- glint

def test_specular_lobe_reflects_rho_times_the_incident_flux():
    """Energy: a narrow normalised facet lobe returns rho_s E cos(theta_i) over the hemisphere."""
    normal = np.array([0.0, 0.0, 1.0])
    theta = np.linspace(0.0, 0.5 * np.pi, 2001)[:-1] + 0.5 * (0.5 * np.pi / 2000)
    phi = np.linspace(0.0, 2 * np.pi, 361)[:-1] + np.pi / 360
    grid_t, grid_p = np.meshgrid(theta, phi, indexing="ij")
    view = np.stack([np.sin(grid_t) * np.cos(grid_p), np.sin(grid_t) * np.sin(grid_p), np.cos(grid_t)], axis=-1)
    solid_angle = np.sin(grid_t) * (theta[1] - theta[0]) * (phi[1] - phi[0])
    for incidence in (0.0, 30.0):
        sun = np.array([np.sin(np.radians(incidence)), 0.0, np.cos(np.radians(incidence))])
        radiance = specular_radiance(np.broadcast_to(normal, view.shape), sun, view, 500.0, 0.05,
                                                 np.radians(3.0))
        reflected = np.sum(radiance * np.cos(grid_t) * solid_angle)
        assert reflected == pytest.approx(0.05 * 500.0 * np.cos(np.radians(incidence)), rel=0.01)
        # the peak is in the mirror direction: rho E / (4 pi m^2 cos theta_v)
        mirror = np.array([-sun[0], 0.0, sun[2]])
        peak = specular_radiance(normal, sun, mirror, 500.0, 0.05, np.radians(3.0))
        m2 = np.tan(np.radians(3.0)) ** 2
        assert float(peak) == pytest.approx(0.05 * 500.0 / (4 * np.pi * m2 * np.cos(np.radians(incidence))), rel=1e-9)


def test_heat_shield_glint_on_the_anti_sun_wall_saturates_and_blooms():
    terrain, profile = flat_terrain(), shield_below()
    plain = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(), None)
    glint = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(heat_shield_glint=True), None)
    added = glint.radiance.exposure.astype(np.float64) - plain.radiance.exposure
    mask = plain.heat_shield_mask
    assert mask.any() and np.all(added[~mask] == 0.0) and added.max() > 0
    # camera straight above, sun 40 deg from zenith: the half vector is 20 deg from vertical, the lining's
    # normal tilt (70 deg half-angle cone) -> the glint is on the wall whose normal leans toward the sun,
    # the far (west, smaller column) side
    rows, cols = np.nonzero(mask)
    weights = added[rows, cols]
    assert np.average(cols, weights=weights) < cols.mean() - 5
    irradiance = photometry.solar_band_irradiance_w_m2_um(photometry.MARS_MEAN_SUN_DISTANCE_AU)
    peak = 0.05 * irradiance / (4 * np.pi * np.tan(np.radians(3.0)) ** 2 * np.cos(np.radians(20.0)))
    assert 0.8 * peak < added.max() <= 1.02 * peak
    # far above full well: the 12-bit image saturates and the column blooms (charge kept, not clipped)
    assert glint.dn.max() == CAMERA.electronics.max_dn and plain.dn.max() < CAMERA.electronics.max_dn
    clipped = render_descent_image(terrain, profile, CAMERA, 0, SUN_40,
                                   with_off_nominal(heat_shield_glint=True, blooming=False), None)
    bloomed_charge = glint.image.expected_charge_e.astype(np.float64)
    clipped_charge = clipped.image.expected_charge_e.astype(np.float64)
    assert bloomed_charge.sum() > clipped_charge.sum() + 10 * CAMERA.electronics.full_well_e
    full_binned = CAMERA.binning_rows * CAMERA.electronics.full_well_e
    assert np.count_nonzero(bloomed_charge >= 0.999 * full_binned) > np.count_nonzero(clipped_charge >= 0.999 * full_binned)


def test_no_glint_where_the_geometry_forbids_it():
    # sun overhead and camera overhead: half vector vertical, 20 deg from every lining normal (~7 sigma)
    terrain, profile = flat_terrain(), shield_below()
    overhead = np.array([0.0, 0.0, 1.0])
    plain = render_descent_image(terrain, profile, CAMERA, 0, overhead, with_off_nominal(), None)
    glint = render_descent_image(terrain, profile, CAMERA, 0, overhead, with_off_nominal(heat_shield_glint=True), None)
    assert np.abs(glint.radiance.exposure.astype(np.float64) - plain.radiance.exposure).max() < 1e-6 * irradiance_ratio()


def irradiance_ratio() -> float:
    return photometry.solar_band_irradiance_w_m2_um(photometry.MARS_MEAN_SUN_DISTANCE_AU)


# ---------------------------------------------------------------- angular rate multiplier

def rotating_still_profile(rate_rad_s: float) -> DescentProfile:
    """A hovering lander (zero velocity) turning about a tilted axis at a constant rate."""
    time = np.linspace(0.0, 1.0, 5)
    axis = np.array([1.0, 0.4, 0.2])
    attitude = np.stack([quat_from_axis_angle(axis, rate_rad_s * (t - 0.5)) for t in time])
    rates = np.tile(rate_rad_s * axis / np.linalg.norm(axis), (5, 1))
    return DescentProfile(time, np.tile([0.0, 0.0, 2000.0], (5, 1)), np.zeros((5, 3)), attitude, rates,
                          np.zeros((5, 3)), None, np.array([0.4]), "rotating")


def test_rate_multiplier_scales_the_exposure_image_shift_linearly():
    profile = rotating_still_profile(np.radians(30.0))
    start, exposure = 0.4, CAMERA.timing.exposure_s
    centre = start + 0.5 * exposure

    def exposure_shift(k):
        scaled = scale_angular_rates(profile, k, centre)
        poses = [ground_mapping.camera_pose(CAMERA, scaled.pose(t)) for t in (start, start + exposure)]
        return motion_blur.image_shift(CAMERA, poses[0], poses[1], terrain_mpp=1e-3)   # image px dominate

    base = exposure_shift(1.0)
    centre_px = np.radians(30.0) * exposure * 1222.5          # shift at the image centre for a pure tilt, 3.3 px
    assert centre_px < base < 1.5 * centre_px                   # corners add roll and the 1/cos^2 edge scale
    for k in (0.5, 2.0, 4.0, 8.0):
        assert exposure_shift(k) == pytest.approx(k * base, rel=0.01)
    assert exposure_shift(0.0) == pytest.approx(0.0, abs=1e-6)
    # the attitude at mid-exposure is unchanged; the rotation relative to it is k times larger
    scaled = scale_angular_rates(profile, 3.0, centre)
    assert np.allclose(scaled.pose(centre).attitude_quat, profile.pose(centre).attitude_quat, atol=1e-12)
    relative = quat_multiply(quat_conjugate(profile.pose(centre).attitude_quat), scaled.pose(centre + 0.01).attitude_quat)
    assert np.linalg.norm(quat_to_rotation_vector(relative)) == pytest.approx(3.0 * np.radians(30.0) * 0.01, rel=1e-9)
    assert np.allclose(scaled.pose(centre).angular_rate_radps, 3.0 * profile.pose(centre).angular_rate_radps)
    assert scale_angular_rates(profile, 1.0, centre) is profile


def test_rate_multiplier_in_the_renderer_adds_motion_substeps():
    terrain, profile = flat_terrain(), rotating_still_profile(np.radians(20.0))
    nominal = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(), None)
    fast = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(angular_rate_multiplier=4.0), None)
    assert fast.diagnostics.substeps["exposure"] >= 3 * nominal.diagnostics.substeps["exposure"]
    assert np.allclose(fast.diagnostics.camera_pose.camera_to_world, nominal.diagnostics.camera_pose.camera_to_world)
    assert np.std(np.diff(fast.dn[100:150, 512].astype(float))) < np.std(np.diff(nominal.dn[100:150, 512].astype(float)))


# ---------------------------------------------------------------- config and artefacts

def test_off_nominal_toml_keys_defaults_and_errors():
    assert parse(SceneConfig, {}, "s.toml", "scene").off_nominal == OffNominalConfig()
    assert not OffNominalConfig().needs_case_artefacts and OffNominalConfig().blooming
    table = {"dust_particle_count": 20, "dust_particle_diameter_mean_m": 2e-4, "dust_particle_diameter_max_m": 2e-3,
             "dust_lens_distance_m": 0.01, "hot_pixel_fraction": 1e-3, "hot_pixel_amplitude_mean_e_per_s": 3e5,
             "particle_hit_rate_per_cm2_s": 50.0, "particle_hit_charge_e_per_m": 8e7, "particle_hit_depth_m": 1.5e-5,
             "particle_hit_max_track_length_m": 5e-4, "heat_shield_glint": True,
             "heat_shield_specular_reflectance": 0.08, "heat_shield_specular_roughness_deg": 5.0,
             "blooming": False, "angular_rate_multiplier": 2.5}
    config = parse(SceneConfig, {"off_nominal": table}, "s.toml", "scene").off_nominal
    assert config.heat_shield_specular_roughness_rad == pytest.approx(np.radians(5.0))
    for key, value in table.items():
        if key != "heat_shield_specular_roughness_deg":
            assert getattr(config, key) == value
    assert config.needs_case_artefacts
    for bad, message in (({"dust_particle_count": 1.5}, "dust_particle_count must be an integer"),
                         ({"angular_rate_multiplier": -1.0}, "angular_rate_multiplier = -1 is out of range"),
                         ({"hot_pixel_fraction": 2.0}, "hot_pixel_fraction = 2 is out of range; allowed: >= 0 and <= 1"),
                         ({"heat_shield_glint": "yes"}, "heat_shield_glint must be true or false"),
                         ({"dust_count": 3}, "dust_count is not a known field; allowed: dust_particle_count")):
        with pytest.raises(ConfigError, match=f"s.toml: scene.off_nominal.{message}") as error:
            parse(OffNominalConfig, bad, "s.toml", "scene.off_nominal")
        assert "\n" not in str(error.value)


def test_case_artefacts_are_fixed_across_images_and_required_when_configured():
    terrain = flat_terrain()
    profile = constant_velocity_profile([0.0, 0.0, 2000.0], [5.0, 0.0, -72.0], LEVEL, 10.0, [1.0, 4.0, 7.75])
    off = OffNominalConfig(dust_particle_count=30, hot_pixel_fraction=1e-4, particle_hit_rate_per_cm2_s=200.0)
    config = SceneConfig(off_nominal=off)
    with pytest.raises(ValueError, match="draw_case_artefacts"):
        render_descent_image(terrain, profile, CAMERA, 0, SUN_40, config, np.random.default_rng(0))

    seeds = np.random.SeedSequence([7, 3]).spawn(4)
    fixed = draw_case_artefacts(CAMERA, off, np.random.default_rng(seeds[0]))
    images = [with_particle_hits(fixed, CAMERA, off, np.random.default_rng(seeds[1 + k])) for k in range(3)]
    assert all(image.dust_transmission is fixed.dust_transmission and image.hot_pixels is fixed.hot_pixels
               for image in images)
    assert fixed.dust_transmission.min() < 0.99 and fixed.hot_pixels.flat_index.size > 50
    assert len({image.particle_hits.count for image in images}) > 1 or not np.array_equal(
        images[0].particle_hits.rows, images[1].particle_hits.rows)
    again = draw_case_artefacts(CAMERA, off, np.random.default_rng(np.random.SeedSequence([7, 3]).spawn(4)[0]))
    assert np.array_equal(again.dust_transmission, fixed.dust_transmission)

    first = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, config, np.random.default_rng(1), images[0])
    clean = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, SceneConfig(), np.random.default_rng(1))
    empty = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, SceneConfig(), np.random.default_rng(1),
                                 OffNominalArtefacts())
    assert np.array_equal(clean.dn, empty.dn)                         # empty artefacts change nothing
    assert not np.array_equal(first.dn, clean.dn)
    ratio = first.image.expected_charge_e / clean.image.expected_charge_e
    binned_transmission = fixed.dust_transmission.reshape(256, 4, 1024).mean(axis=1)
    # the charge follows the dust transmission (smear and dark current dilute it by ~1 %)
    assert np.median(ratio / binned_transmission) == pytest.approx(1.0, abs=0.01)
    assert np.corrcoef(ratio.ravel(), binned_transmission.ravel())[0, 1] > 0.95


def test_glint_is_added_to_every_period_field_with_its_area_kept():
    # a descending, turning lander: the smear periods get their own (possibly block-mean) fields
    terrain = flat_terrain()
    time = np.linspace(0.0, 1.0, 3)
    attitude = np.stack([quat_from_axis_angle([1.0, 0.0, 0.0], np.radians(10.0) * t) for t in time])
    position = np.array([[0.0, 0.0, 2000.0]]) + np.outer(time, [8.0, 0.0, -72.0])
    profile = DescentProfile(time, position, np.tile([8.0, 0.0, -72.0], (3, 1)), attitude,
                             np.tile([np.radians(10.0), 0.0, 0.0], (3, 1)), np.zeros((3, 3)),
                             position + [0.0, 0.0, -150.0], np.array([0.5]), "moving")
    plain = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(), None)
    glint = render_descent_image(terrain, profile, CAMERA, 0, SUN_40, with_off_nominal(heat_shield_glint=True), None)
    assert not glint.diagnostics.shared_fields
    totals = {}
    for period in ("flush", "exposure", "transfer"):
        added = getattr(glint.radiance, period).astype(np.float64) - getattr(plain.radiance, period)
        rows_per_value = CAMERA.height_px // added.shape[0]           # 1, or 4 for a block-mean smear field
        totals[period] = added.sum() * rows_per_value
        assert added.min() > -1e-3
    assert totals["exposure"] > 0
    for period in ("flush", "transfer"):
        assert totals[period] == pytest.approx(totals["exposure"], rel=0.2)
