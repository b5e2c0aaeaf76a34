"""The estimator contract: what every velocity estimator gets and must give back.

An estimator sees only what a flight system has. It never imports :mod:`simulator` or :mod:`campaign`
and never receives simulator truth (the campaign passes the true flat field only when a campaign asks
for it with ``[estimator] flat_field = "truth"``, to measure what calibration costs).

Inputs (:class:`EstimatorInputs`)
---------------------------------
``images``
    The descent images in time order (three for DIMES), as the camera reads them out: DN, unsigned
    16-bit integers, shape ``camera.binned_shape`` (256 rows binned on chip x 1024 columns for MER).
``image_times_s``
    Start of each image's exposure (s), equal to ``measurements.images[k].time_s``.
``measurements``
    :class:`flight_interface.measurements.DescentMeasurements`: per image the measured attitude
    (lander body-to-world quaternion w, x, y, z), angular rate, radar altitude, IMU velocity (biased)
    and optionally IMU position and predicted heat-shield offset; the sun direction. World frame x
    east, y north, z up. As JSON: the schema in :mod:`file_formats.measurements_json`.
``camera``
    :class:`flight_interface.camera.Camera`: the camera model as designed (CAHVOR, mounting, timing,
    radiometry, electronics), read from the camera TOML (``camera.source``).
``calibration``
    :class:`flight_interface.calibration.CalibrationProducts`: the flat field (relative response per
    read-out pixel, shape ``camera.binned_shape``, about 1 on axis) or None.
``parameters``
    The estimator's own parameters from its ``[[estimators]]`` entry (a plain dict, JSON types).

Output (:class:`EstimatorOutput`; as JSON an object with these keys)
--------------------------------------------------------------------
``velocity_east_mps``, ``velocity_north_mps`` : number
    Horizontal velocity of the lander at the last image (world frame, m/s). Finite when valid; may be
    ``null`` when not valid.
``valid`` : bool
    True only when the estimator vouches for the velocity.
``reason`` : str
    ``"ok"`` when valid, else a short non-empty code saying why not (the estimator's own vocabulary).
``velocity_uncertainty_mps`` : number, optional
    The estimator's own stated 1-sigma horizontal velocity uncertainty (m/s), stored in the campaign's
    ``velocity_uncertainty_mps`` column (0 when not given or not valid).
``features`` : list of objects, optional
    Per-feature metrics, each with optional numbers ``brightness_dn``, ``contrast_dn``,
    ``correlation`` (paper Table 3) and an optional string ``status`` (``"ok"`` for a feature that
    was used); stored in the campaign's ``feature_*`` columns.

Other keys are allowed and ignored (diagnostics, timings). Anything else is a contract violation
(:class:`ContractViolation`): a missing key, a wrong type, a valid result with a non-finite velocity,
an empty reason, ``valid`` with a reason other than ``"ok"``. The campaign records a violation, a
crash, a non-zero exit or a timeout as *that* estimator's failed result for the case, with the
message; the other estimators' results for the case are kept.

Ways in (``[[estimators]]`` entries of a campaign file, :mod:`estimators.registry`)
----------------------------------------------------------------------------------
``kind = "reference"``  the reference DIMES estimator (:mod:`dimes_velocity`), parameters = its
                        ``EstimatorConfig`` fields; the default when a campaign names no estimator.
``kind = "python"``     ``callable = "package.module:function"``, called as
                        ``function(inputs: EstimatorInputs) -> EstimatorOutput | Mapping``; with
                        ``isolate = true`` it runs in its own process like a command (timeout, crash-proof).
``kind = "command"``    an external program (:mod:`estimators.command`): ``argv`` with placeholders
                        for the image files, the measurements JSON, the camera TOML, the flat field
                        file and the output JSON, and ``timeout_s``; it writes the output JSON above.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from flight_interface.calibration import CalibrationProducts
from flight_interface.camera import Camera
from flight_interface.measurements import DescentMeasurements

FEATURE_METRICS = ("brightness_dn", "contrast_dn", "correlation")
REQUIRED_KEYS = ("velocity_east_mps", "velocity_north_mps", "valid", "reason")


class ContractViolation(Exception):
    """An estimator broke the contract (bad output, crash, non-zero exit, timeout); one-line message."""


@dataclass(frozen=True)
class EstimatorInputs:
    """Everything an estimator receives for one case (see the module docstring)."""

    images: tuple
    image_times_s: np.ndarray
    measurements: DescentMeasurements
    camera: Camera
    calibration: CalibrationProducts = CalibrationProducts()
    parameters: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class EstimatorOutput:
    """An estimator's answer (see the module docstring)."""

    velocity_east_mps: float | None
    velocity_north_mps: float | None
    valid: bool
    reason: str
    features: tuple = ()          # of dicts with (some of) FEATURE_METRICS, floats, and "status", str
    velocity_uncertainty_mps: float | None = None


