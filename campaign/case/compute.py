"""The case computation: simulate a case's three descent images and sensor measurements once, run every
estimator of the campaign on them, and know the case's truth.

A case's inputs are a :class:`~campaign.case.inputs.PlanRow` (one row of the plan) and the campaign's
:class:`~campaign.case.inputs.CampaignInputs` (camera, trajectory set, terrain, calibration products,
estimators); :func:`compute_case` turns them into a :class:`CaseComputation` (the case's truth and one
:class:`EstimatorResult` per estimator), which :mod:`campaign.case.result_rows` turns into result rows.
Running a case on a worker (retries, writing the case file and example PNGs) is :mod:`campaign.run.worker`;
``campaign export`` and the report's gallery simulate a case again with :func:`simulate_case_inputs`,
:func:`case_truth` and :func:`estimator_inputs`.

Randomness: a case with id ``c`` (``class_index * 1_000_000 + index within class``, see
:mod:`campaign.plan.placement`) of a campaign with seed ``s`` draws everything from
``SeedSequence([s, c]).spawn(...)``: one stream per image (scene + camera noise), one for the sensors,
one for the off-nominal artefacts (dust, hot pixels, per-image particle hits; drawn only when
configured), so a case is bit-for-bit reproducible whatever the worker count or order. The flat field
is drawn once per campaign (:mod:`campaign.case.inputs`).

No-op cases (``[execution] case_mode = "no_op"``, :func:`no_op_case`) skip all of this: they exist to measure
the orchestration and the store at 10^5-10^6 cases, and their rows say so (``reason = "no_op"``).

Estimators: every estimator runs on the same images, measurements and calibration products
(:class:`estimators.contract.EstimatorInputs`), handed over read-only. An estimator that violates the
contract, raises anything (``SystemExit`` included), times out or answers implausibly (a valid horizontal
speed not below :attr:`CampaignInputs.max_horizontal_speed_mps`) gets a row with ``status = "failed"``,
reason ``estimator_failed`` or ``implausible``, and the error; the other estimators' rows are kept.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from campaign.case.error_budget import attitude_floor_mps
from campaign.case.inputs import CampaignInputs, PlanRow
from campaign.configuration.execution import NO_OP_REASON
from campaign.store.result_schema import IMAGE_COUNT
from estimators.contract import EstimatorInputs
from estimators.plugins import EstimatorRun, run_estimator
from flight_interface.measurements import DescentMeasurements
from simulator.descent_image import DescentImage, render_descent_image
from simulator.off_nominal import OffNominalArtefacts, draw_case_artefacts, with_particle_hits
from simulator.scene.descent_profile import DescentProfile
from simulator.scene_config import SceneConfig
from simulator.sensors import measure


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
    artefacts: list[OffNominalArtefacts | None] = [None] * IMAGE_COUNT
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
        Velocity error the attitude bias alone causes (m/s, :mod:`campaign.case.error_budget`).
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
        # a valid answer has both velocities (estimators.contract refuses a valid one without)
        east = float(output.velocity_east_mps) if valid and output.velocity_east_mps is not None else None
        north = float(output.velocity_north_mps) if valid and output.velocity_north_mps is not None else None
        error = (float(np.hypot(east - truth_velocity_mps[0], north - truth_velocity_mps[1]))
                 if east is not None and north is not None else None)
        return cls(
            estimator=run.name, status="ok", error="",
            estimate_velocity_east_mps=east,
            estimate_velocity_north_mps=north,
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
    def of_no_op_case(cls, estimator: str) -> EstimatorResult:
        """The row of an estimator on a no-op case (``[execution] case_mode = "no_op"``: nothing rendered or
        estimated): status ok, no answer, invalid with reason ``no_op``."""
        return cls(estimator=estimator, status="ok", error="", estimate_velocity_east_mps=None,
                   estimate_velocity_north_mps=None, valid=False, reason=NO_OP_REASON, velocity_error_mps=None,
                   velocity_uncertainty_mps=None, feature_brightness=(), feature_contrast=(),
                   feature_correlation=(), feature_status=(), t_estimator_ms=0.0)

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
        outside_terrain_fraction=tuple(rendered.outside_terrain_fraction for rendered in inputs.images),
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


def no_op_case(estimator_names: list[str]) -> tuple[EstimatorResult, ...]:
    """The estimator results of a no-op case (``[execution] case_mode = "no_op"``, an orchestration test): no
    image is rendered, no sensor drawn, no estimator run and no campaign input loaded; one
    :meth:`EstimatorResult.of_no_op_case` per estimator, and the case has no truth (its case columns null)."""
    return tuple(EstimatorResult.of_no_op_case(name) for name in estimator_names)
