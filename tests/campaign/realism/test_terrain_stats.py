"""campaign.realism.terrain_stats: each statistic against a closed form on a constructed field, the camera
numbers against the documented ones, and the CLI on real files (synthetic PNG + side-car, a small
site, the real data folder when present)."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from campaign.realism import terrain_stats as ts
from sitedata.terrain import synthetic_features as feat

REPO = Path(__file__).resolve().parents[3]
REALDATA = REPO.parent / "shared" / "realdata"


@pytest.fixture(scope="module")
def sampling(mer_a):
    return ts.descent_sampling(mer_a, 1.478)


def test_descent_sampling_numbers_follow_the_camera_file(sampling):
    # MER-A: 12 um pixels, f = 14.67 mm, 4-row binning: 6.54 m per binned sample at 2 km
    assert sampling.ground_sample_m(2000.0) == pytest.approx(4 * 12e-6 / 0.01467 * 2000.0, rel=2e-3)
    # README: 1.86e5 e-/s per W m^-2 sr^-1 um^-1 per pixel; band irradiance 1251 W m^-2 um^-1 at 1 AU;
    # 16 pixels per block, collected over 3 x 5.1 ms (fast flush, exposure, frame transfer)
    expected = 1251.0 / 1.478**2 / math.pi * 0.906 * 1.86e5 * 16 * 3 * 0.0051
    assert sampling.electrons_per_if == pytest.approx(expected, rel=0.01)
    assert sampling.noise_floor_e2 == pytest.approx(4 * 30.0**2 + 4 * 150.0**2 / 12.0)
    assert sampling.template_px == 15 and sampling.min_contrast_to_noise == 2.5


def test_resampling_a_linear_ramp_is_exact(sampling):
    # bilinear samples of a linear field are exact and a block mean of a linear field is its centre value
    rows, cols = np.mgrid[0:400, 0:300].astype(np.float64)
    ramp = 0.2 + 1e-4 * rows + 3e-4 * cols
    metres, sample_m = 3.0, 6.0                       # pitch 1.5 m = 0.5 terrain px, blocks 2 px
    out = ts.resample_to_ground_sample(ramp, metres, sample_m, 4)
    centre_r = np.arange(out.shape[0]) * 2.0 + (1.5 / 3.0) * 2.0     # (i + 0.5) pitch averaged over i = 0..3
    centre_c = np.arange(out.shape[1]) * 2.0 + 1.0
    expected = 0.2 + 1e-4 * centre_r[:, None] + 3e-4 * centre_c[None, :]
    np.testing.assert_allclose(out, expected, rtol=1e-5)
    assert out.shape == (int((400 - 1) / 2), int((300 - 1) / 2))


def test_resampling_averages_texture_finer_than_the_sample():
    # a checkerboard of 1 terrain px averages out in 4 x 4 blocks of 1 px pitch; a 64 px wave keeps
    # its amplitude (x sinc of the block: 0.984 for 4 px blocks)
    rows, cols = np.mgrid[0:512, 0:512]
    checker = 0.2 + 0.02 * np.where((rows + cols) % 2 == 0, 1.0, -1.0)
    out = ts.resample_to_ground_sample(checker, 1.0, 4.0, 4)
    assert out.std() / out.mean() < 1e-6
    wave = 0.2 + 0.02 * np.cos(2 * np.pi * cols / 64.0)
    out = ts.resample_to_ground_sample(wave, 1.0, 4.0, 4)
    assert out.std() / out.mean() == pytest.approx(0.1 / np.sqrt(2) * np.sinc(4 / 64.0), rel=0.02)


def test_tile_contrast_and_detrended_std_of_known_fields():
    rows, cols = np.mgrid[0:512, 0:512]
    checker = 0.25 + 0.01 * np.where((rows + cols) % 2 == 0, 1.0, -1.0)
    contrasts = ts.tile_contrasts(checker)
    assert contrasts.size == 9 and np.allclose(contrasts, 0.04, rtol=1e-3)      # 3 x 3 half-overlapping tiles
    plane = 0.3 + 0.01 * rows + 0.02 * cols
    assert np.allclose(ts.detrended_window_std(plane, 15), 0.0, atol=1e-9)
    noise = np.random.default_rng(1).standard_normal((450, 450))
    spread = ts.detrended_window_std(plane[:450, :450] + 0.5 * noise, 15)
    assert spread.size == 900 and np.median(spread) == pytest.approx(0.5 * np.sqrt(1 - 3 / 225), rel=0.03)


def test_untrackable_fraction_applies_the_estimator_noise_model(sampling):
    # left half: detrended template std at half the threshold, right half: at twice it
    mean_if = 0.2
    noise_e = math.sqrt(mean_if * sampling.electrons_per_if + sampling.dark_charge_e + sampling.noise_floor_e2)
    threshold_if = math.sqrt(2.5**2 - 1.0) * noise_e / sampling.electrons_per_if
    rows, cols = np.mgrid[0:150, 0:300]
    checker = np.where((rows + cols) % 2 == 0, 1.0, -1.0) * np.sqrt(1.0 / (1 - 1 / 225**2))
    amplitude = np.where(cols < 150, 0.5 * threshold_if, 2.0 * threshold_if)
    field = mean_if + amplitude * checker
    assert ts.untrackable_fraction(field, sampling) == pytest.approx(0.5)
    assert ts.untrackable_fraction(np.full((150, 150), mean_if), sampling) == 1.0


def test_psd_slope_of_known_spectra():
    rng = np.random.default_rng(3)
    assert abs(ts.psd_slope(rng.standard_normal((512, 512)))) < 0.15
    for beta in (1.5, 2.5):
        field = feat.gaussian_random_field((768, 512), beta, 2000.0, np.random.default_rng(4))
        assert ts.psd_slope(field) == pytest.approx(-beta, abs=0.15)
    assert math.isnan(ts.psd_slope(np.ones((100, 5))))          # too small for 64 px wavelengths


def _discs(depth: float, count_side: int = 6, radius_m: float = 30.0, metres: float = 3.0, grain: float = 0.0):
    size = 600
    image = np.full((size, size), 0.2)
    rows, cols = np.mgrid[0:size, 0:size]
    centres = np.linspace(60, size - 60, count_side)
    for r in centres:
        for c in centres:
            image[np.hypot(rows - r, cols - c) <= radius_m / metres] *= 1.0 - depth
    image += grain * 0.2 * np.random.default_rng(5).standard_normal(image.shape)
    return image, size * metres


def test_crater_density_counts_dark_discs_deeper_than_the_threshold():
    # 36 dark discs 60 m across: counted when 12 % deep (even under MOC-like grain, SNR 60), not when 3 % deep
    for depth, grain, expected in ((0.12, 0.0, 36), (0.12, 1 / 60, 36), (0.03, 0.0, 0)):
        image, side_m = _discs(depth, grain=grain)
        margin_m = 2 * math.ceil(2 * 120 / (2 * math.sqrt(2)) / 3.0) * 3.0
        area_km2 = ((side_m - margin_m) / 1e3) ** 2
        assert ts.crater_density_per_km2(image, 3.0) * area_km2 == pytest.approx(expected, abs=0.5), depth
    # the closed form the threshold rests on: sigma^2 LoG at the centre of a disc at sigma = r / sqrt 2
    rows, cols = np.mgrid[0:601, 0:601]
    relative = np.where(np.hypot(rows - 300, cols - 300) <= 60.0, 0.9, 1.0).astype(np.float32)
    sigma = 60.0 / math.sqrt(2.0)
    response = sigma**2 * cv2.Laplacian(cv2.GaussianBlur(relative, (0, 0), sigma), cv2.CV_32F, ksize=1)
    assert response[300, 300] == pytest.approx(0.10 * ts.LOG_PEAK_PER_DEPTH, rel=0.03)


def test_statistics_of_a_too_small_or_uncalibrated_terrain_say_why(sampling):
    tiny = ts.terrain_statistics(np.full((3, 3), 0.2), 3.0, sampling)
    assert math.isnan(tiny.contrast_2km) and math.isnan(tiny.psd_slope) and "smaller than one ground sample" in tiny.notes
    raw = ts.terrain_statistics(np.random.default_rng(2).uniform(50, 60, (300, 300)), None, sampling, "uncalibrated PNG")
    assert math.isnan(raw.mean_if) and math.isnan(raw.contrast_1km) and not math.isnan(raw.psd_slope)
    assert "uncalibrated PNG" in raw.notes and "metres_per_pixel unknown" in raw.notes


def _run_cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "campaign.realism.measure_terrains", *args], cwd=cwd, capture_output=True,
                          text=True, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin",
                                          "MOC2DIMES_CACHE": str(Path(cwd) / "cache")}, timeout=300)


def test_cli_measures_a_png_with_side_car_and_a_small_site(tmp_path):
    rng = np.random.default_rng(9)
    dn = np.clip(150 + 10 * rng.standard_normal((800, 800)), 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "tile.png"), dn)
    (tmp_path / "tile.toml").write_text("metres_per_pixel = 5.0\ndn_to_if_scale = 0.001\n")
    site = (REPO / "sitedata" / "gusev.toml").read_text().replace('camera = "cameras/', f'camera = "{REPO}/sitedata/cameras/')
    site = site.replace('preset = "gcp", seed = 4101 }', 'preset = "gcp", seed = 4101, overrides = { rows = 400, cols = 300 } }')
    site = site.replace('preset = "gdcp", seed = 4102 }', 'preset = "gdcp", seed = 4102, overrides = { rows = 400, cols = 300 } }')
    site = site.replace('preset = "gkep", seed = 4103 }', 'preset = "gkep", seed = 4103, overrides = { rows = 400, cols = 300 } }')
    (tmp_path / "small.toml").write_text(site)
    result = _run_cli(f"{tmp_path / 'tile.png'}:{tmp_path / 'tile.toml'}", str(tmp_path / "small.toml"),
                      "--csv", str(tmp_path / "out.csv"), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    frame = pd.read_csv(tmp_path / "out.csv")
    assert list(frame["source"]) == ["tile.png + tile.toml", "Gusev:gcp (synthetic-gcp-4101)",
                                     "Gusev:gdcp (synthetic-gdcp-4102)", "Gusev:gkep (synthetic-gkep-4103)"]
    assert frame.loc[0, "mean_if"] == pytest.approx(0.001 * dn.mean(), rel=1e-5)
    # white DN noise of std 10 on 150, averaged over blocks of 4 x 4 point samples at 0.33 / 0.65 px pitch
    assert 0.0 < frame.loc[0, "contrast_2km"] < frame.loc[0, "contrast_1km"] < 10 / 150
    assert "Gusev:gkep" in result.stdout and "contrast 1 km" in result.stdout


def test_cli_refuses_an_unknown_source_with_one_line_and_writes_nothing(tmp_path):
    result = _run_cli("no_such_thing", "--csv", str(tmp_path / "out.csv"), cwd=tmp_path)
    assert result.returncode == 2 and not (tmp_path / "out.csv").exists()
    assert result.stderr.strip().count("\n") == 0 and "not a synthetic preset; presets: gcp" in result.stderr


@pytest.mark.skipif(not REALDATA.is_dir(), reason=f"real Mars data folder {REALDATA} is absent")
def test_cli_prints_every_real_file(tmp_path):
    files = sorted(p for p in REALDATA.rglob("*") if p.is_file() and p.name != "README.md")
    sources = [f"{p}:{REPO / 'sitedata' / 'examples' / 'M0100115.sidecar.toml'}" if p.stem.startswith("M0100115")
               else str(p) for p in files]
    result = _run_cli(*sources, "--csv", str(tmp_path / "real.csv"), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    frame = pd.read_csv(tmp_path / "real.csv")
    assert len(frame) == len(files)
    moc = frame[frame["source"].str.startswith("M0100115")]
    assert len(moc) == 2 and np.allclose(moc["contrast_2km"], moc["contrast_2km"].iloc[0])   # .imq == .img
    cube = frame[frame["source"] == "E0201461.tiny.cub"].iloc[0]
    assert cube["radiometry"] == "I/F" and 0.18 < cube["mean_if"] < 0.2 and 0.03 < cube["contrast_1km"] < 0.1
