"""What a terrain looks like to the descent camera and its estimator: one function, :func:`terrain_statistics`.

    python -m campaign.realism.measure_terrains SOURCE... [--csv FILE]

Every SOURCE is a real image file (``FILE`` or ``FILE:SIDECAR.toml``), a synthetic class preset name
(``gcp``; its seed and site are taken from the shipped site file that uses it) or a whole site TOML
(every class). The table is printed and written as CSV (:mod:`campaign.realism.measure_terrains`).

Statistics (:class:`TerrainStatistics`), all measured on the I/F image as the orbiter recorded it:

* ``mean_if``: mean I/F.
* ``contrast_{1,2}km``: RMS contrast (std / mean) at the descent camera's ground sample at 1 and 2 km.
  The terrain is resampled as the camera and estimator sample it at nadir: bilinear point samples at
  the full-resolution pixel pitch ``altitude x IFOV`` (IFOV = pixel pitch / focal length, 0.818 mrad
  for MER), then ``b x b`` block means (``b`` rows summed on chip, ``b`` columns summed by the
  estimator), i.e. one sample per ``b x IFOV x altitude`` (6.5 m at 2 km, 3.3 m at 1 km for MER).
  The contrast is taken in footprint-sized tiles (256 x 256 samples, the estimator's rectified image;
  half-tile steps) and the median over tiles is reported with its 10-90 % spread, so that strips of
  any length compare with what one descent image sees.
* ``psd_slope``: log-log slope of the radially averaged power spectrum between wavelengths of 4 and
  64 native pixels (Welch average of Hann-windowed 256 x 256 tiles).
* ``untrackable_{1,2}km``: fraction of template-sized windows (``template_size_px`` of the estimator,
  non-overlapping, at the ground sample of that altitude) whose contrast-to-noise is too low to track:
  the estimator keeps a template when the standard deviation of the noisy template minus its
  best-fit plane, over the expected pixel noise, reaches ``min_contrast_to_noise`` (2.5). With
  terrain detrended standard deviation ``s`` and noise ``n`` the noisy template has ``sqrt(s^2 + n^2)``,
  so a window is untrackable when ``s / n < sqrt(k^2 - 1)``. ``s`` and ``n`` are in electrons of a
  binned block: signal = I/F x photometric ratio x E_sun / pi x spectral ratio x responsivity x
  ``b^2``, collected over fast flush + exposure + frame transfer (the smear of a uniform scene adds
  the flush and transfer periods), plus image-area dark; noise = ``sqrt(charge + b read^2 +
  b gain^2 / 12)`` (shot, read, quantisation: the estimator's own noise model).
* ``crater_density_per_km2``: dark blobs 30-120 m across deeper than 5 % of the mean I/F: local
  maxima over space and scale of the scale-normalised Laplacian of Gaussian of I/F / mean at
  ``sigma = D / (2 sqrt 2)`` (D = 30, 60, 120 m); a dark disc of radius ``r`` and fractional depth
  ``c`` gives ``2 c / e`` at ``sigma = r / sqrt 2`` (heat-equation closed form), so the threshold is
  ``0.05 x 2 / e``. Craters (shaded bowls), pits and dark spots count; so do knob shadows. MOC grain
  (SNR ~60) gives a response of standard deviation ``n / (sigma sqrt(pi))`` < 0.005, far below it.

What a source lacks limits what is measured: without a scale (``metres_per_pixel``) nothing at a
ground sample nor the crater density is; without an I/F calibration (raw DN, display-stretched PNG)
only the PSD slope is: a DN offset or a display stretch changes std / mean arbitrarily.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from dimes_velocity.config import EstimatorConfig
from flight_interface.camera import Camera
from simulator.scene import photometry

ALTITUDES_M = (1000.0, 2000.0)
FOOTPRINT_SAMPLES = 256                 # the estimator's rectified image side
PSD_TILE_PX = 256
PSD_WAVELENGTHS_PX = (4.0, 64.0)
CRATER_DIAMETERS_M = (30.0, 60.0, 120.0)
CRATER_MIN_DEPTH = 0.05                 # fractional I/F depth of a detected dark blob
LOG_PEAK_PER_DEPTH = 2.0 / math.e       # sigma^2 LoG at the centre of a disc, sigma = r / sqrt(2), per unit depth


@dataclass(frozen=True)
class DescentSampling:
    """How the descent camera and its estimator sample and see terrain at nadir (SI units).

    Attributes
    ----------
    ifov_rad : float
        Angle subtended by one full-resolution pixel at the centre (pixel pitch / focal length).
    binning : int
        Rows summed on chip (= columns summed by the estimator).
    electrons_per_if : float
        Signal charge of one binned block per unit terrain I/F (e-), over fast flush + exposure +
        frame transfer.
    dark_charge_e : float
        Image-area dark charge of one binned block over the same periods (e-).
    noise_floor_e2 : float
        Read + quantisation variance of a binned block (e-^2).
    template_px : int
        Estimator template side (binned, rectified pixels).
    min_contrast_to_noise : float
        The estimator's threshold on (detrended template std) / (pixel noise).
    """

    ifov_rad: float
    binning: int
    electrons_per_if: float
    dark_charge_e: float
    noise_floor_e2: float
    template_px: int
    min_contrast_to_noise: float

    def ground_sample_m(self, altitude_m: float) -> float:
        """Side of one binned sample on level ground at nadir (m)."""
        return self.binning * self.ifov_rad * altitude_m


def descent_sampling(camera: Camera, sun_distance_au: float, estimator_config=None, spectral_ratio: float = 0.906,
                     photometric_ratio: float = 1.0) -> DescentSampling:
    """The :class:`DescentSampling` of ``camera`` (see the module doc for the signal and noise model).

    Parameters
    ----------
    camera : Camera
    sun_distance_au : float
        Sun-Mars distance (solar irradiance scales as its inverse square).
    estimator_config : dimes_velocity.config.EstimatorConfig, optional (defaults)
    spectral_ratio : float
        MOC -> DIMES band reflectance ratio (scene default 0.906).
    photometric_ratio : float
        Descent-view I/F at nadir over the terrain's (MOC-geometry) I/F: equation (1) at the landing sun
        over equation (1) at the orbital geometry; 1 when the orbital geometry is unknown.
    """

    config = estimator_config if estimator_config is not None else EstimatorConfig()
    timing, electronics, b = camera.timing, camera.electronics, camera.binning_rows
    collect_s = timing.fast_flush_s + timing.exposure_s + timing.frame_transfer_s
    radiance_per_if = photometry.solar_band_irradiance_w_m2_um(sun_distance_au) / math.pi * spectral_ratio
    return DescentSampling(
        ifov_rad=1.0 / camera.model.hs, binning=b,
        electrons_per_if=photometric_ratio * radiance_per_if * camera.responsivity_e_per_s * b * b * collect_s,
        dark_charge_e=electronics.dark_current_e_per_s() * b * b * collect_s,
        noise_floor_e2=b * electronics.read_noise_e**2 + b * electronics.adc_gain_e_per_dn**2 / 12.0,
        template_px=config.template_size_px, min_contrast_to_noise=config.min_contrast_to_noise)


def nadir_photometric_ratio(sun_elevation_rad: float, moc_incidence_rad: float, moc_emission_rad: float,
                            moc_phase_rad: float) -> float:
    """Equation (1) for a nadir view under the landing sun over equation (1) at the orbital geometry."""
    incidence = 0.5 * math.pi - sun_elevation_rad
    descent = float(photometry.reflectance_model(np.cos(incidence), 1.0, np.cos(incidence)))
    return descent / photometry.moc_reflectance_model(moc_incidence_rad, moc_emission_rad, moc_phase_rad)


@dataclass(frozen=True)
class TerrainStatistics:
    """Statistics of one terrain (NaN where the source does not allow the measurement; see ``notes``)."""

    rows: int
    cols: int
    metres_per_pixel: float
    radiometry: str
    mean_if: float
    contrast_1km: float
    contrast_1km_p10: float
    contrast_1km_p90: float
    contrast_2km: float
    contrast_2km_p10: float
    contrast_2km_p90: float
    psd_slope: float
    untrackable_1km: float
    untrackable_2km: float
    crater_density_per_km2: float
    notes: str = ""


def resample_to_ground_sample(image: np.ndarray, metres_per_pixel: float, sample_m: float, binning: int) -> np.ndarray:
    """The terrain as binned descent-camera samples of side ``sample_m`` (see module doc), float32.

    Bilinear point samples at pitch ``sample_m / binning`` averaged over ``binning x binning`` blocks,
    computed as the mean of ``binning^2`` bilinear remaps on the coarse grid (no full-resolution
    intermediate). Only samples whose whole block lies inside the terrain are returned.
    """
    pitch_px = sample_m / binning / metres_per_pixel
    rows, cols = image.shape
    out_rows = int(math.floor((rows - 1) / (pitch_px * binning)))
    out_cols = int(math.floor((cols - 1) / (pitch_px * binning)))
    if out_rows < 1 or out_cols < 1:
        return np.zeros((0, 0), np.float32)
    source = np.ascontiguousarray(image, dtype=np.float32)
    base_r = (np.arange(out_rows, dtype=np.float64) * binning * pitch_px)[:, None]
    base_c = (np.arange(out_cols, dtype=np.float64) * binning * pitch_px)[None, :]
    total = np.zeros((out_rows, out_cols), np.float64)
    for i in range(binning):
        for j in range(binning):
            map_r = np.broadcast_to(base_r + (i + 0.5) * pitch_px, (out_rows, out_cols)).astype(np.float32)
            map_c = np.broadcast_to(base_c + (j + 0.5) * pitch_px, (out_rows, out_cols)).astype(np.float32)
            total += cv2.remap(source, map_c, map_r, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return (total / (binning * binning)).astype(np.float32)


def tile_contrasts(samples: np.ndarray, tile: int = FOOTPRINT_SAMPLES) -> np.ndarray:
    """std / mean of every ``tile x tile`` window at half-tile steps (the whole image when smaller)."""
    rows, cols = samples.shape
    if rows == 0 or cols == 0:
        return np.zeros(0)
    if rows < tile or cols < tile:
        return np.array([samples.std() / samples.mean()])
    step = tile // 2
    values = [samples[r:r + tile, c:c + tile] for r in range(0, rows - tile + 1, step)
              for c in range(0, cols - tile + 1, step)]
    return np.array([v.std() / v.mean() for v in values], dtype=np.float64)


def detrended_window_std(samples: np.ndarray, size: int) -> np.ndarray:
    """Standard deviation of each non-overlapping ``size x size`` window minus its best-fit plane."""
    rows, cols = (samples.shape[0] // size) * size, (samples.shape[1] // size) * size
    if rows == 0 or cols == 0:
        return np.zeros(0)
    grid = samples[:rows, :cols].astype(np.float64).reshape(rows // size, size, cols // size, size)
    windows = grid.transpose(0, 2, 1, 3).reshape(-1, size, size)
    offsets = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    norm = size * float(offsets @ offsets)
    mean = windows.mean(axis=(1, 2))
    slope_x = (windows.sum(axis=1) @ offsets) / norm
    slope_y = (windows.sum(axis=2) @ offsets) / norm
    residual = (windows - mean[:, None, None] - slope_x[:, None, None] * offsets[None, None, :]
                - slope_y[:, None, None] * offsets[None, :, None])
    return residual.std(axis=(1, 2))


def untrackable_fraction(samples_if: np.ndarray, sampling: DescentSampling) -> float:
    """Fraction of template windows of ``samples_if`` (binned I/F samples) too bland to track."""
    size = sampling.template_px
    spread = detrended_window_std(samples_if, size)
    if spread.size == 0:
        return float("nan")
    rows, cols = (samples_if.shape[0] // size) * size, (samples_if.shape[1] // size) * size
    means = samples_if[:rows, :cols].astype(np.float64).reshape(rows // size, size, cols // size, size).mean(axis=(1, 3))
    noise_e = np.sqrt(means.ravel() * sampling.electrons_per_if + sampling.dark_charge_e + sampling.noise_floor_e2)
    threshold = math.sqrt(max(sampling.min_contrast_to_noise**2 - 1.0, 0.0))
    return float(np.mean(spread * sampling.electrons_per_if / noise_e < threshold))


def psd_slope(image: np.ndarray, wavelengths_px: tuple[float, float] = PSD_WAVELENGTHS_PX,
              tile: int = PSD_TILE_PX) -> float:
    """Log-log slope of the radially averaged power spectrum over ``wavelengths_px`` (Welch, Hann tiles)."""
    rows, cols = image.shape
    size = min(tile, rows, cols)
    if size < 2 * wavelengths_px[1]:
        return float("nan")
    window = np.outer(np.hanning(size), np.hanning(size))
    power = np.zeros((size, size))
    count = 0
    for r in range(0, rows - size + 1, size):
        for c in range(0, cols - size + 1, size):
            patch = image[r:r + size, c:c + size].astype(np.float64)
            power += np.abs(np.fft.fft2((patch - patch.mean()) * window)) ** 2
            count += 1
    power /= count
    k = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.fftfreq(size)[None, :]).ravel()
    edges = np.geomspace(1.0 / wavelengths_px[1], 1.0 / wavelengths_px[0], 13)
    which = np.digitize(k, edges)
    centres = np.sqrt(edges[:-1] * edges[1:])
    means = np.array([power.ravel()[which == i].mean() for i in range(1, len(edges))])
    return float(np.polyfit(np.log(centres), np.log(means), 1)[0])


def crater_density_per_km2(image_if: np.ndarray, metres_per_pixel: float) -> float:
    """Dark blobs (30-120 m, deeper than :data:`CRATER_MIN_DEPTH`) per km^2 (see module doc)."""
    relative = (image_if / float(image_if.mean())).astype(np.float32)
    sigmas = [d / (2.0 * math.sqrt(2.0)) / metres_per_pixel for d in CRATER_DIAMETERS_M]
    sigmas = [s for s in sigmas if s >= 0.7]
    if not sigmas:
        return float("nan")
    responses = []
    for sigma in sigmas:
        blurred = cv2.GaussianBlur(relative, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        responses.append(sigma**2 * cv2.Laplacian(blurred, cv2.CV_32F, ksize=1, borderType=cv2.BORDER_REFLECT))
    stack = np.stack(responses)
    kernel = np.ones((3, 3), np.uint8)
    spatial_max = np.stack([cv2.dilate(r, kernel) for r in responses])
    scale_max = spatial_max.copy()
    scale_max[1:] = np.maximum(scale_max[1:], spatial_max[:-1])
    scale_max[:-1] = np.maximum(scale_max[:-1], spatial_max[1:])
    margin = int(math.ceil(2 * max(sigmas)))
    peaks = (stack >= scale_max) & (stack > CRATER_MIN_DEPTH * LOG_PEAK_PER_DEPTH)
    peaks[:, :margin, :] = peaks[:, -margin:, :] = False
    peaks[:, :, :margin] = peaks[:, :, -margin:] = False
    area_km2 = (image_if.shape[0] - 2 * margin) * (image_if.shape[1] - 2 * margin) * (metres_per_pixel / 1e3) ** 2
    if area_km2 <= 0:
        return float("nan")
    return float(np.count_nonzero(peaks.any(axis=0)) / area_km2)


def terrain_statistics(image: np.ndarray, metres_per_pixel: float | None, sampling: DescentSampling,
                       radiometry: str = "I/F", altitudes_m: tuple[float, float] = ALTITUDES_M) -> TerrainStatistics:
    """Measure a terrain as the descent camera and its estimator would see it (see module doc).

    Parameters
    ----------
    image : ndarray (rows, cols)
        Terrain I/F (``radiometry = "I/F"``), or uncalibrated values (anything else: only the PSD
        slope is measured).
    metres_per_pixel : float or None
        Ground sampling of ``image`` (m); None when unknown (nothing scale-dependent is measured).
    sampling : DescentSampling
    altitudes_m : (low, high)
        The two altitudes of the contrast and untrackable columns (1000, 2000 m).
    """
    image = np.asarray(image, dtype=np.float32)
    nan = float("nan")
    notes = []
    calibrated = radiometry == "I/F"
    values = dict(mean_if=float(image.mean()) if calibrated else nan, psd_slope=psd_slope(image))
    if math.isnan(values["psd_slope"]):
        notes.append(f"under {2 * PSD_WAVELENGTHS_PX[1]:.0f} px across: no 4-64 px PSD slope")
    if not calibrated:
        notes.append(f"{radiometry}: only the PSD slope is measurable (std/mean, I/F and noise need an I/F calibration)")
    if metres_per_pixel is None:
        notes.append("metres_per_pixel unknown: no ground-sample statistics (give it in a side-car)")
    for label, altitude in zip(("1km", "2km"), altitudes_m):
        contrast = untrackable = np.zeros(0)
        if calibrated and metres_per_pixel is not None:
            samples = resample_to_ground_sample(image, metres_per_pixel, sampling.ground_sample_m(altitude),
                                                sampling.binning)
            contrast = tile_contrasts(samples)
            untrackable = np.array([untrackable_fraction(samples, sampling)]) if samples.size else untrackable
            if 0 < samples.shape[0] < FOOTPRINT_SAMPLES or 0 < samples.shape[1] < FOOTPRINT_SAMPLES:
                notes.append(f"smaller than one descent footprint at {label} ({samples.shape[1]} x {samples.shape[0]} "
                             f"samples of {sampling.ground_sample_m(altitude):.2f} m)")
            elif samples.size == 0:
                notes.append(f"smaller than one ground sample at {label}")
        values[f"contrast_{label}"] = float(np.median(contrast)) if contrast.size else nan
        values[f"contrast_{label}_p10"] = float(np.percentile(contrast, 10)) if contrast.size else nan
        values[f"contrast_{label}_p90"] = float(np.percentile(contrast, 90)) if contrast.size else nan
        values[f"untrackable_{label}"] = float(untrackable[0]) if untrackable.size else nan
    craters = nan
    if calibrated and metres_per_pixel is not None:
        craters = crater_density_per_km2(image, metres_per_pixel)
    return TerrainStatistics(rows=image.shape[0], cols=image.shape[1],
                             metres_per_pixel=nan if metres_per_pixel is None else float(metres_per_pixel),
                             radiometry=radiometry, crater_density_per_km2=craters, notes="; ".join(notes), **values)

