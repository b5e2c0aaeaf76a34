"""Build estimators from their specs and run one on a case's inputs, whatever happens.

:func:`build_estimator` turns an :class:`~estimators.registry.EstimatorSpec` into an object with
``estimate(inputs) -> EstimatorOutput``; :func:`run_estimator` runs it on read-only inputs
(:func:`estimators.contract.read_only_inputs`) and never raises: a contract violation, any exception
(``SystemExit`` and ``KeyboardInterrupt`` included), a non-zero exit or a timeout becomes an
:class:`EstimatorRun` with ``output = None``, ``failure = "estimator_failed"`` and a one-line ``error``;
an implausible answer (:func:`estimators.contract.check_plausible`) the same with ``failure = "implausible"``.
"""
from __future__ import annotations

import copy
import importlib
import time
import traceback
from dataclasses import dataclass, replace

from dimes_velocity.config import estimator_config_from_data
from dimes_velocity.estimator import estimate_velocity
from estimators.command import CommandEstimator
from estimators.contract import (
    ContractViolation,
    EstimatorInputs,
    EstimatorOutput,
    ImplausibleOutput,
    check_plausible,
    read_only_inputs,
    validate_output,
)
from estimators.registry import EstimatorSpec


class ReferenceEstimator:
    """The reference DIMES estimator (:mod:`dimes_velocity`) behind the contract."""

    def __init__(self, name: str, parameters: dict):

        self.name = name
        self.config = estimator_config_from_data(dict(parameters), f"estimator {name}", "parameters")

    def estimate(self, inputs: EstimatorInputs) -> EstimatorOutput:

        result = estimate_velocity(list(inputs.images), inputs.measurements, inputs.camera, self.config,
                                   inputs.calibration.flat_field)
        features = tuple({"brightness_dn": float(f.brightness_dn), "contrast_dn": float(f.contrast_dn),
                          "correlation": float(f.correlation), "status": str(f.status)} for f in result.features)
        return EstimatorOutput(velocity_east_mps=float(result.velocity_east_mps),
                               velocity_north_mps=float(result.velocity_north_mps), valid=bool(result.valid),
                               reason=str(result.reason), features=features,
                               velocity_uncertainty_mps=float(result.velocity_uncertainty_mps))


class PythonEstimator:
    """A ``package.module:function`` called in this process with the case's :class:`EstimatorInputs`."""

    def __init__(self, name: str, target: str, parameters: dict):
        module_name, function_name = target.split(":")
        self.name = name
        self.function = getattr(importlib.import_module(module_name), function_name)
        self.parameters = dict(parameters)

    def estimate(self, inputs: EstimatorInputs) -> EstimatorOutput:
        return validate_output(self.function(replace(inputs, parameters=copy.deepcopy(self.parameters))))


def build_estimator(spec: EstimatorSpec):
    """The estimator object of a spec (built once per worker process by the campaign)."""
    if spec.kind == "reference":
        return ReferenceEstimator(spec.name, spec.parameters)
    if spec.kind == "python" and not spec.isolate:
        return PythonEstimator(spec.name, spec.callable, spec.parameters)
    if spec.kind == "python":
        argv = ("{python}", "-m", "estimators.run_python", spec.callable, "--measurements", "{measurements}",
                "--camera", "{camera}", "--flat-field", "{flat_field}", "--parameters", "{parameters}",
                "--output", "{output}", "{images}")
        return CommandEstimator(spec.name, argv, spec.timeout_s, "npy", "npy", spec.parameters)
    return CommandEstimator(spec.name, spec.argv, spec.timeout_s, spec.image_format, spec.flat_field_format,
                            spec.parameters)


@dataclass(frozen=True)
class EstimatorRun:
    """One estimator's outcome on one case: its output, or why there is none (``failure``: the row's
    reason, ``estimator_failed`` or ``implausible``; ``error``: the one-line message); wall time (ms)."""

    name: str
    output: EstimatorOutput | None
    error: str
    elapsed_ms: float
    failure: str = ""


def run_estimator(name: str, estimator, inputs: EstimatorInputs,
                  max_horizontal_speed_mps: float | None = None) -> EstimatorRun:
    """Run ``estimator`` on read-only ``inputs`` and check its answer's plausibility (a valid horizontal
    speed below ``max_horizontal_speed_mps``, None: no bound); any failure is returned as the run's
    ``failure`` and ``error``, never raised: whatever the plug-in raises, ``SystemExit`` and
    ``KeyboardInterrupt`` included, ends here and the worker goes on."""
    started = time.perf_counter()
    failure = "estimator_failed"
    try:
        output = estimator.estimate(read_only_inputs(inputs))
        output = check_plausible(validate_output(output), max_horizontal_speed_mps)
        error, failure = "", ""
    except ImplausibleOutput as exc:
        output, error, failure = None, f"estimator {name}: implausible: {exc}"[:500], "implausible"
    except ContractViolation as exc:
        output, error = None, f"estimator {name}: {exc}"
    except BaseException as exc:  # noqa: B036 -- the plug-in's own crash or exit: recorded, never re-raised
        where = traceback.format_exc(limit=-1).splitlines()
        location = next((line.strip() for line in reversed(where) if line.strip().startswith("File ")), "")
        what = f"{type(exc).__name__}: {exc}" if isinstance(exc, Exception) else repr(exc)
        output, error = None, f"estimator {name}: crashed: {what} | {location}"[:500]
    return EstimatorRun(name, output, error, 1e3 * (time.perf_counter() - started), failure)
