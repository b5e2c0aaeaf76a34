"""How the correlation of a tracked template with its match is measured and taken apart (the decorrelation
study, :mod:`campaign.studies.decorrelation`).

- :func:`noise_correlation`: the closed form of two noisy copies of one template, ``rho = S / sqrt((S +
  n_A^2) (S + n_B^2))``;
- :func:`case_features`: one rendered case through the reference estimator, one record per tracked template,
  with the signal and noise variance each "ok" template really has after rectification (noisy minus
  noise-free expected DN through the same flattening, blur and map) and the correlation read on the
  whole-pixel grid (:func:`grid_peak_correlation`) beside the refined one;
- :func:`unresolved_texture_experiment`: what ground texture finer than the terrain strip's pixels would add,
  on a synthetic power-law field seen by two binned cameras.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from campaign.case.compute import simulate_case_inputs
from dimes_velocity.estimator import MAX_BLUR_PX, DimesEstimator, RectifiedImage
from dimes_velocity.matching import fit_peak
from dimes_velocity.preprocess import flatten


def noise_correlation(signal_variance, noise_variance_a, noise_variance_b=None):
    """Correlation coefficient of two copies of one signal with independent additive noise.

    ``rho = S / sqrt((S + n_A^2) (S + n_B^2))``; with equal noise ``S / (S + n^2)``.

    Parameters
    ----------
    signal_variance : float or ndarray
        Variance ``S`` of the noise-free template (DN^2).
    noise_variance_a, noise_variance_b : float or ndarray
        Pixel noise variances of the two images (DN^2); ``b`` defaults to ``a``.
    """
    signal = np.asarray(signal_variance, dtype=float)
    noise_a = np.asarray(noise_variance_a, dtype=float)
    noise_b = noise_a if noise_variance_b is None else np.asarray(noise_variance_b, dtype=float)
    return signal / np.sqrt((signal + noise_a) * (signal + noise_b))


def recording_estimator(camera, config, flat_field):
    """A :class:`~dimes_velocity.estimator.DimesEstimator` that keeps each pair's rectified images
    (``pairs_seen[k] = (A, B)``) for the noise measurement of :func:`case_features`."""

    class RecordingEstimator(DimesEstimator):
        def __init__(self, *args):
            super().__init__(*args)
            self.pairs_seen: dict[int, tuple] = {}

        def _pair(self, index, a, b, dt_s, unusable_reason="bad_attitude"):
            self.pairs_seen[index] = (a, b)
            return super()._pair(index, a, b, dt_s, unusable_reason)

    return RecordingEstimator(camera, config, flat_field)


def _clean_rectified(estimator, rectified, clean_dn: np.ndarray):
    """The noise-free image ``clean_dn`` (expected DN) flattened and rectified exactly as ``rectified``
    (same map, same resolution-equalising blur)."""

    config = estimator.config
    ratio = rectified.rectification.sample_m * estimator.focal_px / rectified.pose.centre_m[2]
    blur = config.resolution_blur * np.sqrt(max(ratio * ratio - 1.0, 0.0)) if config.equalize_resolution else 0.0
    flat = flatten(clean_dn, estimator.flattening, config)
    return RectifiedImage(flat, rectified.rectification, rectified.pose, config, min(blur, MAX_BLUR_PX))


def _template_noise(noisy: np.ndarray, clean: np.ndarray, column: int, row: int, half: int) -> tuple[float, float]:
    """(signal variance, noise variance) of the template at (column, row): variance of the noise-free
    rectified template and of noisy minus noise-free (DN^2); NaN when the template leaves the image."""
    if row - half < 0 or column - half < 0 or row + half >= noisy.shape[0] or column + half >= noisy.shape[1]:
        return float("nan"), float("nan")
    window = (slice(row - half, row + half + 1), slice(column - half, column + half + 1))
    signal = clean[window].astype(np.float64)
    return float(signal.var()), float((noisy[window].astype(np.float64) - signal).var())


def grid_peak_correlation(image_a: np.ndarray, image_b: np.ndarray, template_px: tuple[int, int],
                          match_px: tuple[float, float], half: int) -> tuple[float, float]:
    """The correlation of a template with its match read on the whole-pixel grid: the normalised correlation
    surface (``TM_CCOEFF_NORMED``) of the template of ``image_a`` at ``template_px`` (column, row) over whole-pixel
    shifts of ``image_b`` within 2 px of ``match_px``; returns its highest value and the value of the biquadratic
    fitted to the 3 x 3 values around it (:func:`dimes_velocity.matching.fit_peak`). NaN when a window leaves an
    image or the highest value lies on the window's edge."""
    import cv2

    column, row = template_px
    centre_column, centre_row = int(round(match_px[0])), int(round(match_px[1]))
    reach = half + 2
    if (min(row - half, column - half, centre_row - reach, centre_column - reach) < 0
            or row + half >= image_a.shape[0] or column + half >= image_a.shape[1]
            or centre_row + reach >= image_b.shape[0] or centre_column + reach >= image_b.shape[1]):
        return float("nan"), float("nan")
    template = np.ascontiguousarray(image_a[row - half:row + half + 1, column - half:column + half + 1], np.float32)
    window = np.ascontiguousarray(image_b[centre_row - reach:centre_row + reach + 1,
                                          centre_column - reach:centre_column + reach + 1], np.float32)
    surface = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    peak_row, peak_column = np.unravel_index(int(np.argmax(surface)), surface.shape)
    if not (0 < peak_row < surface.shape[0] - 1 and 0 < peak_column < surface.shape[1] - 1):
        return float("nan"), float("nan")
    _, fitted, _ = fit_peak(surface[peak_row - 1:peak_row + 2, peak_column - 1:peak_column + 2])
    return float(surface[peak_row, peak_column]), float(fitted)


