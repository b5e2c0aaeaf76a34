"""Synthetic appearance-class terrain: physics of each stage against closed forms, class ordering,
spectral realism against the real MOC and CTX images, determinism and the disk cache."""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy import ndimage

from campaign.realism.terrain_stats import crater_density_per_km2
from sitedata.terrain import synthetic_features as feat
from sitedata.terrain import synthetic_terrain as st

REPO = Path(__file__).resolve().parents[3]
REALDATA = REPO.parent / "shared" / "realdata"

# A plain, featureless class: every effect off unless a test switches it on.
BARE = dict(rows=256, cols=256, albedo_relative_spread=0.0, rms_slope_deg=0.0, crater_density_per_km2=0.0,
            crater_rim_albedo_contrast=0.0, haze_optical_depth=0.0, haze_path_if=0.0, grain_snr=1e9)


# ----------------------------------------------------------------------------------------------
# independent image measurements
def radial_power_spectrum(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hann-windowed 2-D power spectrum; returns (|k| cycles/px, power) for every frequency."""
    data = image.astype(np.float64) - image.mean()
    window = np.outer(np.hanning(data.shape[0]), np.hanning(data.shape[1]))
    power = np.abs(np.fft.fft2(data * window)) ** 2
    k = np.hypot(np.fft.fftfreq(data.shape[0])[:, None], np.fft.fftfreq(data.shape[1])[None, :])
    return k.ravel(), power.ravel()


def spectral_slope(image: np.ndarray, shortest_px: float = 4.0, longest_px: float = 64.0) -> float:
    """Log-log slope of the radially averaged power spectrum over the given wavelengths."""
    k, power = radial_power_spectrum(image)
    edges = np.geomspace(1.0 / longest_px, 1.0 / shortest_px, 13)
    which = np.digitize(k, edges)
    centres = np.sqrt(edges[:-1] * edges[1:])
    means = np.array([power[which == i].mean() for i in range(1, len(edges))])
    return float(np.polyfit(np.log(centres), np.log(means), 1)[0])


def binned_rms_contrast(image: np.ndarray, factor: int = 4) -> float:
    """RMS / mean after factor x factor block averaging (terrain contrast, grain suppressed)."""
    rows, cols = (image.shape[0] // factor) * factor, (image.shape[1] // factor) * factor
    blocks = image[:rows, :cols].reshape(rows // factor, factor, cols // factor, factor).mean(axis=(1, 3))
    return float(blocks.std() / blocks.mean())


def read_moc_pds3(path: Path) -> np.ndarray:
    """Minimal reader for the attached-label uint8 MOC product (RECORD_BYTES, ^IMAGE, LINES, LINE_SAMPLES)."""
    raw = path.read_bytes()
    label = raw[:raw.find(b"\nEND\r\n") if b"\nEND\r\n" in raw else 4096].decode("ascii", "replace")
    def value(key):
        return int(re.search(rf"^\s*{re.escape(key)}\s*=\s*(\d+)", label, re.M).group(1))
    record, start = value("RECORD_BYTES"), (value("^IMAGE") - 1) * value("RECORD_BYTES")
    lines, samples = value("LINES"), value("LINE_SAMPLES")
    assert record == samples
    return np.frombuffer(raw, np.uint8, lines * samples, start).reshape(lines, samples)


@pytest.fixture(scope="module")
def real_slope_range():
    if not REALDATA.is_dir():
        pytest.skip(f"real Mars data folder {REALDATA} is absent: spectral realism not checked")
    slopes = {"MOC M0100115": spectral_slope(read_moc_pds3(REALDATA / "moc_na" / "M0100115_decompressed.img"))}
    for tile in sorted((REALDATA / "ctx_tiles").glob("MC11E-*.png")):
        slopes[f"CTX {tile.stem}"] = spectral_slope(cv2.imread(str(tile), cv2.IMREAD_GRAYSCALE))
    assert len(slopes) == 7, slopes
    return min(slopes.values()), max(slopes.values()), slopes


# ----------------------------------------------------------------------------------------------
# class ordering and realism
@pytest.mark.slow
def test_strip_geometry_and_values(site_strips):
    """Slow by design when it is the session's first user of ``site_strips`` (tests/conftest.py; over 60 s in
    a loaded suite run): that fixture synthesises the shipped classes' full strips once for the session."""
    for name, (_, _, terrain) in site_strips.items():
        image = terrain.reflectance_if
        assert image.dtype == np.float32 and image.shape == (5000, 1000), name
        assert np.all(np.isfinite(image)) and image.min() > 0 and image.max() < 0.6, name
        assert terrain.metres_per_pixel == 3.0
        west, east, south, north = terrain.extent_m
        assert east - west == pytest.approx(3000.0) and north - south == pytest.approx(15000.0)
        assert (west + east) == pytest.approx(0.0) and (south + north) == pytest.approx(0.0)
        assert 0 < terrain.moc_incidence_rad < np.radians(60) and terrain.moc_phase_rad < np.radians(60)


