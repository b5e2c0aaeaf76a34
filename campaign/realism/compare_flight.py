"""``campaign compare-flight``: real descent images next to the simulator's rendering of the same view
(paper section 6: Fig. 10 side by side, Fig. 11 column profile and pixel scatter, Table 3 DIMES metrics).

    campaign compare-flight FLIGHT.toml [--out DIR] [--column N]

FLIGHT.toml (paths relative to it)::

    site = "../sitedata/gusev.toml"     # camera, sun at landing and class terrains
    class = "gcp"                       # the appearance class whose terrain lies under the images
    seed = 0                            # noise stream of the simulated images
    column = 296                        # raw image column of the profile and scatter (default 512)
    output_dir = "runs/compare-flight"  # default
    [scene]                             # optional, as in campaign files (fidelity, atmosphere, ...)
    [estimator]                         # optional, as in campaign files
    [[images]]                          # one to three descent images, in time order
    file = "image1.png"                 # raw image as the camera returns it (256 x 1024): 16-bit PNG, .npy, raw uint16
    time_s = 0.0                        # start of the exposure (s)
    position_m = [120.0, -40.0, 2000.0] # lander at time_s, world frame of the terrain (east, north, up; m)
    attitude_quat = [1.0, 0.0, 0.0, 0.0]  # lander body-to-world (w, x, y, z)
    velocity_mps = [0.0, 0.0, -72.0]    # optional (default 0): motion through the CCD periods
    angular_rate_radps = [0.0, 0.0, 0.0]  # optional, body frame
    heat_shield_position_m = [0.0, 0.0, 1850.0]  # optional: drawn, and excluded by the estimator

Written to DIR: ``image_K_side_by_side.png`` (simulated | flight, one display range, the profile column
in green), ``image_K_column.png``, ``image_K_scatter.png`` (flight DN against simulated DN of the column with
the best-fit line), ``simulated_image_K.png`` (16-bit), ``comparison.json``, ``pixels.csv`` (per image:
correlation r, slope and intercept of ``flight = slope * simulated + intercept`` over the column and over
the whole image, and r of the texture: both images flattened by the estimator's pre-processing with a
16-block Gaussian background removed), ``features.csv`` (Table 3: brightness, contrast and correlation of
DIMES templates). Pixels the simulator sees outside the terrain, sky, heat shield or saturated are left out.

DIMES metrics go through the estimator's public functions: the templates :func:`dimes_velocity.features.select_features`
picks in each flight image are measured in both images (mean = brightness, standard deviation = contrast,
flattened DN as in the campaign's ``feature_*`` columns) with the normalised correlation of the flight
template against the simulated one at the same place; with two or more images the estimator also runs on
both sequences (measurements from the given poses) and its per-template brightness, contrast and
correlation between consecutive images, Table 3's own columns, are written for both.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from campaign.realism.flight_file import FlightFile
from campaign.realism.flight_plots import column_plot, scatter_plot, side_by_side
from config_tables.errors import ConfigError
from config_tables.models import parse
from config_tables.toml_file import load_toml
from dimes_velocity import DescentMeasurements, DimesEstimator, ImageMeasurement
from dimes_velocity.config import EstimatorConfig
from dimes_velocity.features import select_features, template_statistics
from dimes_velocity.preprocess import flatten, make_flattening
from file_formats.descent_images import InputFileError, load_image
from flight_interface.camera import Camera, load_camera
from flight_interface.frames import quat_from_rotation_vector, quat_multiply
from simulator.descent_image import render_descent_image
from simulator.scene.descent_profile import DescentProfile
from simulator.scene_config import SceneConfig
from sitedata.sites import Site, TerrainSpec, load_class_terrain, load_site

POSE_SPAN_S = 0.05            # the rendered profile spans the image time +- this (constant velocity and rate)
TEXTURE_SIGMA_BLOCKS = 16.0   # Gaussian background removed before the texture correlation


@dataclass(frozen=True)
class FlightImage:
    """One flight image with its pose (SI, world frame of the terrain)."""

    file: Path
    dn: np.ndarray
    time_s: float
    position_m: np.ndarray
    attitude_quat: np.ndarray
    velocity_mps: np.ndarray
    angular_rate_radps: np.ndarray
    heat_shield_position_m: np.ndarray | None


@dataclass(frozen=True)
class FlightComparison:
    """A validated FLIGHT.toml: site, class terrain spec, camera, scene and estimator configuration."""

    source: Path
    site: Site
    terrain_spec: TerrainSpec
    camera: Camera
    scene: SceneConfig
    estimator: EstimatorConfig
    seed: int
    column: int
    output_dir: Path
    images: tuple[FlightImage, ...]


def load_flight(path: str | Path, output_dir: str | Path | None = None, column: int | None = None) -> FlightComparison:
    """Read and validate FLIGHT.toml (:class:`campaign.realism.flight_file.FlightFile`) and its images (nothing is
    written). Raises ConfigError (one line)."""
    path = Path(path)
    flight = parse(FlightFile, load_toml(path), path, context={"base_dir": path.parent})
    site = load_site(flight.site)
    names = [entry.name for entry in site.classes]
    if flight.class_name not in names:
        raise ConfigError(f"{path}: class = {flight.class_name!r} is not allowed; allowed: {', '.join(names)}")
    camera = load_camera(site.camera_path)
    scene = flight.scene
    if "sun_distance_au" not in scene.model_fields_set:
        scene = scene.model_copy(update={"sun_distance_au": site.heliocentric_distance_au})
    if column is None:
        column = camera.width_px // 2 if flight.column is None else flight.column
        label = f"{path}: column"
    else:
        label = "command line: --column"
    if not 0 <= column < camera.width_px:
        raise ConfigError(f"{label} = {column} is out of range; allowed: 0 .. {camera.width_px - 1}")
    out = Path(output_dir) if output_dir is not None else Path(flight.output_dir)

    images = []
    for index, entry in enumerate(flight.images):
        try:
            dn = load_image(entry.file, camera)
        except InputFileError as exc:
            given = entry.file.relative_to(path.parent) if entry.file.is_relative_to(path.parent) else entry.file
            raise ConfigError(f"{path}: images[{index}].file = {str(given)!r}: {exc}") from None
        attitude = np.array(entry.attitude_quat)
        images.append(FlightImage(entry.file, dn, entry.time_s, np.array(entry.position_m),
                                  attitude / np.linalg.norm(attitude), np.array(entry.velocity_mps),
                                  np.array(entry.angular_rate_radps),
                                  None if entry.heat_shield_position_m is None else np.array(entry.heat_shield_position_m)))
    terrain_spec = next(entry.terrain for entry in site.classes if entry.name == flight.class_name)
    return FlightComparison(path, site, terrain_spec, camera, scene, flight.estimator, flight.seed, int(column), out,
                            tuple(images))


def pose_profile(image: FlightImage):
    """A short profile through the image's pose: constant velocity and body rate over +- POSE_SPAN_S."""

    offsets = np.array([-POSE_SPAN_S, 0.0, POSE_SPAN_S])
    attitude = np.stack([quat_multiply(image.attitude_quat, quat_from_rotation_vector(image.angular_rate_radps * dt))
                         for dt in offsets])
    shield = None if image.heat_shield_position_m is None else np.tile(image.heat_shield_position_m, (3, 1))
    return DescentProfile(time_s=image.time_s + offsets,
                          position_m=image.position_m + offsets[:, None] * image.velocity_mps,
                          velocity_mps=np.tile(image.velocity_mps, (3, 1)), attitude_quat=attitude,
                          angular_rate_radps=np.tile(image.angular_rate_radps, (3, 1)), wind_mps=np.zeros((3, 3)),
                          heat_shield_position_m=shield, image_times_s=np.array([image.time_s]), name=image.file.name)


