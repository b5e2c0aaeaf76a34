"""Camera TOML validation: bad files give one clear line and exit code 2."""
import subprocess
import sys

import numpy as np
import pytest

from config_tables.errors import ConfigError
from flight_interface.camera import load_camera


def test_nominal_cameras_match_the_paper(mer_a_path):
    for name in ("mer_a.toml", "mer_b.toml"):
        camera = load_camera(mer_a_path.with_name(name))
        horizontal, vertical = camera.fov_deg()
        assert horizontal == pytest.approx(2 * np.degrees(np.arctan(512 * 12e-6 / 0.01467)), abs=0.3)
        assert 44.5 < vertical < 46.5
        assert camera.binned_shape == (256, 1024)
        assert camera.timing.exposure_s == camera.timing.fast_flush_s == camera.timing.frame_transfer_s == 0.0051


def test_camera_boresight_points_down_the_lander_axis(mer_a):
    boresight_in_lander = mer_a.camera_to_lander_matrix @ mer_a.model.a
    np.testing.assert_allclose(boresight_in_lander, [0, 0, -1], atol=1e-12)


@pytest.mark.parametrize("edit, field", [
    (("focal_length_m = 0.01467", "focal_length_m = -0.01"), "geometry.focal_length_m"),
    (("focal_length_m = 0.01467", "focal_length_m = \"short\""), "geometry.focal_length_m"),
    (("adc_bits = 12\n", ""), "electronics.adc_bits"),
    (("f_number = 12.0", "f_number = 0.0"), "radiometry.f_number"),
    (("camera_to_lander_quaternion = [0.0, 1.0, 0.0, 0.0]", "camera_to_lander_quaternion = [0.0, 2.0, 0.0, 0.0]"),
     "mounting.camera_to_lander_quaternion"),
])
@pytest.mark.slow
def test_bad_camera_toml_names_file_and_field(tmp_path, mer_a_path, edit, field):
    text = mer_a_path.read_text()
    assert edit[0] in text
    bad = tmp_path / "bad_camera.toml"
    bad.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(ConfigError) as info:
        load_camera(bad)
    message = str(info.value)
    assert "\n" not in message and str(bad) in message and field in message

    result = subprocess.run([sys.executable, "-m", "campaign.cli", "camera", str(bad)], capture_output=True, text=True)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and field in result.stderr


@pytest.mark.slow
def test_toml_syntax_error_is_one_line(tmp_path):
    bad = tmp_path / "syntax.toml"
    bad.write_text("[camera\nname = 1")
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "camera", str(bad)], capture_output=True, text=True)
    assert result.returncode == 2 and "invalid TOML" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_camera_command_prints_derived_numbers(mer_a_path):
    result = subprocess.run([sys.executable, "-m", "campaign.cli", "camera", str(mer_a_path)],
                            capture_output=True, text=True, check=True)
    assert "FOV 45.5" in result.stdout
