"""What decorrelates a template from its match: an ablation study on rendered descent cases (issue 30).

The paper's Table 3 gives the normalised correlation of three templates tracked by the DIMES flight
software between the first two MER-A flight images: 0.88, 0.91, 1.00 (its own MOC2DIMES simulation
0.84-0.94, on templates of contrast/brightness ~0.3 %). This module measures, on cases rendered by the
simulator and run through the reference estimator (its feature selection and matching, default
parameters), the distribution of that correlation and how much each mechanism of the image chain
moves it, one mechanism at a time.

Protocol
--------
1. Cases: the first ``cases_per_class`` cases of every class of a site's plan (the same plan, cases
   and seeds for every variant), rendered with the campaign's scene, sensors and calibration.
2. Terrain: the site file's classes (``sitedata/gusev.toml``: anchored to MER-A flight's template
   contrast/brightness, ~1.1 %; ``sitedata/examples/gusev_rough_moc.toml``: the rough MOC ground, ~3 %),
   optionally every synthetic class's contrast multiplied by ``--contrast-scale`` (``[site]
   terrain_contrast_scale``).
3. Variants (:data:`MECHANISMS`): the reference variant ("all on") is the campaign's nominal image
   chain; each ablation switches one mechanism off (or, for relief and atmosphere, which are off in
   the nominal Gusev campaign, on) through the campaign file's own tables (``[scene]``,
   ``[scene.effects]``, ``[scene.camera_effects]``, ``[sensors]``, ``[scene.atmosphere]``, the class's
   ``relief``), or holds the lander's attitude at its first-image value (no rotation between frames).
4. Metric: the correlation the estimator reports for each tracked template (normalised correlation
   at the refined sub-pixel peak, :mod:`dimes_velocity.matching`; for a match refused at the coarse
   level, the coarse level's best value), summarised as median [10-90 %] (a) over every tracked template
   ("all": whatever its checks said, as the flight software reported every template it tracked) and
   (b) over those whose match passed every check ("ok"), for both pairs and for the first pair alone
   (the images of Table 3).
5. Closed form: with template signal variance ``S`` and noise variances ``n_A^2``, ``n_B^2``, two noisy
   copies of one template correlate at ``rho = S / sqrt((S + n_A^2) (S + n_B^2))``
   (:func:`noise_correlation`). For every "ok" match ``S`` and ``n^2`` are measured after rectification
   (noisy minus noise-free expected DN through the same flattening, blur and map: :func:`case_features`);
   the estimator's own raw-pixel prediction ``rho ~ 1 / (1 + e)``, ``e = (n_A^2 / S_A + n_B^2 / S_B) / 2``,
   is reported beside it.
6. The same "ok" matches' correlation read on the whole-pixel grid (:func:`grid_peak_correlation`).
7. ``--unresolved-texture``: what ground texture finer than the terrain strip's pixels would add
   (:func:`unresolved_texture_experiment`).

Run ``python -m campaign.studies.decorrelation --help``.
"""
from __future__ import annotations

import copy
import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from campaign.case.compute import simulate_case_inputs
from campaign.case.inputs import CampaignInputs, PlanRow, SharedInputs
from campaign.configuration.campaign_file import campaign_config_from_data
from campaign.run.planning import plan_campaign
from config_tables.command_line import OneLineParser
from config_tables.toml_file import load_toml
from dimes_velocity.estimator import MAX_BLUR_PX, DimesEstimator, RectifiedImage
from dimes_velocity.matching import fit_peak
from dimes_velocity.preprocess import flatten
from simulator.scene.descent_profile import DescentProfile

#: Table 3 of the paper, correlation of the three templates (features 00, 01, 10) of the first pair.
FLIGHT_CORRELATION = (0.88, 0.91, 1.00)
PAPER_SIMULATION_CORRELATION = (0.87, 0.84, 0.94)


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


@dataclass(frozen=True)
class Mechanism:
    """One variant of the image chain.

    Attributes
    ----------
    name : str
        Short label of the table.
    change : str
        What the variant changes against the reference ("all on").
    patch : dict
        Deep-merged into the campaign file's parsed TOML (e.g. ``{"scene": {"effects": {...}}}``).
    class_terrain : dict
        Merged into every class's ``terrain`` table (e.g. ``{"relief": True}``).
    steady_attitude : bool
        Hold every trajectory's attitude at its first-image value, angular rates zero (no rotation
        between or during the frames).
    """

    name: str
    change: str
    patch: dict = field(default_factory=dict)
    class_terrain: dict = field(default_factory=dict)
    steady_attitude: bool = False


