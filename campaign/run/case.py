"""One Monte Carlo case on a worker: simulate three descent images with sensor measurements once, run
every estimator of the campaign on them, and write the case's rows (one per estimator) durably.

Big read-only inputs (camera, trajectory set, terrain strips) are loaded once per worker process and
kept in :data:`_WORKER_RESOURCES`, keyed by the campaign's configuration hash; tasks themselves only
carry the small :class:`CampaignContext` and one plan row.

Randomness: a case with id ``c`` (``class_index * 1_000_000 + index within class``, see
:mod:`campaign.plan.placement`) of a campaign with seed ``s`` draws everything from
``SeedSequence([s, c]).spawn(...)``: one stream per image (scene + camera noise), one for the sensors, one for the off-nominal artefacts (dust, hot pixels, per-image particle hits; drawn only when
configured), so a case is bit-for-bit reproducible whatever the worker count or order. The flat-field
calibration is drawn once per campaign from ``SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))``
(a stream no case uses) and cached per worker process.

Estimators: each ``[[estimators]]`` entry is built once per worker process and runs on the same
images, measurements and calibration products (:class:`estimators.contract.EstimatorInputs`). An
estimator that violates the contract, crashes or times out gets a row with ``status = "failed"`` and
the error; the other estimators' rows for the case are kept.
"""
from __future__ import annotations

import ctypes
import os
import socket
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simulator.scene.descent_profile import DescentProfile

from campaign.run.error_budget import attitude_floor_mps
from campaign.run.faults import InfrastructureError, describe, is_infrastructure
from campaign.store.case_files import write_case_rows
from simulator.descent_image import render_descent_image
from simulator.sensors import measure
from estimators.contract import EstimatorInputs
from estimators.plugins import build_estimator, run_estimator
from simulator.off_nominal import draw_case_artefacts, with_particle_hits
from campaign.report.plots import save_descent_image
from flight_interface.camera import load_camera
from sitedata.edl.trajectory_io import read_profiles
from flight_interface.calibration import CalibrationProducts
from simulator.calibration import simulate_flat_field, true_flat_field
from sitedata.sites import load_class_terrain
from campaign.plan.coverage import fit_terrain
from campaign.plan.coverage import coverage, trajectory_boxes

_WORKER_RESOURCES: dict[str, "Resources"] = {}
IMAGE_COUNT = 3
FLAT_FIELD_STREAM = 0xF1A7   # spawn key of the flat-field calibration's noise stream


@dataclass(frozen=True)
class CampaignContext:
    """What every task needs besides its plan row (small and picklable)."""

    config: object          # campaign.configuration.campaign_file.CampaignConfig
    config_hash: str
    store_root: str

    @classmethod
    def from_config(cls, config, store_root: Path) -> "CampaignContext":
        return cls(config=config, config_hash=config.config_hash, store_root=str(store_root))


