"""Site files: the shipped Gusev and Meridiani sites against the paper, validation errors, class
terrain loading and the PNG mosaic command."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from config_tables.errors import ConfigError
from sitedata.sites import ASTRONOMICAL_UNIT_M, class_terrain_params, load_class_terrain, load_site, sun_direction
from sitedata.terrain import write_mosaics
from sitedata.terrain.synthetic_classes import CLASS_PRESETS

REPO = Path(__file__).resolve().parents[2]
SITEDATA = REPO / "sitedata"
REALDATA = REPO.parent / "shared" / "realdata"

# paper Tables 1 and 2: class -> (ellipse fraction, number of cases)
PAPER = {"Gusev": {"gcp": (0.59, 186), "gdcp": (0.41, 112), "gkep": (0.0, 78)},
         "Meridiani": {"hbsp": (0.34, 44), "hdcp": (0.40, 179), "heb": (0.26, 31)}}


@pytest.mark.parametrize("file_name, site_name, camera", [("gusev.toml", "Gusev", "mer_a.toml"),
                                                          ("meridiani.toml", "Meridiani", "mer_b.toml")])
def test_shipped_sites_match_the_paper(file_name, site_name, camera):
    site = load_site(SITEDATA / file_name)
    assert site.name == site_name
    assert site.camera_path.resolve() == (SITEDATA / "cameras" / camera).resolve()
    assert site.trajectory_path.name == f"{site_name.lower()}.parquet"
    assert {c.name: (c.ellipse_fraction, c.cases) for c in site.classes} == PAPER[site_name]
    assert sum(c.cases for c in site.classes) == {"Gusev": 376, "Meridiani": 254}[site_name]
    # paper 2.3: DIMES images at 18-33 deg solar incidence; afternoon landings: sun in the west
    assert 18.0 <= math.degrees(site.sun_incidence_rad) <= 33.0
    assert site.sun_direction_world[0] < -0.25
    assert np.linalg.norm(site.sun_direction_world) == pytest.approx(1.0, abs=1e-12)
    assert site.sun_direction_world[2] == pytest.approx(math.cos(site.sun_incidence_rad), abs=1e-12)
    assert 1.38 * ASTRONOMICAL_UNIT_M < site.heliocentric_distance_m < 1.67 * ASTRONOMICAL_UNIT_M
    for site_class in site.classes:
        assert site_class.terrain.kind == "synthetic" and site_class.terrain.preset == site_class.name
    assert len({c.terrain.seed for c in site.classes}) == len(site.classes)


def test_sun_direction_closed_forms():
    np.testing.assert_allclose(sun_direction(math.radians(90), 0.0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(sun_direction(0.0, 0.0), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(sun_direction(math.radians(270), math.radians(30)),
                               [-math.cos(math.radians(30)), 0, 0.5], atol=1e-15)
    np.testing.assert_allclose(sun_direction(1.0, math.pi / 2), [0, 0, 1], atol=1e-15)


# ----------------------------------------------------------------------------------------------
GOOD = '''
[campaign]
anything = "ignored here: read by campaign/configuration/campaign_file.py"

[site]
name = "Test"
camera = "{camera}"
trajectory_set = "trajectories/test.parquet"

[site.sun]
azimuth_deg = 250.0
elevation_deg = 60.0
heliocentric_distance_au = 1.5

[[site.classes]]
name = "a"
ellipse_fraction = 0.25
cases = 3
terrain = {{ kind = "synthetic", preset = "gcp", seed = 1, overrides = {{ rows = 128, cols = 96 }} }}

[[site.classes]]
name = "b"
ellipse_fraction = 0.75
cases = 2
terrain = {{ kind = "synthetic", preset = "heb", seed = 2, overrides = {{ rows = 160, cols = 120, haze_optical_depth = 0.2 }} }}
'''


def write_site(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "site.toml"
    path.write_text(text.replace("{camera}", str(SITEDATA / "cameras" / "mer_a.toml")).replace("{{", "{").replace("}}", "}"))
    return path


def test_good_site_loads_with_relative_paths_and_overrides(tmp_path):
    site = load_site(write_site(tmp_path, GOOD))
    assert site.trajectory_path == tmp_path / "trajectories" / "test.parquet"
    assert [c.name for c in site.classes] == ["a", "b"]
    params = class_terrain_params(site.class_named("b").terrain)
    assert (params.rows, params.cols, params.haze_optical_depth, params.name) == (160, 120, 0.2, "heb")
    terrain = load_class_terrain(site.class_named("a").terrain, cache=False)
    assert terrain.shape == (128, 96) and terrain.metres_per_pixel == 3.0
    assert np.all(np.isfinite(terrain.reflectance_if)) and terrain.reflectance_if.dtype == np.float32
    with pytest.raises(KeyError, match="no appearance class 'zz'; classes: a, b"):
        site.class_named("zz")


def test_contrast_scales_multiply_the_presets_own(tmp_path):
    # gcp's calibrated preset already has a contrast scale; the terrain's and the site's multiply it
    text = GOOD.replace('name = "Test"', 'name = "Test"\nterrain_contrast_scale = 0.5').replace(
        "seed = 1,", "seed = 1, contrast_scale = 0.4,")
    site = load_site(write_site(tmp_path, text))
    preset_scale = CLASS_PRESETS["gcp"].contrast_scale
    assert class_terrain_params(site.class_named("a").terrain).contrast_scale == pytest.approx(preset_scale * 0.4 * 0.5)
    assert class_terrain_params(site.class_named("b").terrain).contrast_scale == pytest.approx(
        CLASS_PRESETS["heb"].contrast_scale * 0.5)
    plain = load_site(write_site(tmp_path, GOOD))
    assert class_terrain_params(plain.class_named("a").terrain) == CLASS_PRESETS["gcp"].__class__(
        **{**CLASS_PRESETS["gcp"].__dict__, "rows": 128, "cols": 96})
    # the rough-MOC variant is the calibrated class before its scale
    rough = CLASS_PRESETS["gcp_rough_moc"]
    assert rough.contrast_scale == 1.0 and rough.albedo_relative_spread == CLASS_PRESETS["gcp"].albedo_relative_spread


def test_class_terrain_is_built_once_per_process(tmp_path, monkeypatch):
    monkeypatch.setenv("MOC2DIMES_CACHE", str(tmp_path / "cache"))
    spec = load_site(write_site(tmp_path, GOOD)).class_named("b").terrain
    first = load_class_terrain(spec)
    assert load_class_terrain(spec) is first and not first.reflectance_if.flags.writeable
    fresh = load_class_terrain(spec, cache=False)
    assert fresh is not first and fresh.reflectance_if.tobytes() == first.reflectance_if.tobytes()


BROKEN = [
    (lambda t: t.replace("ellipse_fraction = 0.75", "ellipse_fraction = 0.7"),
     r"site.toml: site.classes ellipse_fraction values sum to 0.95; allowed: 1 within 1e-06"),
    (lambda t: t.replace("ellipse_fraction = 0.75", "ellipse_fraction = 1.75"),
     r"site.toml: site.classes\[1\].ellipse_fraction = 1.75 is out of range; allowed: >= 0 and <= 1"),
    (lambda t: t.replace('name = "Test"', 'name = "Test"\ncolour = "red"'),
     r"site.toml: site.colour is not a known field; allowed: name, camera, trajectory_set, sun, classes, "
     r"terrain_contrast_scale"),
    (lambda t: t.replace("seed = 1,", "seed = 1, contrast_scale = 0.0,"),
     r"site.classes\[0\].terrain.contrast_scale = 0 is out of range; allowed: > 0 and <= 4"),
    (lambda t: t.replace('name = "Test"', 'name = "Test"\nterrain_contrast_scale = 5.0'),
     r"site.terrain_contrast_scale = 5 is out of range; allowed: > 0 and <= 4"),
    (lambda t: t.replace("rows = 128", "contrast_scale = 0.5, rows = 128"),     # the terrain's own key, not an override
     r"site.classes\[0\].terrain.overrides.contrast_scale is not a known field"),
    (lambda t: t.replace('preset = "gcp"', 'preset = "gxx"'),
     r"site.classes\[0\].terrain.preset = 'gxx' is not allowed; allowed: gcp, gdcp, gkep, hbsp, hdcp, heb"),
    (lambda t: t.replace('kind = "synthetic", preset = "gcp"', 'kind = "moc", preset = "gcp"'),
     r"site.classes\[0\].terrain.kind = 'moc' is not allowed; allowed: synthetic, file"),
    (lambda t: t.replace("cases = 3", "cases = -3"),
     r"site.classes\[0\].cases = -3 is out of range; allowed: >= 0"),
    (lambda t: t.replace('name = "b"', 'name = "a"'),
     r"site.classes\[1\].name = 'a' is a duplicate; class names must be unique"),
    (lambda t: t.replace("elevation_deg = 60.0", "elevation_deg = 95.0"),
     r"site.sun.elevation_deg = 95 is out of range; allowed: > 0 and <= 90"),
    (lambda t: t.replace("heliocentric_distance_au = 1.5", "heliocentric_distance_au = 1.0"),
     r"site.sun.heliocentric_distance_au = 1 is out of range; allowed: >= 1.38 and <= 1.67"),
    (lambda t: t.replace("azimuth_deg = 250.0\n", ""),
     r"site.toml: site.sun.azimuth_deg is missing"),
    (lambda t: t.replace("rows = 128", "rowz = 128"),
     r"site.classes\[0\].terrain.overrides.rowz is not a known field; allowed: rows, cols, metres_per_pixel"),
    (lambda t: t.replace("haze_optical_depth = 0.2", "haze_optical_depth = 9.0"),
     r"site.classes\[1\].terrain.overrides: synthetic terrain preset 'heb': haze_optical_depth = 9.0 is out of range"),
    (lambda t: t.replace("seed = 1,", 'seed = "one",'),
     r"site.classes\[0\].terrain.seed must be an integer; got str 'one'"),
    (lambda t: t.replace('"{camera}"', '"nowhere/cam.toml"'),
     r"site.toml: site.camera = 'nowhere/cam.toml': no such file"),
    (lambda t: t.replace("[site.sun]", "[site.moon]"),
     r"site.toml: site.moon is not a known field"),
    (lambda t: t.replace("[[site.classes]]", "[[site.klasses]]"),
     r"site.toml: site.klasses is not a known field"),
    (lambda t: t.split("[site]")[0],
     r"site.toml: site is missing"),
    (lambda t: t + "\n[[site.classes]]\nname = \"c\"\nellipse_fraction = 0.0\ncases = 1\n"
                   "terrain = {{ kind = \"file\", path = \"x.img\", preset = \"gcp\" }}\n",
     r"site.classes\[2\].terrain.preset is not a known field; allowed: resample, kind, path, sidecar"),
]


@pytest.mark.parametrize("edit, message", BROKEN)
def test_broken_site_files_give_one_line_errors(tmp_path, edit, message):
    path = write_site(tmp_path, edit(GOOD))
    with pytest.raises(ConfigError, match=message) as caught:
        load_site(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)


def test_invalid_toml_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_site(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[site\nname=")
    with pytest.raises(ConfigError, match="bad.toml: invalid TOML"):
        load_site(bad)


def test_file_terrain_missing_image_is_a_clear_error(tmp_path):
    text = GOOD + ('\n[[site.classes]]\nname = "c"\nellipse_fraction = 0.0\ncases = 1\n'
                   'terrain = {{ kind = "file", path = "images/none.img" }}\n')
    site = load_site(write_site(tmp_path, text))
    spec = site.class_named("c").terrain
    assert spec.path == tmp_path / "images" / "none.img" and spec.sidecar is None
    with pytest.raises(ConfigError, match=r"site.classes\[2\].terrain.path: no such file .*none.img"):
        load_class_terrain(spec)


def test_real_moc_example_terrain_loads():
    if not REALDATA.is_dir():
        pytest.skip(f"real Mars data folder {REALDATA} is absent: real MOC example not loaded")
    site = load_site(SITEDATA / "examples" / "real_moc.toml")
    terrain = load_class_terrain(site.classes[0].terrain)
    assert terrain.shape == (4864, 672) and np.all(np.isfinite(terrain.reflectance_if))


def test_mosaic_command_writes_viewable_pngs(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("MOC2DIMES_CACHE", str(tmp_path / "cache"))
    site_path = write_site(tmp_path, GOOD)
    out = tmp_path / "png"
    assert write_mosaics.main(["--site", str(site_path), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "mean I/F" in printed and "RMS contrast" in printed
    for name in ("test_a.png", "test_b.png", "test_mosaic.png"):
        image = cv2.imread(str(out / name), cv2.IMREAD_UNCHANGED)
        assert image is not None and image.dtype == np.uint8 and image.ndim == 2
        assert image.std() > 10                                        # not blank
    mosaic = cv2.imread(str(out / "test_mosaic.png"), cv2.IMREAD_UNCHANGED)
    assert mosaic.shape[1] >= 96 // 4 + 120 // 4
    broken = write_site(tmp_path, GOOD.replace('preset = "gcp"', 'preset = "zzz"'))
    assert write_mosaics.main(["--site", str(broken), "--out", str(out)]) == 2
    assert "preset = 'zzz' is not allowed" in capsys.readouterr().err
