"""Synthetic relief per class (sitedata.terrain.relief): the height field under a level-ground I/F,
the class's slope distribution, site files with ``relief = true`` and the shipped example."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from config_tables.errors import ConfigError
from simulator.scene.relief import ReliefTerrain
from sitedata.sites import load_class_terrain, load_site, site_from_data
from sitedata.terrain import relief
from sitedata.terrain.synthetic_terrain import generate_reflectance, preset, surface_fields

SITEDATA = Path(__file__).resolve().parents[3] / "sitedata"


def small(name, **overrides):
    return dataclasses.replace(preset(name), rows=320, cols=320, **overrides)


def slope_correlation(image, height, mpp):
    """Correlation of an image with the east-west height gradient (the MOC sun is in the west)."""
    d_col = np.gradient(height.astype(float), mpp, axis=1)
    return float(np.corrcoef(image.ravel(), d_col.ravel())[0, 1])


def test_level_ground_reflectance_has_no_slope_shading_while_the_plain_strip_does():
    params = small("gkep", albedo_relative_spread=0.01, grain_snr=1000.0)
    reflectance, height = relief.generate_relief(params, 5)
    plain = generate_reflectance(params, 5)               # bakes the MOC's slope shading into its I/F
    assert abs(slope_correlation(plain, height, params.metres_per_pixel)) > 0.3
    assert abs(slope_correlation(reflectance, height, params.metres_per_pixel)) < 0.05
    # the height is the generator's, about the strip's mean plane
    generator_height, _ = surface_fields(params, 5)
    assert np.allclose(height, generator_height - generator_height.mean(), atol=1e-4)
    assert abs(float(height.mean())) < 1e-3


def test_background_relief_has_the_class_slope_distribution():
    for name in ("hbsp", "gdcp"):
        params = small(name, crater_density_per_km2=0.0)
        _, height = relief.generate_relief(params, 11)
        terrain = ReliefTerrain(np.ones_like(height), params.metres_per_pixel, np.zeros(2), 0.5, 0.0, 0.5,
                                height_m=height)
        stats = relief.relief_statistics(terrain)
        # RMS bidirectional slope at the pixel baseline: the preset's, in both directions (isotropic field),
        # its tangent times the class's contrast scale (the whole height field is scaled)
        expected = np.degrees(np.arctan(params.contrast_scale * np.tan(np.radians(params.rms_slope_deg))))
        assert stats["rms_slope_deg"] == pytest.approx(expected, rel=0.1)


def test_fresh_craters_reach_depth_over_diameter_of_the_literature():
    params = small("hdcp_rough_moc", rms_slope_deg=0.0, crater_density_per_km2=400.0, crater_depth_to_diameter=(0.2, 0.2),
                   crater_min_diameter_m=60.0, crater_max_diameter_m=61.0)      # contrast scale 1: the literature's depths
    _, height = relief.generate_relief(params, 2)
    height = height - np.median(height)                     # the plains level
    # fresh simple craters (Pike 1977): floor 0.2 D = 12 m below the rim crest at 0.04 D = 2.4 m
    assert height.min() == pytest.approx(-(0.2 - 0.04) * 60.0, rel=0.15)
    assert height.max() == pytest.approx(0.04 * 60.0, rel=0.5)   # overlapping rims add up


def test_site_with_relief_loads_a_relief_terrain_on_the_plain_grid(tmp_path):
    data = {"site": {"name": "T", "camera": str(SITEDATA / "cameras" / "mer_a.toml"),
                     "trajectory_set": str(SITEDATA / "trajectories" / "gusev.parquet"),
                     "sun": {"azimuth_deg": 268.0, "elevation_deg": 57.0, "heliocentric_distance_au": 1.5},
                     "classes": [{"name": "a", "ellipse_fraction": 1.0, "cases": 1,
                                  "terrain": {"kind": "synthetic", "preset": "gcp", "seed": 3, "relief": True,
                                              "overrides": {"rows": 256, "cols": 256}}}]}}
    site = site_from_data(data, tmp_path / "t.toml")
    terrain = load_class_terrain(site.classes[0].terrain, cache=False)
    plain_spec = site.classes[0].terrain.model_copy(update={"relief": False})
    plain = load_class_terrain(plain_spec, cache=False)
    assert isinstance(terrain, ReliefTerrain) and not isinstance(plain, ReliefTerrain)
    assert terrain.shape == plain.shape == terrain.height_m.shape
    assert np.array_equal(terrain.origin_m, plain.origin_m) and terrain.metres_per_pixel == plain.metres_per_pixel
    data["site"]["classes"][0]["terrain"]["relief"] = "yes"
    with pytest.raises(ConfigError) as error:
        site_from_data(data, tmp_path / "t.toml")
    assert "relief" in str(error.value) and "\n" not in str(error.value)


def test_relief_cache_round_trips(tmp_path):
    params = small("gcp")
    first = relief.cached_relief(params, 1, tmp_path)
    assert len(list(tmp_path.glob("relief_gcp_*.npz"))) == 1
    second = relief.cached_relief(params, 1, tmp_path)
    assert all(np.array_equal(a, b) for a, b in zip(first, second))


def test_shipped_example_is_gusev_with_relief_on_every_class():
    example = load_site(SITEDATA / "examples" / "relief.toml")
    gusev = load_site(SITEDATA / "gusev.toml")
    assert [c.terrain.relief for c in example.classes] == [True] * len(gusev.classes)
    for mine, theirs in zip(example.classes, gusev.classes):
        assert mine.terrain.model_dump() == {**theirs.terrain.model_dump(), "relief": True}
        assert (mine.name, mine.cases, mine.ellipse_fraction) == (theirs.name, theirs.cases, theirs.ellipse_fraction)


def test_a_mosaicked_relief_terrain_tiles_its_heights_with_its_image():
    from campaign.plan.coverage import Coverage, fit_terrain
    height = np.arange(64 * 64, dtype=np.float32).reshape(64, 64)
    terrain = ReliefTerrain(height / height.max(), 2.0, np.array([-63.0, 63.0]), 0.5, 0.0, 0.5, height_m=height)
    cover = Coverage(scale_needed=2.0, failing=1, trajectories=1, required_extent_m=(300.0, 200.0),
                     first_altitude_m=1000.0)
    tiled = fit_terrain(terrain, "mosaic", cover)
    assert isinstance(tiled, ReliefTerrain) and tiled.shape == tiled.height_m.shape == (101, 151)
    assert np.array_equal(tiled.height_m / height.max(), tiled.reflectance_if)   # the same mirror tiling


def test_planner_margin_is_the_parallax_of_the_lowest_ground_at_the_steepest_border_ray():
    from campaign.plan.coverage import relief_margin_m
    from flight_interface.camera import load_camera
    from simulator.scene.descent_profile import constant_velocity_profile
    from simulator.scene.terrain import Terrain
    camera = load_camera(SITEDATA / "cameras" / "mer_a.toml")
    profile = constant_velocity_profile([0.0, 0.0, 1500.0], [0.0, 0.0, 0.0], np.array([1.0, 0.0, 0.0, 0.0]),
                                        2.0, [0.1, 0.5])
    height = np.zeros((64, 64), np.float32)
    height[10, 20] = -12.0
    terrain = ReliefTerrain(np.ones((64, 64), np.float32), 3.0, np.zeros(2), 0.5, 0.0, 0.5, height_m=height)
    # nadir camera: the steepest border ray is a corner's, tan(theta) = |corner ray horizontal| / vertical
    corner = camera.pixel_rays[0, 0]
    expected = 12.0 * np.hypot(corner[0], corner[1]) / abs(corner[2])
    assert relief_margin_m(terrain, camera, [profile]) == pytest.approx(expected, rel=2e-3)
    plain = Terrain(np.ones((64, 64), np.float32), 3.0, np.zeros(2), 0.5, 0.0, 0.5)
    assert relief_margin_m(plain, camera, [profile]) == 0.0
    assert relief_margin_m(ReliefTerrain(plain.reflectance_if, 3.0, np.zeros(2), 0.5, 0.0, 0.5,
                                         height_m=np.abs(height)), camera, [profile]) == 0.0