REFERENCE = Mechanism("all on", "the nominal image chain of the campaign file")
NOISE_OFF = Mechanism("photon + read noise off", "camera shot (photon, dark) and read noise off",
                      {"scene": {"camera_effects": {"shot_noise": False, "read_noise": False}}})
SENSORS_EXACT = Mechanism("attitude/altitude exact", "every sensor exact: rectification with the true attitude "
                          "and altitude ([sensors] perfect)", {"sensors": {"perfect": True}})
NO_ROTATION = Mechanism("no rotation", "attitude held at image 1's, no angular rate (no rotation between "
                        "or during frames)", steady_attitude=True)
BLUR_OFF = Mechanism("motion blur off", "one pose per CCD period ([scene.effects] motion_blur)",
                     {"scene": {"effects": {"motion_blur": False}}})
PSF_OFF = Mechanism("optics PSF off", "no optics point-spread function", {"scene": {"camera_effects": {"optics_psf": False}}})
PHOTOMETRY_OFF = Mechanism("photometry off", "no DIMES/MOC photometric ratio (phase-angle change, opposition "
                           "halo)", {"scene": {"effects": {"photometric_correction": False}}})
RELIEF_ON = Mechanism("relief on", "terrain height field rendered: parallax, occlusion, slope shading at each "
                      "view, cast shadows", class_terrain={"relief": True})
ATMOSPHERE_ON = Mechanism("atmosphere on (tau 0.5)", "dust column tau = 0.5: MOC haze removed, descent path "
                          "light and attenuation added", {"scene": {"atmosphere": {"orbital_optical_depth": 0.5}}})
HIGH_FIDELITY = Mechanism("fidelity high", "the high fidelity preset: exact rays and photometry per pixel, smear and "
                          "blur fields rendered, exact Poisson noise (simulator.fidelity)", {"scene": {"fidelity": "high"}})
REFERENCE_FIDELITY = Mechanism("fidelity reference", "the reference preset: every shortcut off, 3 x 3 rays per pixel, "
                               ">= 4 motion sub-poses per terrain pixel (simulator.fidelity)",
                               {"scene": {"fidelity": "reference"}})
GRAIN_OFF = Mechanism("MOC grain off", "the terrain strip without the MOC's shot-noise grain (grain_snr 1e6 instead "
                      "of 60): static texture of the orbital source, not of the ground", class_terrain={"overrides": {"grain_snr": 1e6}})
ALL_OFF = Mechanism("resampling only", "noise off, sensors exact, no rotation, no blur, no PSF: what remains is "
                    "the scale change and resampling between altitudes",
                    {"scene": {"camera_effects": {"shot_noise": False, "read_noise": False, "optics_psf": False},
                               "effects": {"motion_blur": False}},
                     "sensors": {"perfect": True}}, steady_attitude=True)

NO_EQUALISATION = Mechanism("estimator: no resolution equalisation", "the estimator does not blur the lower "
                            "images to the highest one's resolution before rectifying (metric protocol, not physics)",
                            {"estimator": {"equalize_resolution": False}})
NO_REFINEMENT = Mechanism("estimator: biquadratic peak", "correlation read from the biquadratic fit of the 3 x 3 "
                          "correlation values, no Lucas-Kanade refinement (metric protocol, not physics)",
                          {"estimator": {"subpixel_iterations": 0}})

MECHANISMS: dict[str, Mechanism] = {m.name: m for m in (
    REFERENCE, NOISE_OFF, SENSORS_EXACT, NO_ROTATION, BLUR_OFF, PSF_OFF, PHOTOMETRY_OFF, RELIEF_ON, ATMOSPHERE_ON,
    HIGH_FIDELITY, REFERENCE_FIDELITY, GRAIN_OFF, ALL_OFF, NO_EQUALISATION, NO_REFINEMENT)}


def _merge(base: dict, patch: dict) -> dict:
    """``base`` deep-merged with ``patch`` (a new dict; tables merged, values replaced)."""
    merged = copy.deepcopy(base)
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def variant_data(data: dict, mechanism: Mechanism, contrast_scale: float = 1.0) -> dict:
    """The campaign file's parsed TOML ``data`` changed for ``mechanism``, its synthetic terrain's contrast
    multiplied by ``contrast_scale`` (``[site] terrain_contrast_scale``, times any the file gives)."""
    changed = _merge(data, mechanism.patch)
    site = changed.setdefault("site", {})
    if contrast_scale != 1.0:
        site["terrain_contrast_scale"] = float(site.get("terrain_contrast_scale", 1.0)) * contrast_scale
    for entry in site.get("classes", []):
        terrain = entry.get("terrain", {})
        if terrain.get("kind") == "synthetic":
            for key, value in mechanism.class_terrain.items():
                terrain[key] = {**terrain.get(key, {}), **value} if isinstance(value, dict) else value
    return changed


