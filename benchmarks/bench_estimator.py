"""Reference DIMES estimator: ms per estimate (target ``ESTIMATOR_MS``, one thread), per stage, with the velocity error.

Cases are simulator images (``render_descent_image`` on a synthetic Gusev dark-cratered-plains
strip, camera noise on) with measurements from the sensor models (paper noise): a nadir and a
tilted descent, a descent with the zero-phase halo in view, and a blank scene (invalid, early exit).
Each case is timed as the median wall time of repeated estimates on the same inputs (the
estimator's per-camera constants are built once, as in a campaign worker); ``cpu_ms`` is the
process CPU time per estimate (all threads), less sensitive to other load on the machine. The rows are
timed interleaved: each of the ``REPEATS`` rounds calls every case once, in turn, so that every row sees the
same machine state (timed one block after another, a row carried the order it ran in: the campaign-call row
read 7.5 ms against the nadir row's 6.2 on the idle machine, while the two calls differ by ~0.05 ms of
argument handling when alternated in one process).

``estimator/nadir_gdcp_campaign_call`` runs the nadir case the way a campaign worker calls the estimator: through
:func:`estimators.plugins.run_estimator` with a flat field, every call handed fresh read-only views of the inputs
(:func:`estimators.contract.read_only_inputs`). Its time beside the nadir row is what the campaign adds per case
(it was ~5 ms when each fresh view of the flat field rebuilt the estimator).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmarks.targets import ESTIMATOR_MS, target_columns
from dimes_velocity import DimesEstimator
from flight_interface.camera import load_camera
from flight_interface.frames import quat_from_axis_angle
from simulator.descent_image import render_descent_image
from simulator.scene.descent_profile import constant_velocity_profile
from simulator.scene.terrain import Terrain
from simulator.sensors import SensorConfig, measure
from sitedata.terrain.synthetic_terrain import synthetic_terrain

CAMERA = Path(__file__).resolve().parents[1] / "sitedata" / "cameras" / "mer_a.toml"
TIMES_S = np.array([0.0, 275.0 / 72.0, 550.0 / 72.0])
REPEATS = 25


def _sun(elevation_deg: float, azimuth_deg: float) -> np.ndarray:
    elevation, azimuth = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.cos(elevation) * np.sin(azimuth), np.cos(elevation) * np.cos(azimuth), np.sin(elevation)])


def _case(camera, terrain, seed: int, tilt_deg: float, sun: np.ndarray):
    rng = np.random.default_rng(np.random.SeedSequence([77, seed]))
    velocity = np.array([14.0, -9.0, -72.0])
    attitude = quat_from_axis_angle(np.array([1.0, 0.5, 0.0]), np.radians(tilt_deg))
    profile = constant_velocity_profile([0.0, -1500.0, 2000.0], velocity, attitude, 10.0, TIMES_S)
    images = [render_descent_image(terrain, profile, camera, k, sun, None, rng).dn for k in range(3)]
    measurements, _ = measure(profile, camera, sun, SensorConfig(), rng)
    return images, measurements, velocity


def run() -> list[dict]:
    camera = load_camera(CAMERA)
    estimator = DimesEstimator(camera)
    terrain = synthetic_terrain("gdcp", 3)
    blank = Terrain(np.full((400, 400), 0.2, np.float32), 15.0, np.array([-3000.0, 3000.0]),
                    terrain.moc_incidence_rad, terrain.moc_emission_rad, terrain.moc_phase_rad, "blank")
    cases = {
        "nadir_gdcp": _case(camera, terrain, 1, 0.0, _sun(55.0, 120.0)),
        "tilt15_gdcp": _case(camera, terrain, 2, 15.0, _sun(55.0, 120.0)),
        "halo_in_view_gdcp": _case(camera, terrain, 3, 5.0, _sun(78.0, 200.0)),
        "blank_scene": _case(camera, blank, 4, 0.0, _sun(55.0, 120.0)),
    }
    timed = {name: (lambda images=images, measurements=measurements: estimator.estimate(images, measurements), velocity)
             for name, (images, measurements, velocity) in cases.items()}
    images, measurements, velocity = cases["nadir_gdcp"]
    timed["nadir_gdcp_campaign_call"] = (_campaign_call(camera, images, measurements), velocity)
    return _rows(timed)


def _campaign_call(camera, images, measurements):
    """One estimate as a campaign worker makes it (run_estimator, read-only views, a flat field): a callable."""
    from estimators.contract import EstimatorInputs
    from estimators.plugins import ReferenceEstimator, run_estimator
    from flight_interface.calibration import CalibrationProducts, readout_flat_field

    flat = readout_flat_field(camera.falloff_map, camera.binned_shape, "falloff")   # any flat field: one per campaign
    flat.setflags(write=False)
    inputs = EstimatorInputs(tuple(images), np.array([m.time_s for m in measurements.images]), measurements, camera,
                             CalibrationProducts(flat, "falloff"))
    reference = ReferenceEstimator("dimes", {})

    def call():
        run = run_estimator("dimes", reference, inputs)
        assert run.output is not None, run.error
        return run.output

    return call


def _rows(timed: dict) -> list[dict]:
    """Time each ``estimate()`` of ``timed`` (name -> (estimate, true velocity)): the bench rows.

    One warm call each, then ``REPEATS`` rounds calling every estimate once, in turn (interleaved: the same
    machine state for every row).
    """
    results = {name: estimate() for name, (estimate, _) in timed.items()}
    totals: dict[str, list[float]] = {name: [] for name in timed}
    stages: dict[str, list] = {name: [] for name in timed}
    cpu_s = dict.fromkeys(timed, 0.0)
    for _ in range(REPEATS):
        for name, (estimate, _) in timed.items():
            cpu_start = time.process_time()
            start = time.perf_counter()
            result = estimate()
            totals[name].append(time.perf_counter() - start)
            cpu_s[name] += time.process_time() - cpu_start
            stages[name].append(getattr(result, "timings", None))
            results[name] = result
    return [_record(name, totals[name], stages[name], cpu_s[name], results[name], velocity)
            for name, (_, velocity) in timed.items()]


def _record(name: str, totals: list[float], stages: list, cpu_s: float, result, velocity: np.ndarray) -> dict:
    """One bench row from a case's wall times (s), stage timings, total CPU time (s) and last result."""
    middle = stages[int(np.argsort(totals)[len(totals) // 2])]
    return {
        "name": f"estimator/{name}", "ms": 1e3 * float(np.median(totals)), "min_ms": 1e3 * float(np.min(totals)),
        "cpu_ms": 1e3 * cpu_s / len(totals),
        **({"preprocess_ms": middle.preprocess_ms, "rectify_ms": middle.rectify_ms, "select_ms": middle.select_ms,
            "match_ms": middle.match_ms} if middle is not None else {}),
        "valid": result.valid, "reason": result.reason,
        "velocity_error_mps": float(np.hypot(result.velocity_east_mps - velocity[0], result.velocity_north_mps - velocity[1])),
        **target_columns(1e3 * float(np.median(totals)), ESTIMATOR_MS, "ms"),
    }
