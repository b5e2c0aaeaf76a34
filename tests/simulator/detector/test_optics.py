"""simulator.detector.optics: the lens stage against the documented radiometric constant and a pinhole
cos^4 falloff worked out here from the camera file's focal length and pixel pitch."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_interface.camera import load_camera
from simulator.detector import optics

H_PLANCK = 6.62607015e-34
C_LIGHT = 299792458.0


@pytest.fixture(scope="module")
def pinhole_camera(tmp_path_factory, mer_a_path):
    """MER-A with the radial distortion removed: field angle = atan(r pitch / f) exactly."""
    text = mer_a_path.read_text().replace("radial_distortion = [0.0, -0.01, 0.0]", "radial_distortion = [0.0, 0.0, 0.0]")
    assert "radial_distortion = [0.0, 0.0, 0.0]" in text
    path = tmp_path_factory.mktemp("camera") / "pinhole.toml"
    path.write_text(text)
    return load_camera(path)


def test_on_axis_response_is_the_documented_constant(mer_a):
    # k = pi T A dlambda QE lambda / (4 N^2 h c) with the MER numbers: 1.86e5 e-/s per unit radiance
    k = math.pi * 0.8 * (12e-6) ** 2 * 0.7 * 0.12 * 0.70e-6 / (4 * 12.0**2 * H_PLANCK * C_LIGHT)
    assert k == pytest.approx(1.86e5, rel=5e-3)
    rate = optics.photoelectron_rate(np.full((4, 5), 40.0), mer_a, falloff=False)
    assert rate.dtype == np.float32 and rate.shape == (4, 5)
    assert np.allclose(rate, 40.0 * k, rtol=1e-5)
    # the docstring's 949 e- per unit radiance in the 5.1 ms exposure
    assert float(rate[0, 0]) / 40.0 * 0.0051 == pytest.approx(949.0, rel=2e-3)


def test_falloff_is_cos4_of_the_pinhole_field_angle(pinhole_camera):
    rate = optics.photoelectron_rate(np.ones((1024, 1024)), pinhole_camera, falloff=True)
    flat = optics.photoelectron_rate(np.ones((1024, 1024)), pinhole_camera, falloff=False)
    focal_px = 0.01467 / 12e-6
    for row, col in ((0, 0), (511, 512), (0, 1023), (1023, 300), (700, 100)):
        radius_px = math.hypot(col - 511.5, row - 511.5)
        theta = math.atan(radius_px / focal_px)
        assert rate[row, col] / flat[row, col] == pytest.approx(math.cos(theta) ** 4, rel=1e-4)
    # the corner of the 45.5 deg (side) field is 30.6 deg off axis: cos^4 = 0.549
    assert rate[0, 0] / flat[0, 0] == pytest.approx(0.549, abs=2e-3)


def test_zero_radiance_is_zero_and_overflow_is_infinite(mer_a):
    radiance = np.zeros((2, 2))
    radiance[1, 1] = 1e36
    rate = optics.photoelectron_rate(radiance, mer_a, falloff=False)
    assert rate[0, 0] == 0.0 and np.isinf(rate[1, 1])
