"""simulator.detector.psf: the optics' blur against closed forms worked out here (the Airy pattern and its
encircled energy, the circular-aperture MTF, the pixel sinc), energy conservation, the camera chain hook,
the camera TOML's [optics] checks and the numbers `campaign camera` prints."""
from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import scipy.integrate
import scipy.special

from campaign.cli import main as campaign_main
from config_tables.errors import ConfigError
from flight_interface.camera import load_camera
from flight_interface.camera_file import Optics
from simulator.detector import psf
from simulator.detector.camera_chain import CameraEffects, render_image
from simulator.scene.radiance import pixel_area_average

WAVELENGTH_M = 0.7e-6
PITCH_M = 12e-6


def closed_form_mtf(v):
    """2/pi (acos v - v sqrt(1 - v^2)), v = f lambda N < 1."""
    return 2.0 / np.pi * (np.arccos(v) - v * np.sqrt(1.0 - v * v))


def narrow_band(camera, wavelength_um=0.7, **optics):
    """The camera with a 0.2 nm band at ``wavelength_um`` (one wavelength, to within 1.5e-4) and ``optics``."""
    radiometry = camera.radiometry.model_copy(update=dict(band_min_um=wavelength_um - 1e-4,
                                                          band_max_um=wavelength_um + 1e-4))
    return dataclasses.replace(camera, radiometry=radiometry, optics=Optics(**optics))


@pytest.fixture(scope="module")
def mono(mer_a):
    return narrow_band(mer_a)


def amplitude(field, fx, fy, margin=64):
    """Least-squares amplitude of cos/sin at (fx, fy) cycles per sample over the field's interior."""
    rows, cols = np.indices(field.shape)
    inner = (slice(margin, field.shape[0] - margin), slice(margin, field.shape[1] - margin))
    phase = 2 * np.pi * (fx * cols + fy * rows)[inner]
    design = np.stack([np.ones(phase.size), np.cos(phase).ravel(), np.sin(phase).ravel()], axis=1)
    coefficients = np.linalg.lstsq(design, field[inner].astype(float).ravel(), rcond=None)[0]
    return float(np.hypot(coefficients[1], coefficients[2]))


def test_airy_pattern_and_its_first_zero(mono):
    lambda_n = WAVELENGTH_M * 12.0
    radius = np.linspace(0.05, 3.0, 60) * lambda_n
    x = np.pi * radius / lambda_n
    airy = np.pi / (4 * lambda_n**2) * (2 * scipy.special.j1(x) / x) ** 2     # unit energy, peak pi/(4 lambda^2 N^2)
    assert np.max(np.abs(psf.psf_radial(radius, mono) - airy)) < 2e-3 * airy[0]
    fine = np.linspace(1.1, 1.35, 251) * lambda_n
    first_zero = fine[np.argmin(psf.psf_radial(fine, mono))]
    assert first_zero / lambda_n == pytest.approx(1.2197, abs=2e-3)


def test_encircled_energy_of_the_airy_pattern(mono):
    lambda_n = WAVELENGTH_M * 12.0
    radius = np.linspace(0.2, 4.0, 20) * lambda_n
    x = np.pi * radius / lambda_n
    closed = 1 - scipy.special.j0(x) ** 2 - scipy.special.j1(x) ** 2              # Rayleigh's formula
    assert np.allclose(psf.encircled_energy(radius, mono), closed, atol=1e-3)
    assert float(psf.encircled_energy(1.2197 * lambda_n, mono)) == pytest.approx(0.838, abs=1e-3)
    # 80 %: solve Rayleigh's formula independently by bisection on x
    x80 = scipy.optimize.brentq(lambda u: 1 - scipy.special.j0(u) ** 2 - scipy.special.j1(u) ** 2 - 0.8, 2.0, 3.8)
    assert psf.encircled_energy_radius_m(mono, 0.8) == pytest.approx(x80 * lambda_n / np.pi, rel=1e-3)


@pytest.mark.parametrize("fx, fy", [(0.1, 0.0), (0.25, 0.0), (0.5, 0.0), (0.0, 0.4), (0.3, 0.3)])
def test_filter_multiplies_a_sinusoid_by_the_circular_aperture_mtf(mono, fx, fy):
    rows, cols = np.indices((1024, 1024))
    field = (40.0 + 10.0 * np.cos(2 * np.pi * (fx * cols + fy * rows) + 0.3)).astype(np.float32)
    blurred = psf.blur_field(field, mono)
    v = np.hypot(fx, fy) / PITCH_M * WAVELENGTH_M * 12.0       # f (cycles/m) x lambda N
    assert amplitude(blurred, fx, fy) / amplitude(field, fx, fy) == pytest.approx(closed_form_mtf(v), abs=2e-3)