@pytest.mark.slow
def test_rms_contrast_follows_the_documented_class_ordering(site_strips):
    contrast = {name: binned_rms_contrast(t.reflectance_if) for name, (_, _, t) in site_strips.items()}
    # paper Figs. 7 and 9: bright smooth plains lowest (hbsp lowest of all), cratered/tracked plains,
    # ejecta and knobs higher
    assert contrast["hbsp"] < contrast["gcp"] < contrast["hdcp"] < contrast["gdcp"], contrast
    assert contrast["hdcp"] < contrast["heb"] and contrast["gcp"] < contrast["gkep"], contrast
    assert max(contrast["gcp"], contrast["hbsp"]) < 0.9 * min(contrast[n] for n in ("gdcp", "hdcp", "heb", "gkep"))
    # "tuned to Gusev where there is more scene contrast": ellipse-weighted site contrast
    weighted = {}
    for name, (site, fraction, _) in site_strips.items():
        weighted[site] = weighted.get(site, 0.0) + fraction * contrast[name]
    assert weighted["Gusev"] > 1.03 * weighted["Meridiani"], weighted
    # how bland against real MOC images of the same kind of ground: tests/campaign/realism/test_terrain_calibration.py


@pytest.mark.slow
def test_feature_density_follows_the_documented_class_ordering(site_strips):
    # dark features (craters, pits, track segments, knob shadows) as campaign.realism.terrain_stats counts them,
    # on the strip's departures from its mean divided by the class's contrast scale (the default classes are
    # the rough-MOC-ground populations with every contrast x scale: a feature 5 % dark there is 5 % x scale here)
    from sitedata.terrain.synthetic_classes import CLASS_PRESETS

    def unscaled(image, name):
        mean = float(image.mean())
        return (mean + (image - mean) / CLASS_PRESETS[name].contrast_scale).astype(np.float32)

    density = {name: crater_density_per_km2(unscaled(t.reflectance_if, name), t.metres_per_pixel)
               for name, (_, _, t) in site_strips.items()}
    assert density["hbsp"] < density["gcp"], density
    assert max(density["gcp"], density["hbsp"]) < 0.8 * min(density[n] for n in ("gdcp", "hdcp", "heb", "gkep")), density


@pytest.mark.slow
def test_power_spectrum_slope_lies_within_real_moc_and_ctx_images(site_strips, real_slope_range):
    low, high, real = real_slope_range
    assert -3.0 < low < high < -1.0, real          # the real images are neither white noise nor a blur
    for name, (_, _, terrain) in site_strips.items():
        slope = spectral_slope(terrain.reflectance_if)
        assert low <= slope <= high, f"{name}: slope {slope:.2f} outside real range {real}"


def test_spectral_slope_measurement_on_known_fields():
    rng = np.random.default_rng(3)
    assert abs(spectral_slope(rng.standard_normal((512, 512)))) < 0.15            # white noise
    for beta in (1.5, 2.5):
        field = feat.gaussian_random_field((512, 512), beta, 2000.0, np.random.default_rng(4))
        assert spectral_slope(field) == pytest.approx(-beta, abs=0.15)
        assert field.std() == pytest.approx(1.0, rel=1e-4) and abs(field.mean()) < 1e-5


# ----------------------------------------------------------------------------------------------
# physics of the stages against closed forms
def test_flat_ground_if_is_the_paper_photometric_function():
    albedo = 0.25
    for inc_deg in (20.0, 45.0):
        params = st.preset("gcp", normal_albedo_mean=albedo, moc_incidence_deg=inc_deg, **BARE)
        image = st.generate_reflectance(params, 1)
        mu0 = np.cos(np.radians(inc_deg))
        alpha = inc_deg                                   # nadir view: phase = incidence
        f = 1.82 - 1.03e-2 * (alpha - 10.0)               # paper equation (3)
        expected = albedo * 2 * mu0 / (1 + mu0) * f / 2.05
        np.testing.assert_allclose(image, expected, rtol=1e-4)


def test_haze_scales_contrast_by_transmission_and_adds_path_if():
    tau, path_if, emission = 0.6, 0.05, 20.0
    base = dict(BARE, albedo_relative_spread=0.05, moc_emission_deg=emission)
    clear = st.generate_reflectance(st.preset("hdcp", **base), 7)
    hazy = st.generate_reflectance(st.preset("hdcp", **dict(base, haze_optical_depth=tau, haze_path_if=path_if)), 7)
    transmission = np.exp(-tau / np.cos(np.radians(emission)))
    assert hazy.std() / clear.std() == pytest.approx(transmission, rel=1e-3)
    assert hazy.mean() - clear.mean() == pytest.approx(path_if, rel=1e-3)