def case_features(resources, plan_row, estimator) -> list[dict[str, Any]]:
    """Render one case and run the reference estimator on it: one record per tracked template.

    For every match that passed every check, the template and its match are also cut from the noise-free
    images (the camera's expected DN, flattened and rectified the same way), giving the signal variance
    ``S`` and the noise variance ``n^2`` each really has after rectification, hence the closed-form noise
    correlation ``S_A^(1/2) S_B^(1/2) / ((S_A + n_A^2)(S_B + n_B^2))^(1/2)`` (``noise_factor``; NaN otherwise).
    ``noise_decorrelation`` is the estimator's own prediction of ``1 - correlation`` from its pixel noise
    model (raw binned pixels, before rectification). ``grid_correlation`` and ``fitted_grid_correlation``
    (:func:`grid_peak_correlation`, same matches) read the correlation on the whole-pixel grid instead of at
    the refined sub-pixel position."""

    inputs = simulate_case_inputs(resources, plan_row)
    estimator.pairs_seen = {}
    estimate = estimator.estimate([image.dn for image in inputs.images], inputs.measurements)
    half = estimator.config.template_size_px // 2
    clean: dict[tuple[int, int], Any] = {}
    records = []
    for f in estimate.features:
        factor = grid = fitted = float("nan")
        if f.status == "ok" and f.pair in estimator.pairs_seen:
            a, b = estimator.pairs_seen[f.pair]
            for k, image in ((f.pair, a), (f.pair + 1, b)):
                if (f.pair, k) not in clean:
                    clean[(f.pair, k)] = _clean_rectified(estimator, image, inputs.images[k].image.expected_dn)
            match = b.rectification.pixel_of(np.array([f.east_m + f.displacement_east_m,
                                                       f.north_m + f.displacement_north_m]))
            signal_a, noise_a = _template_noise(a.image, clean[(f.pair, f.pair)].image, f.column_px, f.row_px, half)
            signal_b, noise_b = _template_noise(b.image, clean[(f.pair, f.pair + 1)].image,
                                                int(round(float(match[0]))), int(round(float(match[1]))), half)
            factor = float(np.sqrt(signal_a / (signal_a + noise_a) * signal_b / (signal_b + noise_b)))
            grid, fitted = grid_peak_correlation(a.image, b.image, (f.column_px, f.row_px),
                                                 (float(match[0]), float(match[1])), half)
        records.append(dict(case_id=plan_row.case_id, class_name=plan_row.class_name, pair=f.pair, status=f.status,
                            correlation=f.correlation, brightness_dn=f.brightness_dn, contrast_dn=f.contrast_dn,
                            contrast_to_noise=f.contrast_to_noise, noise_decorrelation=f.noise_decorrelation,
                            noise_factor=factor, grid_correlation=grid, fitted_grid_correlation=fitted,
                            valid=estimate.valid, reason=estimate.reason))
    return records