def _number(data: Mapping, key: str, allow_null: bool) -> float | None:
    value = data[key]
    if value is None and allow_null:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ContractViolation(f"field {key!r} must be a number; got {type(value).__name__} {value!r}"[:200])
    value = float(value)
    if not allow_null and not math.isfinite(value):
        raise ContractViolation(f"field {key!r} must be finite when valid; got {value!r}")
    return value if math.isfinite(value) else None


def validate_output(result: Any) -> EstimatorOutput:
    """Check an estimator's answer (an :class:`EstimatorOutput` or a mapping such as parsed JSON) and
    return it as an :class:`EstimatorOutput`; raise :class:`ContractViolation` naming the field."""
    data: Mapping[str, Any]
    if isinstance(result, EstimatorOutput):
        data = {"velocity_east_mps": result.velocity_east_mps, "velocity_north_mps": result.velocity_north_mps,
                "valid": result.valid, "reason": result.reason, "features": list(result.features),
                "velocity_uncertainty_mps": result.velocity_uncertainty_mps}
    elif isinstance(result, Mapping):
        data = result
    else:
        raise ContractViolation(f"result must be an object with {', '.join(REQUIRED_KEYS)}; got {type(result).__name__}")
    missing = [key for key in REQUIRED_KEYS if key not in data]
    if missing:
        raise ContractViolation(f"missing field{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))}")
    valid = data["valid"]
    if not isinstance(valid, (bool, np.bool_)):
        raise ContractViolation(f"field 'valid' must be true or false; got {type(valid).__name__} {valid!r}"[:200])
    valid = bool(valid)
    reason = data["reason"]
    if not isinstance(reason, str) or not reason.strip():
        raise ContractViolation(f"field 'reason' must be a non-empty string; got {reason!r}"[:200])
    if valid and reason != "ok":
        raise ContractViolation(f"field 'reason' must be 'ok' when valid; got {reason!r}"[:200])
    east = _number(data, "velocity_east_mps", allow_null=not valid)
    north = _number(data, "velocity_north_mps", allow_null=not valid)
    features = data.get("features", None)
    if features is None:
        features = []
    if not isinstance(features, (list, tuple)):
        raise ContractViolation(f"field 'features' must be a list of objects; got {type(features).__name__}")
    checked = []
    for index, feature in enumerate(features):
        if not isinstance(feature, Mapping):
            raise ContractViolation(f"features[{index}] must be an object; got {type(feature).__name__}")
        record: dict[str, float | str] = {}
        for key in FEATURE_METRICS:
            if key in feature and feature[key] is not None:
                value = feature[key]
                if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                    raise ContractViolation(f"features[{index}].{key} must be a number; got {value!r}"[:200])
                record[key] = float(value)
        if feature.get("status") is not None:
            if not isinstance(feature["status"], str):
                raise ContractViolation(f"features[{index}].status must be a string; got {feature['status']!r}"[:200])
            record["status"] = feature["status"]
        checked.append(record)
    uncertainty = None
    if data.get("velocity_uncertainty_mps") is not None:
        uncertainty = _number(data, "velocity_uncertainty_mps", allow_null=True)
        if uncertainty is not None and uncertainty < 0:
            raise ContractViolation(f"field 'velocity_uncertainty_mps' must be >= 0; got {uncertainty!r}")
    return EstimatorOutput(velocity_east_mps=east, velocity_north_mps=north, valid=valid, reason=reason.strip(),
                           features=tuple(checked), velocity_uncertainty_mps=uncertainty)


def output_to_dict(output: EstimatorOutput) -> dict:
    """The JSON form of an :class:`EstimatorOutput`."""
    return {"velocity_east_mps": output.velocity_east_mps, "velocity_north_mps": output.velocity_north_mps,
            "valid": output.valid, "reason": output.reason, "features": [dict(f) for f in output.features],
            "velocity_uncertainty_mps": output.velocity_uncertainty_mps}
