"""The flat field as a calibration product: simulated ground calibration (noise as predicted from shot,
read, dark and quantisation noise), what it leaves in flattened images against no flat field and the
truth, files (.npy, TIFF, FITS) and their errors, and the command lines that make and use them."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dimes_velocity.config import EstimatorConfig
from dimes_velocity.preprocess import flatten, make_flattening
from file_formats.flat_field_files import flat_field_next_to, load_flat_field, save_flat_field
from flight_interface.calibration import CalibrationError, normalise_flat_field, readout_flat_field
from simulator.calibration import flat_source_radiance, simulate_flat_field, true_flat_field
from simulator.detector.camera_chain import CameraEffects, render_image
from simulator.fields import RadianceFields

REPO = Path(__file__).resolve().parents[2]
NOISE_FREE = CameraEffects(shot_noise=False, read_noise=False)


def _central_mean(array: np.ndarray) -> float:
    rows, columns = array.shape
    return float(array[rows // 2 - 16: rows // 2 + 16, columns // 2 - 64: columns // 2 + 64].mean())


def test_calibrated_flat_field_noise_matches_shot_read_dark_and_quantisation(mer_a):
    """Per read-out pixel, (mean of N flats - mean of N darks) scatters around the truth by
    sqrt((Q_flat + Q_dark + 2 r^2 + 2 g^2 / 12) / N) / (Q_flat - Q_dark), Q the expected charges."""
    frames = 8
    calibrated = simulate_flat_field(mer_a, frames, np.random.default_rng(11))
    truth = true_flat_field(mer_a)
    ratio = calibrated / truth
    ratio = ratio / _central_mean(ratio)
    rows, columns = mer_a.binned_shape
    source = np.full((mer_a.height_px, mer_a.width_px), flat_source_radiance(mer_a), np.float32)
    zero_block = np.zeros((rows, columns), np.float32)
    lit = render_image(mer_a, RadianceFields(zero_block, source, zero_block), np.random.default_rng(0), NOISE_FREE)
    dark = render_image(mer_a, RadianceFields(zero_block, np.zeros_like(source), zero_block), np.random.default_rng(0),
                        NOISE_FREE)
    electronics = mer_a.electronics
    floor = 2.0 * electronics.read_noise_e**2 + 2.0 * electronics.adc_gain_e_per_dn**2 / 12.0
    variance = (lit.expected_charge_e + dark.expected_charge_e + floor) / frames
    signal = lit.expected_charge_e - dark.expected_charge_e
    predicted = float(np.sqrt(np.mean(variance / signal**2)))
    measured = float(np.std(ratio - 1.0))
    assert 0.9 < measured / predicted < 1.1, (measured, predicted)
    assert predicted < 0.1 * mer_a.radiometry.prnu_sigma        # 16 frames of MER: far below the 1 % PRNU


def test_calibration_is_deterministic_per_seed(mer_a):
    first = simulate_flat_field(mer_a, 2, np.random.default_rng(5))
    again = simulate_flat_field(mer_a, 2, np.random.default_rng(5))
    other = simulate_flat_field(mer_a, 2, np.random.default_rng(6))
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert first.shape == mer_a.binned_shape and first.dtype == np.float32
    assert abs(_central_mean(first) - 1.0) < 1e-6


def test_flattened_uniform_scene_keeps_the_prnu_without_flat_field_and_loses_it_with_one(mer_a):
    """A uniform scene, noise free: with only the design falloff the flattened 4 x 4 blocks keep the PRNU
    averaged over 16 pixels (sigma / 4); the calibrated flat removes it down to its own noise; the
    truth removes it exactly."""
    radiance = np.full((mer_a.height_px, mer_a.width_px), 40.0, np.float32)
    rendered = render_image(mer_a, (radiance, radiance, radiance), np.random.default_rng(0), NOISE_FREE)
    config = EstimatorConfig()

    def residual(flat_field):
        signal = flatten(rendered.expected_dn, make_flattening(mer_a, config, flat_field), config).signal_dn
        return float(np.std(signal / signal.mean()))

    block_prnu = mer_a.radiometry.prnu_sigma / 4.0
    none = residual(None)
    calibrated = residual(simulate_flat_field(mer_a, 16, np.random.default_rng(2)))
    truth = residual(true_flat_field(mer_a))
    assert 0.85 < none / block_prnu < 1.15, none
    assert calibrated < 0.2 * block_prnu, calibrated
    assert truth < 2e-4, truth


@pytest.mark.parametrize("suffix", [".npy", ".tif", ".fits"])
def test_flat_field_files_round_trip(mer_a, tmp_path, suffix):
    flat = simulate_flat_field(mer_a, 1, np.random.default_rng(4))
    path = save_flat_field(tmp_path / f"camera.flat{suffix}", flat)
    loaded = load_flat_field(path, mer_a.binned_shape)
    assert loaded.dtype == np.float32 and np.array_equal(loaded, flat)


def test_full_frame_flat_is_averaged_over_binned_rows(mer_a):
    full = np.ones((mer_a.height_px, mer_a.width_px), np.float32)
    full[0::4] = 2.0                                             # one row of every 4-row block
    readout = readout_flat_field(full, mer_a.binned_shape)
    assert readout.shape == mer_a.binned_shape and np.allclose(readout, 1.25)


@pytest.mark.parametrize("array, expected", [
    (np.ones((100, 1024)), "flat field shape (100, 1024)"),
    (np.full((256, 1024), np.nan), "non-finite"),
    (np.zeros((256, 1024)), "median response"),
    (np.ones((256, 1024, 3)), "2-D numeric array"),
])
def test_unusable_flat_field_files_are_refused_naming_the_file(mer_a, tmp_path, array, expected):
    path = tmp_path / "bad.flat.npy"
    np.save(path, array)
    with pytest.raises(CalibrationError) as error:
        load_flat_field(path, mer_a.binned_shape)
    assert str(path) in str(error.value) and expected in str(error.value)
    with pytest.raises(CalibrationError, match="unknown flat-field format"):
        load_flat_field(shutil.copy(path, tmp_path / "bad.flat.xyz"), mer_a.binned_shape)


def test_normalised_flat_is_one_in_the_centre():
    flat = normalise_flat_field(np.full((256, 1024), 3.0))
    assert np.allclose(flat, 1.0)


def test_commands_make_and_use_a_flat_field_file(mer_a, mer_a_path, tmp_path, capsys):
    """`python -m simulator.calibrate_flat_field` writes a flat field; `python -m dimes_velocity` finds
    <camera stem>.flat.* beside the camera TOML, and refuses a broken --flat-field in one line, exit 2."""
    camera = Path(shutil.copy(mer_a_path, tmp_path / "mer_a.toml"))
    made = subprocess.run([sys.executable, "-m", "simulator.calibrate_flat_field", str(camera), "--out",
                           str(tmp_path / "mer_a.flat.npy"), "--frames", "2"], capture_output=True, text=True,
                          cwd=REPO, timeout=300)
    assert made.returncode == 0, made.stderr
    assert flat_field_next_to(camera) == tmp_path / "mer_a.flat.npy"
    assert flat_field_next_to(mer_a_path) is None or flat_field_next_to(mer_a_path).name.startswith("mer_a.flat")
    from dimes_velocity.__main__ import main

    image = np.full(mer_a.binned_shape, 800, np.uint16)
    paths = []
    for k in range(3):
        paths.append(tmp_path / f"image{k}.npy")
        np.save(paths[-1], image)
    measurements = tmp_path / "m.json"
    measurements.write_text(json.dumps({"sun_direction_world": [0, 0, 1], "images": [
        {"time_s": 3.8 * k, "attitude_quat": [1, 0, 0, 0], "radar_altitude_m": 2000.0 - 275 * k,
         "imu_velocity_mps": [1.0, 2.0, -72.0]} for k in range(3)]}))
    broken = tmp_path / "broken.flat.npy"
    np.save(broken, np.ones((10, 10)))
    capsys.readouterr()
    code = main([*map(str, paths), str(measurements), "--camera", str(camera), "--flat-field", str(broken)])
    error = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(error) == 1 and str(broken) in error[0] and "flat field shape" in error[0]
    code = main([*map(str, paths), str(measurements), "--camera", str(camera), "--summary"])
    assert code == 0                 # the flat beside the camera TOML is read (a blank scene: invalid, no error)