def unresolved_texture_experiment(spectral_exponent: float = 2.2, seed: int = 1, sample_m: float = 0.5,
                                  size: int = 4096) -> dict[str, float]:
    """Does ground texture finer than the terrain strip's 3 m pixels decorrelate descent templates?

    A power-law albedo field (``P(k) ~ k^-spectral_exponent``, the classes' spectrum, outer scale 1 km) on
    a ``sample_m`` grid is seen by two binned cameras: A with 6.5 m pixels (2000 m), B with 5.6 m pixels
    (1725 m), turned 12 deg and moved 37.3 m east, -21.9 m north (each binned pixel the mean of 8 x 8 point
    samples of its square); B is blurred to A's resolution (the estimator's equalising blur) and both are
    resampled bilinearly onto A's grid at the true motion, as the estimator rectifies. Returns, for the field
    band-limited to wavelengths above 6 m (what a 3 m terrain strip can hold), 3 m, 1.5 m and unlimited, the
    median correlation of 15 x 15 templates at the true (zero) offset: no noise, no attitude error, only
    the sampling. Takes ~1 min."""
    import cv2

    rng = np.random.default_rng(seed)
    frequency = np.hypot(np.fft.rfftfreq(size, d=sample_m)[None, :], np.fft.fftfreq(size, d=sample_m)[:, None])
    amplitude = np.where(frequency > 0, (frequency + 1.0 / 1000.0) ** (-spectral_exponent / 2.0), 0.0)
    spectrum = amplitude * (rng.standard_normal(amplitude.shape) + 1j * rng.standard_normal(amplitude.shape))
    pixels, supersample = 256, 8
    offsets = (np.arange(pixels * supersample) + 0.5) / supersample - pixels / 2

    def view(albedo, pixel_m, angle_rad, shift_m):
        cos, sin = np.cos(angle_rad), np.sin(angle_rad)
        u, v = np.meshgrid(offsets, offsets)
        east = ((cos * u - sin * v) * pixel_m + shift_m[0]) / sample_m + size / 2
        north = ((sin * u + cos * v) * pixel_m + shift_m[1]) / sample_m + size / 2
        samples = cv2.remap(albedo, east.astype(np.float32), north.astype(np.float32), cv2.INTER_LINEAR)
        return samples.reshape(pixels, supersample, pixels, supersample).mean(axis=(1, 3))

    def rectify(image, pixel_m, angle_rad, shift_m, blur_px):
        if blur_px > 0.05:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        cos, sin = np.cos(angle_rad), np.sin(angle_rad)
        grid = (np.arange(pixels) - pixels / 2 + 0.5) * 6.5
        east, north = np.meshgrid(grid - shift_m[0], grid - shift_m[1])
        column = (cos * east + sin * north) / pixel_m + pixels / 2 - 0.5
        row = (-sin * east + cos * north) / pixel_m + pixels / 2 - 0.5
        return cv2.remap(image.astype(np.float32), column.astype(np.float32), row.astype(np.float32), cv2.INTER_LINEAR)

    results = {}
    angle, shift = np.radians(12.0), (37.3, -21.9)
    for label, shortest_m in (("above 6 m (3 m strip)", 6.0), ("above 3 m", 3.0), ("above 1.5 m", 1.5),
                              ("unlimited", 0.0)):
        band = spectrum * (frequency <= 1.0 / shortest_m) if shortest_m else spectrum
        albedo = np.fft.irfft2(band, s=(size, size)).astype(np.float32)
        image_a = rectify(view(albedo, 6.5, 0.0, (0.0, 0.0)), 6.5, 0.0, (0.0, 0.0), 0.0)
        image_b = rectify(view(albedo, 5.6, angle, shift), 5.6, angle, shift, 0.5 * np.sqrt((6.5 / 5.6) ** 2 - 1.0))
        correlations = [np.corrcoef(image_a[r - 7:r + 8, c - 7:c + 8].ravel(), image_b[r - 7:r + 8, c - 7:c + 8].ravel())[0, 1]
                        for r in range(60, 200, 12) for c in range(60, 200, 12)]
        results[label] = float(np.median(correlations))
    return results
