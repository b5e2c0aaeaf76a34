"""One Monte Carlo case as a typed unit: simulate three descent images with sensor measurements once, run
every estimator of the campaign on them, and give the case's result rows (one per estimator).

A case's inputs are a :class:`PlanRow` (one row of the plan) and the campaign's :class:`CampaignInputs`
(camera, trajectory set, terrain, calibration products, estimators); :func:`compute_case` turns them into
a :class:`CaseComputation` (the case's truth and one :class:`EstimatorResult` per estimator) and
:func:`case_rows` is the one place that assembles result rows (:class:`ResultRow`, whose columns are
declared by :mod:`campaign.store.result_schema`). Running a case on a worker (retries, process tuning,
the per-process caches, writing the case file and example PNGs) is :mod:`campaign.run.worker`.

Randomness: a case with id ``c`` (``class_index * 1_000_000 + index within class``, see
:mod:`campaign.plan.placement`) of a campaign with seed ``s`` draws everything from
``SeedSequence([s, c]).spawn(...)``: one stream per image (scene + camera noise), one for the sensors,
one for the off-nominal artefacts (dust, hot pixels, per-image particle hits; drawn only when
configured), so a case is bit-for-bit reproducible whatever the worker count or order. The flat-field
calibration is drawn once per campaign from ``SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))``
(a stream no case uses) and cached per worker process.

Estimators: each ``[[estimators]]`` entry is built once per worker process and runs on the same
images, measurements and calibration products (:class:`estimators.contract.EstimatorInputs`), handed
over read-only (the cached flat field is read-only at its source). An estimator that violates the
contract, raises anything (``SystemExit`` included), times out or answers implausibly (a valid horizontal
speed not below :attr:`CampaignInputs.max_horizontal_speed_mps`) gets a row with ``status = "failed"``,
reason ``estimator_failed`` or ``implausible``, and the error; the other estimators' rows are kept.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.coverage import Coverage, coverage, fit_terrain, trajectory_boxes
from campaign.run.error_budget import attitude_floor_mps
from campaign.store.result_schema import CASE_FILE_SCHEMA, IMAGE_COUNT, SENSOR_PREFIX
from estimators.contract import EstimatorInputs
from estimators.entries import EstimatorSpec
from estimators.plugins import EstimatorRun, build_estimator, run_estimator
from flight_interface.calibration import CalibrationProducts
from flight_interface.camera import Camera, load_camera
from flight_interface.measurements import DescentMeasurements
from simulator.calibration import simulate_flat_field, true_flat_field
from simulator.descent_image import DescentImage, render_descent_image
from simulator.off_nominal import draw_case_artefacts, with_particle_hits
from simulator.scene.descent_profile import DescentProfile
from simulator.scene.terrain import Terrain
from simulator.scene_config import SceneConfig
from simulator.sensors import measure
from sitedata.edl.trajectory_io import read_profiles
from sitedata.sites import load_class_terrain

FLAT_FIELD_STREAM = 0xF1A7   # spawn key of the flat-field calibration's noise stream
#: Margin (m/s) above the trajectory set's fastest horizontal speed: a valid answer at or above the sum is
#: ``implausible`` (no estimator can be that far off on a real descent; the reference stays within ~30 m/s
#: of the truth by its 25 m/s bias search range).
PLAUSIBLE_SPEED_MARGIN_MPS = 100.0


def read_only_array(array: np.ndarray) -> np.ndarray:
    """``array`` itself, made read-only (for arrays cached per process and handed to every estimator)."""
    array.setflags(write=False)
    return array


class SharedInputs:
    """Inputs shared by every campaign (or sweep point) a process serves, loaded once per source: the
    sweep's points differ in scene/sensor/estimator parameters, not in camera, trajectories or terrain.

    Attributes
    ----------
    loaded : dict
        (kind, repr(source)[, file size in bytes, mtime in ns]) -> the loaded input.
    """

    def __init__(self) -> None:
        self.loaded: dict[tuple, Any] = {}

    def get(self, kind: str, source: Any, loader: Callable[[Any], Any]) -> Any:
        """``loader(source)``, loaded once per process per source (a path, keyed with its size and mtime so
        a changed file is read again, or a terrain spec)."""
        key: tuple = (kind, repr(source))
        path = Path(source) if isinstance(source, (str, Path)) else getattr(source, "path", None)
        if path is not None and Path(path).exists():
            stat = Path(path).stat()
            key += (stat.st_size, stat.st_mtime_ns)
        if key not in self.loaded:
            self.loaded[key] = loader(source)
        return self.loaded[key]


@dataclass(frozen=True)
class PlanRow:
    """One planned case (a row of ``plan.parquet``, :mod:`campaign.plan.placement`) as the case uses it.

    Attributes
    ----------
    case_id : int
        ``class_index * 1_000_000 + case_in_class``.
    case_in_class : int
        Index of the case within its class (0: the class's example images are saved).
    heading_rad : float
        Rotation of the trajectory about the vertical (rad).
    offset_east_m, offset_north_m : float
        Offset of the trajectory on the terrain (m).
    footprint_inside : bool
        Every image footprint lies inside the terrain (the planner's check).
    """

    case_id: int
    class_name: str
    terrain_name: str
    case_in_class: int
    profile_index: int
    profile_name: str
    heading_rad: float
    offset_east_m: float
    offset_north_m: float
    footprint_inside: bool

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> PlanRow:
        """The typed row of a plan record (a dict of ``plan.parquet`` columns; extra columns are ignored)."""
        return cls(case_id=int(record["case_id"]), class_name=str(record["class_name"]),
                   terrain_name=str(record["terrain_name"]), case_in_class=int(record["case_in_class"]),
                   profile_index=int(record["profile_index"]), profile_name=str(record["profile_name"]),
                   heading_rad=float(record["heading_rad"]), offset_east_m=float(record["offset_east_m"]),
                   offset_north_m=float(record["offset_north_m"]), footprint_inside=bool(record["footprint_inside"]))


class CampaignInputs:
    """Camera, trajectory set, terrain, calibration products and estimators of one campaign, loaded once per
    process (through the process's :class:`SharedInputs`)."""

    def __init__(self, config: CampaignConfig, shared: SharedInputs):
        self.config = config
        self.shared = shared
        self.camera: Camera = shared.get("camera", config.site.camera_path, load_camera)
        self.profiles: list[DescentProfile] = shared.get("profiles", config.site.trajectory_path, read_profiles)
        self.built_estimators: list[tuple[EstimatorSpec, Any]] | None = None   # built on first use
        fastest = max((float(np.hypot(p.velocity_mps[:, 0], p.velocity_mps[:, 1]).max()) for p in self.profiles),
                      default=0.0)
        #: The plausibility bound of a valid answer (m/s): the fastest horizontal speed of any profile of the
        #: trajectory set, at any time, plus :data:`PLAUSIBLE_SPEED_MARGIN_MPS`.
        self.max_horizontal_speed_mps = fastest + PLAUSIBLE_SPEED_MARGIN_MPS

    def calibration(self) -> CalibrationProducts:
        """The campaign's calibration products (``[estimator] flat_field``), made once per process."""
        calibration = self.config.calibration
        if calibration.flat_field == "none":
            return CalibrationProducts(None, "none")
        effects = self.config.scene.camera_effects.model_copy(update={"dark_current_scale": 1.0})   # the detector on the ground
        camera_path = Path(self.config.site.camera_path)
        stat = camera_path.stat()
        if calibration.flat_field == "truth":
            flat = self.shared.get("flat_truth", (str(camera_path), stat.st_size, stat.st_mtime_ns, effects),
                                   lambda _: read_only_array(true_flat_field(self.camera, effects)))
            return CalibrationProducts(flat, "truth")
        frames, seed = calibration.flat_field_frames, self.config.seed
        key = (str(camera_path), stat.st_size, stat.st_mtime_ns, effects, frames, seed)
        flat = self.shared.get("flat_calibrated", key, lambda _: read_only_array(simulate_flat_field(
            self.camera, frames, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))),
            effects)))
        return CalibrationProducts(flat, f"calibrated: {frames} frames")

    def estimators(self) -> list[tuple[EstimatorSpec, Any]]:
        """(spec, estimator object) of every configured estimator, built on first use."""
        if self.built_estimators is None:
            self.built_estimators = [(spec, build_estimator(spec)) for spec in self.config.estimators]
        return self.built_estimators

    def terrain(self, class_name: str) -> Terrain:
        """The class's terrain, fitted to the trajectory set's footprints when its spec asks (``resample``)."""
        entry = next(entry for entry in self.config.site.classes if entry.name == class_name)
        terrain = self.shared.get("terrain", entry.terrain, load_class_terrain)
        if entry.terrain.resample == "none":
            return terrain
        source = (entry.terrain, id(terrain), str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        return self.shared.get("fitted-terrain", source,
                               lambda _: fit_terrain(terrain, entry.terrain.resample, self.coverage(terrain)))

    def coverage(self, terrain: Terrain) -> Coverage:
        """How ``terrain`` holds this campaign's trajectory set (:func:`campaign.plan.coverage.coverage`)."""
        key = (str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        boxes = self.shared.get("footprint-boxes", key, lambda _: trajectory_boxes(self.camera, self.profiles))
        return coverage(terrain, self.camera, self.profiles, boxes)

    def placed_profile(self, plan: PlanRow) -> DescentProfile:
        """The case's trajectory, turned by its heading and moved by its offset (m) on the terrain."""
        profile = self.profiles[plan.profile_index]
        return profile.placed(plan.heading_rad, np.array([plan.offset_east_m, plan.offset_north_m]),
                              name=f"{profile.name}@case{plan.case_id}")


@dataclass(frozen=True)
class CaseInputs:
    """What the estimators get for one case, and the truth behind it.

    Attributes
    ----------
    sensor_truth : dict of float
        The sensor errors drawn (:func:`simulator.sensors.measure`; SI unit in each name).
    sensors_ms : float
        Time to draw the sensor measurements (ms).
    """

    profile: DescentProfile
    images: list[DescentImage]        # one per image time
    measurements: DescentMeasurements
    sensor_truth: dict[str, float]
    sensors_ms: float


def simulate_case_inputs(resources: CampaignInputs, plan: PlanRow, scene_config: SceneConfig | None = None) -> CaseInputs:
    """Render the three images of one case and draw its sensor measurements (the case's seeds; the
    campaign's scene configuration unless ``scene_config`` is given, e.g. another fidelity preset)."""
    config = resources.config
    scene_config = config.scene if scene_config is None else scene_config
    camera = resources.camera
    # children 0..IMAGE_COUNT-1: images, IMAGE_COUNT: sensors, IMAGE_COUNT+1: off-nominal artefacts
    # (spawned children do not depend on the count, so adding the last one changed no other stream)
    image_seeds = np.random.SeedSequence([config.seed, plan.case_id]).spawn(IMAGE_COUNT + 2)
    profile = resources.placed_profile(plan)
    terrain = resources.terrain(plan.class_name)
    sun = np.asarray(config.site.sun_direction_world, dtype=float)
    artefacts = [None] * IMAGE_COUNT
    off_nominal = scene_config.off_nominal
    if off_nominal.needs_case_artefacts:
        # artefact child 0: dust and hot pixels (the same in every image); 1 + k: particle hits of image k
        artefact_seeds = image_seeds[IMAGE_COUNT + 1].spawn(1 + IMAGE_COUNT)
        fixed = draw_case_artefacts(camera, off_nominal, np.random.default_rng(artefact_seeds[0]))
        artefacts = [with_particle_hits(fixed, camera, off_nominal, np.random.default_rng(artefact_seeds[1 + k]))
                     for k in range(IMAGE_COUNT)]
    images = [render_descent_image(terrain, profile, camera, index, sun, scene_config,
                                   np.random.default_rng(image_seeds[index]), artefacts[index])
              for index in range(IMAGE_COUNT)]
    started = time.perf_counter()
    measurements, sensor_truth = measure(profile, camera, sun, config.sensors,
                                         np.random.default_rng(image_seeds[IMAGE_COUNT]))
    return CaseInputs(profile, images, measurements, sensor_truth, 1e3 * (time.perf_counter() - started))


@dataclass(frozen=True)
class CaseTruth:
    """What the simulation knows about a case (the same for every estimator).

    Attributes
    ----------
    truth_velocity_east_mps, truth_velocity_north_mps : float
        True horizontal velocity at the last image (m/s).
    wind_east_mps, wind_north_mps : float
        Wind at the last image (m/s).
    altitude_image1_m, altitude_image3_m : float
        Lander altitude at the first and last image (m).
    attitude_floor_mps : float
        Velocity error the attitude bias alone causes (m/s, :mod:`campaign.run.error_budget`).
    heat_shield_in_view : tuple of bool
        The heat shield is visible, per image.
    outside_terrain_fraction : tuple of float
        Fraction of the pixels on ground outside the terrain, per image.
    sensor_errors : dict of float
        The sensor errors drawn, by name without the ``sensor_`` prefix (SI unit in each name).
    t_scene_ms, t_camera_ms, t_sensors_ms : float
        Stage times of the simulation (ms).
    """

    truth_velocity_east_mps: float
    truth_velocity_north_mps: float
    wind_east_mps: float
    wind_north_mps: float
    altitude_image1_m: float
    altitude_image3_m: float
    attitude_floor_mps: float
    heat_shield_in_view: tuple[bool, ...]
    outside_terrain_fraction: tuple[float, ...]
    sensor_errors: dict[str, float]
    t_scene_ms: float
    t_camera_ms: float
    t_sensors_ms: float


@dataclass(frozen=True)
class EstimatorResult:
    """One estimator's answer on one case (velocities in m/s; ``None``: no value).

    Attributes
    ----------
    status : str
        "ok", or "failed" when the estimator (or the whole case) failed; ``error`` says why.
    reason : str
        The estimator's reason, or ``outside_terrain``, ``estimator_failed``, ``case_failed``.
    velocity_error_mps : float or None
        Horizontal error of a valid estimate against the truth.
    feature_brightness, feature_contrast, feature_correlation, feature_status : tuple or None
        Per tracked feature: brightness and contrast (DN), correlation score, status.
    t_estimator_ms : float or None
        The estimator's wall time (ms).
    """

    estimator: str
    status: str
    error: str
    estimate_velocity_east_mps: float | None
    estimate_velocity_north_mps: float | None
    valid: bool
    reason: str
    velocity_error_mps: float | None
    velocity_uncertainty_mps: float | None
    feature_brightness: tuple[float, ...] | None
    feature_contrast: tuple[float, ...] | None
    feature_correlation: tuple[float, ...] | None
    feature_status: tuple[str, ...] | None
    t_estimator_ms: float | None

    @classmethod
    def of_run(cls, run: EstimatorRun, truth_velocity_mps: np.ndarray, outside_terrain: bool) -> EstimatorResult:
        """The result of one estimator's run: status/error, the estimate, its error against the true
        horizontal velocity (m/s), metrics (``outside_terrain``: the case cannot score; an answer is
        recorded invalid with that reason)."""
        output = run.output
        if output is None:
            return cls(estimator=run.name, status="failed", error=run.error, estimate_velocity_east_mps=None,
                       estimate_velocity_north_mps=None, valid=False, reason=run.failure or "estimator_failed",
                       velocity_error_mps=None, velocity_uncertainty_mps=None, feature_brightness=(),
                       feature_contrast=(), feature_correlation=(), feature_status=(), t_estimator_ms=run.elapsed_ms)
        valid = bool(output.valid) and not outside_terrain
        error = (float(np.hypot(output.velocity_east_mps - truth_velocity_mps[0],
                                output.velocity_north_mps - truth_velocity_mps[1])) if valid else None)
        return cls(
            estimator=run.name, status="ok", error="",
            estimate_velocity_east_mps=float(output.velocity_east_mps) if valid else None,
            estimate_velocity_north_mps=float(output.velocity_north_mps) if valid else None,
            valid=valid, reason="outside_terrain" if outside_terrain else str(output.reason),
            velocity_error_mps=error,
            velocity_uncertainty_mps=(float(output.velocity_uncertainty_mps)     # none stated: null (NaN), never 0
                                      if valid and output.velocity_uncertainty_mps is not None else None),
            feature_brightness=tuple(float(f.get("brightness_dn", np.nan)) for f in output.features),
            feature_contrast=tuple(float(f.get("contrast_dn", np.nan)) for f in output.features),
            feature_correlation=tuple(float(f.get("correlation", np.nan)) for f in output.features),
            feature_status=tuple(str(f.get("status", "")) for f in output.features),
            t_estimator_ms=run.elapsed_ms)

    @classmethod
    def of_failed_case(cls, estimator: str, error: str) -> EstimatorResult:
        """The row of an estimator on a case whose simulation failed (no answer: nulls, invalid)."""
        return cls(estimator=estimator, status="failed", error=error, estimate_velocity_east_mps=None,
                   estimate_velocity_north_mps=None, valid=False, reason="case_failed", velocity_error_mps=None,
                   velocity_uncertainty_mps=None, feature_brightness=None, feature_contrast=None,
                   feature_correlation=None, feature_status=None, t_estimator_ms=None)


@dataclass(frozen=True)
class CaseComputation:
    """What :func:`compute_case` found: the case's truth, one result per estimator (``[[estimators]]``
    order) and the rendered images (DN) for the example PNGs."""

    truth: CaseTruth
    estimates: tuple[EstimatorResult, ...]
    images_dn: tuple[np.ndarray, ...]


def case_truth(resources: CampaignInputs, inputs: CaseInputs) -> CaseTruth:
    """What the simulation knows about a simulated case (:func:`simulate_case_inputs`)."""
    camera = resources.camera
    profile = inputs.profile
    last_time = float(profile.image_times_s[-1])
    truth_velocity = profile.pose(last_time).velocity_mps
    wind = profile.wind_at(last_time)
    first_mid, last_mid = (camera.timing.exposure_mid_time_s(float(profile.image_times_s[index])) for index in (0, -1))
    return CaseTruth(
        truth_velocity_east_mps=float(truth_velocity[0]), truth_velocity_north_mps=float(truth_velocity[1]),
        wind_east_mps=float(wind[0]), wind_north_mps=float(wind[1]),
        altitude_image1_m=float(profile.pose(float(profile.image_times_s[0])).position_m[2]),
        altitude_image3_m=float(profile.pose(last_time).position_m[2]),
        attitude_floor_mps=attitude_floor_mps(
            inputs.sensor_truth["attitude_bias_east_rad"], inputs.sensor_truth["attitude_bias_north_rad"],
            float(profile.pose(first_mid).position_m[2]), float(profile.pose(last_mid).position_m[2]),
            first_mid, last_mid),
        heat_shield_in_view=tuple(bool(rendered.diagnostics.heat_shield_visible) for rendered in inputs.images),
        outside_terrain_fraction=tuple(float(rendered.outside_terrain_mask.mean()) for rendered in inputs.images),
        sensor_errors=dict(inputs.sensor_truth),
        t_scene_ms=sum(rendered.diagnostics.scene_ms for rendered in inputs.images),
        t_camera_ms=sum(rendered.diagnostics.camera_ms for rendered in inputs.images),
        t_sensors_ms=inputs.sensors_ms)


def estimator_inputs(resources: CampaignInputs, inputs: CaseInputs) -> EstimatorInputs:
    """What every estimator gets for a simulated case: its images (DN), times, measurements, the camera and
    the campaign's calibration products."""
    images = tuple(rendered.dn for rendered in inputs.images)
    return EstimatorInputs(images=images, image_times_s=np.array([m.time_s for m in inputs.measurements.images]),
                           measurements=inputs.measurements, camera=resources.camera,
                           calibration=resources.calibration())


def compute_case(resources: CampaignInputs, plan: PlanRow) -> CaseComputation:
    """Simulate the three images and measurements of one case once and run every estimator on them."""
    inputs = simulate_case_inputs(resources, plan)
    truth = case_truth(resources, inputs)
    truth_velocity = inputs.profile.pose(float(inputs.profile.image_times_s[-1])).velocity_mps
    shared = estimator_inputs(resources, inputs)
    images = shared.images
    # an image that sees untextured ground outside the terrain cannot score: recorded invalid, never valid
    outside_terrain = max(truth.outside_terrain_fraction) > resources.config.max_outside_terrain_fraction
    bound = resources.max_horizontal_speed_mps
    estimates = tuple(EstimatorResult.of_run(run_estimator(spec.name, estimator, shared, bound), truth_velocity,
                                             outside_terrain)
                      for spec, estimator in resources.estimators())
    return CaseComputation(truth, estimates, images)


@dataclass(frozen=True)
class CaseRun:
    """How a case ran on its worker (varies from run to run).

    Attributes
    ----------
    attempts : int
        Attempts used (at most ``retries + 1``).
    worker : str
        ``host:pid`` of the worker process.
    t_case_ms : float
        Wall time of the whole case, retries included (ms).
    """

    attempts: int
    worker: str
    t_case_ms: float


@dataclass(frozen=True)
class ResultRow:
    """One result row: a case's plan row, how it ran, one estimator's answer and the case's truth (None when
    the case's simulation failed). Its columns are :data:`campaign.store.result_schema.RESULT_COLUMNS`."""

    plan: PlanRow
    campaign_seed: int
    run: CaseRun
    estimate: EstimatorResult
    truth: CaseTruth | None

    def columns(self) -> dict[str, Any]:
        """Column name -> value (lists for the per-image and per-feature columns)."""
        plan, estimate, truth = self.plan, self.estimate, self.truth
        values: dict[str, Any] = {
            "case_id": plan.case_id, "class_name": plan.class_name, "terrain_name": plan.terrain_name,
            "profile_index": plan.profile_index, "profile_name": plan.profile_name, "heading_rad": plan.heading_rad,
            "offset_east_m": plan.offset_east_m, "offset_north_m": plan.offset_north_m,
            "footprint_inside": plan.footprint_inside, "campaign_seed": self.campaign_seed,
            "attempts": self.run.attempts, "worker": self.run.worker, "t_case_ms": self.run.t_case_ms,
            "estimator": estimate.estimator, "status": estimate.status, "error": estimate.error,
            "estimate_velocity_east_mps": estimate.estimate_velocity_east_mps,
            "estimate_velocity_north_mps": estimate.estimate_velocity_north_mps,
            "valid": estimate.valid, "reason": estimate.reason, "velocity_error_mps": estimate.velocity_error_mps,
            "velocity_uncertainty_mps": estimate.velocity_uncertainty_mps,
            "feature_brightness": _listed(estimate.feature_brightness),
            "feature_contrast": _listed(estimate.feature_contrast),
            "feature_correlation": _listed(estimate.feature_correlation),
            "feature_status": _listed(estimate.feature_status),
            "t_estimator_ms": estimate.t_estimator_ms,
        }
        case_columns = ("truth_velocity_east_mps", "truth_velocity_north_mps", "wind_east_mps", "wind_north_mps",
                        "altitude_image1_m", "altitude_image3_m", "attitude_floor_mps", "heat_shield_in_view",
                        "outside_terrain_fraction", "t_scene_ms", "t_camera_ms", "t_sensors_ms")
        if truth is None:                          # the simulation failed: every case column is null
            values.update({name: None for name in CASE_FILE_SCHEMA.names if name not in values})
        else:
            values.update({name: _listed(getattr(truth, name)) for name in case_columns})
            values.update({f"{SENSOR_PREFIX}{name}": value for name, value in truth.sensor_errors.items()})
        return values


def _listed(value: Any) -> Any:
    """A tuple as a list (an Arrow list value); anything else unchanged."""
    return list(value) if isinstance(value, tuple) else value


def case_rows(plan: PlanRow, campaign_seed: int, run: CaseRun, estimates: Sequence[EstimatorResult],
              truth: CaseTruth | None) -> list[ResultRow]:
    """The result rows of one case, one per estimator (in ``estimates`` order)."""
    return [ResultRow(plan, campaign_seed, run, estimate, truth) for estimate in estimates]