def steady_profile(profile):
    """``profile`` with its attitude held at the first image's and no angular rate."""

    attitude = np.asarray(profile.pose(float(profile.image_times_s[0])).attitude_quat, dtype=float)
    values = {f.name: getattr(profile, f.name) for f in dataclasses.fields(DescentProfile)}
    values["attitude_quat"] = np.repeat(attitude[None, :], len(profile.time_s), axis=0)
    values["angular_rate_radps"] = np.zeros_like(np.asarray(profile.angular_rate_radps, dtype=float))
    return DescentProfile(**values)


def _recording_estimator(camera, config, flat_field):
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


def run_mechanism(site_file: Path, mechanism: Mechanism, contrast_scale: float, plan: pd.DataFrame,
                  output_dir: Path) -> pd.DataFrame:
    """Every tracked template of the cases of ``plan`` under ``mechanism`` (one row each)."""

    data = variant_data(load_toml(site_file), mechanism, contrast_scale)
    config = campaign_config_from_data(data, site_file, output_dir=output_dir)
    resources = CampaignInputs(config, SharedInputs())
    if mechanism.steady_attitude:
        resources.profiles = [steady_profile(profile) for profile in resources.profiles]
    estimator = _recording_estimator(resources.camera, config.estimator, resources.calibration().flat_field)
    rows: list[dict[str, Any]] = []
    for record in plan.to_dict("records"):
        rows.extend(case_features(resources, PlanRow.from_record(record), estimator))
    frame = pd.DataFrame(rows)
    frame.insert(0, "mechanism", mechanism.name)
    return frame


def first_cases(site_file: Path, cases_per_class: int, contrast_scale: float, output_dir: Path,
                classes: list[str] | None = None) -> pd.DataFrame:
    """The first ``cases_per_class`` cases of every class (or of ``classes``) of the site's plan (terrain at
    ``contrast_scale``)."""

    config = campaign_config_from_data(variant_data(load_toml(site_file), REFERENCE, contrast_scale), site_file,
                                       output_dir=output_dir)
    _, plan = plan_campaign(config)
    chosen = plan["case_in_class"] < cases_per_class
    if classes:
        chosen &= plan["class_name"].isin(classes)
    return plan[chosen].reset_index(drop=True)


def _percentiles(values: np.ndarray) -> tuple[float, float, float]:
    if values.size == 0:
        return (float("nan"),) * 3
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return float(p50), float(p10), float(p90)


def summarise(features: pd.DataFrame, reference: str = REFERENCE.name) -> pd.DataFrame:
    """Per mechanism: median and 10-90 % of the correlation (every tracked template, and matches that
    passed every check), of the first pair alone, the closed-form noise correlation ``1 / (1 + e)`` of
    the "ok" matches, contrast/brightness, and the change of the median against ``reference``."""
    rows = []
    for name, group in features.groupby("mechanism", sort=False):
        ok = group[group["status"] == "ok"]
        first = group[group["pair"] == 0]
        every = _percentiles(group["correlation"].to_numpy(float))
        passed = _percentiles(ok["correlation"].to_numpy(float))
        noise = 1.0 / (1.0 + ok["noise_decorrelation"].to_numpy(float))
        factor = ok["noise_factor"].to_numpy(float)
        grid = ok["grid_correlation"].to_numpy(float)
        grid = _percentiles(grid[np.isfinite(grid)])
        rows.append(dict(
            mechanism=name, templates=len(group), ok=len(ok),
            median_all=every[0], p10_all=every[1], p90_all=every[2],
            median_ok=passed[0], p10_ok=passed[1], p90_ok=passed[2],
            median_first_pair=_percentiles(first["correlation"].to_numpy(float))[0],
            median_noise_closed_form=_percentiles(factor[np.isfinite(factor)])[0],
            median_noise_pixel_model=_percentiles(noise)[0],
            median_grid=grid[0], p10_grid=grid[1], p90_grid=grid[2],
            contrast_percent=100.0 * float(np.median(group["contrast_dn"] / group["brightness_dn"])),
            valid_percent=100.0 * float(group.drop_duplicates("case_id")["valid"].mean())))
    table = pd.DataFrame(rows)
    if reference in set(table["mechanism"]):
        base = table.loc[table["mechanism"] == reference].iloc[0]
        table["change_all"] = table["median_all"] - base["median_all"]
        table["change_ok"] = table["median_ok"] - base["median_ok"]
    return table


