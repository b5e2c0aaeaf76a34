"""The estimator boundary at run time: the estimators run on image files with simulator and campaign made
unimportable (a meta-path blocker in a fresh interpreter). The static import rules of every package are
checked by tests/test_layers.py."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from file_formats.flat_field_files import save_flat_field
from file_formats.measurements_json import measurements_to_dict
from simulator.calibration import simulate_flat_field

REPO = Path(__file__).resolve().parents[2]
VELOCITY = (9.0, -5.0, -70.0)
BIAS = (-4.0, 7.0)

BLOCKER = """
import importlib.abc, sys
class Blocker(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("simulator", "campaign"):
            raise ImportError(f"blocked import of {name}: the estimator must not use it")
        return None
sys.meta_path.insert(0, Blocker())
"""


@pytest.fixture(scope="module")
def case_files(mer_a, mer_a_path, tmp_path_factory):
    """Three descent images as 16-bit PNG, a biased measurements JSON and a calibrated flat field file."""
    directory = tmp_path_factory.mktemp("boundary")
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(31)), np.random.default_rng(32),
                                        velocity_mps=VELOCITY)
    images = [directory / f"image{k + 1}.png" for k in range(3)]
    for path, image in zip(images, descent.images):
        assert cv2.imwrite(str(path), image)
    data = measurements_to_dict(descent.truth)
    for record in data["images"]:
        record["imu_velocity_mps"][0] += BIAS[0]
        record["imu_velocity_mps"][1] += BIAS[1]
        record.pop("imu_position_m", None)
    measurements = directory / "measurements.json"
    measurements.write_text(json.dumps(data))
    flat = save_flat_field(directory / "mer_a.flat.fits", simulate_flat_field(mer_a, 4, np.random.default_rng(3)))
    return images, measurements, flat


def _blocked_python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCKER + code], capture_output=True, text=True, cwd=REPO,
                          timeout=300)


def test_blocker_really_blocks_the_simulator():
    result = _blocked_python("import simulator.detector.camera_chain")
    assert result.returncode != 0 and "blocked import of simulator" in result.stderr


@pytest.mark.slow
def test_reference_cli_runs_on_files_with_simulator_unimportable(case_files, mer_a_path):
    images, measurements, flat = case_files
    argv = [*map(str, images), str(measurements), "--camera", str(mer_a_path), "--flat-field", str(flat), "--summary"]
    result = _blocked_python(f"import sys\nfrom dimes_velocity.__main__ import main\nsys.exit(main({argv!r}))")
    assert result.returncode == 0, result.stderr
    output = json.loads(result.stdout)
    assert output["valid"] and output["reason"] == "ok"
    assert np.hypot(output["velocity_east_mps"] - VELOCITY[0], output["velocity_north_mps"] - VELOCITY[1]) < 0.5
    assert np.hypot(output["imu_bias_east_mps"] - BIAS[0], output["imu_bias_north_mps"] - BIAS[1]) < 0.5


@pytest.mark.slow
def test_phase_correlation_runs_on_files_with_simulator_unimportable(case_files, mer_a_path, tmp_path):
    images, measurements, flat = case_files
    output = tmp_path / "result.json"
    argv = ["estimators.phase_correlation:estimate", *map(str, images), "--measurements", str(measurements),
            "--camera", str(mer_a_path), "--flat-field", str(flat), "--output", str(output)]
    result = _blocked_python(f"import sys\nfrom estimators.run_python import main\nsys.exit(main({argv!r}))")
    assert result.returncode == 0, result.stderr
    answer = json.loads(output.read_text())
    assert answer["valid"] and answer["reason"] == "ok"
    assert np.hypot(answer["velocity_east_mps"] - VELOCITY[0], answer["velocity_north_mps"] - VELOCITY[1]) < 0.5
