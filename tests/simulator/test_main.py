"""``python -m simulator.render_example --out DIR``: the estimator's exact inputs as files, replayable bit for bit."""
from __future__ import annotations

import json
import shlex
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from dimes_velocity.estimator import DimesEstimator
from file_formats.descent_images import read_descent_image
from file_formats.flat_field_files import load_flat_field
from file_formats.measurements_json import load_measurements, measurements_to_dict
from flight_interface.camera import load_camera
from simulator import render_example as example
from simulator.calibration import DEFAULT_FLAT_FRAMES, simulate_flat_field
from simulator.descent_image import render_descent_image
from simulator.scene_config import SceneConfig
from simulator.sensors import SensorConfig, measure

ROOT = Path(__file__).resolve().parents[2]
CAMERA = ROOT / "sitedata" / "cameras" / "mer_a.toml"


@pytest.mark.slow
def test_replay_files_give_the_in_process_estimate_bit_for_bit(tmp_path):
    out = tmp_path / "case"
    assert example.main(["--out", str(out), "--seed", "2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["flat_field.npy", "image_1.png", "image_2.png", "image_3.png",
                                                     "measurements.json", "truth.json"]
    # the same case in memory, from the seed's streams as documented (0..2 images, 3 sensors, 4 flat field)
    camera = load_camera(CAMERA)
    terrain, profile, sun = example.crater_field(2), example.example_profile(), example.example_sun()
    seeds = np.random.SeedSequence(2).spawn(5)
    images = [render_descent_image(terrain, profile, camera, k, sun, SceneConfig(), np.random.default_rng(seeds[k])).dn
              for k in range(3)]
    measurements, errors = measure(profile, camera, sun, SensorConfig(), np.random.default_rng(seeds[3]))
    flat = simulate_flat_field(camera, DEFAULT_FLAT_FRAMES, np.random.default_rng(seeds[4]))

    # the files hold exactly these inputs: raw DN unstretched, measurements and flat field exact
    for k, image in enumerate(images, start=1):
        read = read_descent_image(out / f"image_{k}.png", camera)
        assert read.dn.dtype == np.uint16 and np.array_equal(read.dn, image)
        assert read.dn_rule == "DN = value (16-bit container of camera DN)"
    assert measurements_to_dict(load_measurements(out / "measurements.json")) == measurements_to_dict(measurements)
    assert np.array_equal(load_flat_field(out / "flat_field.npy", camera.binned_shape), flat)

    truth = json.loads((out / "truth.json").read_text())
    assert (truth["truth_velocity_east_mps"], truth["truth_velocity_north_mps"]) == (12.0, -5.0)  # example_profile
    assert truth["altitude_image1_m"] == 2000.0 and truth["altitude_image3_m"] == pytest.approx(1450.0)
    assert truth["sensor_errors"] == errors and truth["flat_field_source"] == "calibrated"

    # the replay line, run as a user would, answers what the estimator answers in memory, bit for bit
    expected = DimesEstimator(camera, flat_field=flat).estimate(images, measurements).to_dict()
    command = shlex.split(truth["replay"])
    assert command[1:3] == ["-m", "dimes_velocity"] and "--flat-field" in command
    completed = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert completed.returncode == 0, completed.stderr
    answer = json.loads(completed.stdout)
    for key in ("velocity_east_mps", "velocity_north_mps", "valid", "reason", "velocity_uncertainty_mps",
                "imu_bias_east_mps", "imu_bias_north_mps", "pairs"):
        assert answer[key] == expected[key], key
    assert [f["correlation"] for f in answer["features"]] == [f["correlation"] for f in expected["features"]]
    assert answer["valid"]          # the example descent is trackable: a replay worth making


@pytest.mark.slow
def test_no_flat_field_and_display_pictures_are_explicit(tmp_path):
    (tmp_path / "flat_field.npy").write_bytes(b"stale")
    assert example.main(["--out", str(tmp_path), "--seed", "2", "--flat-field", "none", "--display"]) == 0
    assert not (tmp_path / "flat_field.npy").exists()          # another run's flat field is not left beside
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["replay"].endswith("--flat-field none") and truth["flat_field_source"] == "none"
    raw = cv2.imread(str(tmp_path / "image_1.png"), cv2.IMREAD_UNCHANGED)
    picture = cv2.imread(str(tmp_path / "display_1.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and picture.dtype == np.uint8 and picture.shape == raw.shape == (256, 1024)
    assert picture.std() > 5 and raw.max() <= 4095
    assert cv2.imread(str(tmp_path / "display_1_tall.png"), cv2.IMREAD_UNCHANGED).shape == (1024, 1024)
    assert cv2.imread(str(tmp_path / "radiance_3.png"), cv2.IMREAD_UNCHANGED).shape == (1024, 1024)
    footprint = cv2.imread(str(tmp_path / "footprint.png"))
    red = (footprint[..., 2] == 255) & (footprint[..., 1] == 0) & (footprint[..., 0] == 0)
    assert red.sum() > 500          # the first image's footprint outline is drawn



@pytest.mark.parametrize("arguments, message", [
    (["--camera", "missing.toml"], "missing.toml: file not found"),
    (["--seed", "x"], "argument --seed: invalid int value: 'x'"),
    (["--flat-field", "truth"], "argument --flat-field: invalid choice: 'truth'"),
    (["--out-is-a-file"], "exists and is not a directory; allowed: a directory"),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, arguments, message):
    out = tmp_path / "case"
    if arguments == ["--out-is-a-file"]:
        out.write_text("")
        arguments = []
    with pytest.raises(SystemExit) as raised:
        code = example.main(["--out", str(out), *arguments])
        raise SystemExit(code)
    err = capsys.readouterr().err
    assert raised.value.code == 2 and err.count("\n") == 1 and err.startswith("python -m simulator.render_example: error: ")
    assert message in err
    assert not out.is_dir() or not any(out.iterdir())
