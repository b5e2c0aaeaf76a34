"""The dusty atmosphere stage (simulator.scene.atmosphere) against closed forms and independent quadrature."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

from config_tables.errors import ConfigError
from config_tables.models import parse
from config_tables.toml_file import load_toml
from flight_interface.camera import load_camera
from simulator.descent_image import render_descent_image
from simulator.scene import atmosphere, ground_mapping, photometry
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.scene_config import AtmosphereConfig, SceneConfig

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
LEVEL = np.array([1.0, 0.0, 0.0, 0.0])
SUN = np.array([-np.sin(np.radians(33.0)), 0.0, np.cos(np.radians(33.0))])   # from the west, 33 deg incidence
ISOTROPIC = dict(forward_asymmetry=0.0, backward_asymmetry=0.0, forward_fraction=1.0)


def isotropic_diffuse_transmission(t: float, mu: float, albedo: float) -> float:
    """(A4) for p = 1, integrated by adaptive quadrature (independent of the code's Gauss/table)."""
    if t == 0.0:
        return 0.0

    def integrand(mu_prime):
        if abs(mu_prime - mu) < 1e-9:
            return t / mu * np.exp(-t / mu)
        return mu_prime * (np.exp(-t / mu_prime) - np.exp(-t / mu)) / (mu_prime - mu)
    return 0.5 * albedo * integrate.quad(integrand, 0.0, 1.0, points=[mu], limit=200)[0]


def step_terrain(left_if: float, right_if: float) -> Terrain:
    """A 3 km square at 3 m/pixel, I/F ``left_if`` west of x = 0 and ``right_if`` east of it (exactly half each)."""
    size, mpp = 1000, 3.0
    values = np.full((size, size), left_if, np.float32)
    values[:, size // 2:] = right_if
    origin = np.array([-(size // 2 - 0.5) * mpp, 0.5 * (size - 1) * mpp])
    return Terrain(values, mpp, origin, np.radians(40.0), 0.0, np.radians(40.0), "step")


def nadir_profile(altitude_m: float):
    return constant_velocity_profile([0.0, 0.0, altitude_m], [0.0, 0.0, 0.0], LEVEL, 1.0, [0.5])


def plain_scene(atmosphere_config: AtmosphereConfig | None = None) -> SceneConfig:
    config = SceneConfig().with_effects(photometric_correction=False, shadows=False, heat_shield=False)
    return config if atmosphere_config is None else config.with_fields(atmosphere=atmosphere_config)


def test_zero_optical_depth_is_the_identity():
    terrain = step_terrain(0.18, 0.26)
    config = AtmosphereConfig(orbital_optical_depth=0.0)
    haze = atmosphere.orbital_haze(terrain, config)
    assert haze.offset_if == 0.0 and haze.path_if == 0.0 and haze.transmission == 1.0 and haze.illumination == 1.0
    views = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.8, 0.6]])
    gain, adjacency, path = atmosphere.descent_factors(views, SUN, 2000.0, haze, config)
    assert np.all(gain == 1.0) and np.all(adjacency == 0.0) and np.all(path == 0.0)
    # the whole render: a vanishing optical depth goes through the atmosphere path (its own photometric
    # ratio and radiometric scale) and lands on the render without atmosphere
    rough = Terrain(0.2 + 0.03 * np.random.default_rng(4).standard_normal((1000, 1000)).astype(np.float32), 3.0,
                    np.array([-1498.5, 1498.5]), np.radians(40.0), 0.0, np.radians(40.0), "rough")
    profile = nadir_profile(2000.0)
    off = render_descent_image(rough, profile, CAMERA, 0, SUN, SceneConfig(), None)
    thin = render_descent_image(rough, profile, CAMERA, 0, SUN,
                                SceneConfig(atmosphere=AtmosphereConfig(orbital_optical_depth=1e-7)), None)
    assert np.allclose(thin.radiance.exposure, off.radiance.exposure, rtol=2e-6, atol=1e-5)
    assert SceneConfig().atmosphere.enabled is False


def test_step_scene_contrast_ratio_matches_the_closed_form():
    """Uniform-plus-step terrain, isotropic dust: descent/orbital contrast from (A1)-(A7) by hand."""
    left, right, tau, albedo, altitude = 0.18, 0.26, 0.6, 0.9, 2000.0
    terrain = step_terrain(left, right)
    config = AtmosphereConfig(orbital_optical_depth=tau, single_scattering_albedo=albedo, **ISOTROPIC)
    field = render_descent_image(terrain, nadir_profile(altitude), CAMERA, 0, SUN, plain_scene(config), None)
    cam = field.diagnostics.camera_pose
    pixels = np.array([[511.5 - 80.0, 511.5], [511.5 + 80.0, 511.5]])
    points, hit = ground_mapping.ground_points(CAMERA, cam, pixels)
    assert hit.all() and points[0, 0] < -100.0 and points[1, 0] > 100.0
    view = cam.ray_origin_m[None, :] - points
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    measured = np.array([field.radiance.exposure[511:513, 431], field.radiance.exposure[511:513, 592]]).mean(axis=1)

    # orbital side: MOC at incidence 40, emission 0, phase 40 deg; isotropic p = 1
    mu0_o, mu_o = np.cos(np.radians(40.0)), 1.0
    path_o = albedo / 4.0 * mu0_o / (mu_o + mu0_o) * (1.0 - np.exp(-tau * (1.0 / mu_o + 1.0 / mu0_o)))
    td_o = isotropic_diffuse_transmission(tau, mu_o, albedo)
    surface = (0.5 * (left + right) - path_o) / (np.exp(-tau / mu_o) + td_o)
    offset = surface * td_o + path_o
    illumination_o = np.exp(-tau / mu0_o) + isotropic_diffuse_transmission(tau, mu0_o, albedo)
    # descent side: dust below 2 km, sun at 33 deg
    below = tau * (1.0 - np.exp(-altitude / 11100.0))
    above = tau - below
    mu0_d = SUN[2]
    illumination_d = np.exp(-tau / mu0_d) + isotropic_diffuse_transmission(tau, mu0_d, albedo)
    kappa = illumination_d / illumination_o
    expected = []
    for value, v in zip((left, right), view):
        mu = v[2]
        path_d = (np.exp(-above / mu0_d) * albedo / 4.0 * mu0_d / (mu + mu0_d)
                  * (1.0 - np.exp(-below * (1.0 / mu + 1.0 / mu0_d))))
        reflectance = kappa * ((value - offset) * np.exp(tau / mu_o - below / mu)
                               + surface * isotropic_diffuse_transmission(below, mu, albedo)) + path_d
        expected.append(reflectance)
    expected = np.array(expected)
    irradiance = photometry.solar_band_irradiance_w_m2_um(SceneConfig().sun_distance_au)
    scale = irradiance / np.pi * SceneConfig().spectral_ratio
    assert measured == pytest.approx(scale * expected, rel=2e-3)
    descent_contrast = (measured[1] - measured[0]) / (measured[1] + measured[0])
    orbital_contrast = (right - left) / (right + left)
    ratio = descent_contrast / orbital_contrast
    expected_contrast = (expected[1] - expected[0]) / (expected[1] + expected[0])
    assert ratio == pytest.approx(expected_contrast / orbital_contrast, rel=2e-3)
    assert ratio > 1.2            # the descent camera sees more contrast than MOC did: the paper's explanation
    # without atmosphere the contrast is the orbital one
    clear = render_descent_image(terrain, nadir_profile(altitude), CAMERA, 0, SUN, plain_scene(), None)
    plain = np.array([clear.radiance.exposure[511:513, 431], clear.radiance.exposure[511:513, 592]]).mean(axis=1)
    assert (plain[1] - plain[0]) / (plain[1] + plain[0]) == pytest.approx(orbital_contrast, rel=1e-4)


def test_diffuse_transmission_matches_independent_quadrature():
    isotropic = AtmosphereConfig(orbital_optical_depth=1.0, single_scattering_albedo=0.9, **ISOTROPIC)
    for t in (0.05, 0.4, 1.5):
        for mu in (0.3, 0.71, 1.0):
            assert atmosphere.diffuse_transmission(t, mu, isotropic) == pytest.approx(
                isotropic_diffuse_transmission(t, mu, 0.9), rel=2e-3)
    # double Henyey-Greenstein: azimuthal mean and mu' integral by nested adaptive quadrature
    dhg = AtmosphereConfig(orbital_optical_depth=1.0)
    t, mu = 0.5, 0.8

    def integrand(phi, mu_prime):
        cos_theta = mu * mu_prime + np.sqrt((1 - mu**2) * (1 - mu_prime**2)) * np.cos(phi)
        p = (0.9 * (1 - 0.49) / (1 + 0.49 - 1.4 * cos_theta) ** 1.5
             + 0.1 * (1 - 0.09) / (1 + 0.09 + 0.6 * cos_theta) ** 1.5)
        if abs(mu_prime - mu) < 1e-9:
            kernel = t / mu * np.exp(-t / mu)
        else:
            kernel = mu_prime * (np.exp(-t / mu_prime) - np.exp(-t / mu)) / (mu_prime - mu)
        return p * kernel / (2 * np.pi)
    reference = 0.5 * 0.94 * integrate.dblquad(integrand, 0.0, 1.0, 0.0, 2 * np.pi, epsabs=1e-7)[0]
    assert atmosphere.diffuse_transmission(t, mu, dhg) == pytest.approx(reference, rel=3e-3)


def test_phase_function_is_normalised():
    config = AtmosphereConfig()
    mean = integrate.quad(lambda c: 0.5 * atmosphere.phase_function(c, config), -1.0, 1.0)[0]
    assert mean == pytest.approx(1.0, rel=1e-6)
    assert atmosphere.phase_function(1.0, config) > 10 * atmosphere.phase_function(0.0, config)   # forward peak


def test_path_radiance_grows_with_altitude_toward_the_orbital_value():
    config = AtmosphereConfig(orbital_optical_depth=0.7)
    sun = SUN
    view = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
    altitudes = [0.0, 10.0, 200.0, 1000.0, 2000.0, 5000.0, 20000.0, 80000.0, 400000.0]
    paths = [atmosphere.path_reflectance(*atmosphere.optical_depths(z, config), sun[2], view[2], -(view @ sun), config)
             for z in altitudes]
    assert paths[0] == 0.0
    assert np.all(np.diff(paths) > 0)
    orbital = atmosphere.path_reflectance(0.0, 0.7, sun[2], view[2], -(view @ sun), config)
    assert paths[-1] == pytest.approx(orbital, rel=1e-9)
    # at 2 km the camera has ~16.5 % of the column below it: about that fraction of the path light
    # (a bit more: the sun beam has been dimmed by the dust above)
    assert 0.12 * orbital < paths[4] < 0.2 * orbital


def test_energy_is_not_created():
    albedo = 1.0
    for tau in (1e-3, 0.3, 1.0, 3.0):
        config = AtmosphereConfig(orbital_optical_depth=tau, single_scattering_albedo=albedo, **ISOTROPIC)
        for mu0 in (0.3, 0.8, 1.0):
            # upward flux of the path light over the incident flux mu0 (I/F units: F = flux / pi)
            up = integrate.quad(lambda mu: 2 * np.pi * mu * float(
                atmosphere.path_reflectance(0.0, tau, mu0, mu, 0.0, config)),  # noqa: B023 - integrated right here
                1e-6, 1.0)[0] / (np.pi * mu0)
            scattered = albedo * (1.0 - np.exp(-tau / mu0))
            assert 0.0 < up < scattered
            if tau == 1e-3:
                assert up == pytest.approx(0.5 * albedo * tau / mu0, rel=0.03)   # thin layer: half goes up
            for mu in (0.2, 0.6, 1.0):
                direct = np.exp(-tau / mu)
                diffuse = float(atmosphere.diffuse_transmission(tau, mu, config))
                assert 0.0 < diffuse and direct + diffuse <= 1.0
                if tau == 1e-3:
                    assert diffuse == pytest.approx(0.5 * albedo * tau / mu, rel=0.03)
    # a realistic atmosphere never makes radiance negative, and the mean surface brightness is positive
    terrain = step_terrain(0.05, 0.3)
    config = AtmosphereConfig(orbital_optical_depth=0.9)
    rendered = render_descent_image(terrain, nadir_profile(2000.0), CAMERA, 0, SUN,
                                    SceneConfig(atmosphere=config), None)
    assert rendered.radiance.exposure.min() >= 0.0
    assert atmosphere.orbital_haze(terrain, config).surface_mean_if > 0.0


def test_too_thick_an_atmosphere_for_the_terrain_is_refused():
    terrain = step_terrain(0.01, 0.02)
    with pytest.raises(ValueError, match=r"scene.atmosphere: orbital path I/F .* orbital_optical_depth 5 .* "
                                         r"allowed: a smaller"):
        atmosphere.orbital_haze(terrain, AtmosphereConfig(orbital_optical_depth=5.0))


def test_atmosphere_table(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text("[scene.atmosphere]\norbital_optical_depth = 0.5\nscale_height_m = 10800.0\n"
                    "single_scattering_albedo = 0.96\ndescent_path = false\n")
    config = parse(SceneConfig, load_toml(path)["scene"], path, "scene").atmosphere
    assert config == AtmosphereConfig(orbital_optical_depth=0.5, scale_height_m=10800.0,
                                      single_scattering_albedo=0.96, descent_path=False)
    assert config.enabled
    assert parse(SceneConfig, {}, "x").atmosphere == AtmosphereConfig()
    path.write_text("[scene.atmosphere]\norbital_optical_depth = -0.1\n")
    with pytest.raises(ConfigError, match=r"scene.toml: scene.atmosphere.orbital_optical_depth = -0.1 is out of range; "
                                          r"allowed: >= 0 and <= 10"):
        parse(SceneConfig, load_toml(path)["scene"], path, "scene")
    path.write_text("[scene.atmosphere]\noptical_depth = 0.5\n")
    with pytest.raises(ConfigError, match=r"scene.atmosphere.optical_depth is not a known field; "
                                          r"allowed: .*orbital_optical_depth"):
        parse(SceneConfig, load_toml(path)["scene"], path, "scene")
