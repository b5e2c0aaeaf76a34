"""Template matching: sub-pixel recovery of exact shifts, peak fitting and the quality checks."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from dimes_velocity.config import EstimatorConfig
from dimes_velocity.matching import (
    correlation_difference_sigma,
    fit_peak,
    lobes_above,
    match_template,
    second_peak,
    shift_window,
)
from dimes_velocity.solution import combine_pairs, consensus, displacement_standard_error

SIZE = 256


class ShiftableTexture:
    """A band-limited periodic random texture that can be shifted exactly (Fourier shift theorem)."""

    def __init__(self, seed: int, cutoff: float = 0.25, slope: float = 1.0):
        rng = np.random.default_rng(seed)
        self.fy = np.fft.fftfreq(SIZE)[:, None]
        self.fx = np.fft.fftfreq(SIZE)[None, :]
        frequency = np.hypot(self.fx, self.fy)
        amplitude = np.where(frequency > 0, (frequency + 0.01) ** -slope, 0.0) * np.exp(-(frequency / cutoff) ** 2)
        self.spectrum = amplitude * (rng.standard_normal((SIZE, SIZE)) + 1j * rng.standard_normal((SIZE, SIZE)))
        self.scale = 40.0 / np.real(np.fft.ifft2(self.spectrum)).std()

    def image(self, shift_x: float = 0.0, shift_y: float = 0.0) -> np.ndarray:
        """Texture moved by (+shift_x, +shift_y) pixels: ``image(s)[y, x] = image(0)[y - s_y, x - s_x]``."""
        phase = np.exp(-2j * np.pi * (self.fx * shift_x + self.fy * shift_y))
        return (2000.0 + self.scale * np.real(np.fft.ifft2(self.spectrum * phase))).astype(np.float32)


def run_match(a, b, centre, predicted, radius=20.0, config=EstimatorConfig()):
    return match_template(a, b, cv2.pyrDown(a), cv2.pyrDown(b), centre, np.asarray(predicted, float), radius, config)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pure_shift_recovered_within_a_tenth_of_a_pixel(seed):
    texture = ShiftableTexture(seed)
    a = texture.image()
    rng = np.random.default_rng(100 + seed)
    errors = []
    for _ in range(12):
        shift = rng.uniform(-12.0, 12.0, 2)
        b = texture.image(*shift)
        centre = tuple(int(v) for v in rng.integers(70, 186, 2))
        guess = np.array(centre) + rng.uniform(-4, 4, 2)          # prediction off by a few pixels
        match = run_match(a, b, centre, guess)
        assert match.status == "ok"
        errors.append(np.hypot(*(match.position_px - (np.array(centre) + shift))))
    assert max(errors) < 0.1
    assert np.sqrt(np.mean(np.square(errors))) < 0.03


def test_shift_recovered_with_noise():
    texture = ShiftableTexture(7)
    rng = np.random.default_rng(8)
    a = texture.image() + rng.normal(0, 4.0, (SIZE, SIZE)).astype(np.float32)
    errors = []
    for _ in range(10):
        shift = rng.uniform(-8.0, 8.0, 2)
        b = texture.image(*shift) + rng.normal(0, 4.0, (SIZE, SIZE)).astype(np.float32)
        centre = tuple(int(v) for v in rng.integers(70, 186, 2))
        match = run_match(a, b, centre, centre)
        assert match.status == "ok" and match.correlation > 0.9
        errors.append(np.hypot(*(match.position_px - (np.array(centre) + shift))))
    assert max(errors) < 0.1


def test_pyramid_finds_a_shift_beyond_the_fine_search():
    texture = ShiftableTexture(3)
    a, b = texture.image(), texture.image(17.3, -14.6)
    match = run_match(a, b, (128, 128), (128, 128), radius=24.0)
    assert match.status == "ok"
    assert np.allclose(match.position_px, [145.3, 113.4], atol=0.1)


def test_shift_outside_the_search_window_is_rejected():
    texture = ShiftableTexture(4)
    a, b = texture.image(), texture.image(30.0, 0.0)
    match = run_match(a, b, (128, 128), (128, 128), radius=10.0)
    assert match.status != "ok"


def test_blank_and_noise_only_templates_fail_quality_checks():
    rng = np.random.default_rng(0)
    a = (2000 + rng.normal(0, 3.0, (SIZE, SIZE))).astype(np.float32)
    b = (2000 + rng.normal(0, 3.0, (SIZE, SIZE))).astype(np.float32)
    match = run_match(a, b, (128, 128), (128, 128))
    assert match.status in ("low_correlation", "ambiguous_match", "flat_peak", "search_border")
    flat = np.full((SIZE, SIZE), 2000.0, np.float32)
    match = run_match(flat, flat, (128, 128), (128, 128))
    assert match.status != "ok" and np.isfinite(match.correlation)


def test_repetitive_texture_is_ambiguous():
    columns, rows = np.meshgrid(np.arange(SIZE), np.arange(SIZE))
    pattern = (2000 + 50 * np.sin(2 * np.pi * columns / 7.0) * np.sin(2 * np.pi * rows / 7.0)).astype(np.float32)
    match = run_match(pattern, pattern, (128, 128), (129, 127), radius=20.0)
    assert match.status == "ambiguous_match"
    assert match.second_peak_ratio > 0.9


def test_repetitive_texture_with_noise_is_ambiguous():
    """A periodic pattern: its repeats correlate as well as the true position, within the noise."""
    columns, rows = np.meshgrid(np.arange(SIZE), np.arange(SIZE))
    pattern = 2000 + 50 * np.sin(2 * np.pi * columns / 9.0) * np.sin(2 * np.pi * rows / 9.0)
    rng = np.random.default_rng(3)
    a = (pattern + rng.normal(0, 4.0, (SIZE, SIZE))).astype(np.float32)
    b = (pattern + rng.normal(0, 4.0, (SIZE, SIZE))).astype(np.float32)
    match = match_template(a, b, cv2.pyrDown(a), cv2.pyrDown(b), (128, 128), np.array([129.0, 127.0]), 20.0,
                           EstimatorConfig(), 4.0, 4.0)
    assert match.status == "ambiguous_match"


def test_broad_peak_of_red_texture_is_distinct_despite_a_high_second_peak():
    """Smooth (red-spectrum) ground: the template's autocorrelation is broad, so another local maximum of
    the surface reaches > 0.9 of the best, yet lies many noise standard deviations below it. The
    noise-based test keeps the match (found within 0.1 px); a fixed ratio of 0.9 refuses it."""
    texture = ShiftableTexture(0, slope=2.0)
    rng = np.random.default_rng(0)
    shift = np.array([5.3, -3.6])
    a = texture.image() + rng.normal(0, 2.0, (SIZE, SIZE)).astype(np.float32)
    b = texture.image(*shift) + rng.normal(0, 2.0, (SIZE, SIZE)).astype(np.float32)
    centre, predicted = (100, 80), np.array([104.0, 78.0])
    match = match_template(a, b, cv2.pyrDown(a), cv2.pyrDown(b), centre, predicted, 20.0, EstimatorConfig(), 2.0, 2.0)
    assert match.status == "ok" and match.second_peak_ratio > 0.9
    assert np.hypot(*(match.position_px - (np.array(centre) + shift))) < 0.1
    ratio_gate = EstimatorConfig(max_second_peak_ratio=0.9, ambiguity_confidence_sigma=0.0)
    refused = match_template(a, b, cv2.pyrDown(a), cv2.pyrDown(b), centre, predicted, 20.0, ratio_gate, 2.0, 2.0)
    assert refused.status == "ambiguous_match"


@pytest.mark.parametrize("slope, noise_dn, target", [(2.0, 2.0, 0.9), (2.0, 6.0, 0.9), (1.0, 4.0, 0.8)])
def test_correlation_difference_sigma_bounds_the_monte_carlo_scatter(slope, noise_dn, target):
    """The closed-form standard deviation of (best - other) coarse correlation, against the scatter of 300
    noisy renderings of one shifted texture: an upper bound (pyrDown passes at most 1/4 of white noise power in
    2-D), and not a loose one (within 2x)."""
    texture = ShiftableTexture(3, slope=slope)
    clean_a, clean_b = texture.image()[64:192, 64:192], texture.image(6.0, -4.0)[64:192, 64:192]
    half, reach, centre = 5, 12, 32          # coarse template 11 x 11 at coarse (32, 32); true shift (3, -2)
    window_at = (slice(centre - 2 - half - reach, centre - 2 + half + reach + 1),
                 slice(centre + 3 - half - reach, centre + 3 + half + reach + 1))

    def surface(image_a, image_b):
        template = cv2.pyrDown(image_a)[centre - half:centre + half + 1, centre - half:centre + half + 1]
        return cv2.matchTemplate(cv2.pyrDown(image_b)[window_at], template, cv2.TM_CCOEFF_NORMED), template

    clean, _ = surface(clean_a, clean_b)
    assert np.unravel_index(np.argmax(clean), clean.shape) == (reach, reach)
    rows, columns = np.mgrid[:clean.shape[0], :clean.shape[1]]
    away = np.hypot(rows - reach, columns - reach) >= 1
    other = np.unravel_index(int(np.argmin(np.where(away, np.abs(clean - target), 9.0))), clean.shape)
    rng = np.random.default_rng(1)
    differences, bests, others, sigmas = [], [], [], []
    for _ in range(300):
        a = clean_a + rng.normal(0, noise_dn, clean_a.shape).astype(np.float32)
        b = clean_b + rng.normal(0, noise_dn, clean_b.shape).astype(np.float32)
        noisy, template = surface(a, b)
        window = cv2.pyrDown(b)[window_at][reach:reach + 2 * half + 1, reach:reach + 2 * half + 1]
        differences.append(noisy[reach, reach] - noisy[other])
        bests.append(noisy[reach, reach])
        others.append(noisy[other])
        sigmas.append((float(template.var()), float(window.var())))
    template_variance, window_variance = np.mean(sigmas, axis=0)
    predicted = correlation_difference_sigma(float(np.mean(bests)), float(np.mean(others)), template_variance,
                                             window_variance, noise_dn, noise_dn, (2 * half + 1) ** 2)
    measured = float(np.std(differences))
    assert measured <= predicted <= 2.0 * measured


def test_lobes_above_counts_separate_regions():
    columns, rows = np.meshgrid(np.arange(31.0), np.arange(31.0))
    surface = np.exp(-((columns - 15) ** 2 + (rows - 15) ** 2) / 40.0).astype(np.float32)
    assert lobes_above(surface, 0.9) == 1                  # one broad peak: one lobe, however wide
    surface[4, 5] = 0.95                                   # a separate peak above the level
    assert lobes_above(surface, 0.9) == 2
    assert lobes_above(surface, 0.96) == 1                 # ... not above a higher one
    surface[5:15, 5] = 0.95                                # joined to the main lobe by a ridge above the level
    surface[15, 5:15] = 0.95
    assert lobes_above(surface, 0.9) == 1


def test_ridge_texture_has_a_flat_peak_at_the_search_level():
    """Dune crests: a 1-D texture matches all along the crest; its coarse peak has ~zero curvature
    across the ridge and is refused there, before any fine-level work."""
    columns, rows = np.meshgrid(np.arange(SIZE), np.arange(SIZE))
    crest = (columns * np.cos(0.6) + rows * np.sin(0.6)) / 23.0
    ridges = (2000 + 60 * np.sin(2 * np.pi * crest) + 25 * np.sin(4 * np.pi * crest + 1.0)).astype(np.float32)
    match = run_match(ridges, ridges, (128, 128), (130, 126), radius=8.0,
                      config=EstimatorConfig(max_second_peak_ratio=1.0))
    assert match.status == "flat_peak" and match.coarse_curvature_per_px2 < 0.02


@pytest.mark.parametrize("factor, status", [(0.6, "ok"), (0.9, "outside_prior")])
def test_match_must_lie_within_the_prior_radius(factor, status):
    """The search window is a square of half-width R; the prior bounds the displacement by a circle of
    radius R, so a true shift of (0.9 R, 0.9 R) (1.27 R away) is found but refused."""
    texture = ShiftableTexture(5)
    radius = 16.0
    shift = factor * radius * np.ones(2)
    match = run_match(texture.image(), texture.image(*shift), (128, 128), (128, 128), radius=radius)
    assert np.allclose(match.position_px, np.array([128.0, 128.0]) + shift, atol=0.2) or status != "ok"
    assert match.status == status


def test_fit_peak_recovers_the_vertex_of_a_quadratic():
    x, y = np.meshgrid([-1.0, 0.0, 1.0], [-1.0, 0.0, 1.0])
    centre = np.array([0.3, -0.2])
    hessian = np.array([[-0.4, 0.05], [0.05, -0.25]])
    d = np.stack([x - centre[0], y - centre[1]], axis=-1)
    patch = 0.95 + 0.5 * np.einsum("...i,ij,...j->...", d, hessian, d)
    offset, value, curvature = fit_peak(patch)
    assert np.allclose(offset, centre, atol=1e-9)
    assert value == pytest.approx(0.95, abs=1e-9)
    assert curvature == pytest.approx(-np.linalg.eigvalsh(hessian)[1], rel=1e-9)


def test_shift_window_reproduces_quadratics_exactly():
    """Keys cubic convolution reproduces polynomials up to degree 2 exactly."""
    columns, rows = np.meshgrid(np.arange(31.0), np.arange(31.0))

    def field(x, y):
        return 3.0 + 0.5 * x - 0.25 * y + 0.01 * x * x + 0.02 * x * y - 0.015 * y * y

    offset = np.array([0.37, -1.21])
    out = shift_window(field(columns, rows), offset, 17)
    expected_columns, expected_rows = np.meshgrid(np.arange(7.0, 24.0), np.arange(7.0, 24.0))
    assert np.allclose(out, field(expected_columns + offset[0], expected_rows + offset[1]), atol=1e-9)


def test_second_peak_ignores_the_flanks_of_the_main_peak():
    columns, rows = np.meshgrid(np.arange(21.0), np.arange(21.0))
    surface = np.exp(-((columns - 10) ** 2 + (rows - 10) ** 2) / 30.0).astype(np.float32)
    assert second_peak(surface, (10, 10), 2) == -1.0       # a single broad peak has no second maximum
    surface[3, 4] = 0.8                    # a separate local maximum
    assert second_peak(surface, (10, 10), 2) == pytest.approx(0.8)


def test_consensus_rejects_a_planted_wrong_match():
    good = np.array([[20.0, -10.0], [20.3, -10.2], [19.8, -9.9]])
    planted = np.array([[35.0, 4.0]])
    displacements = np.vstack([good[:2], planted, good[2:]])
    group = consensus(displacements, np.array([0.9, 0.95, 0.99, 0.92]), 5.0, 1, True)
    assert sorted(group.tolist()) == [0, 1, 3]
    # one good and one wrong match: no majority, no answer
    assert consensus(np.vstack([good[:1], planted]), np.array([0.9, 0.9]), 5.0, 1, True).size == 0
    assert consensus(np.zeros((0, 2)), np.zeros(0), 5.0, 1, True).size == 0


def test_combine_pairs_checks_agreement():
    ok, reason, bias = combine_pairs(np.array([[5.0, 1.0], [5.4, 0.8]]), np.array([True, True]), ["ok", "ok"], 1.0, True)
    assert ok and reason == "ok" and np.allclose(bias, [5.2, 0.9])
    ok, reason, bias = combine_pairs(np.array([[5.0, 1.0], [9.0, 0.8]]), np.array([True, True]), ["ok", "ok"], 1.0, True)
    assert not ok and reason == "pairs_disagree" and np.allclose(bias, 0.0)
    ok, reason, _ = combine_pairs(np.array([[5.0, 1.0], [0.0, 0.0]]), np.array([True, False]), ["ok", "low_contrast"], 1.0, True)
    assert not ok and reason == "low_contrast"
    ok, reason, bias = combine_pairs(np.array([[5.0, 1.0], [0.0, 0.0]]), np.array([True, False]), ["ok", "low_contrast"], 1.0, False)
    assert ok and np.allclose(bias, [5.0, 1.0])


def test_displacement_standard_error_is_the_rms_axis_spread_over_root_n():
    """Closed form: per-axis sample variances (ddof 1) averaged, square-rooted, over sqrt(n); floored."""
    displacements = np.array([[1.0, 10.0], [3.0, 10.0], [5.0, 16.0]])     # east var 4, north var 12
    assert displacement_standard_error(displacements, 0.01) == pytest.approx(np.sqrt((4.0 + 12.0) / 2) / np.sqrt(3))
    assert displacement_standard_error(displacements, 5.0) == 5.0                      # the floor
    assert displacement_standard_error(displacements[:1], 0.3) == 0.3                  # one match: the floor
    rng = np.random.default_rng(9)
    for count in range(2, 12):                                                         # numpy's var, same bits
        sample = rng.normal(size=(count, 2)) * 40.0 + 300.0
        expected = max(float(np.sqrt(sample.var(axis=0, ddof=1).mean())) / np.sqrt(count), 1e-9)
        assert displacement_standard_error(sample, 1e-9) == expected