def test_block_field_rows_are_four_pixels_apart(mono):
    # a field given per binning block: rows 48 um apart, so 0.25 cycles/row is 0.25 / 48 um
    rows = np.indices((256, 1024))[0]
    field = (40.0 + 10.0 * np.cos(2 * np.pi * 0.25 * rows)).astype(np.float32)
    blurred = psf.blur_field(field, mono)
    v = 0.25 / (4 * PITCH_M) * WAVELENGTH_M * 12.0
    assert amplitude(blurred, 0.0, 0.25, margin=32) / amplitude(field, 0.0, 0.25, margin=32) == pytest.approx(
        closed_form_mtf(v), abs=2e-3)


def test_gaussian_blur_and_wavefront_error_terms(mer_a):
    blurred = narrow_band(mer_a, blur_sigma_um=5.0)
    cols = np.indices((512, 1024))[1]
    field = (40.0 + 10.0 * np.cos(2 * np.pi * 0.2 * cols)).astype(np.float32)
    f = 0.2 / PITCH_M
    expected = closed_form_mtf(f * WAVELENGTH_M * 12.0) * np.exp(-2 * np.pi**2 * (5e-6 * f) ** 2)
    ratio = amplitude(psf.blur_field(field, blurred), 0.2, 0.0) / amplitude(field, 0.2, 0.0)
    assert ratio == pytest.approx(expected, abs=2e-3)
    # 0.063 um rms at 0.7 um = 0.09 waves: at v = 0.5 the transfer factor is 1 - (0.09 / 0.18)^2 = 0.75
    aberrated = narrow_band(mer_a, wavefront_error_rms_um=0.063)
    f_half = 0.5 / (WAVELENGTH_M * 12.0)
    assert float(psf.optics_mtf(f_half, aberrated)) == pytest.approx(0.75 * closed_form_mtf(0.5), rel=1e-3)


def test_pixel_sinc_and_the_pixel_area_the_scene_already_integrates():
    # the mean of a continuous cosine over one pixel, by brute-force sub-sampling, is sinc(f p)
    sub = (np.arange(2000) + 0.5) / 2000 - 0.5
    for f in (0.1, 0.25, 0.5):
        box_mean = np.mean(np.cos(2 * np.pi * f * sub))
        assert float(psf.pixel_mtf(f / PITCH_M, PITCH_M)) == pytest.approx(box_mean, abs=1e-6)
    # the scene's pixel-area filter already applies it (second order): the PSF must not apply it twice
    cols = np.indices((64, 512))[1]
    points = np.cos(2 * np.pi * 0.1 * cols).astype(np.float32)
    assert amplitude(pixel_area_average(points), 0.1, 0.0, margin=8) == pytest.approx(np.sinc(0.1), abs=1e-3)


def test_energy_is_conserved(mer_a):
    uniform = np.full((1024, 1024), 37.5, dtype=np.float32)
    assert np.allclose(psf.blur_field(uniform, mer_a), 37.5, rtol=1e-5, atol=0)
    # a point (a compact spot) in the middle: what leaves the 1024-px frame is the Airy tail beyond
    # 512 px, 1 - EE ~ 2 lambda N / (pi^2 r) < 5e-4 at 1.1 um
    rows, cols = np.indices((1024, 1024))
    spot = np.exp(-((rows - 511.3) ** 2 + (cols - 512.6) ** 2) / (2 * 1.2**2)).astype(np.float32)
    blurred = psf.blur_field(spot, mer_a)
    assert float(blurred.sum(dtype=np.float64)) == pytest.approx(float(spot.sum(dtype=np.float64)), rel=1e-3)
    assert blurred.max() < 0.9 * spot.max()          # and it was spread


def test_non_finite_and_negative_input(mer_a):
    field = np.full((256, 1024), 10.0, dtype=np.float32)
    field[100, 100], field[10, 10] = np.nan, np.inf
    out = psf.blur_field(field, mer_a)
    assert np.isnan(out[100, 100]) and np.isinf(out[10, 10]) and np.isfinite(out[50, 500])
    with pytest.raises(ValueError, match="negative"):
        psf.blur_field(-field, mer_a)