def markdown(table: pd.DataFrame, changes: dict[str, str]) -> str:
    """The ablation table as markdown (median [10-90 %], change of the median against "all on")."""
    lines = ["| mechanism | change | templates (ok) | contrast/brightness | correlation, every tracked template "
             "| change | correlation, ok matches | pair 1 median | noise closed form, rectified (raw pixels) "
             "| ok matches, whole-pixel peak | % valid |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table.itertuples():
        lines.append(
            f"| {row.mechanism} | {changes.get(row.mechanism, '')} | {row.templates} ({row.ok}) | "
            f"{row.contrast_percent:.2f} % | {row.median_all:.3f} [{row.p10_all:.3f}-{row.p90_all:.3f}] | "
            f"{getattr(row, 'change_all', float('nan')):+.3f} | {row.median_ok:.3f} [{row.p10_ok:.3f}-{row.p90_ok:.3f}] | "
            f"{row.median_first_pair:.3f} | {row.median_noise_closed_form:.3f} ({row.median_noise_pixel_model:.3f}) | "
            f"{row.median_grid:.3f} [{row.p10_grid:.3f}-{row.p90_grid:.3f}] | {row.valid_percent:.0f} % |")
    lines.append(f"| MER-A flight (paper Table 3, pair 1) | | 3 | 1.01-1.18 % | "
                 f"{', '.join(f'{v:.2f}' for v in FLIGHT_CORRELATION)} | | | | | | |")
    lines.append(f"| MOC2DIMES (paper Table 3, pair 1) | | 3 | 0.26-0.42 % | "
                 f"{', '.join(f'{v:.2f}' for v in PAPER_SIMULATION_CORRELATION)} | | | | | | |")
    return "\n".join(lines)


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


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m campaign.studies.decorrelation", description=__doc__.split("\n")[0])
    parser.add_argument("site_file", nargs="?", default="sitedata/gusev.toml", type=Path,
                        help="campaign/site file (default sitedata/gusev.toml)")
    parser.add_argument("--cases-per-class", type=int, default=8, help="first N cases of each class (default 8)")
    parser.add_argument("--contrast-scale", type=float, default=1.0,
                        help="[site] terrain_contrast_scale: multiplies every synthetic class's contrast (default 1: the file's terrain)")
    parser.add_argument("--mechanisms", default=",".join(MECHANISMS),
                        help=f"comma-separated variants (default all: {', '.join(MECHANISMS)})")
    parser.add_argument("--classes", help="comma-separated classes (default every class of the site)")
    parser.add_argument("--features", type=Path, help="write every tracked template's row to this parquet file")
    parser.add_argument("--scratch", type=Path, default=Path("/tmp/decorrelation"),
                        help="output directory given to the campaign configuration (nothing is written there)")
    parser.add_argument("--unresolved-texture", action="store_true",
                        help="instead: the sub-terrain-pixel texture experiment (unresolved_texture_experiment)")
    args = parser.parse_args(argv)
    if args.unresolved_texture:
        for label, value in unresolved_texture_experiment().items():
            print(f"ground texture {label}: median template correlation {value:.4f}")
        return 0
    names = [name.strip() for name in args.mechanisms.split(",") if name.strip()]
    unknown = [name for name in names if name not in MECHANISMS]
    if unknown:
        parser.error(f"unknown mechanism(s) {unknown}; allowed: {', '.join(MECHANISMS)}")
    classes = [name.strip() for name in args.classes.split(",")] if args.classes else None
    plan = first_cases(args.site_file, args.cases_per_class, args.contrast_scale, args.scratch, classes)
    print(f"{args.site_file}: {len(plan)} cases ({args.cases_per_class} per class), contrast scale "
          f"{args.contrast_scale:g}", file=sys.stderr)
    frames = []
    for name in names:
        started = time.perf_counter()
        frames.append(run_mechanism(args.site_file, MECHANISMS[name], args.contrast_scale, plan, args.scratch))
        print(f"  {name}: {len(frames[-1])} templates, {time.perf_counter() - started:.0f} s", file=sys.stderr)
    features = pd.concat(frames, ignore_index=True)
    if args.features is not None:
        features.to_parquet(args.features)
    print(markdown(summarise(features), {name: MECHANISMS[name].change for name in names}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