class Resources:
    """Camera, trajectory set and (lazily) terrain strips of one campaign, loaded once per process."""

    def __init__(self, config):

        self.config = config
        self.camera = _shared("camera", config.site.camera_path, load_camera)
        self.profiles: list[DescentProfile] = _shared("profiles", config.site.trajectory_path, read_profiles)

    def calibration(self):
        """The campaign's calibration products (``[estimator] flat_field``), made once per process."""

        calibration = self.config.calibration
        if calibration.flat_field == "none":
            return CalibrationProducts(None, "none")
        effects = self.config.scene.camera_effects.model_copy(update={"dark_current_scale": 1.0})   # the detector on the ground
        camera_path = Path(self.config.site.camera_path)
        stat = camera_path.stat()
        if calibration.flat_field == "truth":
            flat = _shared("flat_truth", (str(camera_path), stat.st_size, stat.st_mtime_ns, effects),
                           lambda _: true_flat_field(self.camera, effects))
            return CalibrationProducts(flat, "truth")
        frames, seed = calibration.flat_field_frames, self.config.seed
        key = (str(camera_path), stat.st_size, stat.st_mtime_ns, effects, frames, seed)
        flat = _shared("flat_calibrated", key, lambda _: simulate_flat_field(
            self.camera, frames, np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FLAT_FIELD_STREAM,))),
            effects))
        return CalibrationProducts(flat, f"calibrated: {frames} frames")

    def estimators(self) -> list:
        """(spec, estimator object) of every configured estimator, built once per process."""
        if not hasattr(self, "_estimators"):

            self._estimators = [(spec, build_estimator(spec)) for spec in self.config.estimators]
        return self._estimators

    def terrain(self, class_name: str):
        """The class's terrain, fitted to the trajectory set's footprints when its spec asks (``resample``)."""

        entry = next(entry for entry in self.config.site.classes if entry.name == class_name)
        terrain = _shared("terrain", entry.terrain, load_class_terrain)
        if entry.terrain.resample == "none":
            return terrain

        source = (entry.terrain, id(terrain), str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        return _shared("fitted-terrain", source,
                       lambda _: fit_terrain(terrain, entry.terrain.resample, self.coverage(terrain)))

    def coverage(self, terrain):
        """How ``terrain`` holds this campaign's trajectory set (:func:`campaign.plan.coverage.coverage`)."""

        key = (str(self.config.site.camera_path), str(self.config.site.trajectory_path))
        boxes = _shared("footprint-boxes", key, lambda _: trajectory_boxes(self.camera, self.profiles))
        return coverage(terrain, self.camera, self.profiles, boxes)

    def placed_profile(self, row: dict) -> DescentProfile:
        profile = self.profiles[int(row["profile_index"])]
        return profile.placed(float(row["heading_rad"]), np.array([row["offset_east_m"], row["offset_north_m"]]),
                              name=f"{profile.name}@case{int(row['case_id'])}")


# Inputs shared by every campaign (or sweep point) a process serves, keyed by what they are read from:
# the sweep's points differ in scene/sensor/estimator parameters, not in camera, trajectories or terrain.
_SHARED_INPUTS: dict = {}


def _shared(kind: str, source, loader):
    """``loader(source)``, loaded once per process per source (a path, keyed with its size and mtime so a
    changed file is read again, or a terrain spec)."""
    key = (kind, repr(source))
    path = Path(source) if isinstance(source, (str, Path)) else getattr(source, "path", None)
    if path is not None and Path(path).exists():
        stat = Path(path).stat()
        key += (stat.st_size, stat.st_mtime_ns)
    if key not in _SHARED_INPUTS:
        _SHARED_INPUTS[key] = loader(source)
    return _SHARED_INPUTS[key]


def keep_freed_memory_for_reuse() -> bool:
    """Ask glibc to recycle freed image buffers instead of returning them to the kernel at once.

    dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also freezes glibc's
    mmap threshold at 128 KiB: every 1024 x 1024 array is then a fresh ``mmap`` whose pages the
    kernel zero-fills on first touch, and a case runs 2.5 times slower (measured: 311 vs 125 ms),
    most of it as system time. Raising both thresholds (mmap 32 MiB, the largest glibc accepts; trim
    64 MiB) keeps a case's image buffers (4-12 MiB each) in the heap for reuse while larger scratch
    (terrain generation) is still returned at once, so a worker stays well under its memory limit. Returns False where there is no
    glibc (the setting is then simply not needed).
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(libc.mallopt(m_trim_threshold, 64 << 20)) and bool(libc.mallopt(m_mmap_threshold, 32 << 20))


def load_resources(config) -> Resources:
    """The per-process resources of a campaign (created on first use; the process is tuned once)."""
    if not _WORKER_RESOURCES:
        keep_freed_memory_for_reuse()
        import cv2

        cv2.setNumThreads(1)   # one worker process per core: OpenCV's own threads would only contend
    if config.config_hash not in _WORKER_RESOURCES:
        _WORKER_RESOURCES[config.config_hash] = Resources(config)
    return _WORKER_RESOURCES[config.config_hash]


def execute_case(context: CampaignContext, row: dict) -> str:
    """Run one case with retries and write its rows (ok or failed) to the store; return the status.

    Only an exception of the case's own computation (:func:`simulate_case`) is retried and then recorded
    ``failed``. A storage error (``OSError`` such as ENOSPC, EDQUOT, EROFS, EIO) or ``MemoryError``, in
    the computation or while writing the case file, is the machine's fault: nothing is recorded, the
    writes remove their own temporary files and :class:`~campaign.run.faults.InfrastructureError` is raised (the
    driver stops the run; the next submit runs the case again)."""
    config = context.config
    case_id = int(row["case_id"])
    worker = f"{socket.gethostname()}:{os.getpid()}"
    attempts = config.execution.retries + 1
    error = ""
    started = time.perf_counter()
    for attempt in range(1, attempts + 1):
        try:
            results = simulate_case(load_resources(config), row, context.store_root)
            status, attempts_used = "ok", attempt
            break
        except Exception as exc:  # the case's own failure is recorded in its rows; the campaign goes on
            if is_infrastructure(exc):
                raise InfrastructureError(describe(exc, case_id, "computing", worker, context.store_root)) from None
            where = [line.strip() for line in traceback.format_exc().splitlines() if line.strip().startswith("File ")]
            error = f"{type(exc).__name__}: {exc} | {where[-1] if where else ''}"
            attempts_used = attempt
    else:
        status = "failed"
        results = [{"estimator": name, "status": "failed", "error": error, **failed_fields()}
                   for name in config.estimator_names]
    common = {**plan_fields(row, config.seed), "attempts": attempts_used,
              "worker": worker, "t_case_ms": 1e3 * (time.perf_counter() - started)}
    records = [{**common, **result} for result in results]
    try:
        write_case_rows(Path(context.store_root) / "cases", case_id, records, ok=status == "ok")
    except (OSError, MemoryError) as exc:       # the failed write removed its own temporary file
        raise InfrastructureError(describe(exc, case_id, "writing its result", worker, context.store_root)) from None
    return status


def plan_fields(row: dict, seed: int) -> dict:
    return {
        "case_id": int(row["case_id"]), "class_name": str(row["class_name"]), "terrain_name": str(row["terrain_name"]),
        "profile_index": int(row["profile_index"]), "profile_name": str(row["profile_name"]),
        "heading_rad": float(row["heading_rad"]), "offset_east_m": float(row["offset_east_m"]),
        "offset_north_m": float(row["offset_north_m"]), "footprint_inside": bool(row["footprint_inside"]),
        "campaign_seed": int(seed),
    }


def failed_fields() -> dict:
    """The result columns of a case that produced no answer (nulls, invalid)."""
    return {"valid": False, "reason": "case_failed"}


@dataclass(frozen=True)
class CaseInputs:
    """What the estimator gets for one case, and the truth behind it."""

    profile: DescentProfile
    images: list                 # simulator.descent_image.DescentImage, one per image time
    measurements: object         # flight_interface.measurements.DescentMeasurements
    sensor_truth: dict
    sensors_ms: float


def simulate_case_inputs(resources: Resources, row: dict, scene_config=None) -> CaseInputs:
    """Render the three images of one case and draw its sensor measurements (the case's seeds; the
    campaign's scene configuration unless ``scene_config`` is given, e.g. another fidelity preset)."""

    config = resources.config
    scene_config = config.scene if scene_config is None else scene_config
    camera = resources.camera
    case_id = int(row["case_id"])
    # children 0..IMAGE_COUNT-1: images, IMAGE_COUNT: sensors, IMAGE_COUNT+1: off-nominal artefacts
    # (spawned children do not depend on the count, so adding the last one changed no other stream)
    image_seeds = np.random.SeedSequence([config.seed, case_id]).spawn(IMAGE_COUNT + 2)
    profile = resources.placed_profile(row)
    terrain = resources.terrain(str(row["class_name"]))
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


def simulate_case(resources: Resources, row: dict, store_root: str) -> list[dict]:
    """Simulate the three images and measurements of one case once, run every estimator on them; return
    one dict of row fields per estimator (in ``[[estimators]]`` order)."""

    camera = resources.camera
    inputs = simulate_case_inputs(resources, row)
    profile = inputs.profile
    images = [rendered.dn for rendered in inputs.images]
    last_time = float(profile.image_times_s[-1])
    truth_velocity = profile.pose(last_time).velocity_mps
    wind = profile.wind_at(last_time)
    first_mid, last_mid = (camera.timing.exposure_mid_time_s(float(profile.image_times_s[index])) for index in (0, -1))
    if int(row["case_in_class"]) == 0:
        _save_examples(Path(store_root), row, images)
    common = {
        "truth_velocity_east_mps": float(truth_velocity[0]), "truth_velocity_north_mps": float(truth_velocity[1]),
        "wind_east_mps": float(wind[0]), "wind_north_mps": float(wind[1]),
        "altitude_image1_m": float(profile.pose(float(profile.image_times_s[0])).position_m[2]),
        "altitude_image3_m": float(profile.pose(last_time).position_m[2]),
        "attitude_floor_mps": attitude_floor_mps(
            inputs.sensor_truth["attitude_bias_east_rad"], inputs.sensor_truth["attitude_bias_north_rad"],
            float(profile.pose(first_mid).position_m[2]), float(profile.pose(last_mid).position_m[2]),
            first_mid, last_mid),
        "heat_shield_in_view": [bool(rendered.diagnostics.heat_shield_visible) for rendered in inputs.images],
        "outside_terrain_fraction": [float(rendered.outside_terrain_mask.mean()) for rendered in inputs.images],
        **{f"sensor_{key}": value for key, value in inputs.sensor_truth.items()},
        "t_scene_ms": sum(rendered.diagnostics.scene_ms for rendered in inputs.images),
        "t_camera_ms": sum(rendered.diagnostics.camera_ms for rendered in inputs.images),
        "t_sensors_ms": inputs.sensors_ms,
    }
    shared = EstimatorInputs(images=tuple(images),
                             image_times_s=np.array([m.time_s for m in inputs.measurements.images]),
                             measurements=inputs.measurements, camera=camera, calibration=resources.calibration())
    # an image that sees untextured ground outside the terrain cannot score: recorded invalid, never valid
    outside_terrain = max(common["outside_terrain_fraction"]) > resources.config.max_outside_terrain_fraction
    rows = []
    for spec, estimator in resources.estimators():
        run = run_estimator(spec.name, estimator, shared)
        rows.append({"estimator": spec.name, **estimator_fields(run, truth_velocity, outside_terrain), **common,
                     "t_estimator_ms": run.elapsed_ms})
    return rows


def estimator_fields(run, truth_velocity: np.ndarray, outside_terrain: bool = False) -> dict:
    """Row fields of one estimator's run: status/error, the estimate, its error against the truth, metrics
    (``outside_terrain``: the case cannot score; an answer is recorded invalid with that reason)."""
    output = run.output
    if output is None:
        return {"status": "failed", "error": run.error, "estimate_velocity_east_mps": None,
                "estimate_velocity_north_mps": None, "valid": False, "reason": "estimator_failed",
                "velocity_error_mps": None, "velocity_uncertainty_mps": 0.0, "feature_brightness": [],
                "feature_contrast": [], "feature_correlation": [], "feature_status": []}
    valid = bool(output.valid) and not outside_terrain
    error = (float(np.hypot(output.velocity_east_mps - truth_velocity[0],
                            output.velocity_north_mps - truth_velocity[1])) if valid else None)
    return {
        "status": "ok", "error": "",
        "estimate_velocity_east_mps": float(output.velocity_east_mps) if valid else None,
        "estimate_velocity_north_mps": float(output.velocity_north_mps) if valid else None,
        "valid": valid, "reason": "outside_terrain" if outside_terrain else str(output.reason),
        "velocity_error_mps": error,
        "velocity_uncertainty_mps": float(output.velocity_uncertainty_mps or 0.0) if valid else 0.0,
        "feature_brightness": [float(f.get("brightness_dn", np.nan)) for f in output.features],
        "feature_contrast": [float(f.get("contrast_dn", np.nan)) for f in output.features],
        "feature_correlation": [float(f.get("correlation", np.nan)) for f in output.features],
        "feature_status": [str(f.get("status", "")) for f in output.features],
    }


def _save_examples(store_root: Path, row: dict, images: list[np.ndarray]) -> None:
    """PNG examples of the first case of each class (for the report), written atomically."""

    directory = store_root / "examples"
    directory.mkdir(exist_ok=True)
    for index, image in enumerate(images):
        target = directory / f"{row['class_name']}-case{int(row['case_id']):06d}-image{index + 1}.png"
        temporary = directory / f".tmp-{os.getpid()}-{target.name}"
        try:
            save_descent_image(image, temporary)
            os.replace(temporary, target)
        except BaseException:                  # e.g. a full disk: leave no temporary file behind
            temporary.unlink(missing_ok=True)
            raise