def test_grain_has_the_stated_signal_to_noise_ratio():
    image = st.generate_reflectance(st.preset("gcp", **dict(BARE, rows=512, cols=512, grain_snr=40.0)), 2)
    assert image.mean() / image.std() == pytest.approx(40.0, rel=0.03)
    assert abs(spectral_slope(image)) < 0.15                          # grain is white


def test_cast_shadow_in_a_parabolic_bowl_matches_the_rim_ray():
    # bowl z = d (rho^2 - 1) inside radius R: the rim's sun ray leaves the floor at
    # x = 2R - tan(e) R^2 / d from the sunward rim (x measured away from the sun)
    radius_px, depth_m, mpp = 100, 40.0, 3.0
    rows, cols = np.mgrid[0:301, 0:301]
    rho = np.hypot(rows - 150, cols - 150) / radius_px
    bowl = np.where(rho < 1, depth_m * (rho**2 - 1), 0.0).astype(np.float32)
    radius_m = radius_px * mpp
    for elevation_deg in (5.0, 8.0):
        tan_e = np.tan(np.radians(elevation_deg))
        length_px = (2 * radius_m - tan_e * radius_m**2 / depth_m) / mpp
        for azimuth_deg, profile in ((270, lambda s: s[150, 50:251]), (90, lambda s: s[150, 250:49:-1]),
                                     (0, lambda s: s[50:251, 150]), (180, lambda s: s[250:49:-1, 150])):
            shadow = feat.cast_shadow_fraction(bowl, mpp, np.radians(azimuth_deg), np.radians(elevation_deg))
            assert profile(shadow).sum() == pytest.approx(length_px, abs=1.5), (elevation_deg, azimuth_deg)
        assert shadow[150, 150 - radius_px - 5:].max() <= 1.0 and shadow[:, :40].max() == 0.0


def test_block_casts_shadow_of_length_height_over_tan_elevation():
    block = np.zeros((200, 200), np.float32)
    block[90:110, 90:110] = 30.0                                   # 40 m square, 30 m high, 2 m pixels
    for azimuth_deg, beyond in ((270.0, lambda s: s[100, 110:]), (180.0, lambda s: s[89::-1, 100])):
        shadow = feat.cast_shadow_fraction(block, 2.0, np.radians(azimuth_deg), np.radians(30.0))
        length_px = 30.0 / np.tan(np.radians(30.0)) / 2.0          # 26 px
        assert beyond(shadow).sum() == pytest.approx(length_px, abs=1.5), azimuth_deg
        assert shadow[90:110, 90:110].max() == 0.0                 # the top is lit
    assert shadow[111:, :].max() == 0.0                            # nothing on the sunward side


def test_craters_are_lit_on_the_wall_facing_the_sun():
    params = st.preset("gcp", **dict(BARE, rows=600, cols=600, crater_density_per_km2=150.0,
                                     crater_min_diameter_m=120.0, crater_max_diameter_m=240.0,
                                     moc_sun_azimuth_deg=270.0, moc_incidence_deg=50.0))
    height, _ = st.surface_fields(params, 11)
    image = st.generate_reflectance(params, 11)
    labels, count = ndimage.label(height < -2.0)
    brighter_east = isolated = 0
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        inside = labels[box] == index
        rows_span, cols_span = inside.shape
        touches_edge = box[0].start == 0 or box[1].start == 0 or box[0].stop == 600 or box[1].stop == 600
        if touches_edge or not 0.8 < rows_span / cols_span < 1.25 or inside.mean() < 0.7:
            continue                                       # overlapping or cut craters: skip
        isolated += 1
        cols = np.nonzero(inside)[1]
        centre = 0.5 * (cols.min() + cols.max())
        west = image[box][inside & (np.arange(inside.shape[1])[None, :] < centre)].mean()
        east = image[box][inside & (np.arange(inside.shape[1])[None, :] > centre)].mean()
        brighter_east += east > west
    assert isolated >= 3
    assert brighter_east == isolated                       # sun in the west lights the east inner wall


def test_crater_population_follows_the_power_law():
    params = st.preset("gdcp", crater_min_diameter_m=10.0, crater_max_diameter_m=1e4)
    rng = np.random.default_rng(5)
    area_km2 = 200.0
    diameters, depth_ratio = st._crater_population(rng, params, area_km2, 50.0, 2.0, 1e4)
    above_ref = np.count_nonzero(diameters > 20.0)
    expected = 50.0 * area_km2
    assert abs(above_ref - expected) < 4 * np.sqrt(expected)
    mle_exponent = len(diameters) / np.log(diameters / 10.0).sum()    # Pareto MLE (d_max >> d_min)
    assert mle_exponent == pytest.approx(2.0, rel=0.03)
    lo, hi = params.crater_depth_to_diameter
    assert depth_ratio.min() >= lo and depth_ratio.max() <= hi