def render_simulated(spec: FlightComparison, terrain) -> list:
    """The simulator's images of the flight poses (:class:`simulator.descent_image.DescentImage`), one
    noise stream per image from ``SeedSequence(seed)``."""

    seeds = np.random.SeedSequence(spec.seed).spawn(len(spec.images))
    return [render_descent_image(terrain, pose_profile(image), spec.camera, image.time_s,
                                 spec.site.sun_direction_world, spec.scene, np.random.default_rng(seed))
            for image, seed in zip(spec.images, seeds)]


def line_fit(simulated: np.ndarray, flight: np.ndarray) -> dict:
    """Correlation r and least-squares ``flight = slope * simulated + intercept`` (NaN with < 3 points)."""
    simulated, flight = np.asarray(simulated, float).ravel(), np.asarray(flight, float).ravel()
    if simulated.size < 3 or simulated.std() == 0 or flight.std() == 0:
        return {"r": float("nan"), "slope": float("nan"), "intercept": float("nan"), "pixels": int(simulated.size)}
    slope, intercept = np.polyfit(simulated, flight, 1)
    return {"r": float(np.corrcoef(simulated, flight)[0, 1]), "slope": float(slope), "intercept": float(intercept),
            "pixels": int(simulated.size)}


def usable_pixels(spec: FlightComparison, flight_dn: np.ndarray, rendered) -> np.ndarray:
    """Binned pixels where both images see terrain inside the orbital image, unsaturated (bool (256, 1024))."""
    camera = spec.camera
    rows = camera.binning_rows
    bad = rendered.sky_mask | rendered.outside_terrain_mask | rendered.heat_shield_mask
    saturated = camera.electronics.max_dn - 1
    return (~rendered.binned_mask(bad, rows) & (flight_dn < saturated) & (rendered.dn < saturated))