def test_camera_chain_applies_the_mtf_and_keeps_shared_fields(mer_a):
    cols = np.indices((1024, 1024))[1]
    field = (30.0 + 6.0 * np.cos(2 * np.pi * 0.25 * cols)).astype(np.float32)
    plain = dict(falloff=False, prnu=False, dark_current=False, smear=False, shot_noise=False, read_noise=False)
    charges = {on: render_image(mer_a, (field, field, field), np.random.default_rng(0),
                                CameraEffects(optics_psf=on, **plain)).expected_charge_e for on in (True, False)}
    ratio = amplitude(charges[True], 0.25, 0.0, margin=16) / amplitude(charges[False], 0.25, 0.0, margin=16)
    assert ratio == pytest.approx(float(psf.optics_mtf(0.25 / PITCH_M, mer_a)), abs=2e-3)
    fields = psf.blurred_fields(psf.RadianceFields(field, field, field), mer_a)
    assert fields.flush is fields.exposure is fields.transfer


def test_campaign_camera_prints_the_band_averaged_mtf_and_ee80(capsys, mer_a_path):
    assert campaign_main(["camera", str(mer_a_path)]) == 0
    out = capsys.readouterr().out
    found = re.search(r"\(41\.7 cycles/mm\) ([\d.]+) optics x ([\d.]+) pixel = ([\d.]+); 80 % encircled energy "
                      r"within ([\d.]+) um", out)
    assert found, out
    optics_value, pixel_value, system_value, ee80 = map(float, found.groups())
    # the band average worked out independently: quad over the file's transmission x QE tables
    tables = load_camera(mer_a_path).optics
    wavelength_um, weight = np.array(tables.spectral_wavelengths_um), (
        np.array(tables.spectral_transmission) * np.array(tables.spectral_quantum_efficiency))
    response = lambda lam: np.interp(lam, wavelength_um, weight)                       # noqa: E731
    nyquist = 0.5 / PITCH_M
    numerator = scipy.integrate.quad(lambda lam: response(lam) * closed_form_mtf(min(nyquist * lam * 1e-6 * 12, 1)),
                                     0.4, 1.1, points=wavelength_um[1:-1], limit=200)[0]
    expected = numerator / scipy.integrate.quad(response, 0.4, 1.1, points=wavelength_um[1:-1], limit=200)[0]
    assert optics_value == pytest.approx(expected, abs=2e-3)
    assert pixel_value == pytest.approx(2 / np.pi, abs=1e-3)
    assert system_value == pytest.approx(expected * 2 / np.pi, abs=2e-3)
    # 80 % encircled energy lies between the monochromatic Airy radii of the band's ends (x80 = 2.23 / pi lambda N)
    assert 0.7 * 0.4 * 12 < ee80 < 0.72 * 1.1 * 12


@pytest.mark.parametrize("optics_text, field", [
    ("spectral_wavelengths_um = [0.4, 1.1]\nspectral_transmission = [0.8, 0.8]", "optics.spectral_quantum_efficiency"),
    ("spectral_wavelengths_um = [0.4, 1.1]\nspectral_transmission = [0.8, 0.8]\nspectral_quantum_efficiency = [0.1, 1.5]",
     "optics.spectral_quantum_efficiency"),
    ("spectral_wavelengths_um = [0.4, 0.7, 1.1]\nspectral_transmission = [0.8, 0.8]\nspectral_quantum_efficiency = [0.1, 0.1, 0.1]",
     "optics.spectral_transmission"),
    ("spectral_wavelengths_um = [0.5, 1.1]\nspectral_transmission = [0.8, 0.8]\nspectral_quantum_efficiency = [0.1, 0.1]",
     "optics.spectral_wavelengths_um"),
    ("wavefront_error_rms_um = 0.1", "optics.wavefront_error_rms_um"),
    ("blur_sigma_um = -1.0", "optics.blur_sigma_um"),
])
def test_bad_optics_tables_get_one_line_naming_the_field(tmp_path, mer_a_path, optics_text, field):
    text = mer_a_path.read_text()
    path = tmp_path / "camera.toml"
    path.write_text(text[:text.index("[optics]")] + "[optics]\n" + optics_text + "\n")
    with pytest.raises(ConfigError) as raised:
        load_camera(path)
    message = str(raised.value)
    assert "\n" not in message and str(path) in message and field in message, message