def test_dust_devil_tracks_cover_the_stated_length():
    mask = feat.draw_tracks((800, 800), 4000.0, (3.0, 3.0), np.radians(135), 0.0, 400.0, np.random.default_rng(2))
    # tracks start up to 20 % outside the image, so about (1 / 1.4^2) of their length falls inside
    inside_length = mask.sum() / 3.0
    assert 0.25 * 4000 < inside_length < 0.9 * 4000
    assert mask.min() >= 0.0 and mask.max() <= 1.0


# ----------------------------------------------------------------------------------------------
# determinism and cache
def test_same_seed_same_bits_different_seed_different_image():
    params = st.preset("heb", rows=700, cols=300)
    first = st.generate_reflectance(params, 42)
    again = st.generate_reflectance(params, 42)
    assert first.tobytes() == again.tobytes()
    other = st.generate_reflectance(params, 43)
    assert not np.array_equal(first, other)


def test_cache_round_trip_and_recovery(tmp_path):
    params = st.preset("gkep", rows=300, cols=200)
    made = st.cached_reflectance(params, 9, tmp_path)
    files = list(tmp_path.glob("*.npy"))
    assert len(files) == 1 and st.cache_key(params, 9) in files[0].name
    assert np.load(files[0]).tobytes() == made.tobytes()
    files[0].write_bytes(b"not a numpy file")                  # corrupt entry: regenerated
    assert st.cached_reflectance(params, 9, tmp_path).tobytes() == made.tobytes()
    assert np.load(files[0]).tobytes() == made.tobytes()
    assert st.cache_key(params, 10) != st.cache_key(params, 9)
    assert st.cache_key(st.preset("gkep", rows=300, cols=201), 9) != st.cache_key(params, 9)


def test_cache_directory_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("MOC2DIMES_CACHE", str(tmp_path / "c"))
    assert st.cache_directory() == tmp_path / "c"
    terrain = st.synthetic_terrain(st.preset("hbsp", rows=128, cols=128), 1)
    assert len(list((tmp_path / "c").glob("synthetic_hbsp_*.npy"))) == 1
    assert terrain.name == "synthetic-hbsp-1"


def test_bad_parameters_are_refused_with_a_clear_message():
    with pytest.raises(ValueError, match=r"preset 'gcp': haze_optical_depth = -1.0 is out of range; allowed: 0 .. 5"):
        st.preset("gcp", haze_optical_depth=-1.0)
    with pytest.raises(ValueError, match=r"unknown synthetic terrain preset 'xyz'; allowed: gcp, gdcp, gkep, hbsp, hdcp, heb"):
        st.preset("xyz")


def test_contrast_scale_multiplies_every_slope_and_albedo_modulation():
    # hdcp (craters, fractal albedo, relief) with the rim brightening off: the height field scales exactly and
    # the albedo's departure from its mean scales with it; the rough preset is the default class unscaled
    import dataclasses

    params = st.preset("hdcp_rough_moc", rows=256, cols=256, crater_rim_albedo_contrast=0.0)
    height, albedo = st.surface_fields(params, 11)
    scaled_height, scaled_albedo = st.surface_fields(dataclasses.replace(params, contrast_scale=0.3), 11)
    assert np.abs(height).max() > 1.0
    np.testing.assert_allclose(scaled_height, 0.3 * height, rtol=1e-5, atol=1e-5)
    unclipped = (albedo > 0.02) & (albedo < 0.8)
    mean = params.normal_albedo_mean
    np.testing.assert_allclose(scaled_albedo[unclipped] - mean, 0.3 * (albedo[unclipped] - mean), rtol=1e-4, atol=1e-6)
    # dust devil tracks darken by scale x their contrast: the darkest track pixel of gdcp, no other modulation
    bare_tracks = dict(rows=256, cols=256, albedo_relative_spread=0.0, crater_density_per_km2=0.0,
                       crater_rim_albedo_contrast=0.0, track_length_per_km2=40.0)
    _, tracked = st.surface_fields(st.preset("gdcp_rough_moc", **bare_tracks), 3)
    _, faint = st.surface_fields(st.preset("gdcp_rough_moc", contrast_scale=0.5, **bare_tracks), 3)
    mean = st.preset("gdcp_rough_moc").normal_albedo_mean
    np.testing.assert_allclose(mean - faint, 0.5 * (mean - tracked), rtol=1e-4, atol=1e-6)
    assert st.preset("gdcp").contrast_scale < 1.0 == st.preset("gdcp_rough_moc").contrast_scale
    with pytest.raises(ValueError, match=r"preset 'gcp': contrast_scale = 0\.0 is out of range; allowed: 0 < scale <= 4"):
        st.preset("gcp", contrast_scale=0.0)