def texture(signal_dn: np.ndarray) -> np.ndarray:
    """Flattened signal minus its Gaussian background (sigma TEXTURE_SIGMA_BLOCKS), float32."""
    signal = signal_dn.astype(np.float32)
    return signal - cv2.GaussianBlur(signal, (0, 0), TEXTURE_SIGMA_BLOCKS, borderType=cv2.BORDER_REPLICATE)


def template_metrics(spec: FlightComparison, flight_flat, simulated_flat, usable_blocks: np.ndarray,
                     image_index: int) -> list[dict]:
    """Table-3 brightness and contrast of the templates DIMES picks in the flight image, measured in both
    images, and the normalised correlation of each flight template with the simulated one in place."""

    config = spec.estimator
    half = config.template_size_px // 2
    kernel = np.ones((2 * (half + config.border_margin_px) + 1,) * 2, np.uint8)
    candidates = cv2.erode(usable_blocks.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
    flight_signal, simulated_signal = flight_flat.signal_dn, simulated_flat.signal_dn
    selection = select_features(flight_signal, candidates, lambda c, r: flight_flat.noise_dn_at(r, c), config)
    rows = []
    for index, feature in enumerate(selection.features):
        brightness, contrast, _ = template_statistics(simulated_signal, feature.column, feature.row, half)
        window = np.s_[feature.row - half:feature.row + half + 1, feature.column - half:feature.column + half + 1]
        correlation = line_fit(simulated_signal[window], flight_signal[window])["r"]
        rows.append({"source": "templates", "image": image_index, "pair": -1, "index": index, "column": feature.column,
                     "row": feature.row, "flight_brightness_dn": feature.brightness_dn,
                     "flight_contrast_dn": feature.contrast_dn, "simulated_brightness_dn": brightness,
                     "simulated_contrast_dn": contrast, "flight_simulated_correlation": correlation})
    return rows


def estimator_metrics(spec: FlightComparison, rendered: list) -> tuple[list[dict], dict]:
    """With two or more images: the estimator on the flight and on the simulated sequence, measurements
    from the given poses; per-template Table-3 rows of both and each run's answer."""

    if len(spec.images) < 2:
        return [], {}
    measurements = DescentMeasurements(tuple(
        ImageMeasurement(time_s=image.time_s, attitude_quat=image.attitude_quat,
                         angular_rate_radps=image.angular_rate_radps, radar_altitude_m=float(image.position_m[2]),
                         imu_velocity_mps=image.velocity_mps, imu_position_m=image.position_m,
                         heat_shield_offset_m=(None if image.heat_shield_position_m is None
                                               else image.heat_shield_position_m - image.position_m))
        for image in spec.images), np.asarray(spec.site.sun_direction_world, dtype=float))
    estimator = DimesEstimator(spec.camera, spec.estimator)
    rows, answers = [], {}
    for source, images in (("flight", [image.dn for image in spec.images]), ("simulated", [r.dn for r in rendered])):
        estimate = estimator.estimate(images, measurements)
        answers[source] = {"valid": bool(estimate.valid), "reason": estimate.reason,
                           "velocity_east_mps": estimate.velocity_east_mps,
                           "velocity_north_mps": estimate.velocity_north_mps}
        for f in estimate.features:
            rows.append({"source": f"estimator_{source}", "image": f.pair, "pair": f.pair, "index": f.index,
                         "column": f.column_px, "row": f.row_px, "east_m": f.east_m, "north_m": f.north_m,
                         "brightness_dn": f.brightness_dn, "contrast_dn": f.contrast_dn, "correlation": f.correlation,
                         "status": f.status})
    return rows, answers


def compare(spec: FlightComparison) -> dict:
    """Render, measure and write every output to ``spec.output_dir``; return the summary (also comparison.json)."""
    terrain = load_class_terrain(spec.terrain_spec)
    rendered = render_simulated(spec, terrain)
    flattening = make_flattening(spec.camera, spec.estimator)
    out = spec.output_dir
    out.mkdir(parents=True, exist_ok=True)
    pixel_rows, feature_rows = [], []
    for k, (image, sim) in enumerate(zip(spec.images, rendered)):
        usable = usable_pixels(spec, image.dn, sim)
        column_rows = np.flatnonzero(usable[:, spec.column])
        column = line_fit(sim.dn[column_rows, spec.column], image.dn[column_rows, spec.column])
        whole = line_fit(sim.dn[usable], image.dn[usable])
        flight_flat = flatten(image.dn, flattening, spec.estimator)
        simulated_flat = flatten(sim.dn, flattening, spec.estimator)
        b = spec.camera.binning_rows
        blocks = (usable.reshape(usable.shape[0], -1, b).all(axis=2) & (flight_flat.excluded == 0)
                  & (simulated_flat.excluded == 0))
        detail = line_fit(texture(simulated_flat.signal_dn)[blocks], texture(flight_flat.signal_dn)[blocks])
        pixel_rows.append({"image": k, "file": str(image.file), "column": spec.column,
                           **{f"column_{key}": value for key, value in column.items()},
                           **{f"image_{key}": value for key, value in whole.items()},
                           "texture_r": detail["r"], "usable_fraction": float(usable.mean()),
                           "flight_mean_dn": float(image.dn[usable].mean()) if usable.any() else float("nan"),
                           "simulated_mean_dn": float(sim.dn[usable].mean()) if usable.any() else float("nan")})
        feature_rows += template_metrics(spec, flight_flat, simulated_flat, blocks, k)
        cv2.imwrite(str(out / f"simulated_image_{k}.png"), sim.dn.astype(np.uint16))
        side_by_side(sim.dn, image.dn, spec.column, b, out / f"image_{k}_side_by_side.png")
        column_plot(sim.dn[:, spec.column], image.dn[:, spec.column], usable[:, spec.column], spec.column,
                    out / f"image_{k}_column.png")
        scatter_plot(sim.dn[column_rows, spec.column], image.dn[column_rows, spec.column], column, spec.column,
                     out / f"image_{k}_scatter.png")
    estimator_rows, answers = estimator_metrics(spec, rendered)
    features = pd.DataFrame(feature_rows + estimator_rows)
    features.to_csv(out / "features.csv", index=False)
    pd.DataFrame(pixel_rows).to_csv(out / "pixels.csv", index=False)
    summary = {"flight_file": str(spec.source), "class": spec.terrain_spec.source, "images": pixel_rows,
               "templates": _template_summary(features), "estimator": answers}
    (out / "comparison.json").write_text(json.dumps(summary, indent=2, default=float))
    return summary


def _template_summary(features) -> dict:
    """Means of the Table-3 metrics per source (brightness, contrast, their ratio, correlation)."""
    if features.empty:
        return {}
    result: dict[str, dict[str, float] | float] = {}
    templates = features[features["source"] == "templates"]
    if len(templates):
        for who in ("flight", "simulated"):
            brightness, contrast = templates[f"{who}_brightness_dn"], templates[f"{who}_contrast_dn"]
            result[who] = {"templates": len(templates), "brightness_dn": float(brightness.mean()),
                           "contrast_dn": float(contrast.mean()),
                           "contrast_over_brightness": float((contrast / brightness).mean())}
        result["flight_simulated_correlation"] = float(templates["flight_simulated_correlation"].mean())
    for who in ("flight", "simulated"):
        rows = features[features["source"] == f"estimator_{who}"]
        if len(rows):
            brightness, contrast = rows["brightness_dn"], rows["contrast_dn"]
            result[f"estimator_{who}"] = {"templates": len(rows), "brightness_dn": float(brightness.mean()),
                                          "contrast_dn": float(contrast.mean()),
                                          "contrast_over_brightness": float((contrast / brightness).mean()),
                                          "correlation": float(rows["correlation"].mean())}
    return result


def summary_lines(summary: dict) -> list[str]:
    """What the command prints."""
    lines = []
    for row in summary["images"]:
        lines.append(f"image {row['image']} ({row['file']}): column {row['column']}: r = {row['column_r']:.4f}, "
                     f"slope = {row['column_slope']:.3f} "
                     f"(flight = slope x simulated + {row['column_intercept']:.1f} DN); "
                     f"whole image: r = {row['image_r']:.4f}, slope = {row['image_slope']:.3f}; "
                     f"texture r = {row['texture_r']:.4f}; usable {100 * row['usable_fraction']:.1f} %")
    for who, values in summary["templates"].items():
        if isinstance(values, dict):
            extra = f", correlation {values['correlation']:.3f}" if "correlation" in values else ""
            lines.append(f"{who}: {values['templates']} templates, brightness {values['brightness_dn']:.0f} DN, "
                         f"contrast "
                         f"{values['contrast_dn']:.1f} DN ({100 * values['contrast_over_brightness']:.2f} %){extra}")
    if "flight_simulated_correlation" in summary["templates"]:
        correlation = summary["templates"]["flight_simulated_correlation"]
        lines.append(f"flight vs simulated template correlation: {correlation:.3f}")
    for who, answer in summary["estimator"].items():
        lines.append(f"estimator on {who}: valid {answer['valid']} ({answer['reason']}), velocity "
                     f"({answer['velocity_east_mps']:.2f}, {answer['velocity_north_mps']:.2f}) m/s")
    return lines