@pytest.mark.parametrize("fx", [0.1, 0.3, 0.5])
def test_smear_fields_see_the_line_spread_across_columns_only(mono, fx):
    rows, cols = np.indices((256, 1024))
    across = (40.0 + 10.0 * np.cos(2 * np.pi * fx * cols + 0.3)).astype(np.float32)
    v = fx / PITCH_M * WAVELENGTH_M * 12.0
    ratio = amplitude(psf.blur_field_along_rows(across, mono), fx, 0.0, 32) / amplitude(across, fx, 0.0, 32)
    assert ratio == pytest.approx(closed_form_mtf(v), abs=2e-3)
    along = (40.0 + 10.0 * np.cos(2 * np.pi * 0.25 * rows)).astype(np.float32)   # along a column: untouched
    np.testing.assert_allclose(psf.blur_field_along_rows(along, mono), along, rtol=1e-5)


def test_line_spread_smear_gives_the_charge_of_the_full_psf(mer_a):
    # a textured scene whose flush/transfer fields differ from the exposure field: the chain filters them
    # along rows only; the charge must equal that of the full 2-D PSF on all three to O(w / N) of the smear
    rng = np.random.default_rng(3)
    texture = (30.0 + 8.0 * rng.standard_normal((1024, 1024))).clip(0).astype(np.float32)
    flush, transfer = np.roll(texture, 5, axis=1), np.roll(texture, -7, axis=0)
    plain = dict(falloff=False, prnu=False, dark_current=False, shot_noise=False, read_noise=False)
    chain = render_image(mer_a, (flush, texture, transfer), np.random.default_rng(0),
                         CameraEffects(optics_psf=True, **plain)).expected_charge_e
    full = [psf.blur_field(field, mer_a) for field in (flush, texture, transfer)]
    exact = render_image(mer_a, full, np.random.default_rng(0),
                         CameraEffects(optics_psf=False, **plain)).expected_charge_e
    smear_only = render_image(mer_a, (flush, np.zeros_like(texture), transfer), np.random.default_rng(0),
                              CameraEffects(optics_psf=False, **plain)).expected_charge_e
    assert np.max(np.abs(chain - exact)) < 5e-4 * float(smear_only.mean())
    # and the across-column part matters: without it the smear of this texture differs far more
    unblurred = render_image(mer_a, (flush, full[1], transfer), np.random.default_rng(0),
                             CameraEffects(optics_psf=False, **plain)).expected_charge_e
    assert np.max(np.abs(unblurred - exact)) > 20 * np.max(np.abs(chain - exact))


@pytest.mark.parametrize("shape", [(1024, 1024), (235, 997), (255, 1024)])
def test_blur_equals_the_otf_product_on_the_mirrored_frame(mer_a, shape):
    # independent path: numpy's complex FFT in float64 on the frame mirrored 16 px (rows of a per-block
    # field 4 px: their pitch is 4x), times the radial OTF at each frequency, no padding to a fast length;
    # odd and even padded sizes exercise both layouts of OpenCV's packed spectrum
    rng = np.random.default_rng(5)
    field = (20.0 + 5.0 * rng.random(shape)).astype(np.float32)
    rows, cols = shape
    row_pitch = PITCH_M * mer_a.height_px / rows
    pad_rows = int(np.ceil(psf.PAD_PX * PITCH_M / row_pitch))
    padded = np.pad(field.astype(float), ((pad_rows, pad_rows), (psf.PAD_PX, psf.PAD_PX)), mode="symmetric")
    fy = np.fft.fftfreq(padded.shape[0], d=row_pitch)[:, None]
    fx = np.fft.fftfreq(padded.shape[1], d=PITCH_M)[None, :]
    otf = psf.optics_mtf(np.hypot(fy, fx), mer_a)
    expected = np.fft.ifft2(np.fft.fft2(padded) * otf).real[pad_rows:pad_rows + rows, psf.PAD_PX:psf.PAD_PX + cols]
    assert psf._padded_shape(rows, cols, pad_rows) == {(1024, 1024): (1056, 1056), (235, 997): (243, 1029),
                                                        (255, 1024): (264, 1056)}[shape]
    got = psf.blur_field(field, mer_a)
    # the two differ only where each frame's periodic wrap differs (its own fast length): near the edges
    inner = (slice(2 * pad_rows, rows - 2 * pad_rows), slice(32, cols - 32))
    assert np.max(np.abs(got[inner] - expected[inner])) < 1e-4 * float(field.mean())
    assert np.max(np.abs(got[inner] - field[inner])) > 0.5      # and the blur did act
