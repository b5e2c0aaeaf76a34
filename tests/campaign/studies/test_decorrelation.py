"""The decorrelation study (campaign.studies.decorrelation and its measurement, campaign.studies.template_correlation):
the closed-form noise correlation against a Monte Carlo measurement with the estimator's own matching, and the
variants it builds from a campaign file."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from campaign.studies.decorrelation import MECHANISMS, NO_ROTATION, RELIEF_ON, steady_profile, variant_data
from campaign.studies.template_correlation import noise_correlation
from config_tables.toml_file import load_toml
from dimes_velocity.config import EstimatorConfig
from dimes_velocity.matching import match_template

ROOT = Path(__file__).resolve().parents[3]
SHIFT = (7, -5)                 # (column, row) of B against A, whole pixels: no resampling
TEMPLATE_SIDE = 15


def _textured(rng: np.random.Generator, size: int) -> np.ndarray:
    """A smooth random texture (white noise blurred with sigma 1.5 px), zero mean, unit standard deviation."""
    field = cv2.GaussianBlur(rng.standard_normal((size, size)), (0, 0), 1.5)
    return (field - field.mean()) / field.std()


def test_closed_form_matches_the_estimators_correlation_of_noisy_copies():
    """Two copies of one texture, moved by whole pixels, with independent Gaussian noise: the estimator's
    correlation at its peak falls with the noise as S / (S + n^2), S the noise-free template's variance.
    (At the peak the matcher maximises over shifts, which adds a little: the measurement may lie slightly
    above the closed form, never far below it.)"""
    rng = np.random.default_rng(30)
    config = EstimatorConfig()
    half = TEMPLATE_SIDE // 2
    size = 160
    measured, expected = {}, {}
    for noise_sigma in (0.1, 0.3, 0.5, 0.8):        # template SNR 10 .. 1.25 (signal std ~1)
        values, closed = [], []
        for _ in range(30):
            scene = 1000.0 + 20.0 * _textured(rng, size + 40)
            image_a = scene[20:20 + size, 20:20 + size]
            image_b = scene[20 - SHIFT[1]:20 - SHIFT[1] + size, 20 - SHIFT[0]:20 - SHIFT[0] + size]
            noisy_a = (image_a + 20.0 * noise_sigma * rng.standard_normal(image_a.shape)).astype(np.float32)
            noisy_b = (image_b + 20.0 * noise_sigma * rng.standard_normal(image_b.shape)).astype(np.float32)
            centre = (size // 2, size // 2)
            predicted = np.array([centre[0] + SHIFT[0], centre[1] + SHIFT[1]], dtype=float)
            match = match_template(noisy_a, noisy_b, cv2.pyrDown(noisy_a), cv2.pyrDown(noisy_b), centre, predicted,
                                   6.0, config)
            if match.status in ("search_outside", "search_border"):
                continue
            values.append(match.correlation)
            template = image_a[centre[1] - half:centre[1] + half + 1, centre[0] - half:centre[0] + half + 1]
            closed.append(float(noise_correlation(template.var(), (20.0 * noise_sigma) ** 2)))
        measured[noise_sigma], expected[noise_sigma] = float(np.median(values)), float(np.median(closed))
    for noise_sigma in measured:
        assert expected[noise_sigma] - 0.03 <= measured[noise_sigma] <= expected[noise_sigma] + 0.06, (measured, expected)
    # monotone, and the noisiest case far below the cleanest: the test can see the effect
    ordered = [measured[s] for s in sorted(measured)]
    assert all(a > b for a, b in zip(ordered, ordered[1:]))
    assert measured[0.1] > 0.98 and measured[0.8] < 0.75


def test_closed_form_values():
    """S / (S + n^2) for equal noise; the geometric mean form for unequal noise."""
    assert noise_correlation(9.0, 1.0) == pytest.approx(0.9)
    assert noise_correlation(1.0, 0.0, 3.0) == pytest.approx(0.5)


def test_variants_change_only_their_mechanism():
    data = load_toml(ROOT / "sitedata" / "gusev.toml")
    noise_off = variant_data(data, MECHANISMS["photon + read noise off"], 1.0)
    assert noise_off["scene"]["camera_effects"] == {"shot_noise": False, "read_noise": False}
    assert noise_off["site"] == data["site"] and "scene" not in data          # the input is not changed
    relief = variant_data(data, RELIEF_ON, 0.5)
    assert relief["site"]["terrain_contrast_scale"] == pytest.approx(0.5)
    for entry, original in zip(relief["site"]["classes"], data["site"]["classes"]):
        assert entry["terrain"]["relief"] is True
        assert "relief" not in original["terrain"]
    assert NO_ROTATION.steady_attitude


def test_steady_profile_holds_the_first_attitude():
    from sitedata.edl.trajectory_io import read_profiles

    profile = read_profiles(ROOT / "sitedata" / "trajectories" / "gusev.parquet")[0]
    steady = steady_profile(profile)
    first = profile.pose(float(profile.image_times_s[0])).attitude_quat
    for time_s in profile.image_times_s:
        pose = steady.pose(float(time_s))
        assert np.allclose(pose.attitude_quat, first)
        assert np.allclose(pose.angular_rate_radps, 0.0)
        assert np.allclose(pose.position_m, profile.pose(float(time_s)).position_m)


def test_whole_pixel_peak_loses_the_texture_autocorrelation_at_the_offset():
    """A Gaussian-smoothed white-noise texture (sigma s px) has autocorrelation exp(-d^2 / (4 s^2)): sampled
    half a pixel apart, the best whole-pixel shift is 0.5 px off, so the grid peak reads ~exp(-1 / (16 s^2));
    whole-pixel shifts read 1."""
    from campaign.studies.template_correlation import grid_peak_correlation

    rng = np.random.default_rng(7)
    fine, sigma_px = 4, 1.5
    texture = cv2.GaussianBlur(rng.standard_normal((4 * 200, 4 * 200)), (0, 0), sigma_px * fine)
    image_a = texture[::fine, ::fine].astype(np.float32)
    image_b = texture[::fine, fine // 2::fine].astype(np.float32)       # +0.5 px along x
    moved = np.roll(image_a, (3, -4), axis=(0, 1))                       # whole pixels: rows +3, columns -4
    half = TEMPLATE_SIDE // 2
    halves, wholes = [], []
    for row in range(30, 160, 13):
        for column in range(30, 160, 13):
            halves.append(grid_peak_correlation(image_a, image_b, (column, row), (column - 0.5, row), half)[0])
            wholes.append(grid_peak_correlation(image_a, moved, (column, row), (column - 4, row + 3), half)[0])
    assert np.allclose(wholes, 1.0, atol=1e-5)
    expected = np.exp(-1.0 / (16.0 * sigma_px**2))                      # 0.973
    assert np.median(halves) == pytest.approx(expected, abs=0.01)
    assert np.median(halves) < 0.985


@pytest.mark.slow
def test_study_on_one_case_isolates_the_camera_noise(tmp_path):
    """One gcp case of the Gusev plan, nominal and without camera noise: the noise measured after
    rectification vanishes with the camera's noise (up to the ADC rounding), the refined correlation lies
    below the noise-only closed form (noise is not the only decorrelation), and the whole-pixel reading of the
    same matches does not exceed the refined one."""
    from campaign.studies.decorrelation import NOISE_OFF, REFERENCE, first_cases, run_mechanism

    site = ROOT / "sitedata" / "gusev.toml"
    plan = first_cases(site, 1, 1.0, tmp_path, ["gcp"])
    assert list(plan["class_name"]) == ["gcp"]
    nominal = run_mechanism(site, REFERENCE, 1.0, plan, tmp_path)
    quiet = run_mechanism(site, NOISE_OFF, 1.0, plan, tmp_path)
    ok, quiet_ok = nominal[nominal["status"] == "ok"], quiet[quiet["status"] == "ok"]
    assert len(ok) >= 3 and len(quiet_ok) >= 3
    assert 0.9 < ok["noise_factor"].median() < 0.999
    assert quiet_ok["noise_factor"].min() > 0.999
    assert ok["correlation"].median() < ok["noise_factor"].median()
    assert ok["grid_correlation"].median() <= ok["correlation"].median()
